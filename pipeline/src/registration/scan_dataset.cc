#include "craftscan/pipeline/registration/scan_dataset.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>
#include <utility>

namespace craftscan {
namespace {

constexpr double kMetresToMm = 1000.0;
constexpr double kQuaternionNormTolerance = 1e-3;

bool Fail(std::string* error, std::string message) {
  if (error != nullptr) *error = std::move(message);
  return false;
}

bool ParseFinite(const std::string& text, double* value) {
  std::string_view digits = text;
  if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
  const char* end = digits.data() + digits.size();
  const auto r = std::from_chars(digits.data(), end, *value);
  return r.ec == std::errc() && r.ptr == end && std::isfinite(*value);
}

// Parses 7 pose numbers (tx ty tz qx qy qz qw) into world_from_scan.
bool ParsePose(const std::vector<std::string>& words, std::size_t first, const std::string& at,
               cv::Matx44d* world_from_scan, std::string* error) {
  std::array<double, 7> v{};
  for (std::size_t i = 0; i < 7; ++i) {
    if (!ParseFinite(words[first + i], &v[i])) {
      return Fail(error, at + "value '" + words[first + i] + "' is not a finite number");
    }
  }
  const double norm = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
  if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
    return Fail(error,
                at + "quaternion (qx qy qz qw) has norm " + std::to_string(norm) + ", expected 1");
  }
  // Scanalyze stores the conjugate: p_world = R(q)ᵀ · p_scan + t.
  const cv::Matx33d r = RotationFromQuaternion(v[6], v[3], v[4], v[5]).t();
  *world_from_scan = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*world_from_scan)(i, j) = r(i, j);
    (*world_from_scan)(i, 3) = v[static_cast<std::size_t>(i)] * kMetresToMm;
  }
  return true;
}

bool LoadStanfordScansImpl(const std::string& dir, std::vector<RangeScan>* scans,
                           std::string* error) {
  namespace fs = std::filesystem;
  if (scans == nullptr) return Fail(error, "LoadStanfordScans: null output");
  scans->clear();
  const fs::path conf = fs::path(dir) / "bun.conf";
  std::string where = "'";  // appended, not operator+: dodges a GCC 12 -Wrestrict false positive
  where += conf.string();
  where += "': ";
  std::error_code ec;
  if (!fs::is_regular_file(conf, ec)) return Fail(error, where + "no such file");
  std::ifstream in(conf);
  if (!in) return Fail(error, where + "cannot open");

  std::vector<RangeScan> out;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words_in(line);
    std::vector<std::string> words;
    for (std::string w; words_in >> w;) words.push_back(w);
    if (words.empty() || words[0][0] == '#') continue;
    const std::string at = where + "line " + std::to_string(line_number) + ": ";
    if (words[0] == "camera") {
      if (words.size() != 8) return Fail(error, at + "expected 'camera tx ty tz qx qy qz qw'");
      cv::Matx44d unused;
      if (!ParsePose(words, 1, at, &unused, error)) return false;
    } else if (words[0] == "bmesh") {
      if (words.size() != 9) {
        return Fail(error, at + "expected 'bmesh <file> tx ty tz qx qy qz qw', got " +
                               std::to_string(words.size()) + " fields");
      }
      RangeScan scan;
      scan.name = words[1];
      if (!ParsePose(words, 2, at, &scan.world_from_scan, error)) return false;
      const std::string ply = (fs::path(dir) / scan.name).string();
      std::string why;
      if (!ReadPly(ply, &scan.cloud, &why, kMetresToMm)) {
        return Fail(error, at + "scan '" + scan.name + "': " + why);
      }
      out.push_back(std::move(scan));
    } else {
      return Fail(error, at + "unknown keyword '" + words[0] + "' (expected camera or bmesh)");
    }
  }
  if (in.bad()) return Fail(error, where + "read error");
  if (out.empty()) return Fail(error, where + "no 'bmesh' lines");
  *scans = std::move(out);
  return true;
}

}  // namespace

bool LoadStanfordScans(const std::string& dir, std::vector<RangeScan>* scans, std::string* error) {
  try {
    return LoadStanfordScansImpl(dir, scans, error);
  } catch (const std::exception& e) {
    if (scans != nullptr) scans->clear();
    return Fail(error, "LoadStanfordScans '" + dir + "': " + e.what());
  }
}

cv::Matx33d RotationFromQuaternion(double w, double x, double y, double z) {
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  if (!(n > 0.0)) return cv::Matx33d::eye();
  w /= n;
  x /= n;
  y /= n;
  z /= n;
  return cv::Matx33d(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y));
}

double RotationErrorDeg(const cv::Matx44d& a, const cv::Matx44d& b) {
  const cv::Matx33d ra = a.get_minor<3, 3>(0, 0);
  const cv::Matx33d rb = b.get_minor<3, 3>(0, 0);
  const cv::Matx33d d = ra.t() * rb;
  // atan2 of sin and cos stays accurate near 0 and 180 degrees, unlike acos.
  const double s = 0.5 * std::sqrt((d(2, 1) - d(1, 2)) * (d(2, 1) - d(1, 2)) +
                                   (d(0, 2) - d(2, 0)) * (d(0, 2) - d(2, 0)) +
                                   (d(1, 0) - d(0, 1)) * (d(1, 0) - d(0, 1)));
  const double c = 0.5 * (cv::trace(d) - 1.0);
  return std::atan2(s, c) * 180.0 / M_PI;
}

double TranslationErrorMm(const cv::Matx44d& a, const cv::Matx44d& b) {
  const double dx = a(0, 3) - b(0, 3), dy = a(1, 3) - b(1, 3), dz = a(2, 3) - b(2, 3);
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

cv::Matx44d InvertRigid(const cv::Matx44d& a_from_b) {
  const cv::Matx33d r = a_from_b.get_minor<3, 3>(0, 0);
  const cv::Vec3d t(a_from_b(0, 3), a_from_b(1, 3), a_from_b(2, 3));
  const cv::Matx33d rt = r.t();
  const cv::Vec3d ti = -(rt * t);
  cv::Matx44d b_from_a = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) b_from_a(i, j) = rt(i, j);
    b_from_a(i, 3) = ti[i];
  }
  return b_from_a;
}

cv::Matx44d RelativePose(const cv::Matx44d& world_from_target,
                         const cv::Matx44d& world_from_source) {
  return InvertRigid(world_from_target) * world_from_source;
}

PointCloud TransformCloud(const cv::Matx44d& to_from_cloud, const PointCloud& cloud) {
  PointCloud out = cloud;
  const cv::Matx33d r = to_from_cloud.get_minor<3, 3>(0, 0);
  const cv::Vec3d t(to_from_cloud(0, 3), to_from_cloud(1, 3), to_from_cloud(2, 3));
  for (cv::Vec3f& p : out.points_mm) p = cv::Vec3f(r * cv::Vec3d(p) + t);
  for (cv::Vec3f& n : out.normals) n = cv::Vec3f(r * cv::Vec3d(n));
  return out;
}

}  // namespace craftscan
