// Registration and loop closure on synthetic surfaces with exact ground truth.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include <opencv2/calib3d.hpp>

#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/registration/loop_closure.h"
#include "craftscan/pipeline/registration/registration.h"
#include "pose_util.h"

namespace craftscan {
namespace {

using testing::Pose;

// A bumpy, asymmetric height field z = f(x, y) over [−w/2, w/2]² (mm),
// sampled every `step_mm`, seen from +z. Bumps are seeded.
PointCloud BumpySurface(unsigned seed, double width_mm = 100, double step_mm = 0.7,
                        double x_from = -1e9, double x_to = 1e9, bool rough = false) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pos(-width_mm / 2, width_mm / 2),
      amp(rough ? -6 : -12, rough ? 6 : 12), size(rough ? 3 : 5, rough ? 7 : 14);
  struct Bump {
    double x, y, a, s;
  };
  std::vector<Bump> bumps;
  for (int i = 0; i < (rough ? 120 : 14); ++i)
    bumps.push_back({pos(rng), pos(rng), amp(rng), size(rng)});
  PointCloud cloud;
  for (double y = -width_mm / 2; y <= width_mm / 2; y += step_mm) {
    for (double x = -width_mm / 2; x <= width_mm / 2; x += step_mm) {
      if (x < x_from || x > x_to) continue;
      double z = 0;
      for (const Bump& b : bumps)
        z += b.a * std::exp(-((x - b.x) * (x - b.x) + (y - b.y) * (y - b.y)) / (2 * b.s * b.s));
      cloud.points_mm.emplace_back(x, y, z);
    }
  }
  return cloud;
}

void AddNoise(PointCloud* cloud, double sigma_mm, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0, static_cast<float>(sigma_mm));
  for (auto& p : cloud->points_mm) p += cv::Vec3f(n(rng), n(rng), n(rng));
}

ConditioningOptions Conditioning(cv::Vec3d viewpoint = {0, 0, 1000}) {
  ConditioningOptions o;
  o.viewpoint_mm = viewpoint;
  o.num_threads = 2;
  return o;
}

// Source: the surface's part x ≤ 25 seen through `target_from_source`⁻¹
// (i.e. in its own frame); target: the part x ≥ −25. 50 mm of 100 overlap.
struct Pair {
  ViewCloud source, target;
  cv::Matx44d target_from_source;
};

Pair MakePair(unsigned seed, const cv::Matx44d& target_from_source, double noise_mm = 0.1) {
  PointCloud src = BumpySurface(seed, 100, 0.7, -1e9, 25);
  PointCloud tgt = BumpySurface(seed, 100, 0.7, -25, 1e9);
  AddNoise(&src, noise_mm, seed + 1);
  AddNoise(&tgt, noise_mm, seed + 2);
  const cv::Matx44d source_from_target = InvertRigid(target_from_source);
  Pair pair;
  pair.target_from_source = target_from_source;
  // The source sensor sits where the target's (0, 0, 1000) is seen from it.
  const cv::Vec4d v = source_from_target * cv::Vec4d(0, 0, 1000, 1);
  pair.source = ConditionCloud(TransformCloud(source_from_target, src),
                               Conditioning(cv::Vec3d(v[0], v[1], v[2])));
  pair.target = ConditionCloud(tgt, Conditioning());
  return pair;
}

