// Joining two turns: global registration without a prior, refined from
// several distinct hypotheses, with a verdict on overlap and ambiguity.
#include "craftscan/pipeline/registration/turn_join.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "common/eigen_cv.h"
#include "common/parallel.h"
#include "common/point_index.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/status.h"
#include "craftscan/pipeline/surface/fusion.h"

namespace craftscan {
namespace {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

std::string Fixed(double value, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", digits, value);
  return buffer;
}

// The cloud averaged in voxels of `voxel_mm`, normals kept (fusion's
// per-voxel mean, without multi-view rules or the refinement along the
// normal).
PointCloud Downsample(const PointCloud& cloud, double voxel_mm, std::string* why) {
  FusionOptions f;
  f.voxel_mm = voxel_mm;
  f.refine_along_normal = false;
  f.cluster_gap_mm = std::max(f.cluster_gap_mm, voxel_mm);
  PointCloud plain;
  plain.points_mm = cloud.points_mm;
  plain.normals = cloud.normals;
  return FuseClouds({plain}, f, why);
}

double Diagonal(const PointCloud& cloud) {
  cv::Vec3f lo(1e30f, 1e30f, 1e30f), hi(-1e30f, -1e30f, -1e30f);
  for (const cv::Vec3f& p : cloud.points_mm)
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], p[i]);
      hi[i] = std::max(hi[i], p[i]);
    }
  return cloud.empty() ? 0.0 : cv::norm(hi - lo);
}

struct Fit {
  double fraction = 0;  // of the source points
  double rmse_mm = std::numeric_limits<double>::quiet_NaN();
  // Per source point: 1 fits, 2 lies farther than contradiction_mm from
  // the target, 0 neither.
  std::vector<std::uint8_t> state;
};

// How well `source` mapped by T lies on `target` (see TurnJoinOptions::fit_*).
Fit MeasureFit(const PointCloud& source, const PointCloud& target, const PointIndex& index,
               const cv::Matx44d& T, const TurnJoinOptions& o, const Parallel& parallel) {
  const Eigen::Matrix4d Te = ToEigen(T);
  const Eigen::Matrix3f R = Te.topLeftCorner<3, 3>().cast<float>();
  const Eigen::Vector3f t = Te.topRightCorner<3, 1>().cast<float>();
  std::vector<float> plane(source.size(), -1.f);  // −1: no target point near
  Fit fit;
  fit.state.assign(source.size(), 0);
  const float gate2 = static_cast<float>(o.fit_distance_mm * o.fit_distance_mm);
  const float far2 = static_cast<float>(o.contradiction_mm * o.contradiction_mm);
  parallel.For(0, static_cast<int>(source.size()), [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      const cv::Vec3f& s = source.points_mm[static_cast<std::size_t>(i)];
      const Eigen::Vector3f p = R * Eigen::Vector3f(s[0], s[1], s[2]) + t;
      int j = 0;
      float d2 = 0;
      if (!index.Nearest(p, &j, &d2)) continue;
      if (d2 > far2) fit.state[static_cast<std::size_t>(i)] = 2;
      if (d2 > gate2) continue;
      const cv::Vec3f& q = target.points_mm[static_cast<std::size_t>(j)];
      const cv::Vec3f& n = target.normals[static_cast<std::size_t>(j)];
      plane[static_cast<std::size_t>(i)] =
          std::abs(n[0] * (p[0] - q[0]) + n[1] * (p[1] - q[1]) + n[2] * (p[2] - q[2]));
    }
  });
  std::size_t fits = 0;
  double sum2 = 0;
  for (std::size_t i = 0; i < plane.size(); ++i) {
    const float d = plane[i];
    if (d < 0 || d > o.fit_plane_mm) continue;
    fit.state[i] = 1;
    ++fits;
    sum2 += static_cast<double>(d) * d;
  }
  if (!source.empty())
    fit.fraction = static_cast<double>(fits) / static_cast<double>(source.size());
  if (fits > 0) fit.rmse_mm = std::sqrt(sum2 / static_cast<double>(fits));
  return fit;
}

