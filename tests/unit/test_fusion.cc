// Fusion (voxel averaging) and meshing (Poisson, trimming, PLY/OBJ writers)
// against synthetic surfaces with known geometry.
#include <gtest/gtest.h>

#include <sys/mman.h>
#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <opencv2/core.hpp>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/surface/fusion.h"
#include "craftscan/pipeline/surface/mesh.h"
#include "test_util.h"

namespace craftscan {
namespace {

#define EXPECT_CONTAINS(text, part)                          \
  EXPECT_NE(std::string(text).find(part), std::string::npos) \
      << "message: " << (text) << "\nexpected to contain: " << (part)

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The tilted plane z = 0.2·x + 0.1·y + 5 (mm) and its unit normal.
const cv::Vec3d kPlaneNormal = cv::normalize(cv::Vec3d(-0.2, -0.1, 1));
double PlaneDistance(const cv::Vec3f& p) {
  return (p[2] - (0.2 * p[0] + 0.1 * p[1] + 5)) * kPlaneNormal[2];
}

// A 40 × 40 mm patch of the plane sampled every `spacing` mm from `offset`,
// with Gaussian noise σ along the normal, the given normal sign and colour.
PointCloud NoisyPlane(double spacing, double offset, double sigma, double normal_sign,
                      cv::Vec3b colour, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, sigma);
  PointCloud cloud;
  for (double x = offset; x < 40; x += spacing)
    for (double y = offset; y < 40; y += spacing) {
      const cv::Vec3d p = cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * noise(rng);
      cloud.points_mm.emplace_back(p);
      cloud.normals.emplace_back(kPlaneNormal * normal_sign);
      cloud.colors_rgb.push_back(colour);
    }
  return cloud;
}

double RmsPlaneDistance(const PointCloud& cloud) {
  double sum = 0;
  for (const cv::Vec3f& p : cloud.points_mm) sum += PlaneDistance(p) * PlaneDistance(p);
  return std::sqrt(sum / static_cast<double>(cloud.size()));
}

// Appends a black point with normal n.
void AddPoint(const cv::Vec3d& p, const cv::Vec3d& n, PointCloud* cloud) {
  cloud->points_mm.emplace_back(p);
  cloud->normals.emplace_back(n);
  cloud->colors_rgb.push_back({0, 0, 0});
}

// Appends a sheet 1 mm above the plane over x, y in 10..20 with σ 0.1 mm
// noise (a patch matched at a slightly wrong disparity), normal the plane's.
void AddOffsetSheet(std::mt19937* rng, PointCloud* cloud) {
  std::normal_distribution<double> noise(0, 0.1);
  for (double x = 10; x < 20; x += 0.4)
    for (double y = 10; y < 20; y += 0.4)
      AddPoint(cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * (1.0 + noise(*rng)),
               kPlaneNormal, cloud);
}

// Views a and b of the plane, and a third view c that saw only the sheet of
// AddOffsetSheet so far: {a, b, c}.
std::vector<PointCloud> PlaneViewsAndASheet(std::mt19937* rng) {
  std::vector<PointCloud> clouds{NoisyPlane(0.5, 0.0, 0.1, 1, {200, 100, 50}, 1),
                                 NoisyPlane(0.5, 0.25, 0.1, 1, {200, 100, 50}, 2),
                                 {}};
  AddOffsetSheet(rng, &clouds[2]);
  return clouds;
}

// ------------------------------------------------------------------ fusion ----

TEST(Fusion, TwoNoisyCopiesReduceNoise) {
  // Two views of one surface, sampled at interleaved positions, σ = 0.2 mm,
  // with opposite normal orientation and different colours.
  const PointCloud a = NoisyPlane(0.25, 0.0, 0.2, +1, {100, 50, 0}, 1);
  const PointCloud b = NoisyPlane(0.25, 0.125, 0.2, -1, {200, 150, 10}, 2);
  FusionOptions options;
  options.voxel_mm = 1.0;
  std::string error;
  FusionStats stats;
  const PointCloud fused = FuseClouds({a, b}, options, &error, &stats);
  ASSERT_TRUE(error.empty()) << error;
  ASSERT_TRUE(fused.IsValid(nullptr));
  ASSERT_TRUE(fused.HasNormals());
  ASSERT_TRUE(fused.HasColors());
  const double rms_in = RmsPlaneDistance(a), rms_out = RmsPlaneDistance(fused);
  std::printf("fusion: %zu + %zu points -> %zu (%.1f per voxel); RMS to plane %.4f -> %.4f mm\n",
              a.size(), b.size(), fused.size(), stats.mean_points_per_voxel, rms_in, rms_out);
  EXPECT_EQ(stats.input_points, a.size() + b.size());
  EXPECT_EQ(stats.output_points, fused.size());
  // ~1 mm voxels over a 40 × 40 mm patch tilted by ≈13°: 2000–3200 occupied
  // voxels (noise spills into neighbours); the refinement along the normal
  // averages a 3×3×3 block (~150 points), so the noise shrinks ~10×.
  EXPECT_GT(fused.size(), 1500u);
  EXPECT_LT(fused.size(), 3600u);
  EXPECT_NEAR(rms_in, 0.2, 0.01);
  EXPECT_LT(rms_out, 0.05);
  for (const cv::Vec3f& p : fused.points_mm) ASSERT_LT(std::abs(PlaneDistance(p)), 0.2);
  // Plain voxel means (no refinement) keep much of the noise along the normal.
  FusionOptions plain = options;
  plain.refine_along_normal = false;
  const PointCloud unrefined = FuseClouds({a, b}, plain, &error);
  ASSERT_EQ(unrefined.size(), fused.size());
  std::printf("fusion without refinement along the normal: RMS to plane %.4f mm\n",
              RmsPlaneDistance(unrefined));
  EXPECT_GT(RmsPlaneDistance(unrefined), 2 * rms_out);
  for (std::size_t i = 0; i < fused.size(); ++i) {
    const cv::Vec3f& n = fused.normals[i];
    ASSERT_NEAR(cv::norm(n), 1.0, 1e-5);
    ASSERT_GT(std::abs(cv::Vec3d(n).dot(kPlaneNormal)), 0.999);
  }
  // Colours: the mean of both views' colours (equal point counts per voxel
  // to within one or two, so close to the midpoint).
  double red = 0;
  for (const cv::Vec3b& c : fused.colors_rgb) red += c[0];
  EXPECT_NEAR(red / static_cast<double>(fused.size()), 150, 5);
}

TEST(Fusion, MultiViewSupportDropsSingleViewFloaters) {
  // Two views of the plane; the first also carries a clump of 500 floaters
  // 10–20 mm above it (a stereo mismatch that only one view makes).
  PointCloud a = NoisyPlane(0.5, 0.0, 0.1, 1, {200, 100, 50}, 1);
  const PointCloud b = NoisyPlane(0.5, 0.25, 0.1, 1, {200, 100, 50}, 2);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  for (int i = 0; i < 500; ++i) {
    const double x = 10 + 5 * u(rng), y = 10 + 5 * u(rng);
    const cv::Vec3d p = cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * (10 + 10 * u(rng));
    a.points_mm.emplace_back(p);
    a.normals.emplace_back(kPlaneNormal);
    a.colors_rgb.push_back({0, 0, 0});
  }
  FusionOptions options;
  options.voxel_mm = 0.5;
  std::string error;
  FusionStats stats;
  const PointCloud all = FuseClouds({a, b}, options, &error, &stats);
  ASSERT_FALSE(all.empty()) << error;
  auto floaters = [](const PointCloud& c) {
    return std::count_if(c.points_mm.begin(), c.points_mm.end(),
                         [](const cv::Vec3f& p) { return std::abs(PlaneDistance(p)) > 2; });
  };
  EXPECT_GT(floaters(all), 400);  // one voxel each, mostly
  options.min_views = 2;
  const PointCloud filtered = FuseClouds({a, b}, options, &error, &stats);
  ASSERT_FALSE(filtered.empty()) << error;
  EXPECT_EQ(floaters(filtered), 0);
  EXPECT_GT(stats.single_view_voxels, 400u);
  // The plane seen by both views stays (all but a rim of single-view voxels).
  EXPECT_GT(static_cast<double>(filtered.size()),
            0.95 * static_cast<double>(all.size() - floaters(all)));
  options.min_views = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("min_views"), std::string::npos) << error;
}