TEST(Registration, RecoversALargeRigidMotion) {
  const cv::Matx44d truth = Pose({0.2, -0.35, 0.5}, {20, -15, 30});
  Pair pair = MakePair(7, truth);
  ASSERT_TRUE(pair.source.ok()) << pair.source.error;
  ASSERT_TRUE(pair.target.ok()) << pair.target.error;
  RegistrationOptions options;
  options.num_threads = 2;
  const RegistrationResult r = RegisterPair(pair.source, pair.target, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_LT(RotationErrorDeg(r.target_from_source, truth), 0.05);
  EXPECT_LT(TranslationErrorMm(r.target_from_source, truth), 0.05);
  // Two thirds of the source lie on the target (50 of its 75 mm), plus a
  // band within the 2 mm fitness gate along the target's border.
  EXPECT_GT(r.fitness, 0.6);
  EXPECT_LT(r.fitness, 0.75);
  EXPECT_LT(r.rmse_mm, 0.6);
  EXPECT_TRUE(r.converged);
  EXPECT_GT(r.correspondences, 20u);
}

TEST(Registration, PointToPlaneAgrees) {
  const cv::Matx44d truth = Pose({0.1, 0.2, -0.3}, {-10, 5, 12});
  Pair pair = MakePair(11, truth);
  RegistrationOptions options;
  options.num_threads = 2;
  options.fine.method = FineMethod::kPointToPlane;
  const RegistrationResult r = RegisterPair(pair.source, pair.target, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_LT(RotationErrorDeg(r.target_from_source, truth), 0.05);
  EXPECT_LT(TranslationErrorMm(r.target_from_source, truth), 0.05);
}

// Conditioning's outlier filter and normals (its own neighbour searches,
// PCL's rule and plane fits): floaters above a noisy plane go, the plane's
// normals face the viewpoint, and the thread count changes nothing.
TEST(Conditioning, DropsFloatersAndTheNormalsFaceTheViewpoint) {
  PointCloud cloud;
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0, 0.05f);
  for (double y = -30; y <= 30; y += 0.7)
    for (double x = -30; x <= 30; x += 0.7)
      cloud.points_mm.emplace_back(static_cast<float>(x), static_cast<float>(y), noise(rng));
  std::uniform_real_distribution<float> across(-30, 30), up(5, 20);
  constexpr int kFloaters = 40;
  for (int i = 0; i < kFloaters; ++i)
    cloud.points_mm.emplace_back(across(rng), across(rng), up(rng));
  ConditioningOptions one = Conditioning();
  one.num_threads = 1;
  ConditioningOptions three = one;
  three.num_threads = 3;
  const ViewCloud a = ConditionCloud(cloud, one), b = ConditionCloud(cloud, three);
  ASSERT_TRUE(a.ok()) << a.error;
  EXPECT_GE(a.outlier_points, static_cast<std::size_t>(kFloaters));
  EXPECT_LE(a.outlier_points, static_cast<std::size_t>(kFloaters) + a.fine.size() / 50);
  for (const cv::Vec3f& p : a.fine.points_mm) ASSERT_LT(std::abs(p[2]), 1.f) << p;
  ASSERT_EQ(a.fine.normals.size(), a.fine.size());
  ASSERT_EQ(a.coarse.normals.size(), a.coarse.size());
  for (const cv::Vec3f& n : a.fine.normals) EXPECT_GT(n[2], 0.98f) << n;
  for (const cv::Vec3f& n : a.coarse.normals) EXPECT_GT(n[2], 0.98f) << n;
  ASSERT_EQ(a.fine.size(), b.fine.size());
  ASSERT_EQ(a.coarse.size(), b.coarse.size());
  for (std::size_t i = 0; i < a.fine.size(); ++i) {
    ASSERT_EQ(a.fine.points_mm[i], b.fine.points_mm[i]);
    ASSERT_EQ(a.fine.normals[i], b.fine.normals[i]);
  }
  for (std::size_t i = 0; i < a.coarse.size(); ++i)
    ASSERT_EQ(a.coarse.normals[i], b.coarse.normals[i]);
}

// Indices of the k nearest of `points` to q (q's own index included when
// it is one of them), nearest first, by brute force with nanoflann's float
// metric.
std::vector<int> BruteNearest(const std::vector<cv::Vec3f>& points, const cv::Vec3f& q,
                              std::size_t k) {
  std::vector<std::pair<float, int>> d(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float dx = q[0] - points[i][0], dy = q[1] - points[i][1], dz = q[2] - points[i][2];
    d[i] = {dx * dx + dy * dy + dz * dz, static_cast<int>(i)};
  }
  k = std::min(k, d.size());
  std::partial_sort(d.begin(), d.begin() + static_cast<long>(k), d.end());
  std::vector<int> out(k);
  for (std::size_t j = 0; j < k; ++j) out[j] = d[j].second;
  return out;
}

// The PCA normal of the points `at`, facing `viewpoint` from q.
cv::Vec3d BruteNormal(const std::vector<cv::Vec3f>& points, const std::vector<int>& at,
                      const cv::Vec3f& q, const cv::Vec3d& viewpoint) {
  cv::Vec3d mean(0, 0, 0);
  for (const int i : at) mean += cv::Vec3d(points[static_cast<std::size_t>(i)]);
  mean /= static_cast<double>(at.size());
  cv::Matx33d cov = cv::Matx33d::zeros();
  for (const int i : at) {
    const cv::Vec3d e = cv::Vec3d(points[static_cast<std::size_t>(i)]) - mean;
    cov += e * e.t();
  }
  cv::Mat values, vectors;
  cv::eigen(cv::Mat(cov), values, vectors);  // descending
  cv::Vec3d n(vectors.at<double>(2, 0), vectors.at<double>(2, 1), vectors.at<double>(2, 2));
  return n.dot(viewpoint - cv::Vec3d(q)) < 0 ? -n : n;
}

// Conditioning runs its outlier filter, the normals and the coarse normals
// on one index of the voxel cloud, the filter's neighbour lists reused for
// the normals. Against the rules by brute force on random points (no two
// at equal distances): the outlier rule over all points, each survivor's
// normal from its 15 nearest survivors, the platter band, each coarse
// point's normal from its 15 nearest fine points. The filter's lists are
// long enough (k 20) for most normals, and too short (k 4) for any, so that
// the searches for more points serve them.
TEST(Conditioning, SharedSearchesEqualTheRulesByBruteForce) {
  PointCloud cloud;
  std::mt19937 rng(29);
  std::uniform_real_distribution<float> across(-25, 25), unit(0, 1);
  std::normal_distribution<float> noise(0, 0.1f);
  for (int i = 0; i < 5000; ++i) {
    const float x = across(rng), y = across(rng);
    cloud.points_mm.emplace_back(x, y, 4 + 3 * std::sin(x / 7) * std::cos(y / 5) + noise(rng));
  }
  for (int i = 0; i < 800; ++i)  // platter noise, 0.6–1.4 mm up
    cloud.points_mm.emplace_back(across(rng) - 30, across(rng), 0.6f + 0.8f * unit(rng));
  for (int c = 0; c < 30; ++c) {  // floaters in threes
    const cv::Vec3f at(across(rng), across(rng), 15 + 10 * unit(rng));
    for (int i = 0; i < 3; ++i) cloud.points_mm.push_back(at + cv::Vec3f(unit(rng), unit(rng), 0));
  }
  for (const int outlier_k : {20, 4}) {
    SCOPED_TRACE(::testing::Message() << "outlier_neighbors " << outlier_k);
    ConditioningOptions options = Conditioning({0, -300, 400});
    options.fine_voxel_mm = 0;  // every point
    options.outlier_neighbors = outlier_k;
    options.crop.enabled = true;
    options.crop.volume.min_height_mm = 0.5;
    options.crop.platter_band_mm = 1.5;
    options.crop.platter_normal_deg = 30;
    const ViewCloud view = ConditionCloud(cloud, options);
    ASSERT_TRUE(view.ok()) << view.error;

    // The crop (its volume: above 0.5 mm), then the outlier rule.
    std::vector<cv::Vec3f> cropped;
    for (const cv::Vec3f& p : cloud.points_mm)
      if (p[2] >= 0.5f) cropped.push_back(p);
    std::vector<double> mean_distance(cropped.size());
    for (std::size_t i = 0; i < cropped.size(); ++i) {
      const std::vector<int> near =
          BruteNearest(cropped, cropped[i], static_cast<std::size_t>(outlier_k) + 1);
      double sum = 0;
      for (std::size_t j = 1; j < near.size(); ++j)
        sum += std::sqrt(
            cv::norm(cropped[i] - cropped[static_cast<std::size_t>(near[j])], cv::NORM_L2SQR));
      mean_distance[i] = static_cast<float>(sum / outlier_k);
    }
    double sum = 0, sq_sum = 0;
    for (const double d : mean_distance) sum += d, sq_sum += d * d;
    const double n = static_cast<double>(mean_distance.size());
    const double threshold = sum / n + 2.0 * std::sqrt((sq_sum - sum * sum / n) / (n - 1));
    std::vector<cv::Vec3f> inliers;
    for (std::size_t i = 0; i < cropped.size(); ++i)
      if (!(mean_distance[i] > threshold)) inliers.push_back(cropped[i]);
    EXPECT_EQ(view.outlier_points, cropped.size() - inliers.size());
    EXPECT_GE(view.outlier_points, 60u);  // the floaters at least (k 4: the threes)

    // Normals of the inliers, then the platter band (level, below 1.5 mm).
    std::vector<cv::Vec3f> fine;
    std::vector<cv::Vec3d> fine_normals;
    for (const cv::Vec3f& p : inliers) {
      const cv::Vec3d normal =
          BruteNormal(inliers, BruteNearest(inliers, p, 15), p, options.viewpoint_mm);
      if (p[2] < 1.5f && normal[2] >= std::cos(30 * M_PI / 180)) continue;
      fine.push_back(p);
      fine_normals.push_back(normal);
    }
    ASSERT_EQ(view.fine.size(), fine.size());
    ASSERT_LT(fine.size(), inliers.size() - 500);  // the platter noise went
    for (std::size_t i = 0; i < fine.size(); ++i) {
      ASSERT_EQ(view.fine.points_mm[i], fine[i]) << i;
      ASSERT_GT(cv::Vec3d(view.fine.normals[i]).dot(fine_normals[i]), 0.9999) << i;
    }
    ASSERT_GT(view.coarse.size(), 100u);
    for (std::size_t i = 0; i < view.coarse.size(); ++i) {
      const cv::Vec3f& q = view.coarse.points_mm[i];
      const cv::Vec3d normal =
          BruteNormal(fine, BruteNearest(fine, q, 15), q, options.viewpoint_mm);
      ASSERT_GT(cv::Vec3d(view.coarse.normals[i]).dot(normal), 0.9999) << i;
    }
  }
}

// The platter band: below platter_band_mm, points whose normal is within
// platter_normal_deg of the axis go (the platter, lifted by matching noise,
// level or gently sloped as under an overhang); a wall's lowest millimetre
// stays. Turntable frame = cloud frame; the volume starts at 0.5 mm.
TEST(Conditioning, PlatterBandKeepsTheWallsAndFeetBottomAndDropsSlopedPlatterNoise) {
  PointCloud cloud;
  // A vertical wall facing +x at x = 20 from the platter up to 30 mm.
  for (double y = -20; y <= 20; y += 0.4)
    for (double z = 0; z <= 30; z += 0.4)
      cloud.points_mm.emplace_back(20.f, static_cast<float>(y), static_cast<float>(z));
  // A ramp at 35° from level (its normal 35° from the axis) rising from the
  // platter at x = 40 to 10 mm.
  const double slope = std::tan(35 * M_PI / 180);
  for (double y = -20; y <= 20; y += 0.4)
    for (double x = 40; x <= 40 + 10 / slope; x += 0.4)
      cloud.points_mm.emplace_back(static_cast<float>(x), static_cast<float>(y),
                                   static_cast<float>((x - 40) * slope));
  // Level platter noise 0.8 mm up.
  for (double y = -20; y <= 20; y += 0.4)
    for (double x = -30; x <= 0; x += 0.4)
      cloud.points_mm.emplace_back(static_cast<float>(x), static_cast<float>(y), 0.8f);
  // A foot curving in towards the platter at x = 60: it rises outwards,
  // facing down, 55° from straight down (the camera, at 47° above it, still
  // sees it).
  const double foot = 55 * M_PI / 180;
  for (double y = -20; y <= 20; y += 0.4)
    for (double t = 0; t <= 6; t += 0.4)
      cloud.points_mm.emplace_back(static_cast<float>(60 + std::cos(foot) * t),
                                   static_cast<float>(y),
                                   static_cast<float>(0.6 + std::sin(foot) * t));
  ConditioningOptions options = Conditioning({200, 0, 150});
  options.outlier_neighbors = 0;
  options.crop.enabled = true;
  options.crop.volume.min_height_mm = 0.5;
  options.crop.platter_band_mm = 1.5;
  options.crop.platter_normal_deg = 60;
  auto count = [](const ViewCloud& v, auto&& in_region) {
    int n = 0;
    for (const cv::Vec3f& p : v.fine.points_mm) n += in_region(p) ? 1 : 0;
    return n;
  };
  auto wall_low = [](const cv::Vec3f& p) { return p[0] > 19 && p[0] < 21 && p[2] < 1.5f; };
  auto ramp_low = [](const cv::Vec3f& p) { return p[0] > 39 && p[0] < 55 && p[2] < 1.5f; };
  auto ramp_high = [](const cv::Vec3f& p) { return p[0] > 39 && p[0] < 55 && p[2] > 2.f; };
  auto foot_low = [](const cv::Vec3f& p) { return p[0] > 59 && p[2] < 1.5f; };
  auto level = [](const cv::Vec3f& p) { return p[0] < 1; };
  const ViewCloud steep = ConditionCloud(cloud, options);
  ASSERT_TRUE(steep.ok()) << steep.error;
  EXPECT_GE(count(steep, wall_low), 30);  // 41 voxels of 1 mm along the wall's foot
  EXPECT_EQ(count(steep, ramp_low), 0);
  EXPECT_GE(count(steep, ramp_high), 300);
  EXPECT_EQ(count(steep, level), 0);
  EXPECT_GE(count(steep, foot_low), 30);  // facing down: not the platter
  for (const cv::Vec3f& p : steep.fine.points_mm) ASSERT_GE(p[2], 0.5f) << p;
  // Level only within 30°: the ramp's foot stays, the level noise still goes.
  options.crop.platter_normal_deg = 30;
  const ViewCloud level_only = ConditionCloud(cloud, options);
  ASSERT_TRUE(level_only.ok()) << level_only.error;
  EXPECT_GE(count(level_only, ramp_low), 30);
  EXPECT_EQ(count(level_only, level), 0);
  EXPECT_GE(count(level_only, wall_low), 30);
  // The band at the volume's bottom does nothing: the level noise stays.
  options.crop.platter_band_mm = 0.5;
  EXPECT_GE(count(ConditionCloud(cloud, options), level), 500);
}

TEST(Registration, DeterministicForAnyThreadCount) {
  const cv::Matx44d truth = Pose({0.05, 0.3, 0.1}, {8, 3, -6});
  Pair pair = MakePair(3, truth, 0.2);
  RegistrationOptions one;
  one.num_threads = 1;
  RegistrationOptions three = one;
  three.num_threads = 3;
  const RegistrationResult a = RegisterPair(pair.source, pair.target, one);
  const RegistrationResult b = RegisterPair(pair.source, pair.target, three);
  ASSERT_TRUE(a.IsUsable() && b.IsUsable());
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) EXPECT_EQ(a.target_from_source(r, c), b.target_from_source(r, c));
  EXPECT_EQ(a.iterations, b.iterations);
}