// How firmly the fit holds the placement: the point-to-plane information
// matrix of the fitting points (each pair's row: the target normal n and
// (p − c) × n / r, p the mapped source point, c their centroid, r their RMS
// distance from it, so that a turn by one radian at the object's size
// weighs as a shift by r), per point. Its smallest eigenvalue over its
// largest: ~0 when some motion moves no point off the surface (a surface of
// revolution turning about its axis, a cylinder sliding along it). The
// normals come from `normals_target` (turn A's coarse cloud: averaged over
// a few millimetres, their noise no longer hides the small hold a jug's
// handle gives).
// *weak_rotation receives how much of that motion is a rotation (0..1).
double Constraint(const PointCloud& source, const PointCloud& normals_target,
                  const PointIndex& index, const cv::Matx44d& T, const Fit& fit,
                  double* weak_rotation) {
  const Eigen::Matrix4d Te = ToEigen(T);
  const Eigen::Matrix3d R = Te.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = Te.topRightCorner<3, 1>();
  std::vector<Eigen::Vector3d> points, normals;
  for (std::size_t i = 0; i < source.size(); ++i) {
    if (fit.state[i] != 1) continue;
    const cv::Vec3f& s = source.points_mm[i];
    const Eigen::Vector3d p = R * Eigen::Vector3d(s[0], s[1], s[2]) + t;
    int j = 0;
    float d2 = 0;
    if (!index.Nearest(p.cast<float>(), &j, &d2)) continue;
    const cv::Vec3f& n = normals_target.normals[static_cast<std::size_t>(j)];
    points.push_back(p);
    normals.push_back(Eigen::Vector3d(n[0], n[1], n[2]).normalized());
  }
  *weak_rotation = 0;
  if (points.size() < 6) return 0;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : points) c += p;
  c /= static_cast<double>(points.size());
  double r2 = 0;
  for (const Eigen::Vector3d& p : points) r2 += (p - c).squaredNorm();
  const double r = std::sqrt(r2 / static_cast<double>(points.size()));
  if (!(r > 0)) return 0;
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  for (std::size_t i = 0; i < points.size(); ++i) {
    Eigen::Matrix<double, 6, 1> row;
    row.head<3>() = (points[i] - c).cross(normals[i]) / r;
    row.tail<3>() = normals[i];
    H += row * row.transpose();
  }
  H /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(H);
  const double largest = eig.eigenvalues()(5);
  *weak_rotation = eig.eigenvectors().col(0).head<3>().squaredNorm();
  return largest > 0 ? eig.eigenvalues()(0) / largest : 0;
}

// The largest connected part of `cloud`'s points whose `in_part` is set:
// points within `gap_mm` of each other are connected. Its point count.
std::size_t LargestPart(const PointCloud& cloud, const std::vector<bool>& in_part, double gap_mm) {
  PointCloud part;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (in_part[i]) part.points_mm.push_back(cloud.points_mm[i]);
  if (part.empty()) return 0;
  const PointIndex index(part);
  constexpr std::size_t kNeighbours = 16;  // a surface sampled at ~gap/1.6 has ≤ 12 within gap
  const float gap2 = static_cast<float>(gap_mm * gap_mm);
  std::vector<bool> seen(part.size(), false);
  std::vector<std::size_t> stack;
  std::uint32_t found[kNeighbours];
  float d2[kNeighbours];
  std::size_t largest = 0;
  for (std::size_t s = 0; s < part.size(); ++s) {
    if (seen[s]) continue;
    seen[s] = true;
    stack.assign(1, s);
    std::size_t size = 0;
    while (!stack.empty()) {
      const std::size_t i = stack.back();
      stack.pop_back();
      ++size;
      const std::size_t n = index.KNearest(&part.points_mm[i][0], kNeighbours, found, d2);
      for (std::size_t k = 0; k < n; ++k)
        if (d2[k] <= gap2 && !seen[found[k]]) {
          seen[found[k]] = true;
          stack.push_back(found[k]);
        }
    }
    largest = std::max(largest, size);
  }
  return largest;
}

