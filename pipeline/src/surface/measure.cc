#include "craftscan/pipeline/surface/measure.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <exception>
#include <functional>
#include <nlohmann/json.hpp>
#include <numbers>
#include <numeric>
#include <random>
#include <string_view>
#include <unordered_map>
#include <utility>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;
constexpr std::size_t kMinBoxPoints = 100;

bool Finite(const cv::Vec3f& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}
Vector3d ToEigen(const cv::Vec3f& v) { return Vector3d(v[0], v[1], v[2]); }
Vector3d ToEigen(const cv::Vec3d& v) { return Vector3d(v[0], v[1], v[2]); }
cv::Vec3d ToCv(const Vector3d& v) { return cv::Vec3d(v.x(), v.y(), v.z()); }
cv::Matx33d ToCv(const Matrix3d& m) {
  cv::Matx33d out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out(r, c) = m(r, c);
  return out;
}

// ------------------------------------------------------------ oriented box --

// Lower and upper trimmed quantiles of `values` (reordered).
std::pair<double, double> TrimmedRange(std::vector<double>& values, double trim) {
  const std::size_t n = values.size();
  const auto k = static_cast<std::size_t>(std::floor(trim * static_cast<double>(n)));
  const std::size_t lo = std::min(k, n - 1), hi = n - 1 - std::min(k, n - 1);
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(lo), values.end());
  const double low = values[lo];
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(hi), values.end());
  return {low, values[hi]};
}

struct Extents {
  Vector3d lo, hi;
  double Volume() const { return (hi - lo).prod(); }
};

// The same two quantiles of the points' projections on `axis`, in one pass
// for a small trim: the k + 1 smallest in a max-heap and the k + 1 largest
// in a min-heap, so that most points cost a projection and two comparisons
// (the box search evaluates thousands of rotations; the default trim keeps
// k at 20 of 20 000 points). The values are the order statistics
// TrimmedRange selects, bit for bit.
std::pair<double, double> TrimmedProjection(const std::vector<Vector3d>& pts, const Vector3d& axis,
                                            std::size_t k, std::vector<double>* low,
                                            std::vector<double>* high) {
  const std::size_t m = k + 1;
  low->clear();
  high->clear();
  for (std::size_t i = 0; i < m; ++i) {
    const double v = axis.dot(pts[i]);
    low->push_back(v);
    high->push_back(v);
  }
  std::make_heap(low->begin(), low->end());                            // the largest on top
  std::make_heap(high->begin(), high->end(), std::greater<double>());  // the smallest on top
  for (std::size_t i = m; i < pts.size(); ++i) {
    const double v = axis.dot(pts[i]);
    if (v < low->front()) {
      std::pop_heap(low->begin(), low->end());
      low->back() = v;
      std::push_heap(low->begin(), low->end());
    }
    if (v > high->front()) {
      std::pop_heap(high->begin(), high->end(), std::greater<double>());
      high->back() = v;
      std::push_heap(high->begin(), high->end(), std::greater<double>());
    }
  }
  return {low->front(), high->front()};
}

Extents TrimmedExtents(const std::vector<Vector3d>& pts, const Matrix3d& axes, double trim,
                       std::vector<double>* buffer) {
  Extents e;
  const std::size_t n = pts.size();
  const auto k = static_cast<std::size_t>(std::floor(trim * static_cast<double>(n)));
  // One pass with heaps while they stay small against the cloud.
  const bool heaps = n > 0 && k <= 256 && 4 * (k + 1) <= n;
  std::vector<double> low, high;
  if (!heaps) buffer->resize(n);
  for (int a = 0; a < 3; ++a) {
    const Vector3d axis = axes.col(a);
    std::pair<double, double> range;
    if (heaps) {
      range = TrimmedProjection(pts, axis, k, &low, &high);
    } else {
      for (std::size_t i = 0; i < n; ++i) (*buffer)[i] = axis.dot(pts[i]);
      range = TrimmedRange(*buffer, trim);
    }
    e.lo[a] = range.first;
    e.hi[a] = range.second;
  }
  return e;
}

Matrix3d AxisRotation(int axis, double angle) {
  return Eigen::AngleAxisd(angle, Vector3d::Unit(axis)).toRotationMatrix();
}

// Local search over rotations (about the box's own axes) minimising the
// trimmed volume, with halving steps.
Matrix3d MinimiseVolume(const std::vector<Vector3d>& pts, Matrix3d axes, double trim,
                        std::vector<double>* buffer, double* volume,
                        double min_step = 0.005 * kDeg) {
  // A tiny floor keeps flat (zero-thickness) inputs comparable.
  auto cost = [&](const Matrix3d& r) {
    const Extents e = TrimmedExtents(pts, r, trim, buffer);
    const Vector3d size = (e.hi - e.lo).cwiseMax(1e-6);
    return size.prod();
  };
  double best = cost(axes);
  for (double step = 8 * kDeg; step > min_step; step *= 0.5) {
    for (int round = 0; round < 40; ++round) {
      bool improved = false;
      for (int a = 0; a < 3; ++a) {
        for (double sign : {1.0, -1.0}) {
          const Matrix3d candidate = axes * AxisRotation(a, sign * step);
          const double c = cost(candidate);
          if (c < best) {
            best = c;
            axes = candidate;
            improved = true;
          }
        }
      }
      if (!improved) break;
    }
  }
  *volume = best;
  return axes;
}

// ------------------------------------------------------------------ planes --

struct FitPlane {
  Vector3d n = Vector3d::UnitZ();
  double d = 0;
  double Distance(const Vector3d& p) const { return n.dot(p) + d; }
};