TEST(Registration, CorrectPriorIsKeptAndWrongPriorReplaced) {
  const cv::Matx44d truth = Pose({0, 0, 0.6}, {0, 0, 0});
  Pair pair = MakePair(5, truth);
  RegistrationOptions options;
  options.num_threads = 2;
  options.coarse.prior_target_from_source = truth;
  options.coarse.prior_accept_fitness = 0.3;
  RegistrationResult r = RegisterPair(pair.source, pair.target, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_TRUE(r.prior_kept);
  EXPECT_LT(RotationErrorDeg(r.target_from_source, truth), 0.05);

  // A prior 90° and 30 mm off (a wrong commanded angle, a moved object),
  // verified by RANSAC: fine registration from it ends in a poor local
  // minimum, so RANSAC's pose replaces it.
  options.coarse.prior_accept_fitness = 0;
  options.coarse.prior_target_from_source = Pose({0, 0, 0.6 + M_PI / 2}, {30, 0, 0});
  r = RegisterPair(pair.source, pair.target, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_FALSE(r.prior_kept);
  EXPECT_LT(RotationErrorDeg(r.target_from_source, truth), 0.05);
  EXPECT_LT(TranslationErrorMm(r.target_from_source, truth), 0.05);
}

TEST(Registration, EmptyAndTinyInputsFailWithAReason) {
  const ViewCloud empty = ConditionCloud(PointCloud{}, Conditioning());
  EXPECT_FALSE(empty.ok());
  EXPECT_NE(empty.error.find("no points"), std::string::npos) << empty.error;

  PointCloud nan_cloud;
  nan_cloud.points_mm.assign(100, cv::Vec3f(NAN, 0, 0));
  const ViewCloud nans = ConditionCloud(nan_cloud, Conditioning());
  EXPECT_FALSE(nans.ok());

  const ViewCloud good = ConditionCloud(BumpySurface(1), Conditioning());
  ASSERT_TRUE(good.ok());
  RegistrationResult r = RegisterPair(empty, good, RegistrationOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("conditioning failed"), std::string::npos) << r.message;

  PointCloud few;
  for (int i = 0; i < 20; ++i) few.points_mm.emplace_back(i * 5.f, (i % 4) * 5.f, (i % 3) * 4.f);
  const ViewCloud tiny = ConditionCloud(few, Conditioning());
  ASSERT_TRUE(tiny.ok()) << tiny.error;
  r = RegisterPair(tiny, good, RegistrationOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("too few points"), std::string::npos) << r.message;
}

TEST(Registration, FlatPlaneFailsInsteadOfAWrongSuccess) {
  PointCloud plane;
  for (double y = -50; y <= 50; y += 0.7)
    for (double x = -50; x <= 50; x += 0.7) plane.points_mm.emplace_back(x, y, 0);
  AddNoise(&plane, 0.05, 9);
  const ViewCloud a = ConditionCloud(plane, Conditioning());
  const ViewCloud b =
      ConditionCloud(TransformCloud(Pose({0, 0, 0.3}, {5, 0, 0}), plane), Conditioning());
  ASSERT_TRUE(a.ok() && b.ok());
  const RegistrationResult r = RegisterPair(a, b, RegistrationOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("plane"), std::string::npos) << r.message;
}

TEST(Registration, SphereNeedsAPrior) {
  PointCloud cap;
  for (double th = 0; th < 1.2; th += 0.012)
    for (double ph = 0; ph < 2 * M_PI; ph += 0.012 / std::max(0.05, std::sin(th)))
      cap.points_mm.emplace_back(40 * std::sin(th) * std::cos(ph), 40 * std::sin(th) * std::sin(ph),
                                 40 * std::cos(th));
  AddNoise(&cap, 0.05, 4);
  const ViewCloud a = ConditionCloud(cap, Conditioning());
  const ViewCloud b = ConditionCloud(cap, Conditioning());
  ASSERT_TRUE(a.ok() && b.ok());
  RegistrationOptions options;
  RegistrationResult r = RegisterPair(a, b, options);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("degenerate geometry"), std::string::npos) << r.message;

  options.coarse.prior_target_from_source = cv::Matx44d::eye();
  r = RegisterPair(a, b, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_NE(r.message.find("kept from the prior"), std::string::npos) << r.message;
  EXPECT_LT(TranslationErrorMm(r.target_from_source, cv::Matx44d::eye()), 0.1);
}

TEST(Registration, NoOverlapFails) {
  // Two unrelated rough surfaces: no rigid motion lays one on the other.
  const ViewCloud a = ConditionCloud(BumpySurface(21, 100, 0.7, -1e9, 1e9, true), Conditioning());
  const ViewCloud b = ConditionCloud(BumpySurface(22, 100, 0.7, -1e9, 1e9, true), Conditioning());
  ASSERT_TRUE(a.ok() && b.ok());
  RegistrationOptions options;
  options.num_threads = 2;
  const RegistrationResult r = RegisterPair(a, b, options);
  EXPECT_FALSE(r.IsUsable()) << "fitness " << r.fitness << " rmse " << r.rmse_mm;
  EXPECT_NE(r.message.find("no overlap"), std::string::npos) << r.message;
}

TEST(Registration, InvalidOptionsAreNamed) {
  RegistrationOptions options;
  options.coarse.confidence = 1.5;
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("coarse.confidence"), std::string::npos) << why;
  ConditioningOptions c;
  c.coarse_voxel_mm = 0.5;  // finer than the fine voxel
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_NE(why.find("coarse_voxel_mm"), std::string::npos) << why;
  const ViewCloud v = ConditionCloud(BumpySurface(1), c);
  EXPECT_FALSE(v.ok());
  EXPECT_NE(v.error.find("coarse_voxel_mm"), std::string::npos) << v.error;
  RegistrationOptions weak;
  weak.prior_weak_constraint = 1.0;
  EXPECT_FALSE(weak.IsValid(&why));
  EXPECT_NE(why.find("prior_weak_constraint"), std::string::npos) << why;
}

// A vase: radius 20 + 5·sin(z / 8) mm about the z axis, z in [0, 60], with
// its outward normals; optionally a handle (the two sides of a fin at
// x = 25…35 mm, y = ±2 mm, z = 10…50 mm) that holds the turn about the axis.
PointCloud Vase(bool handle) {
  PointCloud cloud;
  for (double z = 0; z <= 60; z += 0.5) {
    const double r = 20 + 5 * std::sin(z / 8), dr = 5.0 / 8 * std::cos(z / 8);
    for (double a = 0; a < 2 * M_PI; a += 0.5 / r) {
      cloud.points_mm.emplace_back(r * std::cos(a), r * std::sin(a), z);
      const cv::Vec3d n = cv::normalize(cv::Vec3d(std::cos(a), std::sin(a), -dr));
      cloud.normals.emplace_back(n);
    }
  }
  if (handle) {
    for (double x = 25; x <= 35; x += 0.25)
      for (double z = 10; z <= 50; z += 0.25)
        for (const double side : {-1.0, 1.0}) {
          cloud.points_mm.emplace_back(x, 2 * side, z);
          cloud.normals.emplace_back(0, side, 0);
        }
  }
  return cloud;
}

// The prior kept along what the surface does not hold, the registration's
// motion along what it holds: on a vase turned 0.3° about its axis and moved
// (0.2, −0.1, 0.15) mm off the prior, 99 % of the turn is dropped and the
// shift kept to the micrometre; with a handle (or without the rule) all of
// it is kept.
TEST(Registration, WeakMotionsKeepThePrior) {
  const cv::Matx44d prior = Pose({0.1, -0.2, 0.5}, {5, -3, 2});
  const cv::Matx44d turn = Pose({0, 0, 0.3 * M_PI / 180}, {0, 0, 0});
  const cv::Matx44d shift = Pose({0, 0, 0}, {0.2, -0.1, 0.15});
  const cv::Matx44d registered = prior * shift * turn;
  int weak = -1;
  const cv::Matx44d kept = KeepPriorAlongWeakMotions(Vase(false), prior, registered, 0.05, &weak);
  EXPECT_EQ(weak, 1);
  const cv::Matx44d expected = prior * shift;
  EXPECT_LT(RotationErrorDeg(expected, kept), 0.003);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(kept(i, 3), expected(i, 3), 1e-3) << i;

  const cv::Matx44d held = KeepPriorAlongWeakMotions(Vase(true), prior, registered, 0.05, &weak);
  EXPECT_EQ(weak, 0);
  EXPECT_LT(RotationErrorDeg(registered, held), 1e-6);
  const cv::Matx44d off = KeepPriorAlongWeakMotions(Vase(false), prior, registered, 0, &weak);
  EXPECT_EQ(weak, 0);
  EXPECT_LT(RotationErrorDeg(registered, off), 1e-6);
  EXPECT_EQ(KeepPriorAlongWeakMotions(PointCloud{}, prior, registered, 0.05, &weak), registered);
}

// --- Loop closure ----------------------------------------------------------------

// The corners of an object's box around (0, 60, 400) in view 0's frame.
std::vector<cv::Vec3d> Samples() {
  std::vector<cv::Vec3d> s;
  for (int m = 0; m < 8; ++m)
    s.emplace_back(m & 1 ? 40 : -40, 60 + (m & 2 ? 30 : -30), 400 + (m & 4 ? 40 : -40));
  return s;
}

// Six views turning about an axis; pairwise edges with small errors that
// accumulate around the ring.
struct Ring {
  std::vector<cv::Matx44d> truth;  // view0_from_view
  std::vector<PoseEdge> edges;
  std::vector<cv::Matx44d> chained;
};

Ring MakeRing(const cv::Vec3d& axis, const cv::Vec3d& point, unsigned seed, double rot_noise_rad,
              double trans_noise_mm, const cv::Vec3d& drift_mm = {0, 0, 0}) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> rn(0, rot_noise_rad), tn(0, trans_noise_mm);
  Ring ring;
  const int n = 6;
  for (int k = 0; k < n; ++k) {
    cv::Matx44d T = RotationAboutAxis(axis, point, -k * M_PI / 3);
    for (int i = 0; i < 3; ++i) T(i, 3) += drift_mm[i] * (k % 2);  // object slipping back and forth
    ring.truth.push_back(T);
  }
  // Registration errors: a small rotation about the object's centre and a
  // small translation.
  const cv::Vec3d centre(0, 60, 400);
  auto noisy = [&](const cv::Matx44d& T) {
    const cv::Matx44d to = Pose({0, 0, 0}, centre), from = Pose({0, 0, 0}, -centre);
    return to * Pose({rn(rng), rn(rng), rn(rng)}, {tn(rng), tn(rng), tn(rng)}) * from * T;
  };
  for (int k = 1; k < n; ++k)
    ring.edges.push_back({k, k - 1, noisy(InvertRigid(ring.truth[k - 1]) * ring.truth[k]), 1});
  ring.edges.push_back({0, n - 1, noisy(InvertRigid(ring.truth[n - 1]) * ring.truth[0]), 1});
  ring.chained.assign(n, cv::Matx44d::eye());
  for (int k = 1; k < n; ++k)
    ring.chained[k] = ring.chained[k - 1] * ring.edges[k - 1].target_from_source;
  return ring;
}