TEST(Fusion, SupportAlongTheNormalDropsOffsetSheetsWhileLoneViewPartsStay) {
  // Two views of the plane. A third view saw a sheet 1 mm above the plane
  // (x, y in 10..20: a patch matched at a slightly wrong disparity), and
  // also the plane's continuation at x 46..60 that no other view saw.
  std::mt19937 rng(4);
  std::vector<PointCloud> clouds = PlaneViewsAndASheet(&rng);
  PointCloud& c = clouds[2];
  std::normal_distribution<double> noise(0, 0.1);
  for (double x = 46; x < 60; x += 0.4)
    for (double y = 0; y < 40; y += 0.4)
      AddPoint(cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * noise(rng), kPlaneNormal,
               &c);
  const auto count = [](const PointCloud& cloud, auto&& pred) {
    return std::count_if(cloud.points_mm.begin(), cloud.points_mm.end(), pred);
  };
  const auto sheet = [](const cv::Vec3f& p) { return std::abs(PlaneDistance(p)) > 0.7; };
  const auto lone = [](const cv::Vec3f& p) { return p[0] > 51; };  // beyond 2 × 2.5 mm of a, b

  FusionOptions options;
  options.voxel_mm = 0.5;
  options.min_views = 2;
  std::string error;
  FusionStats stats;
  // The cube test alone: the sheet lies within view_support_mm of the plane
  // and stays; the lone part goes.
  PointCloud fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  EXPECT_GT(count(fused, sheet), 100);
  EXPECT_EQ(count(fused, lone), 0);
  EXPECT_EQ(stats.lone_view_voxels, 0u);

  options.view_support_normal_mm = 0.4;
  options.lone_view_radius_mm = 2.5;
  fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  EXPECT_LT(count(fused, sheet), 5);
  // The lone part (9 × 40 mm, about 1440 voxels at 0.5 mm) stays whole.
  EXPECT_GT(count(fused, lone), 1300);
  EXPECT_GT(stats.lone_view_voxels, 1300u);
  for (const cv::Vec3f& p : fused.points_mm) ASSERT_LT(std::abs(PlaneDistance(p)), 1.2);
  // The plane itself, seen by a and b, is all there: 80 × 80 voxels or so.
  EXPECT_GT(count(fused, [](const cv::Vec3f& p) { return p[0] < 40; }), 0.95 * 80 * 80);

  options.view_support_normal_mm = -1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "view_support_normal_mm");
  options.view_support_normal_mm = 0.4;
  options.lone_view_radius_mm = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "lone_view_radius_mm");
}

TEST(Fusion, LocalSurfaceSupportDropsTwoViewsWhoseNoisySheetsMeetByChance) {
  // Views a and b saw the plane except a 10 × 10 mm patch (x, y in 10..20);
  // views c and d each matched that patch at a wrong disparity: c a noisy
  // sheet 1.2 mm above the plane, d one 2.4 mm above it (σ 0.35 mm each, so
  // their tails meet), as two views fooled alike by a periodic stitch do.
  std::vector<PointCloud> clouds(4);
  const auto in_patch = [](double x, double y) { return x >= 10 && x < 20 && y >= 10 && y < 20; };
  for (int k = 0; k < 2; ++k) {
    const PointCloud plane = NoisyPlane(0.5, 0.25 * k, 0.1, 1, {200, 100, 50}, 11 + k);
    for (std::size_t i = 0; i < plane.size(); ++i) {
      const cv::Vec3f& p = plane.points_mm[i];
      if (!in_patch(p[0], p[1])) AddPoint(cv::Vec3d(p), kPlaneNormal, &clouds[k]);
    }
  }
  std::mt19937 rng(7);
  for (int k = 0; k < 2; ++k) {
    std::normal_distribution<double> noise(1.2 * (k + 1), 0.35);
    for (double x = 10; x < 20; x += 0.4)
      for (double y = 10; y < 20; y += 0.4)
        AddPoint(cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * noise(rng), kPlaneNormal,
                 &clouds[2 + k]);
  }
  const auto count = [](const PointCloud& cloud, auto&& pred) {
    return std::count_if(cloud.points_mm.begin(), cloud.points_mm.end(), pred);
  };
  const auto sheet = [](const cv::Vec3f& p) { return PlaneDistance(p) > 0.5; };
  const auto plane = [&](const cv::Vec3f& p) {
    return std::abs(PlaneDistance(p)) <= 0.5 && !in_patch(p[0], p[1]);
  };

  FusionOptions options;
  options.voxel_mm = 0.5;
  options.min_views = 2;
  options.view_support_normal_mm = 0.5;
  std::string error;
  FusionStats stats;
  // Without the option a voxel of either sheet finds a point of the other
  // near its plane: most of the patch stays (measured: 620 voxels).
  PointCloud fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  const auto sheet_before = count(fused, sheet);
  const auto plane_before = count(fused, plane);
  EXPECT_GT(sheet_before, 300);

  options.local_surface_support = true;
  for (const int threads : {1, 3}) {
    options.num_threads = threads;
    const PointCloud local = FuseClouds(clouds, options, &error, &stats);
    ASSERT_FALSE(local.empty()) << error;
    // Each sheet's surface lies 1.2 mm from the other's (measured: 5 voxels; the
    // plane 7988 of 7990).
    EXPECT_LT(count(local, sheet), sheet_before / 20) << threads << " threads";
    // The plane a and b agree on stays whole.
    EXPECT_GE(count(local, plane), plane_before * 99 / 100) << threads << " threads";
    if (threads == 3) {
      options.num_threads = 1;
      const PointCloud one = FuseClouds(clouds, options, &error, &stats);
      ASSERT_EQ(one.size(), local.size());
      for (std::size_t i = 0; i < one.size(); ++i) ASSERT_EQ(one.points_mm[i], local.points_mm[i]);
    }
  }

  options.min_local_points = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "min_local_points");
  options.min_local_points = 3;
  options.local_support_incidence_deg = 90;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "local_support_incidence_deg");
  options.local_support_incidence_deg = 70;
  options.local_support_normal_deg = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "local_support_normal_deg");
  options.local_support_normal_deg = 45;
  options.num_threads = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "num_threads");
}