// Least-squares plane through points[idx]; false when fewer than 3 or
// degenerate.
bool FitLeastSquares(const std::vector<Vector3d>& pts, const std::vector<int>& idx, FitPlane* out) {
  if (idx.size() < 3) return false;
  Vector3d mean = Vector3d::Zero();
  for (int i : idx) mean += pts[static_cast<std::size_t>(i)];
  mean /= static_cast<double>(idx.size());
  Matrix3d cov = Matrix3d::Zero();
  for (int i : idx) {
    const Vector3d q = pts[static_cast<std::size_t>(i)] - mean;
    cov += q * q.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Matrix3d> eig(cov);
  if (eig.info() != Eigen::Success) return false;
  // Smallest eigenvalue first; the plane needs two clearly larger ones.
  if (!(eig.eigenvalues()(1) > 1e-12)) return false;
  Vector3d n = eig.eigenvectors().col(0).normalized();
  if (out->n.dot(n) < 0) n = -n;  // keep the caller's orientation
  out->n = n;
  out->d = -n.dot(mean);
  return true;
}

// Offset of a plane with fixed normal n through points[idx] (least squares).
double FitOffset(const std::vector<Vector3d>& pts, const std::vector<int>& idx, const Vector3d& n) {
  double sum = 0;
  for (int i : idx) sum += n.dot(pts[static_cast<std::size_t>(i)]);
  return -sum / static_cast<double>(idx.size());
}

double RmsDistance(const std::vector<Vector3d>& pts, const std::vector<int>& idx,
                   const FitPlane& p) {
  if (idx.empty()) return 0;
  double sum = 0;
  for (int i : idx) sum += std::pow(p.Distance(pts[static_cast<std::size_t>(i)]), 2);
  return std::sqrt(sum / static_cast<double>(idx.size()));
}

// The measurement's working set: finite points, their (unsigned) normals, and
// whether each normal is known.
struct Points {
  std::vector<Vector3d> p;
  std::vector<Vector3d> n;
  std::vector<char> has_n;

  bool NormalAgrees(std::size_t i, const Vector3d& normal, double cos_tol) const {
    return !has_n[i] || std::abs(n[i].dot(normal)) >= cos_tol;
  }
};

// PCA normals within `radius` (hash grid); points with fewer than 5
// neighbours get no normal.
void EstimateNormals(Points* points, double radius) {
  const double inv = 1.0 / radius;
  auto cell_of = [&](const Vector3d& p) {
    return Eigen::Vector3i(static_cast<int>(std::floor(p.x() * inv)),
                           static_cast<int>(std::floor(p.y() * inv)),
                           static_cast<int>(std::floor(p.z() * inv)));
  };
  auto key_of = [](const Eigen::Vector3i& c) {
    return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(c.x()) & 0x1FFFFF) << 42) |
           (static_cast<std::uint64_t>(static_cast<std::uint32_t>(c.y()) & 0x1FFFFF) << 21) |
           (static_cast<std::uint64_t>(static_cast<std::uint32_t>(c.z()) & 0x1FFFFF));
  };
  std::unordered_map<std::uint64_t, std::vector<int>> grid;
  for (std::size_t i = 0; i < points->p.size(); ++i)
    grid[key_of(cell_of(points->p[i]))].push_back(static_cast<int>(i));
  const double r2 = radius * radius;
  points->n.assign(points->p.size(), Vector3d::UnitZ());
  points->has_n.assign(points->p.size(), 0);
  for (std::size_t i = 0; i < points->p.size(); ++i) {
    const Vector3d& p = points->p[i];
    const Eigen::Vector3i c = cell_of(p);
    Vector3d sum = Vector3d::Zero();
    Matrix3d outer = Matrix3d::Zero();
    int count = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = grid.find(key_of(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == grid.end()) continue;
          for (int j : it->second) {
            const Vector3d q = points->p[static_cast<std::size_t>(j)] - p;
            if (q.squaredNorm() > r2) continue;
            sum += q;
            outer += q * q.transpose();
            ++count;
          }
        }
    if (count < 5) continue;
    const Vector3d mean = sum / count;
    const Matrix3d cov = outer / count - mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Matrix3d> eig(cov);
    if (eig.info() != Eigen::Success) continue;
    points->n[i] = eig.eigenvectors().col(0).normalized();
    points->has_n[i] = 1;
  }
}

// Inliers among `candidates`: |distance| < gate and agreeing normals.
std::vector<int> Inliers(const Points& points, const std::vector<int>& candidates,
                         const FitPlane& plane, double gate, double cos_tol) {
  std::vector<int> out;
  for (int i : candidates) {
    const auto k = static_cast<std::size_t>(i);
    if (std::abs(plane.Distance(points.p[k])) < gate && points.NormalAgrees(k, plane.n, cos_tol))
      out.push_back(i);
  }
  return out;
}

// Least-squares refits alternating with re-gating.
void RefinePlane(const Points& points, const std::vector<int>& candidates, double gate,
                 double cos_tol, FitPlane* plane, std::vector<int>* inliers) {
  *inliers = Inliers(points, candidates, *plane, gate, cos_tol);
  for (int it = 0; it < 3; ++it) {
    FitPlane fitted = *plane;
    if (!FitLeastSquares(points.p, *inliers, &fitted)) return;
    *plane = fitted;
    *inliers = Inliers(points, candidates, *plane, gate, cos_tol);
  }
}

struct Detected {
  FitPlane plane;
  std::vector<int> inliers;
};

// Sequential RANSAC: the best plane of the remaining points, refined and
// removed, until no plane has `min_points` inliers.
std::vector<Detected> DetectPlanes(const Points& points, const std::vector<int>& active,
                                   const BoxMeasureOptions& o, std::size_t min_points) {
  std::mt19937_64 rng(o.seed);
  const double cos_tol = std::cos(o.normal_angle_deg * kDeg);
  std::vector<int> remaining = active;
  std::vector<Detected> found;
  while (static_cast<int>(found.size()) < o.max_planes && remaining.size() >= min_points) {
    // Hypotheses are scored on a random subset.
    std::vector<int> subset = remaining;
    if (subset.size() > static_cast<std::size_t>(o.ransac_sample_points)) {
      std::shuffle(subset.begin(), subset.end(), rng);
      subset.resize(static_cast<std::size_t>(o.ransac_sample_points));
    }
    std::uniform_int_distribution<std::size_t> pick(0, subset.size() - 1);
    FitPlane best;
    std::size_t best_score = 0;
    for (int it = 0; it < o.ransac_iterations; ++it) {
      const auto a = static_cast<std::size_t>(subset[pick(rng)]);
      const auto b = static_cast<std::size_t>(subset[pick(rng)]);
      const auto c = static_cast<std::size_t>(subset[pick(rng)]);
      const Vector3d cross = (points.p[b] - points.p[a]).cross(points.p[c] - points.p[a]);
      const double norm = cross.norm();
      if (!(norm > 1e-9)) continue;
      FitPlane h;
      h.n = cross / norm;
      h.d = -h.n.dot(points.p[a]);
      if (!points.NormalAgrees(a, h.n, cos_tol) || !points.NormalAgrees(b, h.n, cos_tol) ||
          !points.NormalAgrees(c, h.n, cos_tol))
        continue;
      std::size_t score = 0;
      for (int i : subset) {
        const auto k = static_cast<std::size_t>(i);
        if (std::abs(h.Distance(points.p[k])) < o.plane_distance_mm &&
            points.NormalAgrees(k, h.n, cos_tol))
          ++score;
      }
      if (score > best_score) {
        best_score = score;
        best = h;
      }
    }
    if (best_score < 3) break;
    Detected d;
    d.plane = best;
    RefinePlane(points, remaining, o.plane_distance_mm, cos_tol, &d.plane, &d.inliers);
    if (d.inliers.size() < min_points) break;
    std::vector<char> taken(points.p.size(), 0);
    for (int i : d.inliers) taken[static_cast<std::size_t>(i)] = 1;
    std::vector<int> rest;
    rest.reserve(remaining.size() - d.inliers.size());
    for (int i : remaining)
      if (!taken[static_cast<std::size_t>(i)]) rest.push_back(i);
    remaining.swap(rest);
    found.push_back(std::move(d));
  }
  std::stable_sort(found.begin(), found.end(), [](const Detected& a, const Detected& b) {
    return a.inliers.size() > b.inliers.size();
  });
  return found;
}

// Angle of a pair of directions from the nearest of parallel/orthogonal, deg.
double OrthogonalityErrorDeg(const Vector3d& a, const Vector3d& b) {
  const double angle = std::acos(std::clamp(std::abs(a.dot(b)), 0.0, 1.0)) / kDeg;  // 0..90
  return std::min(angle, 90 - angle);
}

// A box face in slot (axis g, side s).
struct Face {
  FitPlane plane;
  std::vector<int> inliers;
  bool given = false;
  bool present = false;
};