TEST(LoopClosure, TurntableAxisModelRemovesAccumulatedDrift) {
  const cv::Vec3d axis = cv::normalize(cv::Vec3d(0.05, -0.86, -0.5));
  const cv::Vec3d point(3, 60, 400);
  const Ring ring = MakeRing(axis, point, 1, 0.0015, 0.08);
  double chained_worst = 0, chained_worst_rot = 0;
  for (int k = 0; k < 6; ++k) {
    chained_worst = std::max(chained_worst, TranslationErrorMm(ring.chained[k], ring.truth[k]));
    chained_worst_rot =
        std::max(chained_worst_rot, RotationErrorDeg(ring.chained[k], ring.truth[k]));
  }
  const LoopClosureResult r = CloseLoop(6, ring.edges, ring.chained, Samples(), {});
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_EQ(r.model, LoopClosureResult::Model::kTurntableAxis)
      << r.message << " axis rms " << r.axis_rms_mm << " axis " << r.axis_direction << " point "
      << r.axis_point_mm << " open " << r.open_loop_rms_mm;
  EXPECT_LT(std::acos(std::min(1.0, std::abs(r.axis_direction.dot(axis)))) * 180 / M_PI, 0.3);
  double worst_rot = 0, worst_mm = 0;
  for (int k = 0; k < 6; ++k) {
    worst_rot = std::max(worst_rot, RotationErrorDeg(r.view0_from_view[k], ring.truth[k]));
    // Compare where the poses put the sample points (the axis point is far
    // from the rig origin, so translations alone overstate errors).
    for (const auto& s : Samples()) {
      const cv::Vec4d a = r.view0_from_view[k] * cv::Vec4d(s[0], s[1], s[2], 1);
      const cv::Vec4d b = ring.truth[k] * cv::Vec4d(s[0], s[1], s[2], 1);
      worst_mm = std::max(worst_mm, cv::norm(a - b));
    }
  }
  std::printf("chained: worst %.3f deg %.3f mm; closed: worst %.3f deg %.3f mm (at the samples)\n",
              chained_worst_rot, chained_worst, worst_rot, worst_mm);
  EXPECT_LT(worst_rot, 0.4);
  EXPECT_LT(worst_mm, 0.6);
  EXPECT_GT(r.open_loop_rot_deg, 0.1);  // the ring did not close before
  EXPECT_LT(r.rms_mm, r.open_loop_rms_mm);
  EXPECT_GT(chained_worst, worst_mm);
  ASSERT_EQ(r.angles_rad.size(), 6u);
  EXPECT_NEAR(std::abs(r.angles_rad[3]), M_PI, 0.01);
}