TEST(Fusion, SparseViewsOnTheSamePlaneSupportAFaceOneViewSawSquarely) {
  // View a saw the plane squarely (every 0.5 mm), view b obliquely: a
  // sample every 3 mm, on the plane. View c saw a sheet 1 mm above the
  // plane over x, y in 10..20 (a patch matched at a slightly wrong
  // disparity), densely.
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0, 0.1);
  std::vector<PointCloud> clouds(3);
  for (double x = 0; x < 40; x += 0.5)
    for (double y = 0; y < 40; y += 0.5)
      AddPoint(cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * noise(rng), kPlaneNormal,
               &clouds[0]);
  for (double x = 0.25; x < 40; x += 3)
    for (double y = 0.25; y < 40; y += 3)
      AddPoint(cv::Vec3d(x, y, 0.2 * x + 0.1 * y + 5) + kPlaneNormal * noise(rng), kPlaneNormal,
               &clouds[1]);
  AddOffsetSheet(&rng, &clouds[2]);
  const auto count = [](const PointCloud& cloud, auto&& pred) {
    return std::count_if(cloud.points_mm.begin(), cloud.points_mm.end(), pred);
  };
  const auto sheet = [](const cv::Vec3f& p) { return std::abs(PlaneDistance(p)) > 0.7; };
  const auto plane = [](const cv::Vec3f& p) { return std::abs(PlaneDistance(p)) < 0.5; };

  FusionOptions options;
  options.voxel_mm = 0.5;
  options.min_views = 2;
  options.view_support_normal_mm = 0.5;
  options.lone_view_radius_mm = 2.5;
  std::string error;
  FusionStats stats;
  // Every voxel of the face, without any support rule.
  FusionOptions all = options;
  all.min_views = 1;
  const auto face = count(FuseClouds(clouds, all, &error), plane);
  ASSERT_GT(face, 5000) << error;
  // Support only within view_support_mm (1 mm): the face keeps only the
  // part near b's samples.
  PointCloud fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  const auto without = count(fused, plane);
  EXPECT_LT(without, 0.75 * face);
  EXPECT_EQ(stats.plane_supported_voxels, 0u);

  options.plane_support_mm = 2.5;
  fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  EXPECT_GT(count(fused, plane), 0.98 * face) << "without: " << without << " of " << face;
  EXPECT_GE(stats.plane_supported_voxels, static_cast<std::size_t>(0.9 * (face - without)));
  // The sheet is on no other view's plane: it goes as before.
  EXPECT_LT(count(fused, sheet), 5);

  options.plane_support_mm = -1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "plane_support_mm");
}

TEST(Fusion, PartsOnlyTheirOwnCameraFacedStayWithoutSupport) {
  // Views a and b see the plane from cameras above it. View c, a camera off
  // to the side at +x, sees a wall at x = 60 facing it (normal +x), which a's
  // and b's cameras see from behind; c also left a sheet 1 mm above the
  // plane (normal: the plane's), which a's and b's cameras face squarely.
  std::mt19937 rng(5);
  std::vector<PointCloud> clouds = PlaneViewsAndASheet(&rng);
  std::normal_distribution<double> noise(0, 0.1);
  for (double y = 0; y < 40; y += 0.4)  // the wall, in c
    for (double z = 0; z < 20; z += 0.4)
      AddPoint(cv::Vec3d(60 + noise(rng), y, z), {1, 0, 0}, &clouds[2]);
  const cv::Vec3d above = cv::Vec3d(20, 20, 9) + 300 * kPlaneNormal;
  const std::vector<cv::Vec3d> centers{
      above + cv::Vec3d(-20, 0, 0), above + cv::Vec3d(20, 0, 0), {360, 20, 10}};
  const auto count = [](const PointCloud& cloud, auto&& pred) {
    return std::count_if(cloud.points_mm.begin(), cloud.points_mm.end(), pred);
  };
  const auto sheet = [](const cv::Vec3f& p) { return p[0] < 40 && PlaneDistance(p) > 0.7; };
  const auto wall = [](const cv::Vec3f& p) { return p[0] > 55; };

  FusionOptions options;
  options.voxel_mm = 0.5;
  options.min_views = 2;
  options.view_support_normal_mm = 0.4;
  std::string error;
  FusionStats stats;
  PointCloud fused = FuseClouds(clouds, options, &error, &stats, &centers);
  ASSERT_FALSE(fused.empty()) << error;
  EXPECT_EQ(count(fused, wall), 0);  // off: unsupported voxels go
  EXPECT_EQ(stats.sole_view_voxels, 0u);

  options.sole_view_incidence_deg = 70;
  fused = FuseClouds(clouds, options, &error, &stats, &centers);
  ASSERT_FALSE(fused.empty()) << error;
  // The wall (40 × 20 mm, about 3200 voxels at 0.5 mm) stays; the sheet goes.
  EXPECT_GT(count(fused, wall), 3000);
  EXPECT_GT(stats.sole_view_voxels, 3000u);
  EXPECT_LT(count(fused, sheet), 5);
  // Without the cameras the rule has nothing to go by.
  fused = FuseClouds(clouds, options, &error, &stats);
  EXPECT_EQ(count(fused, wall), 0);
  // Seen only at a grazing angle by its own camera, the wall needs support
  // too: c's camera moved up to 80° off the wall's normal.
  const std::vector<cv::Vec3d> grazing{
      centers[0], centers[1], {60 + 300 * std::cos(1.4), 20, 10 + 300 * std::sin(1.4)}};
  fused = FuseClouds(clouds, options, &error, &stats, &grazing);
  EXPECT_LT(count(fused, wall), 100);
  // ... unless every other camera is behind it (a and b are): then no other
  // view could have confirmed it, and 80° is within the hidden-view angle.
  options.hidden_view_incidence_deg = 85;
  fused = FuseClouds(clouds, options, &error, &stats, &grazing);
  EXPECT_GT(count(fused, wall), 3000);
  EXPECT_GT(stats.hidden_view_voxels, 3000u);
  EXPECT_LT(count(fused, sheet), 5);  // a and b face the sheet: it still goes
  // Not at 88°, beyond that angle.
  const std::vector<cv::Vec3d> edge_on{
      centers[0], centers[1], {60 + 300 * std::cos(1.536), 20, 10 + 300 * std::sin(1.536)}};
  fused = FuseClouds(clouds, options, &error, &stats, &edge_on);
  EXPECT_LT(count(fused, wall), 100);
  // Nor when another camera sees its front, even at a grazing angle: a's
  // camera moved out to 85° off the wall's normal, in front of it.
  const std::vector<cv::Vec3d> witness{
      {60 + 300 * std::cos(1.48), 20, 10 + 300 * std::sin(1.48)}, centers[1], grazing[2]};
  fused = FuseClouds(clouds, options, &error, &stats, &witness);
  EXPECT_LT(count(fused, wall), 100);
  options.hidden_view_incidence_deg = 0;

  const std::vector<cv::Vec3d> two{centers[0], centers[1]};
  EXPECT_TRUE(FuseClouds(clouds, options, &error, &stats, &two).empty());
  EXPECT_CONTAINS(error, "2 camera centres for 3 clouds");
  const std::vector<cv::Vec3d> bad{centers[0], centers[1], {kNaN, 0, 0}};
  EXPECT_TRUE(FuseClouds(clouds, options, &error, &stats, &bad).empty());
  EXPECT_CONTAINS(error, "camera centre is not finite");
  options.sole_view_incidence_deg = 90;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "sole_view_incidence_deg");
  options.sole_view_incidence_deg = 70;
  options.hidden_view_incidence_deg = -1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "hidden_view_incidence_deg");
}