const char* kSlotNames[6] = {"-axis0", "+axis0", "-axis1", "+axis1", "-axis2", "+axis2"};

struct Line {
  Vector3d point, dir;  // dir unit
};

// Intersection line of two planes, its point closest to `near`.
bool IntersectPlanes(const FitPlane& a, const FitPlane& b, const Vector3d& near, Line* line) {
  Vector3d dir = a.n.cross(b.n);
  const double norm = dir.norm();
  if (!(norm > 1e-6)) return false;
  dir /= norm;
  Matrix3d m;
  m.row(0) = a.n;
  m.row(1) = b.n;
  m.row(2) = dir;
  const Vector3d rhs(-a.d, -b.d, dir.dot(near));
  line->point = m.colPivHouseholderQr().solve(rhs);
  line->dir = dir;
  return line->point.allFinite();
}

// Midpoint of the closest points of two lines.
Vector3d ClosestMidpoint(const Line& l1, const Line& l2) {
  const Vector3d w = l1.point - l2.point;
  const double b = l1.dir.dot(l2.dir), d = l1.dir.dot(w), e = l2.dir.dot(w);
  const double den = 1 - b * b;
  double s = 0, t = 0;
  if (den > 1e-12) {
    s = (b * e - d) / den;
    t = (e - b * d) / den;
  } else {
    t = e;
  }
  return 0.5 * ((l1.point + s * l1.dir) + (l2.point + t * l2.dir));
}

// Centre and radius of the circle through a, b, c; false when (nearly)
// collinear.
bool Circumcircle(const Vector3d& a, const Vector3d& b, const Vector3d& c, Vector3d* centre,
                  double* radius) {
  const Vector3d u = a - c, v = b - c;
  const Vector3d w = u.cross(v);
  const double w2 = w.squaredNorm();
  const double scale = std::max(u.squaredNorm(), v.squaredNorm());
  if (!(w2 > 1e-10 * scale * scale) || !(scale > 0)) return false;
  const Vector3d offset = (u.squaredNorm() * v - v.squaredNorm() * u).cross(w) / (2 * w2);
  *centre = c + offset;
  *radius = offset.norm();
  return centre->allFinite();
}

Vector3d SolveVertex(const FitPlane& a, const FitPlane& b, const FitPlane& c, double* det) {
  Matrix3d m;
  m.row(0) = a.n;
  m.row(1) = b.n;
  m.row(2) = c.n;
  *det = m.determinant();
  return m.colPivHouseholderQr().solve(Vector3d(-a.d, -b.d, -c.d));
}

constexpr auto kFailed = BoxMeasurement::Status::kFailed;
constexpr std::string_view kWhere = "MeasureBox: ";

Plane ToPlane(const FitPlane& p, std::size_t inliers, double rms, bool given) {
  Plane out;
  out.normal = ToCv(p.n);
  out.offset_mm = p.d;
  out.inliers = inliers;
  out.rms_mm = rms;
  out.given = given;
  return out;
}

// Planes grouped by direction: up to three mutually orthogonal axes, two
// face slots per axis (slot 2g+1 along +axes[g], 2g against it).
struct FaceGroups {
  std::vector<Vector3d> axes;
  std::array<Face, 6> faces;

  // Puts `plane` in the slot of its axis (within cos_tol), or starts a new
  // axis when it is orthogonal (within sin_tol) to all so far. Returns 1 when
  // placed, 0 when the slot already holds a (larger, earlier) plane, -1 for
  // an oblique plane or a fourth direction. A `given` plane always wins.
  int Place(const FitPlane& plane, const std::vector<int>* inliers, bool given, double cos_tol,
            double sin_tol) {
    for (std::size_t g = 0; g < axes.size(); ++g) {
      const double c = plane.n.dot(axes[g]);
      if (std::abs(c) < cos_tol) continue;
      Face& f = faces[2 * g + (c > 0 ? 1 : 0)];
      if (f.present && !given) return 0;  // the slot has a larger plane
      f.plane = plane;
      f.inliers = inliers ? *inliers : std::vector<int>{};
      f.given = given;
      f.present = true;
      return 1;
    }
    for (const Vector3d& a : axes)
      if (std::abs(plane.n.dot(a)) > sin_tol) return -1;  // oblique
    if (axes.size() >= 3) return -1;
    axes.push_back(plane.n);
    Face& f = faces[2 * (axes.size() - 1) + 1];
    f.plane = plane;
    f.inliers = inliers ? *inliers : std::vector<int>{};
    f.given = given;
    f.present = true;
    return 1;
  }
};

// The working set: finite points, normals where finite and non-zero.
Points WorkingSet(const PointCloud& cloud) {
  Points points;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!Finite(cloud.points_mm[i])) continue;
    points.p.push_back(ToEigen(cloud.points_mm[i]));
    Vector3d n = Vector3d::UnitZ();
    char has = 0;
    if (cloud.HasNormals() && Finite(cloud.normals[i])) {
      n = ToEigen(cloud.normals[i]);
      if (n.norm() > 1e-6) {
        n.normalize();
        has = 1;
      }
    }
    points.n.push_back(n);
    points.has_n.push_back(has);
  }
  return points;
}

// The given base plane (if any), turned so that its normal points away from
// most points (the box stands on it), and in *active the points above it by
// more than base_exclusion_mm (all points without a base).
std::optional<FitPlane> OrientBasePlane(const BoxMeasureOptions& o, const Points& points,
                                        std::vector<int>* active) {
  if (o.base_plane) {
    FitPlane b;
    const double norm = cv::norm(o.base_plane->normal);
    b.n = ToEigen(o.base_plane->normal) / norm;
    b.d = o.base_plane->offset_mm / norm;
    std::size_t above = 0;
    for (const Vector3d& p : points.p) above += b.Distance(p) > 0 ? 1 : 0;
    if (2 * above > points.p.size()) {  // the box is on the + side: outward is −n
      b.n = -b.n;
      b.d = -b.d;
    }
    for (std::size_t i = 0; i < points.p.size(); ++i)
      if (-b.Distance(points.p[i]) > o.base_exclusion_mm) active->push_back(static_cast<int>(i));
    return b;
  }
  active->resize(points.p.size());
  std::iota(active->begin(), active->end(), 0);
  return std::nullopt;
}