// The largest connected parts of the source that fit under `best` and not
// under `other` (*best_only) and the other way round (*other_only), as
// shares of the source points.
void DistinctParts(const PointCloud& source, const Fit& best, const Fit& other, double gap_mm,
                   double* best_only, double* other_only) {
  std::vector<bool> only_best(source.size()), only_other(source.size());
  for (std::size_t i = 0; i < source.size(); ++i) {
    only_best[i] = best.state[i] == 1 && other.state[i] != 1;
    only_other[i] = other.state[i] == 1 && best.state[i] != 1;
  }
  const double n = static_cast<double>(std::max<std::size_t>(1, source.size()));
  *best_only = static_cast<double>(LargestPart(source, only_best, gap_mm)) / n;
  *other_only = static_cast<double>(LargestPart(source, only_other, gap_mm)) / n;
}

// The share of the source points that fit under `best` and lie far from
// the target under `other`: surface the other placement contradicts.
double Contradicted(const Fit& best, const Fit& other) {
  std::size_t n = 0;
  for (std::size_t i = 0; i < best.state.size(); ++i)
    if (best.state[i] == 1 && other.state[i] == 2) ++n;
  return best.state.empty() ? 0.0 : static_cast<double>(n) / static_cast<double>(best.state.size());
}

// Rotation by `angle_rad` about `axis` through `centre` (turn A's frame).
cv::Matx44d TurnAbout(const Eigen::Vector3d& axis, const Eigen::Vector3d& centre,
                      double angle_rad) {
  return RotationAboutAxis(cv::Vec3d(axis.x(), axis.y(), axis.z()),
                           cv::Vec3d(centre.x(), centre.y(), centre.z()), angle_rad);
}

// The principal axes of the points (columns, ascending variance).
Eigen::Matrix3d PrincipalAxes(const std::vector<cv::Vec3f>& points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const cv::Vec3f& p : points) mean += Eigen::Vector3d(p[0], p[1], p[2]);
  mean /= static_cast<double>(std::max<std::size_t>(1, points.size()));
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const cv::Vec3f& p : points) {
    const Eigen::Vector3d d = Eigen::Vector3d(p[0], p[1], p[2]) - mean;
    cov += d * d.transpose();
  }
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors();
}

// The middle of the points' extent along `axes` (columns), in their frame.
Eigen::Vector3d ExtentMiddle(const std::vector<cv::Vec3f>& points, const Eigen::Matrix3d& axes) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e30), hi = -lo;
  for (const cv::Vec3f& p : points) {
    const Eigen::Vector3d q = axes.transpose() * Eigen::Vector3d(p[0], p[1], p[2]);
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  return axes * ((lo + hi) / 2);
}

struct Placement {
  cv::Matx44d a_from_b = cv::Matx44d::eye();
  Fit fit;
};

}  // namespace

bool TurnJoinOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(fine_voxel_mm > 0)) return fail("fine_voxel_mm must be > 0");
  if (!(coarse_voxel_mm >= 0)) return fail("coarse_voxel_mm must be >= 0 (0: from the size)");
  if (!(feature_radius_voxels > 0)) return fail("feature_radius_voxels must be > 0");
  if (!(inlier_distance_voxels > 0)) return fail("inlier_distance_voxels must be > 0");
  if (ransac_iterations < 1) return fail("ransac_iterations must be >= 1");
  if (hypothesis_source_points < 100) return fail("hypothesis_source_points must be >= 100");
  std::string sub;
  if (!fine.IsValid(&sub)) return fail("fine." + sub);
  if (max_candidates < 1) return fail("max_candidates must be >= 1");
  if (!(distinct_deg > 0) || !(distinct_mm > 0)) return fail("distinct_deg/_mm must be > 0");
  if (!(fit_distance_mm > 0) || !(fit_plane_mm > 0))
    return fail("fit_distance/plane_mm must be > 0");
  if (!(min_overlap >= 0 && min_overlap <= 1)) return fail("min_overlap must be in [0, 1]");
  if (!(max_ambiguity > 0 && max_ambiguity <= 1)) return fail("max_ambiguity must be in (0, 1]");
  if (!(min_constraint >= 0 && min_constraint < 1)) return fail("min_constraint must be in [0, 1)");
  if (!(weak_constraint >= min_constraint && weak_constraint < 1))
    return fail("weak_constraint must be in [min_constraint, 1)");
  if (!(contradiction_mm > fit_distance_mm))
    return fail("contradiction_mm must be > fit_distance_mm");
  if (!(max_contradicted >= 0 && max_contradicted <= 1))
    return fail("max_contradicted must be in [0, 1]");
  if (!(distinct_part_share >= 0 && distinct_part_share <= 1))
    return fail("distinct_part_share must be in [0, 1]");
  if (!(distinct_part_ratio >= 1)) return fail("distinct_part_ratio must be >= 1");
  if (!(contact_band_mm >= 0) || !(contact_cover_mm >= 0))
    return fail("contact_band_mm/contact_cover_mm must be >= 0");
  if (!(polish_min_fit > 0 && polish_min_fit <= 1)) return fail("polish_min_fit must be in (0, 1]");
  if (num_threads < 1) return fail("num_threads must be >= 1");
  return true;
}