// Points every 0.25 mm on the 6 × 2 mm rectangle at `center` spanned by
// the unit vectors u (6 mm) and v (2 mm), normal n, appended to `cloud`.
void AddPatch(const cv::Vec3d& center, const cv::Vec3d& u, const cv::Vec3d& v, const cv::Vec3d& n,
              PointCloud* cloud) {
  for (double a = -3; a <= 3; a += 0.25)
    for (double b = -1; b <= 1; b += 0.25) AddPoint(center + a * u + b * v, n, cloud);
}

TEST(Fusion, UnderAnOverhangByThePlatterAFaceDownNeedsTwoViews) {
  // The platter is z = 0. Facing down and outwards (37° from straight
  // down), 0.9–2.1 mm above it: a skirt only view c made (the platter smeared up
  // under an overhang) and a foot views a and b both saw. View c alone also
  // saw a wall facing sideways at the same height and a face down at 6 mm
  // (the underside of a handle): parts no other view saw, which stay.
  const cv::Vec3d down_out(0.6, 0, -0.8), along(0, 1, 0), slope(0.8, 0, 0.6);
  std::vector<PointCloud> clouds(3);
  AddPatch({0, 0, 1.5}, along, slope, down_out, &clouds[2]);   // skirt
  AddPatch({30, 0, 1.5}, along, slope, down_out, &clouds[0]);  // foot
  AddPatch({30.1, 0.1, 1.5}, along, slope, down_out, &clouds[1]);
  AddPatch({60, 0, 1.5}, along, {0, 0, 1}, {1, 0, 0}, &clouds[2]);  // wall
  AddPatch({90, 0, 6}, along, slope, down_out, &clouds[2]);         // underside
  const auto count_near = [](const PointCloud& cloud, double x) {
    return std::count_if(cloud.points_mm.begin(), cloud.points_mm.end(),
                         [x](const cv::Vec3f& p) { return std::abs(p[0] - x) < 5; });
  };
  FusionOptions options;
  options.min_views = 2;
  options.lone_view_radius_mm = 2.5;
  std::string error;
  FusionStats stats;
  // Without the platter's rule, every part one view saw alone stays.
  PointCloud fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  const auto skirt = count_near(fused, 0);
  EXPECT_GT(skirt, 30);
  EXPECT_EQ(stats.platter_shadow_voxels, 0u);

  options.platter_shadow_mm = 3;
  options.platter = {0, 0, 1, 0};
  fused = FuseClouds(clouds, options, &error, &stats);
  ASSERT_FALSE(fused.empty()) << error;
  EXPECT_EQ(count_near(fused, 0), 0);
  EXPECT_EQ(stats.platter_shadow_voxels, static_cast<std::size_t>(skirt));
  EXPECT_GT(count_near(fused, 30), 30);  // the foot
  EXPECT_GT(count_near(fused, 60), 30);  // the wall
  EXPECT_GT(count_near(fused, 90), 30);  // the underside, above the band
  // The platter 5 mm lower (d = 5): everything is above the band again.
  options.platter = {0, 0, 1, 5};
  fused = FuseClouds(clouds, options, &error, &stats);
  EXPECT_EQ(count_near(fused, 0), skirt);
  // A narrower angle: the faces are 37° from straight down.
  options.platter = {0, 0, 1, 0};
  options.platter_shadow_normal_deg = 30;
  fused = FuseClouds(clouds, options, &error, &stats);
  EXPECT_EQ(count_near(fused, 0), skirt);
  // An unknown platter: not applied.
  options.platter_shadow_normal_deg = 60;
  options.platter = {0, 0, 0, 0};
  fused = FuseClouds(clouds, options, &error, &stats);
  EXPECT_EQ(count_near(fused, 0), skirt);

  options.platter_shadow_mm = -1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "platter_shadow_mm");
  options.platter_shadow_mm = 3;
  options.platter_shadow_normal_deg = 90;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "platter_shadow_normal_deg");
  options.platter_shadow_normal_deg = 60;
  options.platter[3] = kNaN;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "platter");
}

TEST(Fusion, SparseVoxelsAndNonFinitePointsAreDropped) {
  PointCloud cloud = NoisyPlane(0.25, 0.0, 0.05, +1, {10, 20, 30}, 3);
  const std::size_t plane_points = cloud.size();
  // Isolated outliers far from the plane, one per voxel, and NaNs.
  for (int i = 0; i < 10; ++i) {
    cloud.points_mm.emplace_back(10.f * i, 0.f, 100.f);
    cloud.normals.emplace_back(0, 0, 1);
    cloud.colors_rgb.emplace_back(0, 0, 0);
  }
  cloud.points_mm.emplace_back(kNaN, 0.f, 0.f);
  cloud.normals.emplace_back(0, 0, 1);
  cloud.colors_rgb.emplace_back(0, 0, 0);
  FusionOptions options;
  options.voxel_mm = 1.0;
  options.min_points_per_voxel = 3;
  std::string error;
  FusionStats stats;
  const PointCloud fused = FuseClouds({cloud}, options, &error, &stats);
  ASSERT_TRUE(error.empty()) << error;
  EXPECT_EQ(stats.nonfinite_points, 1u);
  EXPECT_GE(stats.sparse_voxel_points, 10u);
  for (const cv::Vec3f& p : fused.points_mm) ASSERT_LT(std::abs(PlaneDistance(p)), 0.2);
  EXPECT_GT(fused.size(), plane_points / 20);
  // Colours pass through unchanged when every point has the same one.
  for (const cv::Vec3b& c : fused.colors_rgb) ASSERT_EQ(c, cv::Vec3b(10, 20, 30));
}

TEST(Fusion, AttributesOnlyWhenEveryInputHasThem) {
  PointCloud a = NoisyPlane(0.5, 0.0, 0.0, +1, {1, 2, 3}, 4);
  PointCloud b = NoisyPlane(0.5, 0.25, 0.0, +1, {1, 2, 3}, 5);
  b.normals.clear();
  a.colors_rgb.clear();
  std::string error;
  const PointCloud fused = FuseClouds({a, b, PointCloud{}}, FusionOptions{}, &error);
  ASSERT_TRUE(error.empty()) << error;
  EXPECT_FALSE(fused.empty());
  EXPECT_FALSE(fused.HasNormals());
  EXPECT_FALSE(fused.HasColors());
  // Deterministic: the same input gives the same output.
  const PointCloud again = FuseClouds({a, b, PointCloud{}}, FusionOptions{}, &error);
  ASSERT_EQ(again.size(), fused.size());
  for (std::size_t i = 0; i < fused.size(); ++i) ASSERT_EQ(again.points_mm[i], fused.points_mm[i]);
}