// Re-gathers face s's inliers from all active points, leaving out the edge
// zones (within edge_margin_mm of the neighbouring faces), with a normal gate
// adapted to the normals' noise, and refits its plane. False when fewer than
// 3 points remain.
bool RefitFace(const Points& points, const std::vector<int>& active, const BoxMeasureOptions& o,
               double cos_normal, std::size_t s, std::array<Face, 6>* faces_io) {
  std::array<Face, 6>& faces = *faces_io;
  Face& f = faces[s];
  std::vector<int> candidates;
  for (int i : active) {
    const Vector3d& p = points.p[static_cast<std::size_t>(i)];
    bool inside = true;
    for (std::size_t t = 0; t < 6 && inside; ++t)
      if (t != s && t / 2 != s / 2) inside = -faces[t].plane.Distance(p) > o.edge_margin_mm;
    if (inside) candidates.push_back(i);
  }
  std::vector<int> inliers = Inliers(points, candidates, f.plane, o.plane_distance_mm, cos_normal);
  // Tighter normal gate: relief walls within the distance gate (shallow
  // cuts) would pull the face inwards; it adapts to the normals' noise.
  std::vector<double> angles;
  for (int i : inliers) {
    const auto q = static_cast<std::size_t>(i);
    if (points.has_n[q])
      angles.push_back(std::acos(std::min(1.0, std::abs(points.n[q].dot(f.plane.n)))) / kDeg);
  }
  if (!angles.empty()) {
    std::nth_element(angles.begin(),
                     angles.begin() + static_cast<std::ptrdiff_t>(angles.size() / 2), angles.end());
    const double gate_deg = std::min(
        o.normal_angle_deg, std::max(o.fit_normal_angle_deg, 2.5 * angles[angles.size() / 2]));
    inliers = Inliers(points, inliers, f.plane, o.plane_distance_mm, std::cos(gate_deg * kDeg));
  }
  if (inliers.size() < 3) return false;
  FitPlane fitted = f.plane;
  if (FitLeastSquares(points.p, inliers, &fitted)) f.plane = fitted;
  // The face's outer layer: relief below it that the cameras smoothed
  // (a chip-cut groove matched as a shallow dish) lies within the distance
  // gate with the face's normal, on the inner side only; noise lies on both.
  // σ from the residuals on the outer side, a gate of outer_layer_sigmas·σ
  // on both sides, refit; until the inliers no longer change.
  for (int round = 0; o.outer_layer_sigmas > 0 && round < 10; ++round) {
    double outer2 = 0;
    std::size_t outer = 0;
    for (int i : inliers) {
      const double r = f.plane.Distance(points.p[static_cast<std::size_t>(i)]);
      if (r > 0) {
        outer2 += r * r;
        ++outer;
      }
    }
    if (outer < 3) break;
    const double gate = o.outer_layer_sigmas * std::sqrt(outer2 / static_cast<double>(outer));
    std::vector<int> kept;
    for (int i : inliers)
      if (std::abs(f.plane.Distance(points.p[static_cast<std::size_t>(i)])) <= gate)
        kept.push_back(i);
    if (kept.size() < 3 || kept.size() == inliers.size()) break;
    inliers = std::move(kept);
    fitted = f.plane;
    if (FitLeastSquares(points.p, inliers, &fitted)) f.plane = fitted;
  }
  f.inliers = std::move(inliers);
  return true;
}

// Sorts the box axes by extent (distance between opposite faces along the
// axis through the centre), descending, reordering the faces with them; keeps
// the frame right-handed. Returns the sorted frame (columns = axes).
Matrix3d SortAxesByExtent(const Matrix3d& frame, const Vector3d& centre,
                          std::array<Face, 6>* faces_io) {
  std::array<Face, 6>& faces = *faces_io;
  std::array<double, 3> extent{};
  for (int g = 0; g < 3; ++g) {
    const Vector3d a = frame.col(g);
    const auto& plus = faces[static_cast<std::size_t>(2 * g + 1)].plane;
    const auto& minus = faces[static_cast<std::size_t>(2 * g)].plane;
    const double tp = -plus.Distance(centre) / plus.n.dot(a);
    const double tm = -minus.Distance(centre) / minus.n.dot(a);
    extent[static_cast<std::size_t>(g)] = tp - tm;
  }
  std::array<int, 3> order{0, 1, 2};
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    return extent[static_cast<std::size_t>(a)] > extent[static_cast<std::size_t>(b)];
  });
  Matrix3d sorted;
  std::array<Face, 6> sorted_faces;
  for (int k = 0; k < 3; ++k) {
    const auto g = static_cast<std::size_t>(order[static_cast<std::size_t>(k)]);
    sorted.col(k) = frame.col(static_cast<int>(g));
    sorted_faces[static_cast<std::size_t>(2 * k)] = faces[2 * g];
    sorted_faces[static_cast<std::size_t>(2 * k + 1)] = faces[2 * g + 1];
  }
  if (sorted.determinant() < 0) {
    sorted.col(2) = -sorted.col(2);
    std::swap(sorted_faces[4], sorted_faces[5]);
  }
  faces = std::move(sorted_faces);

  return sorted;
}

// The fitted planes and their RMS residual (the given base excluded).
void RecordFacePlanes(const Points& points, const std::array<Face, 6>& faces, BoxMeasurement* m) {
  double rms_sum = 0;
  std::size_t rms_count = 0;
  for (const Face& f : faces) {
    const double rms = RmsDistance(points.p, f.inliers, f.plane);
    m->planes.push_back(ToPlane(f.plane, f.inliers.size(), rms, f.given));
    if (!f.given) {
      rms_sum += rms * rms * static_cast<double>(f.inliers.size());
      rms_count += f.inliers.size();
    }
    m->face_points += f.inliers.size();
  }
  m->face_rms_mm = rms_count ? std::sqrt(rms_sum / static_cast<double>(rms_count)) : 0;
}

// A local plane for one side (`side`) of the edge from `vertex` along `t`
// (reach mm long), fitted to the band of points next to the edge; the face's
// own plane when the band is too thin or the side is the given base.
FitPlane LocalEdgePlane(const Points& points, const std::vector<int>& active,
                        const BoxMeasureOptions& o, double cos_normal, const Face& side,
                        const Face& across, const Vector3d& vertex, const Vector3d& t,
                        double reach) {
  if (side.given) return side.plane;
  std::vector<int> band;
  for (int i : active) {
    const auto q = static_cast<std::size_t>(i);
    const Vector3d& p = points.p[q];
    const double u = (p - vertex).dot(t);
    if (u < o.edge_band_min_mm || u > reach) continue;
    const double w = -across.plane.Distance(p);
    if (w < o.edge_band_min_mm || w > o.edge_band_max_mm) continue;
    if (std::abs(side.plane.Distance(p)) >= o.plane_distance_mm) continue;
    if (!points.NormalAgrees(q, side.plane.n, cos_normal)) continue;
    band.push_back(i);
  }
  if (band.size() < static_cast<std::size_t>(o.min_edge_points)) return side.plane;
  FitPlane local = side.plane;
  if (!FitLeastSquares(points.p, band, &local)) return side.plane;
  // One re-gate about the local plane (noise, stray relief).
  std::vector<int> kept;
  for (int i : band)
    if (std::abs(local.Distance(points.p[static_cast<std::size_t>(i)])) < o.plane_distance_mm)
      kept.push_back(i);
  FitPlane refit = local;
  if (kept.size() >= static_cast<std::size_t>(o.min_edge_points) &&
      FitLeastSquares(points.p, kept, &refit))
    local = refit;
  return local;
}