const char* ToString(TurnJoinResult::Status status) {
  switch (status) {
    case TurnJoinResult::Status::kJoined:
      return "joined";
    case TurnJoinResult::Status::kRefusedOverlap:
      return "refused_overlap";
    case TurnJoinResult::Status::kRefusedAmbiguous:
      return "refused_ambiguous";
    case TurnJoinResult::Status::kFailed:
      return "failed";
  }
  return "failed";
}

TurnJoinResult JoinTurns(const PointCloud& turn_a, const PointCloud& turn_b,
                         const TurnJoinOptions& options) {
  return NoThrow<TurnJoinResult>(
      "JoinTurns", TurnJoinResult::Status::kFailed, [&]() -> TurnJoinResult {
        const auto start = Clock::now();
        TurnJoinResult result;
        std::string why;
        if (!options.IsValid(&why)) {
          result.message = "invalid turn join options: " + why;
          return result;
        }
        constexpr std::size_t kMinPoints = 100;
        for (const PointCloud* c : {&turn_a, &turn_b}) {
          if (c->size() < kMinPoints || !c->HasNormals() || !c->IsValid(nullptr)) {
            result.message = std::string("turn ") + (c == &turn_a ? "A" : "B") +
                             "'s cloud needs at least 100 points with normals";
            return result;
          }
        }
        const int threads = options.num_threads;
        const Parallel parallel(threads);
        const double coarse_mm =
            options.coarse_voxel_mm > 0 ? options.coarse_voxel_mm : Diagonal(turn_a) / 40;
        result.coarse_voxel_mm = coarse_mm;
        ViewCloud a, b;
        a.fine = Downsample(turn_a, options.fine_voxel_mm, &why);
        if (why.empty()) b.fine = Downsample(turn_b, options.fine_voxel_mm, &why);
        if (why.empty()) a.coarse = Downsample(turn_a, coarse_mm, &why);
        if (why.empty()) b.coarse = Downsample(turn_b, coarse_mm, &why);
        if (!why.empty()) {
          result.message = "downsampling the turns: " + why;
          return result;
        }
        result.points_a = a.fine.size();
        result.points_b = b.fine.size();
        const PointIndex index_a(a.fine);
        const PointIndex coarse_index_a(a.coarse);

        // Coarse: the distinct best RANSAC hypotheses, no prior.
        CoarseOptions coarse;
        coarse.feature_radius_mm = options.feature_radius_voxels * coarse_mm;
        coarse.inlier_distance_mm = options.inlier_distance_voxels * coarse_mm;
        coarse.max_iterations = options.ransac_iterations;
        coarse.seed = options.seed;
        CoarseCandidates wanted;
        wanted.max_candidates = options.max_candidates;
        // Distinct rotations: shifted copies of one rotation would crowd out
        // the other rotations (at 1280×1024 the box's correct one, leaving
        // its turn end over end as the best).
        wanted.min_separation_mm = std::numeric_limits<double>::infinity();
        const std::vector<RegistrationResult> hypotheses =
            RegisterCoarseCandidates(b, a, coarse, wanted, threads);
        if (hypotheses.empty() || !hypotheses.front().IsUsable()) {
          // Valid clouds and no consistent placement: nothing in common.
          result.status = TurnJoinResult::Status::kRefusedOverlap;
          result.message =
              "the turns overlap too little: no placement of the second turn fits the first "
              "(global registration: " +
              (hypotheses.empty() ? std::string("no hypothesis") : hypotheses.front().message) +
              "); lay the object so that more of what the first turn saw is seen again";
          result.time_ms = MsSince(start);
          return result;
        }

        // Fine: ICP from each; the best fit wins.
        std::vector<Placement> placements;
        FineOptions quick = options.fine;
        quick.max_iterations = std::min(quick.max_iterations, 80);
        quick.min_update_mm = std::max(quick.min_update_mm, 2e-3);
        // From RANSAC's pose (coarse voxels) the first pairs lie up to its gate apart.
        quick.max_correspondence_mm =
            std::max(quick.max_correspondence_mm, coarse.inlier_distance_mm);
        if (quick.max_source_points == 0 ||
            quick.max_source_points > options.hypothesis_source_points)
          quick.max_source_points = options.hypothesis_source_points;
        auto measure = [&](const cv::Matx44d& T) {
          Placement p;
          p.a_from_b = T;
          p.fit = MeasureFit(b.fine, a.fine, index_a, T, options, parallel);
          return p;
        };
        auto refine = [&](const cv::Matx44d& initial) {
          const RegistrationResult r = RegisterFine(b, a, initial, quick, threads);
          placements.push_back(measure(r.IsUsable() ? r.target_from_source : initial));
        };
        for (const RegistrationResult& h : hypotheses)
          if (h.IsUsable()) refine(h.target_from_source);
        auto best_of = [&] {
          return std::max_element(placements.begin(), placements.end(),
                                  [](const Placement& x, const Placement& y) {
                                    return x.fit.fraction < y.fit.fraction;
                                  }) -
                 placements.begin();
        };
        // The best turned about turn B's principal axes (in A's frame): a
        // symmetry RANSAC's samples missed still shows as an equal fit.
        {
          const Placement seed = placements[static_cast<std::size_t>(best_of())];
          const PointCloud moved = TransformCloud(seed.a_from_b, b.fine);
          // Turn about the middle of the extent along each axis, not the
          // centroid: a turn lacks the face it stood on, which pulls its
          // centroid off the object's centre, and a half turn about the
          // centroid would land twice that off, beyond ICP's reach.
          const Eigen::Matrix3d axes_b = PrincipalAxes(moved.points_mm);
          const Eigen::Vector3d centre = ExtentMiddle(moved.points_mm, axes_b);
          constexpr double kNudge = 10 * M_PI / 180;
          // A quarter or half turn of a wrong best also needs a new
          // translation: the turned B is moved too so that the middle of its
          // extent along turn A's principal axes meets turn A's (each turn
          // lacks the face it stood on, but its extent is nearly the whole
          // object's): at 1280×1024 the box's best was 90° off and 18 mm
          // aside, and the turn about B's middle alone left ICP beyond reach.
          const Eigen::Matrix3d axes_a = PrincipalAxes(a.fine.points_mm);
          const Eigen::Vector3d middle_a = ExtentMiddle(a.fine.points_mm, axes_a);
          for (int axis = 0; axis < 3; ++axis)
            for (double angle : {-kNudge, kNudge, M_PI / 2, M_PI, 3 * M_PI / 2}) {
              const cv::Matx44d turned = TurnAbout(axes_b.col(axis), centre, angle) * seed.a_from_b;
              refine(turned);
              if (std::abs(angle) < M_PI / 4 || !options.recentre_turned) continue;
              const Eigen::Vector3d shift =
                  middle_a - ExtentMiddle(TransformCloud(turned, b.fine).points_mm, axes_a);
              cv::Matx44d moved_too = turned;
              for (int i = 0; i < 3; ++i) moved_too(i, 3) += shift[i];
              refine(moved_too);
            }
        }
        result.hypotheses = static_cast<int>(placements.size());
        // The contenders run to convergence on every point: the best and the
        // next that fit nearly as well (the candidates for ambiguity).
        std::vector<std::size_t> order(placements.size());
        for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
        std::stable_sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
          return placements[x].fit.fraction > placements[y].fit.fraction;
        });
        const double leading = placements[order[0]].fit.fraction;
        std::vector<std::size_t> refined;
        for (std::size_t k = 0;
             k < order.size() && k < static_cast<std::size_t>(options.max_contenders); ++k) {
          Placement& p = placements[order[k]];
          if (k > 0 && p.fit.fraction < options.max_ambiguity * leading) break;
          refined.push_back(order[k]);
          const RegistrationResult r = RegisterFine(b, a, p.a_from_b, options.fine, threads);
          if (r.IsUsable()) p = measure(r.target_from_source);
          // Then linearised point-to-plane: the weighted ICP pairs each
          // point with a foot on the other surface, which holds it in place
          // along the surface, so along a shallow valley (the owl turning
          // about its round body) it creeps (0.36° from the truth after 200
          // iterations, 0.08° after 2000); point-to-plane leaves motion along
          // the surface free and lands at the bottom in a few iterations.
          if (options.polish) {
            FineOptions polish = options.fine;
            polish.method = FineMethod::kPointToPlane;
            const RegistrationResult q = RegisterFine(b, a, p.a_from_b, polish, threads);
            if (q.IsUsable()) {
              Placement polished = measure(q.target_from_source);
              if (polished.fit.fraction >= options.polish_min_fit * p.fit.fraction)
                p = std::move(polished);
            }
          }
        }
        // The join: the best of the contenders as refined (a placement left
        // as the quick ICP stopped may count a few more fits along a valley
        // it did not reach the bottom of).
        const Placement best = placements[*std::max_element(
            refined.begin(), refined.end(), [&](std::size_t x, std::size_t y) {
              return placements[x].fit.fraction < placements[y].fit.fraction;
            })];
        result.a_from_b = best.a_from_b;
        result.overlap = best.fit.fraction;
        result.rmse_mm = best.fit.rmse_mm;
        double weak_rotation = 0;
        result.constraint =
            Constraint(b.fine, a.coarse, coarse_index_a, best.a_from_b, best.fit, &weak_rotation);
        result.weak_motion_rotation = weak_rotation;
        // The closest placement dismissed for misplacing a distinctive part.
        constexpr double kPartGapVoxels = 1.6;
        double dismissed_ratio = 0, dismissed_deg = 0, dismissed_part = 0;
        for (const Placement& p : placements) {
          const double deg = RotationErrorDeg(p.a_from_b, best.a_from_b);
          // Distinct: the same points of B land elsewhere by the centroid's
          // shift or by the rotation.
          const double mm = TranslationErrorMm(p.a_from_b, best.a_from_b);
          if (deg < options.distinct_deg && mm < options.distinct_mm) continue;
          // A placement that puts surface the join fits far from turn A's
          // (a jug's handle beside the jug) is contradicted: no rival.
          const double contradicted = Contradicted(best.fit, p.fit);
          if (contradicted > options.max_contradicted) continue;
          const double ratio = best.fit.fraction > 0 ? p.fit.fraction / best.fit.fraction : 0;
          if (ratio <= result.ambiguity) continue;
          // A placement that misplaces a distinctive part the join fits (a
          // jug's handle) is no rival either.
          double best_only = 0, other_only = 0;
          DistinctParts(b.fine, best.fit, p.fit, kPartGapVoxels * options.fine_voxel_mm, &best_only,
                        &other_only);
          if (best_only >= options.distinct_part_share &&
              best_only >= options.distinct_part_ratio * other_only) {
            if (ratio >= options.max_ambiguity && ratio > dismissed_ratio) {
              dismissed_ratio = ratio;
              dismissed_deg = deg;
              dismissed_part = best_only;
            }
            continue;
          }
          result.ambiguity = ratio;
          result.alternative_deg = deg;
          result.alternative_mm = mm;
          result.alternative_contradicted = contradicted;
        }
        result.time_ms = MsSince(start);
        const std::string figures = "fit " + Fixed(100 * result.overlap, 1) + " % of turn B, " +
                                    "RMSE " + Fixed(result.rmse_mm, 2) + " mm, ambiguity " +
                                    Fixed(result.ambiguity, 2) + ", constraint " +
                                    Fixed(result.constraint, 4);
        if (result.overlap < options.min_overlap) {
          result.status = TurnJoinResult::Status::kRefusedOverlap;
          result.message = "the turns overlap too little: " + Fixed(100 * result.overlap, 1) +
                           " % of the second turn's surface fits the first (at least " +
                           Fixed(100 * options.min_overlap, 0) +
                           " % needed), or no right placement was found; lay the object so that "
                           "more of what the first turn saw is seen again";
          return result;
        }
        if (result.constraint < options.min_constraint) {
          result.status = TurnJoinResult::Status::kRefusedAmbiguous;
          result.message =
              "the turns cannot be joined unambiguously: the fit does not hold the second turn "
              "in place (it can turn or slide along the surface without leaving it: constraint " +
              Fixed(result.constraint, 4) + ", refused below " + Fixed(options.min_constraint, 4) +
              "): the object is symmetric (round or cylindrical) where both turns see it; lay it "
              "so that a distinctive part is seen in both turns (" +
              figures + ")";
          return result;
        }
        if (result.ambiguity >= options.max_ambiguity) {
          result.status = TurnJoinResult::Status::kRefusedAmbiguous;
          result.message = "the turns cannot be joined unambiguously: a placement " +
                           Fixed(result.alternative_deg, 1) + "° / " +
                           Fixed(result.alternative_mm, 1) + " mm from the best fits " +
                           Fixed(100 * result.ambiguity, 0) + " % as well (refused from " +
                           Fixed(100 * options.max_ambiguity, 0) +
                           " %): the object looks alike in several poses (it is symmetric); lay "
                           "it so that a distinctive part is seen in both turns (" +
                           figures + ")";
          return result;
        }
        result.status = TurnJoinResult::Status::kJoined;
        result.message =
            "joined: " + figures + ", " + std::to_string(result.hypotheses) + " hypotheses refined";
        if (dismissed_ratio > 0)
          result.message += "; a placement " + Fixed(dismissed_deg, 1) + "° away fits " +
                            Fixed(100 * dismissed_ratio, 0) +
                            " % as well but misplaces a distinctive part the join fits (" +
                            Fixed(100 * dismissed_part, 1) + " % of turn B in one piece)";
        if (result.constraint < options.weak_constraint) {
          result.held_weakly = true;
          result.message +=
              "; held weakly (constraint " + Fixed(result.constraint, 4) + ", below " +
              Fixed(options.weak_constraint, 3) +
              "): one small feature holds the turns' alignment " +
              (result.weak_motion_rotation >= 0.5 ? "about one axis" : "along one direction") +
              ", so they may be a few tenths of a degree apart there; for a "
              "closer join lay the object so that more of its distinctive shape "
              "is seen in both turns";
        }
        return result;
      });
}