TEST(Fusion, DegenerateInputsFail) {
  std::string error;
  PointCloud out = FuseClouds({}, FusionOptions{}, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "no input points");

  out = FuseClouds({PointCloud{}, PointCloud{}}, FusionOptions{}, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "no input points");

  PointCloud nans;
  nans.points_mm.assign(20, cv::Vec3f(kNaN, 1, 2));
  out = FuseClouds({nans}, FusionOptions{}, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "20 non-finite");

  PointCloud far;
  far.points_mm.assign(5, cv::Vec3f(1e9f, 0, 0));
  out = FuseClouds({far}, FusionOptions{}, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "out of range");

  PointCloud bad;
  bad.points_mm.assign(5, cv::Vec3f(0, 0, 0));
  bad.normals.assign(2, cv::Vec3f(0, 0, 1));
  out = FuseClouds({bad}, FusionOptions{}, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "cloud 0 is invalid");

  FusionOptions options;
  options.voxel_mm = 0;
  EXPECT_FALSE(options.IsValid(nullptr));
  out = FuseClouds({NoisyPlane(1, 0, 0, 1, {}, 1)}, options, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "voxel_mm");
  options = FusionOptions{};
  options.min_points_per_voxel = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_CONTAINS(error, "min_points_per_voxel");

  // Nothing dense enough.
  options = FusionOptions{};
  options.min_points_per_voxel = 1000;
  out = FuseClouds({NoisyPlane(1, 0, 0, 1, {}, 1)}, options, &error);
  EXPECT_TRUE(out.empty());
  EXPECT_CONTAINS(error, "min_points_per_voxel");
}

TEST(Fusion, SmallDetachedClustersAreDroppedAndTheObjectKept) {
  // The object: a 40 × 40 mm patch; floaters: a 3 × 3 mm speck 20 mm above
  // it and a 1 mm sliver 10 mm beside it.
  PointCloud cloud = NoisyPlane(0.25, 0, 0.02, 1, cv::Vec3b(200, 0, 0), 3);
  const std::size_t object_points = cloud.size();
  for (double x = 10; x < 13; x += 0.25)
    for (double y = 10; y < 13; y += 0.25) {
      cloud.points_mm.emplace_back(x, y, 0.2 * x + 0.1 * y + 25);
      cloud.normals.emplace_back(kPlaneNormal);
      cloud.colors_rgb.emplace_back(0, 200, 0);
    }
  for (double y = 0; y < 1; y += 0.25) {
    cloud.points_mm.emplace_back(50, y, 0.2 * 50 + 0.1 * y + 5);
    cloud.normals.emplace_back(kPlaneNormal);
    cloud.colors_rgb.emplace_back(0, 0, 200);
  }
  FusionOptions options;
  options.refine_along_normal = false;
  FusionStats stats;
  std::string error;
  const PointCloud all = FuseClouds({cloud}, options, &error, &stats);
  ASSERT_FALSE(all.empty()) << error;
  EXPECT_EQ(stats.clusters, 0u);  // off by default
  options.min_cluster_fraction = 0.05;
  const PointCloud kept = FuseClouds({cloud}, options, &error, &stats);
  ASSERT_FALSE(kept.empty()) << error;
  EXPECT_EQ(stats.clusters, 3u);
  EXPECT_EQ(stats.small_cluster_voxels, all.size() - kept.size());
  EXPECT_GT(stats.small_cluster_voxels, 20u);
  for (const cv::Vec3f& p : kept.points_mm)
    ASSERT_LT(std::abs(PlaneDistance(p)), 0.5) << p;  // only the patch is left
  EXPECT_GT(kept.size(), object_points / 4);          // 4 points per 0.5 mm voxel
  // Bad values are refused, naming the field.
  options.min_cluster_fraction = 1.5;
  EXPECT_TRUE(FuseClouds({cloud}, options, &error).empty());
  EXPECT_CONTAINS(error, "min_cluster_fraction");
  options.min_cluster_fraction = 0.05;
  options.cluster_gap_mm = 0.1;  // below the voxel
  EXPECT_TRUE(FuseClouds({cloud}, options, &error).empty());
  EXPECT_CONTAINS(error, "cluster_gap_mm");
}

// ------------------------------------------------------------------ meshing ----

constexpr double kRadius = 30;

// Fibonacci sphere of radius 30 mm about `centre`, outward normals, colour by
// height; only points with z ≥ min_z (relative to the centre) are kept.
PointCloud Sphere(int count, const cv::Vec3d& centre, double min_z = -1e9) {
  PointCloud cloud;
  const double golden = std::numbers::pi * (3 - std::sqrt(5.0));
  for (int i = 0; i < count; ++i) {
    const double z = 1 - 2 * (i + 0.5) / count;
    const double r = std::sqrt(1 - z * z);
    const cv::Vec3d n(r * std::cos(golden * i), r * std::sin(golden * i), z);
    if (kRadius * z < min_z) continue;
    cloud.points_mm.emplace_back(centre + kRadius * n);
    cloud.normals.emplace_back(n);
    cloud.colors_rgb.emplace_back(static_cast<std::uint8_t>(127 + 127 * z), 40, 200);
  }
  return cloud;
}

class Mesh : public testing::TempDirTest {};

// The share of faces pointing away from `centre`.
double OutwardShare(const TriangleMesh& mesh, const cv::Vec3d& centre) {
  std::size_t outward = 0;
  for (const cv::Vec3i& f : mesh.faces) {
    const cv::Vec3d a(mesh.vertices_mm[static_cast<std::size_t>(f[0])]);
    const cv::Vec3d b(mesh.vertices_mm[static_cast<std::size_t>(f[1])]);
    const cv::Vec3d c(mesh.vertices_mm[static_cast<std::size_t>(f[2])]);
    outward += (b - a).cross(c - a).dot((a + b + c) / 3 - centre) > 0 ? 1 : 0;
  }
  return static_cast<double>(outward) / static_cast<double>(mesh.faces.size());
}

