// Small fixed-size vector algebra for the ray caster (double precision).
#pragma once

#include <cmath>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

namespace craftscan::sim {

struct V3 {
  double x = 0, y = 0, z = 0;
  V3() = default;
  constexpr V3(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
  V3 operator+(const V3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  V3 operator-(const V3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  V3 operator-() const { return {-x, -y, -z}; }
  V3 operator*(double s) const { return {x * s, y * s, z * s}; }
  V3 operator/(double s) const { return {x / s, y / s, z / s}; }
  V3& operator+=(const V3& o) {
    x += o.x;
    y += o.y;
    z += o.z;
    return *this;
  }
  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
};
inline V3 operator*(double s, const V3& v) { return v * s; }
inline V3 Mul(const V3& a, const V3& b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline double Dot(const V3& a, const V3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 Cross(const V3& a, const V3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double Norm(const V3& v) { return std::sqrt(Dot(v, v)); }
inline V3 Normalized(const V3& v) { return v / Norm(v); }
inline V3 Lerp(const V3& a, const V3& b, double t) { return a + (b - a) * t; }
inline V3 FromCv(const cv::Vec3d& v) { return {v[0], v[1], v[2]}; }
inline cv::Vec3d ToCv(const V3& v) { return {v.x, v.y, v.z}; }

struct M3 {
  double m[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major
  V3 operator*(const V3& v) const {
    return {m[0] * v.x + m[1] * v.y + m[2] * v.z, m[3] * v.x + m[4] * v.y + m[5] * v.z,
            m[6] * v.x + m[7] * v.y + m[8] * v.z};
  }
  M3 operator*(const M3& o) const {
    M3 r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        r.m[i * 3 + j] = m[i * 3] * o.m[j] + m[i * 3 + 1] * o.m[3 + j] + m[i * 3 + 2] * o.m[6 + j];
    return r;
  }
  M3 Transposed() const {
    M3 r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r.m[i * 3 + j] = m[j * 3 + i];
    return r;
  }
  static M3 FromCv(const cv::Matx33d& a) {
    M3 r;
    for (int i = 0; i < 9; ++i) r.m[i] = a.val[i];
    return r;
  }
  cv::Matx33d ToCv() const {
    cv::Matx33d a;
    for (int i = 0; i < 9; ++i) a.val[i] = m[i];
    return a;
  }
  static M3 RotZ(double angle_rad) {
    const double c = std::cos(angle_rad), s = std::sin(angle_rad);
    M3 r;
    r.m[0] = c;
    r.m[1] = -s;
    r.m[3] = s;
    r.m[4] = c;
    return r;
  }
  static M3 RotX(double angle_rad) {
    const double c = std::cos(angle_rad), s = std::sin(angle_rad);
    M3 r;
    r.m[4] = c;
    r.m[5] = -s;
    r.m[7] = s;
    r.m[8] = c;
    return r;
  }
  static M3 Rodrigues(const cv::Vec3d& rotation_rad) {
    cv::Matx33d a;
    cv::Rodrigues(rotation_rad, a);
    return FromCv(a);
  }
};

// A rigid transform target_from_source: p_target = R·p_source + t.
struct Rigid {
  M3 R;
  V3 t;
  V3 Apply(const V3& p) const { return R * p + t; }
  V3 Rotate(const V3& d) const { return R * d; }
  Rigid Inverse() const {
    Rigid r;
    r.R = R.Transposed();
    r.t = -(r.R * t);
    return r;
  }
  Rigid operator*(const Rigid& o) const { return {R * o.R, R * o.t + t}; }
  cv::Matx44d ToCv() const {
    cv::Matx44d a = cv::Matx44d::eye();
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) a(i, j) = R.m[i * 3 + j];
      a(i, 3) = t[i];
    }
    return a;
  }
  static Rigid FromCv(const cv::Matx44d& a) {
    Rigid r;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r.R.m[i * 3 + j] = a(i, j);
    }
    r.t = {a(0, 3), a(1, 3), a(2, 3)};
    return r;
  }
};

inline double Clamp01(double v) { return v < 0 ? 0 : (v > 1 ? 1 : v); }
inline double SmoothStep(double e0, double e1, double v) {
  const double t = Clamp01((v - e0) / (e1 - e0));
  return t * t * (3 - 2 * t);
}

}  // namespace craftscan::sim