PointCloud MergeTurns(const PointCloud& turn_a, const PointCloud& turn_b,
                      const cv::Matx44d& a_from_b, const TurnJoinOptions& options,
                      std::size_t* dropped_a, std::size_t* dropped_b) {
  PointCloud merged;
  std::size_t lost_a = 0, lost_b = 0;
  try {
    const PointCloud b_in_a = TransformCloud(a_from_b, turn_b);
    const PointCloud a_in_b = TransformCloud(InvertRigid(a_from_b), turn_a);
    const bool normals = turn_a.HasNormals() && turn_b.HasNormals();
    const bool colours = turn_a.HasColors() && turn_b.HasColors();
    const float cover2 = static_cast<float>(options.contact_cover_mm * options.contact_cover_mm);
    // own: the cloud in its own frame (z: height above its platter); other:
    // the other turn in that frame; out: the points kept, in turn A's frame.
    auto keep = [&](const PointCloud& own, const PointCloud& other, const PointCloud& out_frame,
                    std::size_t* lost) {
      const PointIndex index(other);
      for (std::size_t i = 0; i < own.size(); ++i) {
        const cv::Vec3f& p = own.points_mm[i];
        if (p[2] < options.contact_band_mm) {
          int j = 0;
          float d2 = 0;
          if (index.Nearest(Eigen::Vector3f(p[0], p[1], p[2]), &j, &d2) && d2 <= cover2) {
            ++*lost;
            continue;
          }
        }
        merged.points_mm.push_back(out_frame.points_mm[i]);
        if (normals) merged.normals.push_back(out_frame.normals[i]);
        if (colours) merged.colors_rgb.push_back(out_frame.colors_rgb[i]);
      }
    };
    keep(turn_a, b_in_a, turn_a, &lost_a);
    keep(turn_b, a_in_b, b_in_a, &lost_b);
  } catch (...) {
    merged = PointCloud{};
  }
  if (dropped_a) *dropped_a = lost_a;
  if (dropped_b) *dropped_b = lost_b;
  return merged;
}

}  // namespace craftscan