// Point-circle refinement: three independently fitted edge lines per vertex,
// the vertex the centre of the circle through their closest points. Returns
// -1, or the vertex whose edge line is degenerate.
int PointCircleVertices(const Points& points, const std::vector<int>& active,
                        const BoxMeasureOptions& o, double cos_normal,
                        const std::array<Face, 6>& faces, BoxMeasurement* m) {
  auto face_of = [&](int vertex, int axis) -> const Face& {
    return faces[static_cast<std::size_t>(2 * axis + ((vertex >> axis) & 1))];
  };
  for (int v = 0; v < 8; ++v) {
    const Vector3d vertex = ToEigen(m->vertices_mm[static_cast<std::size_t>(v)]);
    std::array<Line, 3> lines;  // lines[m]: the edge along axis m
    for (int axis = 0; axis < 3; ++axis) {
      const int j = (axis + 1) % 3, k = (axis + 2) % 3;
      const Face& fj = face_of(v, j);
      const Face& fk = face_of(v, k);
      const Vector3d other = ToEigen(m->vertices_mm[static_cast<std::size_t>(v ^ (1 << axis))]);
      const double length = (other - vertex).norm();
      const Vector3d t = (other - vertex) / length;
      const double reach = std::min(o.edge_local_length_mm, 0.45 * length);
      const FitPlane pj = LocalEdgePlane(points, active, o, cos_normal, fj, fk, vertex, t, reach);
      const FitPlane pk = LocalEdgePlane(points, active, o, cos_normal, fk, fj, vertex, t, reach);
      Line line;
      if (!IntersectPlanes(pj, pk, vertex, &line) &&
          !IntersectPlanes(fj.plane, fk.plane, vertex, &line))
        return v;
      lines[static_cast<std::size_t>(axis)] = line;
    }
    const Vector3d a = ClosestMidpoint(lines[0], lines[1]);
    const Vector3d b = ClosestMidpoint(lines[1], lines[2]);
    const Vector3d c = ClosestMidpoint(lines[2], lines[0]);
    Vector3d centre_v;
    double radius = 0;
    const double longest = std::max({(a - b).norm(), (b - c).norm(), (c - a).norm()});
    bool fallback = !Circumcircle(a, b, c, &centre_v, &radius) || radius > o.max_circle_radius_mm ||
                    radius > longest;
    if (fallback) {
      centre_v = (a + b + c) / 3;
      radius = std::max({(a - centre_v).norm(), (b - centre_v).norm(), (c - centre_v).norm()});
    }
    m->refined_vertices_mm.push_back(ToCv(centre_v));
    m->circle_radius_mm.push_back(radius);
    m->circle_fallback.push_back(fallback);
  }

  return -1;
}

// The 12 edges (along axis 0, then 1, then 2; a < b) and the box dimensions
// (mean edge length per axis).
void MeasureEdges(const BoxMeasureOptions& o, BoxMeasurement* m) {
  std::array<double, 3> dims_sum{};
  for (int axis = 0; axis < 3; ++axis) {
    for (int v = 0; v < 8; ++v) {
      if (v & (1 << axis)) continue;
      BoxEdge e;
      e.a = v;
      e.b = v | (1 << axis);
      e.axis = axis;
      e.intersection_length_mm = cv::norm(m->vertices_mm[static_cast<std::size_t>(e.b)] -
                                          m->vertices_mm[static_cast<std::size_t>(e.a)]);
      e.circle_length_mm = cv::norm(m->refined_vertices_mm[static_cast<std::size_t>(e.b)] -
                                    m->refined_vertices_mm[static_cast<std::size_t>(e.a)]);
      e.length_mm = o.vertex_method == VertexMethod::kPointCircle ? e.circle_length_mm
                                                                  : e.intersection_length_mm;
      dims_sum[static_cast<std::size_t>(axis)] += e.length_mm / 4;
      m->edges.push_back(e);
    }
  }
  m->dims_mm = cv::Vec3d(dims_sum[0], dims_sum[1], dims_sum[2]);
}

// The smallest trimmed-volume box's axes over all orientations.
Matrix3d SmallestBoxAxes(const std::vector<Vector3d>& search, double trim,
                         std::vector<double>* buffer_ptr) {
  std::vector<double>& buffer = *buffer_ptr;
  Vector3d mean = Vector3d::Zero();
  for (const Vector3d& p : search) mean += p;
  mean /= static_cast<double>(search.size());
  Matrix3d cov = Matrix3d::Zero();
  for (const Vector3d& p : search) cov += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Matrix3d> eig(cov);
  Matrix3d pca = eig.info() == Eigen::Success ? eig.eigenvectors() : Matrix3d::Identity();
  if (!pca.allFinite()) pca = Matrix3d::Identity();
  if (pca.determinant() < 0) pca.col(2) = -pca.col(2);
  // The volume has several local minima: PCA is ambiguous for symmetric
  // shapes (a cube), and an irregular figure whose two shorter sides are
  // alike has boxes of nearly equal volume in different orientations (a
  // search from PCA alone settled in different ones for a scan and its
  // truth, their extents a millimetre apart). So the search starts from
  // PCA turned by 0°, 30° and 60° about each of its axes (a box repeats
  // every 90°), 27 starts, each searched on a subset of the points down to
  // 0.5°; the three best then run to the end on all the search points.
  constexpr std::size_t kCoarsePoints = 2000;  // every k-th point: evenly over the cloud
  std::vector<Vector3d> coarse;
  const std::size_t stride = (search.size() + kCoarsePoints - 1) / kCoarsePoints;
  for (std::size_t i = 0; i < search.size(); i += stride) coarse.push_back(search[i]);
  std::vector<std::pair<double, Matrix3d>> starts;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b)
      for (int c = 0; c < 3; ++c) {
        const Matrix3d initial = pca * AxisRotation(2, c * kPi / 6) * AxisRotation(1, b * kPi / 6) *
                                 AxisRotation(0, a * kPi / 6);
        double volume = 0;
        const Matrix3d axes = MinimiseVolume(coarse, initial, trim, &buffer, &volume, 0.5 * kDeg);
        starts.emplace_back(volume, axes);
      }
  std::stable_sort(starts.begin(), starts.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  Matrix3d best_axes = pca;
  double best_volume = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < std::min<std::size_t>(3, starts.size()); ++k) {
    double volume = 0;
    const Matrix3d axes = MinimiseVolume(search, starts[k].second, trim, &buffer, &volume);
    if (volume < best_volume * (1 - 1e-9)) {
      best_volume = volume;
      best_axes = axes;
    }
  }
  return best_axes;
}

// The axes of the upright box: the third along `up` (unit), the first two
// about it where the trimmed footprint's area is least: every 1° of a
// quarter turn (the footprint's box repeats every 90°), then the best three
// refined with halving steps down to 0.005°.
Matrix3d UprightAxes(const std::vector<Vector3d>& search, const Vector3d& up, double trim,
                     std::vector<double>* buffer) {
  const Vector3d e1 = up.unitOrthogonal();
  const Vector3d e2 = up.cross(e1);
  const auto axes_at = [&](double yaw) {
    Matrix3d r;
    r.col(0) = std::cos(yaw) * e1 + std::sin(yaw) * e2;
    r.col(1) = up.cross(r.col(0));
    r.col(2) = up;
    return r;
  };
  const auto area = [&](double yaw) {
    const Extents e = TrimmedExtents(search, axes_at(yaw), trim, buffer);
    const Vector3d size = (e.hi - e.lo).cwiseMax(1e-6);
    return size[0] * size[1];
  };
  std::vector<std::pair<double, double>> grid;  // (area, yaw)
  for (int deg = 0; deg < 90; ++deg) grid.emplace_back(area(deg * kDeg), deg * kDeg);
  std::stable_sort(grid.begin(), grid.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  double best_yaw = grid[0].second, best_area = grid[0].first;
  for (std::size_t k = 0; k < std::min<std::size_t>(3, grid.size()); ++k) {
    double yaw = grid[k].second, value = grid[k].first;
    for (double step = 0.5 * kDeg; step > 0.005 * kDeg; step *= 0.5) {
      for (bool moved = true; moved;) {
        moved = false;
        for (double next : {yaw - step, yaw + step}) {
          const double a = area(next);
          if (a < value * (1 - 1e-12)) {
            value = a;
            yaw = next;
            moved = true;
          }
        }
      }
    }
    if (value < best_area * (1 - 1e-9)) {
      best_area = value;
      best_yaw = yaw;
    }
  }
  return axes_at(best_yaw);
}

}  // namespace