// The tilt of an axis from the truth (deg, either sign).
double AxisTiltDeg(const cv::Vec3d& a, const cv::Vec3d& truth) {
  return std::acos(std::min(1.0, std::abs(cv::normalize(a).dot(cv::normalize(truth))))) * 180 /
         M_PI;
}

// The worst angle between a view's pose and the truth over the ring.
double WorstRotationDeg(const LoopClosureResult& r, const Ring& ring) {
  double worst = 0;
  for (std::size_t k = 0; k < ring.truth.size(); ++k)
    worst = std::max(worst, RotationErrorDeg(r.view0_from_view[k], ring.truth[k]));
  return worst;
}

TEST(LoopClosure, CalibratedAxisHoldsTheViewsWhereTheRegistrationsAgreeWithIt) {
  const cv::Vec3d axis = cv::normalize(cv::Vec3d(0.05, -0.86, -0.5));
  const cv::Vec3d point(3, 60, 400);
  for (unsigned seed = 10; seed < 20; ++seed) {
    const Ring ring = MakeRing(axis, point, seed, 0.0015, 0.08);
    const LoopClosureResult fitted = CloseLoop(6, ring.edges, ring.chained, Samples(), {});
    ASSERT_TRUE(fitted.IsUsable()) << fitted.message;
    EXPECT_FALSE(fitted.calibrated_axis);
    EXPECT_TRUE(std::isnan(fitted.axis_disagreement_deg));
    // The calibration: the true axis, any point on it.
    const LoopClosureResult r = CloseLoop(6, ring.edges, ring.chained, Samples(), {},
                                          CalibratedAxis{-axis, point + 40 * axis});
    ASSERT_TRUE(r.IsUsable()) << r.message;
    EXPECT_EQ(r.model, LoopClosureResult::Model::kTurntableAxis);
    EXPECT_TRUE(r.calibrated_axis) << "seed " << seed << ": " << r.axis_disagreement_deg << " deg, "
                                   << r.axis_disagreement_mm << " mm";
    // The fitted axis is off by the registrations' noise; the disagreement
    // says by how much.
    EXPECT_NEAR(r.axis_disagreement_deg, AxisTiltDeg(fitted.axis_direction, axis), 1e-6);
    EXPECT_LT(AxisTiltDeg(r.axis_direction, axis), 1e-9);
    EXPECT_LE(WorstRotationDeg(r, ring), WorstRotationDeg(fitted, ring) + 1e-9) << "seed " << seed;
    std::printf(
        "seed %u: fitted axis %.3f deg off, worst view %.3f deg; about the calibrated "
        "axis %.3f deg\n",
        seed, AxisTiltDeg(fitted.axis_direction, axis), WorstRotationDeg(fitted, ring),
        WorstRotationDeg(r, ring));
  }
}