TEST_F(Mesh, PoissonSphere) {
  const cv::Vec3d centre(10, -20, 150);
  const PointCloud cloud = Sphere(12000, centre);  // ≈ 1 mm spacing
  const MeshResult r = PoissonMesh(cloud, PoissonOptions{});
  ASSERT_TRUE(r.IsUsable()) << r.message;
  const TriangleMesh& mesh = r.mesh;
  std::string why;
  ASSERT_TRUE(mesh.IsValid(&why)) << why;
  ASSERT_EQ(mesh.normals.size(), mesh.vertices_mm.size());
  ASSERT_EQ(mesh.colors_rgb.size(), mesh.vertices_mm.size());
  double max_error = 0, sum_error = 0;
  for (const cv::Vec3f& v : mesh.vertices_mm) {
    const double e = std::abs(cv::norm(cv::Vec3d(v) - centre) - kRadius);
    max_error = std::max(max_error, e);
    sum_error += e;
  }
  const double mean_error = sum_error / static_cast<double>(mesh.vertices_mm.size());
  std::printf(
      "Poisson sphere: %zu vertices, %zu faces (raw %zu/%zu), %.2f s; "
      "|r − 30| mean %.4f max %.4f mm\n",
      mesh.vertices_mm.size(), mesh.faces.size(), r.raw_vertices, r.raw_faces, r.seconds,
      mean_error, max_error);
  EXPECT_GT(mesh.faces.size(), 10000u);
  EXPECT_LT(max_error, 0.3);
  EXPECT_LT(mean_error, 0.1);
  // A closed, fully supported surface loses nothing to trimming.
  EXPECT_EQ(r.trimmed_vertices, 0u);
  // Faces and vertex normals point outwards.
  EXPECT_EQ(OutwardShare(mesh, centre), 1.0);
  for (std::size_t v = 0; v < mesh.vertices_mm.size(); ++v) {
    const cv::Vec3d radial = cv::normalize(cv::Vec3d(mesh.vertices_mm[v]) - centre);
    ASSERT_GT(radial.dot(cv::Vec3d(mesh.normals[v])), 0.95) << v;
  }
}

// A worker holds several jobs in one process: meshes made on several threads
// at once are each the mesh made alone (PCL's Poisson keeps static state; two
// at once segfaulted before PoissonMesh serialised them).
TEST_F(Mesh, PoissonOnSeveralThreadsAtOnceGivesTheMeshMadeAlone) {
  const PointCloud a = Sphere(6000, {0, 0, 150});
  const PointCloud b = Sphere(9000, {40, 10, 120});
  PoissonOptions options;
  options.num_threads = 1;
  const MeshResult alone_a = PoissonMesh(a, options);
  const MeshResult alone_b = PoissonMesh(b, options);
  ASSERT_TRUE(alone_a.IsUsable() && alone_b.IsUsable());
  std::vector<MeshResult> together(4);
  std::vector<std::thread> threads;
  for (std::size_t i = 0; i < together.size(); ++i)
    threads.emplace_back([&, i] { together[i] = PoissonMesh(i % 2 ? b : a, options); });
  for (std::thread& t : threads) t.join();
  for (std::size_t i = 0; i < together.size(); ++i) {
    const MeshResult& alone = i % 2 ? alone_b : alone_a;
    ASSERT_TRUE(together[i].IsUsable()) << i << ": " << together[i].message;
    EXPECT_EQ(together[i].mesh.faces.size(), alone.mesh.faces.size()) << i;
    ASSERT_EQ(together[i].mesh.vertices_mm.size(), alone.mesh.vertices_mm.size()) << i;
    EXPECT_EQ(together[i].mesh.vertices_mm, alone.mesh.vertices_mm) << i;
  }
}

// A scan-like cloud: an open hemisphere whose points lie up to a millimetre
// off the surface and whose normals are off by up to ~15°, with a sprinkle of
// floaters. PCL's Poisson prints "Vertex pair not in list" for such a cloud.
PointCloud RoughHemisphere() {
  PointCloud cloud = Sphere(20000, {0, 0, 150}, /*min_z=*/-5.0);
  std::mt19937 random(11);
  std::normal_distribution<float> off(0.f, 0.5f), tilt(0.f, 0.15f);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    cloud.points_mm[i] += cv::Vec3f(off(random), off(random), off(random));
    cloud.normals[i] =
        cv::normalize(cloud.normals[i] + cv::Vec3f(tilt(random), tilt(random), tilt(random)));
  }
  return cloud;
}

// PCL's Poisson printf()s diagnostics; a bench's JSON or a test's log must
// not fill with them: none reaches stdout, they are counted, and stdout works
// again after the call.
TEST_F(Mesh, PoissonKeepsWhatPclPrintsOffStdoutAndCountsIt) {
  const PointCloud cloud = RoughHemisphere();
  std::fflush(stdout);
  const int capture = memfd_create("test-stdout", MFD_CLOEXEC);
  const int saved = dup(STDOUT_FILENO);
  ASSERT_GE(capture, 0);
  ASSERT_GE(saved, 0);
  ASSERT_GE(dup2(capture, STDOUT_FILENO), 0);
  std::printf("before\n");
  const MeshResult r = PoissonMesh(cloud, PoissonOptions{});
  std::printf("after\n");
  std::fflush(stdout);
  dup2(saved, STDOUT_FILENO);
  close(saved);
  std::string printed(4096, '\0');
  const ssize_t n = pread(capture, printed.data(), printed.size(), 0);
  close(capture);
  printed.resize(static_cast<std::size_t>(std::max<ssize_t>(n, 0)));
  ASSERT_TRUE(r.IsUsable()) << r.message;
  // Else this cloud no longer makes PCL print, and the test shows nothing.
  EXPECT_GT(r.library_stdout_lines, 0u);
  EXPECT_EQ(printed, "before\nafter\n");
  std::printf("PCL's Poisson printed %zu line(s), kept off stdout\n", r.library_stdout_lines);
}

TEST_F(Mesh, SmallComponentsAreRemoved) {
  // A 30 mm sphere and a 3 mm one beside it: Poisson closes both.
  const cv::Vec3d centre(0, 0, 100), small_centre(60, 0, 100);
  PointCloud cloud = Sphere(12000, centre);
  const PointCloud speck = Sphere(400, cv::Vec3d(0, 0, 0));
  for (std::size_t i = 0; i < speck.size(); ++i) {
    cloud.points_mm.emplace_back(cv::Vec3d(small_centre) + cv::Vec3d(speck.points_mm[i]) * 0.1);
    cloud.normals.push_back(speck.normals[i]);
    cloud.colors_rgb.push_back(speck.colors_rgb[i]);
  }
  const MeshResult both = PoissonMesh(cloud, PoissonOptions{});
  ASSERT_TRUE(both.IsUsable()) << both.message;
  EXPECT_EQ(both.components, 2u);
  EXPECT_EQ(both.removed_components, 0u);
  PoissonOptions options;
  options.min_component_fraction = 0.1;
  const MeshResult one = PoissonMesh(cloud, options);
  ASSERT_TRUE(one.IsUsable()) << one.message;
  EXPECT_EQ(one.components, 1u);
  EXPECT_EQ(one.removed_components, 1u);
  EXPECT_LT(one.mesh.faces.size(), both.mesh.faces.size());
  std::string why;
  ASSERT_TRUE(one.mesh.IsValid(&why)) << why;
  for (const cv::Vec3f& v : one.mesh.vertices_mm)
    ASSERT_LT(std::abs(cv::norm(cv::Vec3d(v) - centre) - kRadius), 0.5) << v;
  options.min_component_fraction = -0.1;
  const MeshResult bad = PoissonMesh(cloud, options);
  EXPECT_FALSE(bad.IsUsable());
  EXPECT_CONTAINS(bad.message, "min_component_fraction");
}