// -------------------------------------------------------------- options ----

const char* ToString(VertexMethod method) {
  switch (method) {
    case VertexMethod::kPlaneIntersection:
      return "plane_intersection";
    case VertexMethod::kPointCircle:
      return "point_circle";
  }
  return "unknown";
}

bool VertexMethodFromString(const std::string& text, VertexMethod* method) {
  for (VertexMethod m : {VertexMethod::kPlaneIntersection, VertexMethod::kPointCircle}) {
    if (text == ToString(m)) {
      if (method) *method = m;
      return true;
    }
  }
  return false;
}

bool OrientedBoxOptions::IsValid(std::string* why) const {
  if (!(trim_fraction >= 0 && trim_fraction < 0.2))
    return Fail(why, "OrientedBoxOptions.trim_fraction must be within [0, 0.2)");
  if (max_search_points < 100)
    return Fail(why, "OrientedBoxOptions.max_search_points must be >= 100");
  if (up && !(std::isfinite((*up)[0]) && std::isfinite((*up)[1]) && std::isfinite((*up)[2]) &&
              cv::norm(*up) > 1e-9))
    return Fail(why, "OrientedBoxOptions.up must be finite and non-zero");
  return true;
}

bool BoxMeasureOptions::IsValid(std::string* why) const {
  if (!(outer_layer_sigmas == 0 || (outer_layer_sigmas >= 1 && outer_layer_sigmas <= 10)))
    return Fail(why, "BoxMeasureOptions.outer_layer_sigmas must be 0 (off) or within [1, 10]");
  auto positive = [](double v) { return std::isfinite(v) && v > 0; };
  if (!positive(plane_distance_mm))
    return Fail(why, "BoxMeasureOptions.plane_distance_mm must be finite and > 0");
  if (!(normal_angle_deg > 0 && normal_angle_deg <= 90))
    return Fail(why, "BoxMeasureOptions.normal_angle_deg must be within (0, 90]");
  if (!(fit_normal_angle_deg > 0 && fit_normal_angle_deg <= 90))
    return Fail(why, "BoxMeasureOptions.fit_normal_angle_deg must be within (0, 90]");
  if (!positive(normal_radius_mm))
    return Fail(why, "BoxMeasureOptions.normal_radius_mm must be finite and > 0");
  if (ransac_iterations < 1) return Fail(why, "BoxMeasureOptions.ransac_iterations must be >= 1");
  if (ransac_sample_points < 100)
    return Fail(why, "BoxMeasureOptions.ransac_sample_points must be >= 100");
  if (max_planes < 1) return Fail(why, "BoxMeasureOptions.max_planes must be >= 1");
  if (min_face_points < 3) return Fail(why, "BoxMeasureOptions.min_face_points must be >= 3");
  if (!(min_face_fraction >= 0 && min_face_fraction <= 1))
    return Fail(why, "BoxMeasureOptions.min_face_fraction must be within [0, 1]");
  if (!(orthogonality_tolerance_deg > 0 && orthogonality_tolerance_deg < 45))
    return Fail(why, "BoxMeasureOptions.orthogonality_tolerance_deg must be within (0, 45)");
  if (!(edge_margin_mm >= 0 && std::isfinite(edge_margin_mm)))
    return Fail(why, "BoxMeasureOptions.edge_margin_mm must be finite and >= 0");
  if (base_plane) {
    const cv::Vec3d& n = base_plane->normal;
    if (!(std::isfinite(n[0]) && std::isfinite(n[1]) && std::isfinite(n[2]) &&
          std::isfinite(base_plane->offset_mm)) ||
        !(cv::norm(n) > 1e-9))
      return Fail(why,
                  "BoxMeasureOptions.base_plane must have a finite, non-zero normal and offset");
  }
  if (!(base_exclusion_mm >= 0 && std::isfinite(base_exclusion_mm)))
    return Fail(why, "BoxMeasureOptions.base_exclusion_mm must be finite and >= 0");
  if (!(edge_band_min_mm >= 0 && edge_band_max_mm > edge_band_min_mm &&
        std::isfinite(edge_band_max_mm)))
    return Fail(why,
                "BoxMeasureOptions.edge_band_min_mm/edge_band_max_mm must satisfy 0 <= min < max");
  if (!(edge_local_length_mm > edge_band_min_mm && std::isfinite(edge_local_length_mm)))
    return Fail(why,
                "BoxMeasureOptions.edge_local_length_mm must be finite and > edge_band_min_mm");
  if (min_edge_points < 3) return Fail(why, "BoxMeasureOptions.min_edge_points must be >= 3");
  if (!positive(max_circle_radius_mm))
    return Fail(why, "BoxMeasureOptions.max_circle_radius_mm must be finite and > 0");
  return true;
}

// ---------------------------------------------------------- oriented box ----

bool ComputeOrientedBox(const PointCloud& cloud, OrientedBox* box, std::string* error) {
  return ComputeOrientedBox(cloud, OrientedBoxOptions{}, box, error);
}

bool ComputeOrientedBox(const PointCloud& cloud, const OrientedBoxOptions& options,
                        OrientedBox* box, std::string* error) {
  return NoThrowBool("ComputeOrientedBox", error, [&]() -> bool {
    std::string why;
    if (!options.IsValid(&why)) return Fail(error, "ComputeOrientedBox: " + why);
    if (!box) return Fail(error, "ComputeOrientedBox: no output box given");
    std::vector<Vector3d> pts;
    pts.reserve(cloud.size());
    for (const cv::Vec3f& p : cloud.points_mm)
      if (Finite(p)) pts.push_back(ToEigen(p));
    if (pts.size() < 4)
      return Fail(error, "ComputeOrientedBox: need at least 4 finite points, got " +
                             std::to_string(pts.size()) + " (of " + std::to_string(cloud.size()) +
                             ")");
    std::vector<Vector3d> search = pts;
    std::mt19937_64 rng(options.seed);
    if (search.size() > static_cast<std::size_t>(options.max_search_points)) {
      std::shuffle(search.begin(), search.end(), rng);
      search.resize(static_cast<std::size_t>(options.max_search_points));
    }
    std::vector<double> buffer;
    Matrix3d best_axes;
    if (options.up) {
      best_axes =
          UprightAxes(search, ToEigen(*options.up).normalized(), options.trim_fraction, &buffer);
    } else {
      best_axes = SmallestBoxAxes(search, options.trim_fraction, &buffer);
    }
    const Extents e = TrimmedExtents(pts, best_axes, options.trim_fraction, &buffer);
    const Vector3d size = e.hi - e.lo;
    std::array<int, 3> order{0, 1, 2};
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return size[a] > size[b]; });
    Matrix3d axes;
    Vector3d extents;
    for (int k = 0; k < 3; ++k) {
      axes.col(k) = best_axes.col(order[static_cast<std::size_t>(k)]);
      extents[k] = size[order[static_cast<std::size_t>(k)]];
    }
    if (axes.determinant() < 0) axes.col(2) = -axes.col(2);
    box->up_axis = -1;
    if (options.up)
      for (int k = 0; k < 3; ++k)
        if (order[static_cast<std::size_t>(k)] == 2) box->up_axis = k;  // UprightAxes: up third
    box->center_mm = ToCv(Vector3d(best_axes * (0.5 * (e.lo + e.hi))));
    box->axes = ToCv(axes);
    box->extents_mm = ToCv(extents);
    box->points = pts.size();
    if (error) error->clear();
    return true;
  });
}