TEST(LoopClosure, ACalibrationTheRegistrationsContradictIsNotUsed) {
  const cv::Vec3d axis = cv::normalize(cv::Vec3d(0.05, -0.86, -0.5));
  const cv::Vec3d point(3, 60, 400);
  const Ring ring = MakeRing(axis, point, 4, 0.0015, 0.08);
  // The turntable moved since it was calibrated: its old axis tilted by 2°,
  // or 3 mm aside.
  cv::Matx33d tilt;
  cv::Rodrigues(cv::Vec3d(2 * M_PI / 180, 0, 0), tilt);
  const cv::Vec3d aside = cv::normalize(axis.cross(cv::Vec3d(1, 0, 0))) * 3;
  for (const CalibratedAxis& stale :
       {CalibratedAxis{tilt * axis, point}, CalibratedAxis{axis, point + aside}}) {
    const LoopClosureResult r = CloseLoop(6, ring.edges, ring.chained, Samples(), {}, stale);
    ASSERT_TRUE(r.IsUsable()) << r.message;
    EXPECT_EQ(r.model, LoopClosureResult::Model::kTurntableAxis);
    EXPECT_FALSE(r.calibrated_axis);
    EXPECT_TRUE(r.axis_disagreement_deg > 1.5 || r.axis_disagreement_mm > 2.5)
        << r.axis_disagreement_deg << " deg, " << r.axis_disagreement_mm << " mm";
    EXPECT_LT(AxisTiltDeg(r.axis_direction, axis), 0.3);  // the fitted axis, as without
  }
  LoopClosureOptions bad;
  bad.max_axis_disagreement_deg = 0;
  EXPECT_FALSE(CloseLoop(6, ring.edges, ring.chained, Samples(), bad).IsUsable());
}