TEST_F(Mesh, OpenSurfaceIsTrimmed) {
  // The upper half of the sphere only: Poisson closes it below; trimming
  // must remove what no input point supports.
  const cv::Vec3d centre(0, 0, 0);
  const PointCloud cloud = Sphere(12000, centre, /*min_z=*/0.0);
  PoissonOptions options;
  options.depth = 7;
  const MeshResult r = PoissonMesh(cloud, options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_GT(r.trimmed_vertices, 0u);
  double min_z = 1e9;
  for (const cv::Vec3f& v : r.mesh.vertices_mm) min_z = std::min<double>(min_z, v[2]);
  std::printf("open hemisphere: support radius %.2f mm, trimmed %zu of %zu vertices, min z %.2f\n",
              r.support_radius_mm, r.trimmed_vertices, r.raw_vertices, min_z);
  EXPECT_GT(min_z, -r.support_radius_mm - 0.5);
  // The quantile trims a little more.
  options.trim_density_quantile = 0.2;
  const MeshResult q = PoissonMesh(cloud, options);
  ASSERT_TRUE(q.IsUsable()) << q.message;
  EXPECT_GT(q.trimmed_vertices, r.trimmed_vertices);
}

TEST_F(Mesh, PlyAndObjRoundTrip) {
  PoissonOptions options;
  options.depth = 6;
  const MeshResult r = PoissonMesh(Sphere(3000, {0, 0, 0}), options);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  const TriangleMesh& mesh = r.mesh;
  std::string error;
  for (bool binary : {true, false}) {
    const std::string path = Path(binary ? "mesh_bin.ply" : "mesh_ascii.ply");
    ASSERT_TRUE(WriteMeshPly(path, mesh, binary, &error)) << error;
    PointCloud back;
    ASSERT_TRUE(ReadPly(path, &back, &error)) << error;  // reads the vertex element, skips faces
    ASSERT_EQ(back.size(), mesh.vertices_mm.size());
    ASSERT_TRUE(back.HasNormals());
    ASSERT_TRUE(back.HasColors());
    for (std::size_t i = 0; i < back.size(); ++i) {
      ASSERT_EQ(back.points_mm[i], mesh.vertices_mm[i]) << i;  // bit-exact both ways
      ASSERT_EQ(back.colors_rgb[i], mesh.colors_rgb[i]) << i;
    }
    // The face element: count and the first face, read back by hand.
    std::ifstream in(path, std::ios::binary);
    std::string line;
    bool face_element = false;
    while (std::getline(in, line) && line != "end_header")
      if (line == "element face " + std::to_string(mesh.faces.size())) face_element = true;
    EXPECT_TRUE(face_element);
  }
  const std::string obj = Path("mesh.obj");
  ASSERT_TRUE(WriteMeshObj(obj, mesh, &error)) << error;
  std::ifstream in(obj);
  std::string line;
  std::size_t v = 0, vn = 0, f = 0;
  int max_index = 0;
  while (std::getline(in, line)) {
    if (line.rfind("v ", 0) == 0) ++v;
    if (line.rfind("vn ", 0) == 0) ++vn;
    if (line.rfind("f ", 0) == 0) {
      ++f;
      std::istringstream s(line.substr(2));
      std::string token;
      while (s >> token) max_index = std::max(max_index, std::stoi(token));
    }
  }
  EXPECT_EQ(v, mesh.vertices_mm.size());
  EXPECT_EQ(vn, mesh.vertices_mm.size());
  EXPECT_EQ(f, mesh.faces.size());
  EXPECT_EQ(static_cast<std::size_t>(max_index), mesh.vertices_mm.size());  // 1-based
}

// Edges not shared by exactly two faces (0: a closed surface).
std::size_t BorderEdges(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> edges;
  for (const cv::Vec3i& f : mesh.faces)
    for (int k = 0; k < 3; ++k) ++edges[std::minmax(f[k], f[(k + 1) % 3])];
  std::size_t border = 0;
  for (const auto& [edge, faces] : edges) border += faces != 2 ? 1 : 0;
  return border;
}

TEST_F(Mesh, ImplicitSphereIsClosedAccurateAndColoured) {
  const cv::Vec3d centre(10, -20, 150);
  const PointCloud cloud = Sphere(12000, centre);  // ≈ 1 mm spacing
  const MeshResult r = ImplicitMesh(cloud, ImplicitMeshOptions{});
  ASSERT_TRUE(r.IsUsable()) << r.message;
  const TriangleMesh& mesh = r.mesh;
  std::string why;
  ASSERT_TRUE(mesh.IsValid(&why)) << why;
  double max_error = 0, sum_error = 0, max_colour_error = 0;
  for (std::size_t v = 0; v < mesh.vertices_mm.size(); ++v) {
    const cv::Vec3d p = cv::Vec3d(mesh.vertices_mm[v]) - centre;
    const double e = std::abs(cv::norm(p) - kRadius);
    max_error = std::max(max_error, e);
    sum_error += e;
    // Sphere() colours red by height: 127 + 127 z.
    const double red = 127 + 127 * p[2] / cv::norm(p);
    max_colour_error = std::max(max_colour_error, std::abs(mesh.colors_rgb[v][0] - red));
  }
  const double mean_error = sum_error / static_cast<double>(mesh.vertices_mm.size());
  std::printf(
      "implicit sphere: %zu vertices, %zu faces, %.3f s; |r − 30| mean %.4f max %.4f mm; "
      "red off by at most %.1f\n",
      mesh.vertices_mm.size(), mesh.faces.size(), r.seconds, mean_error, max_error,
      max_colour_error);
  EXPECT_GT(mesh.faces.size(), 10000u);
  // The fitted spheres are this sphere: what is left is marching cubes'
  // linear interpolation along the grid's edges.
  EXPECT_LT(max_error, 0.03);
  EXPECT_LT(mean_error, 0.01);
  // Kolluri's blend of tangent planes lies off a curved surface.
  ImplicitMeshOptions planes;
  planes.sphere_fit = false;
  const MeshResult k = ImplicitMesh(cloud, planes);
  ASSERT_TRUE(k.IsUsable()) << k.message;
  double planes_error = 0;
  for (const cv::Vec3f& v : k.mesh.vertices_mm)
    planes_error += std::abs(cv::norm(cv::Vec3d(v) - centre) - kRadius);
  planes_error /= static_cast<double>(k.mesh.vertices_mm.size());
  std::printf("implicit sphere, tangent planes: |r − 30| mean %.4f mm\n", planes_error);
  EXPECT_GT(planes_error, 2 * mean_error);
  EXPECT_LT(max_colour_error, 12);  // a blend over the 3.5 mm radius of a 30 mm sphere
  EXPECT_EQ(r.components, 1u);
  EXPECT_EQ(OutwardShare(mesh, centre), 1.0);
  EXPECT_EQ(BorderEdges(mesh), 0u);  // closed
  for (std::size_t v = 0; v < mesh.vertices_mm.size(); ++v) {
    const cv::Vec3d radial = cv::normalize(cv::Vec3d(mesh.vertices_mm[v]) - centre);
    ASSERT_GT(radial.dot(cv::Vec3d(mesh.normals[v])), 0.95) << v;
  }
}

TEST_F(Mesh, ImplicitSurfaceStopsAtTheEdgeOfTheData) {
  // The upper half of the sphere: no surface is invented below its rim (z = 0),
  // and the hemisphere is covered up to it.
  const cv::Vec3d centre(0, 0, 0);
  const PointCloud cloud = Sphere(12000, centre, /*min_z=*/0.0);
  const MeshResult r = ImplicitMesh(cloud, ImplicitMeshOptions{});
  ASSERT_TRUE(r.IsUsable()) << r.message;
  double min_z = 1e9;
  for (const cv::Vec3f& v : r.mesh.vertices_mm) min_z = std::min<double>(min_z, v[2]);
  std::printf("implicit hemisphere: radius %.2f mm, %zu faces, min z %.2f mm\n",
              r.support_radius_mm, r.mesh.faces.size(), min_z);
  EXPECT_GT(min_z, -0.5);
  EXPECT_LT(min_z, 1.5);  // the rim itself is meshed
  EXPECT_EQ(OutwardShare(r.mesh, centre), 1.0);
  EXPECT_EQ(r.components, 1u);
}

TEST_F(Mesh, ImplicitFillClosesHolesFromTheSurfaceAroundThem) {
  // A sphere with a hole 10 mm across (no point within 5 mm of its pole):
  // wider than the IMLS radius (≈ 3.7 mm), narrower than the fill radius.
  const cv::Vec3d centre(0, 0, 0), pole(0, 0, kRadius);
  const PointCloud sphere = Sphere(12000, centre);
  PointCloud holed;
  for (std::size_t i = 0; i < sphere.size(); ++i) {
    if (cv::norm(cv::Vec3d(sphere.points_mm[i]) - pole) < 5) continue;
    holed.points_mm.push_back(sphere.points_mm[i]);
    holed.normals.push_back(sphere.normals[i]);
    holed.colors_rgb.push_back(sphere.colors_rgb[i]);
  }
  // The largest distance of a mesh vertex over the hole from the sphere.
  const auto cap_error = [&](const MeshResult& r) {
    double worst = 0;
    for (const cv::Vec3f& v : r.mesh.vertices_mm)
      if (cv::norm(cv::Vec3d(v) - pole) < 6)
        worst = std::max(worst, std::abs(cv::norm(cv::Vec3d(v) - centre) - kRadius));
    return worst;
  };
  ImplicitMeshOptions options;
  const MeshResult filled = ImplicitMesh(holed, options);
  ASSERT_TRUE(filled.IsUsable()) << filled.message;
  EXPECT_EQ(BorderEdges(filled.mesh), 0u);
  double max_error = 0;
  for (const cv::Vec3f& v : filled.mesh.vertices_mm)
    max_error = std::max(max_error, std::abs(cv::norm(cv::Vec3d(v) - centre) - kRadius));
  // The fitted sphere carries the curvature over the hole: the cap (0.42 mm
  // high over its 5 mm) is filled within the grid's resolution.
  EXPECT_LT(max_error, 0.15);
  // Kolluri's value at the fill radius blends the rim's tangent planes,
  // which meet above the cap.
  options.sphere_fit = false;
  const MeshResult planes = ImplicitMesh(holed, options);
  ASSERT_TRUE(planes.IsUsable()) << planes.message;
  EXPECT_EQ(BorderEdges(planes.mesh), 0u);
  EXPECT_GT(cap_error(planes), 2 * cap_error(filled));
  options.sphere_fit = true;
  options.fill_radii = 0;
  const MeshResult open = ImplicitMesh(holed, options);
  ASSERT_TRUE(open.IsUsable()) << open.message;
  std::printf(
      "holed sphere: %zu border edges without the fill, %zu with it; max |r − 30| %.3f; "
      "over the hole %.3f (sphere) vs %.3f (tangent planes)\n",
      BorderEdges(open.mesh), BorderEdges(filled.mesh), max_error, cap_error(filled),
      cap_error(planes));
  EXPECT_GT(BorderEdges(open.mesh), 20u);
  double top = 0;
  for (const cv::Vec3f& v : open.mesh.vertices_mm) top = std::max<double>(top, v[2]);
  EXPECT_LT(top, kRadius - 0.2);  // the pole is not meshed
}

TEST_F(Mesh, ImplicitRefusesBadInputNamingIt) {
  ImplicitMeshOptions bad;
  bad.radius_spacings = 0.5;
  MeshResult r = ImplicitMesh(Sphere(500, {0, 0, 0}), bad);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "radius_spacings");
  bad = ImplicitMeshOptions{};
  bad.fill_radii = 0.5;
  r = ImplicitMesh(Sphere(500, {0, 0, 0}), bad);
  EXPECT_CONTAINS(r.message, "fill_radii");
  bad = ImplicitMeshOptions{};
  bad.max_tangent_radii = 0;
  r = ImplicitMesh(Sphere(500, {0, 0, 0}), bad);
  EXPECT_CONTAINS(r.message, "max_tangent_radii");
  PointCloud no_normals = Sphere(500, {0, 0, 0});
  no_normals.normals.clear();
  r = ImplicitMesh(no_normals, ImplicitMeshOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "no normals");
  r = ImplicitMesh(Sphere(50, {0, 0, 0}), ImplicitMeshOptions{});
  EXPECT_CONTAINS(r.message, "at least 100");
  MeshMethod method{};
  EXPECT_TRUE(MeshMethodFromString("implicit", &method));
  EXPECT_EQ(method, MeshMethod::kImplicit);
  EXPECT_EQ(ToString(MeshMethod::kPoisson), "poisson");
  EXPECT_FALSE(MeshMethodFromString("marching", &method));
}