// ------------------------------------------------------------ box measure ----

namespace {

// Groups the detected planes (and the given base) by direction into up to
// three mutually orthogonal axes, two face slots each; planes that fit no
// group (oblique relief facets) are dropped. Makes the frame right-handed,
// so that one rotation can map the model axes onto it. Returns what is
// missing, empty when all six faces are there.
std::string GroupFaces(const std::vector<Detected>& detected, const std::optional<FitPlane>& base,
                       const BoxMeasureOptions& o, FaceGroups* groups) {
  const double sin_tol = std::sin(o.orthogonality_tolerance_deg * kDeg);
  const double cos_tol = std::cos(o.orthogonality_tolerance_deg * kDeg);
  std::vector<Vector3d>& axes = groups->axes;
  std::array<Face, 6>& faces = groups->faces;
  for (const Detected& d : detected) groups->Place(d.plane, &d.inliers, false, cos_tol, sin_tol);
  if (base && groups->Place(*base, nullptr, true, cos_tol, sin_tol) < 0)
    return "the base plane is neither parallel nor orthogonal (within " +
           std::to_string(o.orthogonality_tolerance_deg) + " deg) to the box faces found";
  if (axes.size() < 3)
    return "found faces along only " + std::to_string(axes.size()) +
           " of 3 orthogonal directions (" + std::to_string(detected.size()) +
           " planes detected); is the object a box?";
  std::string missing;
  for (int s = 0; s < 6; ++s)
    if (!faces[static_cast<std::size_t>(s)].present)
      missing += std::string(missing.empty() ? "" : ", ") + kSlotNames[s];
  if (!missing.empty())
    return "box face(s) not found: " + missing +
           (base ? "" : "; give BoxMeasureOptions::base_plane when the base is unseen");
  Matrix3d found;
  for (int g = 0; g < 3; ++g) found.col(g) = axes[static_cast<std::size_t>(g)];
  if (found.determinant() < 0) {
    axes[2] = -axes[2];
    std::swap(faces[4], faces[5]);
  }
  return {};
}

// The final face fits: inliers re-gathered from all active points, leaving
// out the edge zones, and the box frame as the rotation closest to the face
// normals (Procrustes, axis g along +face 2g+1); with enforce_orthogonality
// the faces take the frame's normals and the fit repeats (three rounds).
// Returns the error, empty on success.
std::string FitBoxFrame(const Points& points, const std::vector<int>& active,
                        const BoxMeasureOptions& o, const Vector3d& centre,
                        std::array<Face, 6>* faces_io, Matrix3d* frame) {
  std::array<Face, 6>& faces = *faces_io;
  const double cos_normal = std::cos(o.normal_angle_deg * kDeg);
  for (int round = 0; round < 3; ++round) {
    for (std::size_t s = 0; s < 6; ++s) {
      if (faces[s].given) continue;
      if (!RefitFace(points, active, o, cos_normal, s, &faces))
        return std::string("face ") + kSlotNames[s] + " lost its points";
    }
    Matrix3d cross = Matrix3d::Zero();
    double max_weight = 0;
    for (const Face& f : faces)
      max_weight = std::max(max_weight, static_cast<double>(f.inliers.size()));
    for (std::size_t s = 0; s < 6; ++s) {
      const double w = faces[s].given ? max_weight : static_cast<double>(faces[s].inliers.size());
      const Vector3d model = Vector3d::Unit(static_cast<int>(s / 2)) * (s % 2 ? 1.0 : -1.0);
      cross += w * faces[s].plane.n * model.transpose();
    }
    Eigen::JacobiSVD<Matrix3d> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Matrix3d fix = Matrix3d::Identity();
    fix(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
    *frame = svd.matrixU() * fix * svd.matrixV().transpose();
    if (!o.enforce_orthogonality) break;
    for (std::size_t s = 0; s < 6; ++s) {
      Face& f = faces[s];
      const Vector3d n = frame->col(static_cast<int>(s / 2)) * (s % 2 ? 1.0 : -1.0);
      if (f.given) {
        // Keep the given plane's point nearest the centre.
        const Vector3d foot = centre - f.plane.Distance(centre) * f.plane.n;
        f.plane.n = n;
        f.plane.d = -n.dot(foot);
      } else {
        f.plane.n = n;
        f.plane.d = FitOffset(points.p, f.inliers, n);
      }
    }
  }
  return {};
}

// The eight vertices as intersections of three faces each (vertex bit g
// picks face 2g or 2g+1). Returns the first degenerate vertex, or -1.
int IntersectFaces(const std::array<Face, 6>& faces, std::vector<cv::Vec3d>* vertices) {
  auto face_of = [&](int vertex, int axis) -> const Face& {
    return faces[static_cast<std::size_t>(2 * axis + ((vertex >> axis) & 1))];
  };
  for (int v = 0; v < 8; ++v) {
    double det = 0;
    const Vector3d p =
        SolveVertex(face_of(v, 0).plane, face_of(v, 1).plane, face_of(v, 2).plane, &det);
    if (!(std::abs(det) > 0.5) || !p.allFinite()) return v;
    vertices->push_back(ToCv(p));
  }
  return -1;
}

}  // namespace

BoxMeasurement MeasureBox(const PointCloud& cloud, const BoxMeasureOptions& o) {
  return NoThrow<BoxMeasurement>(
      "MeasureBox", BoxMeasurement::Status::kFailed, [&]() -> BoxMeasurement {
        BoxMeasurement m;
        m.vertex_method = o.vertex_method;
        std::string why;
        if (!o.IsValid(&why)) return Failed(m, kFailed, std::string(kWhere) + why);
        if (!cloud.IsValid(&why))
          return Failed(m, kFailed, std::string(kWhere) + "invalid cloud: " + why);

        Points points = WorkingSet(cloud);
        m.input_points = points.p.size();
        if (points.p.size() < kMinBoxPoints)
          return Failed(m, kFailed,
                        std::string(kWhere) + "need at least " + std::to_string(kMinBoxPoints) +
                            " finite points, got " + std::to_string(points.p.size()) + " (of " +
                            std::to_string(cloud.size()) + ")");

        // The base plane, turned so that its normal points away from most points
        // (the box stands on it); points at or below the base are ignored.
        std::vector<int> active;
        const std::optional<FitPlane> base = OrientBasePlane(o, points, &active);
        if (active.size() < kMinBoxPoints)
          return Failed(m, kFailed,
                        std::string(kWhere) + "only " + std::to_string(active.size()) +
                            " points lie above the base plane (need " +
                            std::to_string(kMinBoxPoints) + ")");

        bool all_normals = true;
        for (int i : active) all_normals = all_normals && points.has_n[static_cast<std::size_t>(i)];
        if (!all_normals) EstimateNormals(&points, o.normal_radius_mm);

        // Centre of the active points: inside a box seen from outside, so it tells
        // outward from inward.
        Vector3d centre = Vector3d::Zero();
        for (int i : active) centre += points.p[static_cast<std::size_t>(i)];
        centre /= static_cast<double>(active.size());

        const std::size_t min_points = std::max<std::size_t>(
            static_cast<std::size_t>(o.min_face_points),
            static_cast<std::size_t>(
                std::ceil(o.min_face_fraction * static_cast<double>(active.size()))));
        std::vector<Detected> detected = DetectPlanes(points, active, o, min_points);
        for (Detected& d : detected) {
          if (d.plane.Distance(centre) > 0) {
            d.plane.n = -d.plane.n;
            d.plane.d = -d.plane.d;
          }
          m.detected_planes.push_back(
              ToPlane(d.plane, d.inliers.size(), RmsDistance(points.p, d.inliers, d.plane), false));
        }
        if (detected.empty())
          return Failed(m, kFailed,
                        std::string(kWhere) + "no plane with at least " +
                            std::to_string(min_points) + " points found");

        FaceGroups groups;
        if (std::string e = GroupFaces(detected, base, o, &groups); !e.empty())
          return Failed(m, kFailed, std::string(kWhere) + e);
        std::array<Face, 6>& faces = groups.faces;
        for (std::size_t a = 0; a < 6; ++a)
          for (std::size_t b = a + 1; b < 6; ++b)
            m.max_orthogonality_error_deg =
                std::max(m.max_orthogonality_error_deg,
                         OrthogonalityErrorDeg(faces[a].plane.n, faces[b].plane.n));

        Matrix3d frame;
        if (std::string e = FitBoxFrame(points, active, o, centre, &faces, &frame); !e.empty())
          return Failed(m, kFailed, std::string(kWhere) + e);
        m.axes = ToCv(SortAxesByExtent(frame, centre, &faces));
        RecordFacePlanes(points, faces, &m);

        if (const int v = IntersectFaces(faces, &m.vertices_mm); v >= 0)
          return Failed(
              m, kFailed,
              std::string(kWhere) + "degenerate plane intersection at vertex " + std::to_string(v));

        const double cos_normal = std::cos(o.normal_angle_deg * kDeg);
        if (const int v = PointCircleVertices(points, active, o, cos_normal, faces, &m); v >= 0) {
          return Failed(
              m, kFailed,
              std::string(kWhere) + "degenerate edge line at vertex " + std::to_string(v));
        }
        MeasureEdges(o, &m);
        m.status = BoxMeasurement::Status::kOk;
        m.message = base ? "base plane given; 5 faces fitted" : "6 faces fitted";
        return m;
      });
}

// ------------------------------------------------------------------ report ----

namespace {

nlohmann::ordered_json Vec(const cv::Vec3d& v) { return {v[0], v[1], v[2]}; }

nlohmann::ordered_json PlaneJson(const Plane& p) {
  nlohmann::ordered_json j;
  j["normal"] = Vec(p.normal);
  j["offset_mm"] = p.offset_mm;
  j["inliers"] = p.inliers;
  j["rms_mm"] = p.rms_mm;
  j["given"] = p.given;
  return j;
}

}  // namespace

std::string MeasurementReportJson(const OrientedBox& box, const BoxMeasurement* measurement) {
  try {
    nlohmann::ordered_json report;
    report["units"] = "mm";
    nlohmann::ordered_json obb;
    obb["center_mm"] = Vec(box.center_mm);
    nlohmann::ordered_json axes = nlohmann::ordered_json::array();
    for (int c = 0; c < 3; ++c) axes.push_back({box.axes(0, c), box.axes(1, c), box.axes(2, c)});
    obb["axes"] = axes;  // one unit vector per box axis
    obb["extents_mm"] = Vec(box.extents_mm);
    obb["points"] = box.points;
    // Upright: one axis along the turntable's (the object as it stands).
    obb["upright"] = box.up_axis >= 0;
    if (box.up_axis >= 0) obb["height_mm"] = box.extents_mm[box.up_axis];
    report["oriented_box"] = obb;
    if (measurement) {
      const BoxMeasurement& m = *measurement;
      nlohmann::ordered_json j;
      j["status"] = m.IsUsable() ? "ok" : "failed";
      j["message"] = m.message;
      j["vertex_method"] = ToString(m.vertex_method);
      j["dims_mm"] = Vec(m.dims_mm);
      nlohmann::ordered_json frame = nlohmann::ordered_json::array();
      for (int c = 0; c < 3; ++c) frame.push_back({m.axes(0, c), m.axes(1, c), m.axes(2, c)});
      j["axes"] = frame;
      nlohmann::ordered_json faces = nlohmann::ordered_json::array();
      for (const Plane& p : m.planes) faces.push_back(PlaneJson(p));
      j["faces"] = faces;
      nlohmann::ordered_json vertices = nlohmann::ordered_json::array();
      for (std::size_t v = 0; v < m.vertices_mm.size(); ++v) {
        nlohmann::ordered_json jv;
        jv["index"] = v;
        jv["intersection_mm"] = Vec(m.vertices_mm[v]);
        if (v < m.refined_vertices_mm.size()) {
          jv["point_circle_mm"] = Vec(m.refined_vertices_mm[v]);
          jv["circle_radius_mm"] = m.circle_radius_mm[v];
          jv["circle_fallback"] = static_cast<bool>(m.circle_fallback[v]);
        }
        vertices.push_back(jv);
      }
      j["vertices"] = vertices;
      nlohmann::ordered_json edges = nlohmann::ordered_json::array();
      for (const BoxEdge& e : m.edges) {
        nlohmann::ordered_json je;
        je["a"] = e.a;
        je["b"] = e.b;
        je["axis"] = e.axis;
        je["length_mm"] = e.length_mm;
        je["intersection_length_mm"] = e.intersection_length_mm;
        je["circle_length_mm"] = e.circle_length_mm;
        edges.push_back(je);
      }
      j["edges"] = edges;
      nlohmann::ordered_json quality;
      quality["max_orthogonality_error_deg"] = m.max_orthogonality_error_deg;
      quality["face_rms_mm"] = m.face_rms_mm;
      quality["input_points"] = m.input_points;
      quality["face_points"] = m.face_points;
      nlohmann::ordered_json detected = nlohmann::ordered_json::array();
      for (const Plane& p : m.detected_planes) detected.push_back(PlaneJson(p));
      quality["detected_planes"] = detected;
      j["quality"] = quality;
      report["box"] = j;
    }
    return report.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) + "\n";
  } catch (const std::exception&) {
    return std::string("{\"error\": \"report failed\"}\n");
  }
}

bool WriteMeasurementReport(const std::string& path, const OrientedBox& box,
                            const BoxMeasurement* measurement, std::string* error) {
  return WriteFileAtomically(path, MeasurementReportJson(box, measurement), error);
}

}  // namespace craftscan