TEST(LoopClosure, PoseGraphWhenTheObjectMoved) {
  // The object slips 3 mm sideways every other view: no single axis fits.
  const Ring ring = MakeRing(cv::Vec3d(0, -0.86, -0.5), cv::Vec3d(0, 60, 400), 2, 0.001, 0.05,
                             cv::Vec3d(3, 0, 0));
  const LoopClosureResult r = CloseLoop(6, ring.edges, ring.chained, Samples(), {});
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_EQ(r.model, LoopClosureResult::Model::kPoseGraph);
  EXPECT_GT(r.axis_rms_mm, 0.5);
  for (int k = 0; k < 6; ++k) EXPECT_LT(RotationErrorDeg(r.view0_from_view[k], ring.truth[k]), 0.3);
  EXPECT_LT(r.rms_mm, r.open_loop_rms_mm);
}

TEST(LoopClosure, BadInputIsRejected) {
  const Ring ring = MakeRing(cv::Vec3d(0, 0, 1), cv::Vec3d(0, 0, 0), 3, 0.001, 0.05);
  EXPECT_FALSE(CloseLoop(1, ring.edges, ring.chained, Samples(), {}).IsUsable());
  EXPECT_FALSE(CloseLoop(6, ring.edges, {}, Samples(), {}).IsUsable());
  std::vector<PoseEdge> bad = ring.edges;
  bad[0].target = 9;
  LoopClosureResult r = CloseLoop(6, bad, ring.chained, Samples(), {});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("does not join"), std::string::npos) << r.message;
  // View 5 unreachable.
  std::vector<PoseEdge> cut(ring.edges.begin(), ring.edges.begin() + 4);
  r = CloseLoop(6, cut, ring.chained, Samples(), {});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("not connected"), std::string::npos) << r.message;
  r = CloseLoop(6, ring.edges, ring.chained, {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}}, {});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("one line"), std::string::npos) << r.message;
}

}  // namespace
}  // namespace craftscan