TEST_F(Mesh, DegenerateInputsFail) {
  MeshResult r = PoissonMesh(PointCloud{}, PoissonOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "no normals");

  PointCloud few = Sphere(50, {0, 0, 0});
  r = PoissonMesh(few, PoissonOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "at least 100");
  EXPECT_TRUE(r.mesh.faces.empty());

  PointCloud nan_normals = Sphere(500, {0, 0, 0});
  for (cv::Vec3f& n : nan_normals.normals) n = cv::Vec3f(kNaN, 0, 0);
  r = PoissonMesh(nan_normals, PoissonOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "got 0 (of 500)");

  PointCloud no_normals = Sphere(500, {0, 0, 0});
  no_normals.normals.clear();
  r = PoissonMesh(no_normals, PoissonOptions{});
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "no normals");

  PoissonOptions bad;
  bad.depth = 20;
  r = PoissonMesh(Sphere(500, {0, 0, 0}), bad);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_CONTAINS(r.message, "depth");

  // Writers refuse invalid meshes.
  TriangleMesh broken;
  broken.vertices_mm = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  broken.faces.emplace_back(0, 1, 3);
  std::string error;
  EXPECT_FALSE(WriteMeshPly(Path("broken.ply"), broken, true, &error));
  EXPECT_CONTAINS(error, "references vertex 3");
  EXPECT_FALSE(WriteMeshObj(Path("broken.obj"), broken, &error));
  EXPECT_CONTAINS(error, "references vertex 3");
  EXPECT_FALSE(std::filesystem::exists(Path("broken.ply")));
  // An empty but valid mesh writes fine.
  EXPECT_TRUE(WriteMeshPly(Path("empty.ply"), TriangleMesh{}, false, &error)) << error;
}

}  // namespace
}  // namespace craftscan
