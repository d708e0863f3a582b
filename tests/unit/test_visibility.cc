// The free-space check: two cameras looking at a plane; floaters in front of
// it, seen by the other camera, go; the plane and what only one camera can
// judge stay.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/surface/visibility.h"

namespace craftscan {
namespace {

RectifiedCamera Camera() {
  RectifiedCamera c;
  c.fx = c.fy = 500;
  c.cx = 160;
  c.cy = 120;
  c.size = cv::Size(320, 240);
  return c;
}

// What a camera at the origin looking down +z sees of the plane z = depth:
// one point per pixel, in its own frame.
PointCloud PlaneSeenBy(const RectifiedCamera& c, double depth) {
  PointCloud cloud;
  for (int v = 0; v < c.size.height; ++v)
    for (int u = 0; u < c.size.width; ++u)
      cloud.points_mm.emplace_back(static_cast<float>((u - c.cx) * depth / c.fx),
                                   static_cast<float>((v - c.cy) * depth / c.fy),
                                   static_cast<float>(depth));
  return cloud;
}

// View 1 is view 0 moved 20 mm along x: both see the plane z = 400.
std::vector<cv::Matx44d> Poses() {
  cv::Matx44d moved = cv::Matx44d::eye();
  moved(0, 3) = 20;
  return {cv::Matx44d::eye(), moved};
}

TEST(Visibility, FloatersInFreeSpaceGoAndTheSurfaceStays) {
  const RectifiedCamera camera = Camera();
  const PointCloud plane = PlaneSeenBy(camera, 400);
  PointCloud candidates0;
  // Every 10th plane point (the surface), and three floaters view 1 sees
  // through: 30, 5 and 1.5 mm in front of the plane.
  for (std::size_t i = 0; i < plane.size(); i += 10)
    candidates0.points_mm.push_back(plane.points_mm[i]);
  const std::size_t surface = candidates0.size();
  for (float z : {370.f, 395.f, 398.5f}) candidates0.points_mm.emplace_back(5.f, 3.f, z);
  // Within the tolerance: kept (supported).
  candidates0.points_mm.emplace_back(5.f, 3.f, 399.5f);
  // Behind the plane as view 1 sees it: occluded there, no information: kept.
  candidates0.points_mm.emplace_back(5.f, 3.f, 420.f);
  // Outside view 1's image: nobody can judge it: kept.
  candidates0.points_mm.emplace_back(-150.f, 0.f, 300.f);

  VisibilityStats stats;
  std::string error;
  const std::vector<PointCloud> kept = RemoveFreeSpaceViolations(
      {candidates0, PointCloud{}}, {plane, plane}, Poses(), camera, {}, &stats, &error);
  ASSERT_TRUE(error.empty()) << error;
  ASSERT_EQ(kept.size(), 2u);
  EXPECT_EQ(kept[0].size(), surface + 3);
  EXPECT_EQ(stats.removed_points, 3u);
  EXPECT_EQ(stats.removed_per_view[0], 3u);
  EXPECT_EQ(stats.checked_points, surface + 6);
  for (const cv::Vec3f& p : kept[0].points_mm) {
    EXPECT_FALSE(p[2] < 399 && p[0] > -100) << "a floater at z = " << p[2] << " was kept";
  }
  // The two kept points no other view supports: behind, and outside.
  // Plane points near view 0's left edge fall outside view 1 too.
  EXPECT_GE(stats.unsupported_points, 2u);
  EXPECT_LT(stats.unsupported_points, surface / 5);
}

// A point stays only when more views support it than contradict it (or none
// contradicts it): a tie drops it.
TEST(Visibility, MoreSupportThanContradictionKeepsThePointATieDropsIt) {
  const RectifiedCamera camera = Camera();
  const PointCloud plane = PlaneSeenBy(camera, 400);
  PointCloud near_plane = PlaneSeenBy(camera, 390);  // a view whose depth map is wrong
  PointCloud candidate;
  candidate.points_mm.emplace_back(0.f, 0.f, 390.f);
  // Every other view at view 1's place: those that see the plane at 400
  // (the candidate is in their free space) against, those that see 390 for.
  const auto kept_with = [&](const std::vector<const PointCloud*>& others) {
    std::vector<cv::Matx44d> poses = Poses();
    poses.resize(1);
    std::vector<PointCloud> candidates{candidate};
    std::vector<PointCloud> seen{plane};
    for (const PointCloud* other : others) {
      poses.push_back(Poses()[1]);
      candidates.emplace_back();
      seen.push_back(*other);
    }
    VisibilityStats stats;
    std::string error;
    const std::vector<PointCloud> kept =
        RemoveFreeSpaceViolations(candidates, seen, poses, camera, {}, &stats, &error);
    EXPECT_TRUE(error.empty()) << error;
    return kept[0].size();
  };
  EXPECT_EQ(kept_with({&near_plane}), 1u);                       // one for, none against
  EXPECT_EQ(kept_with({&plane}), 0u);                            // one against
  EXPECT_EQ(kept_with({&plane, &near_plane}), 0u);               // one for, one against: a tie
  EXPECT_EQ(kept_with({&plane, &near_plane, &near_plane}), 1u);  // two for, one against
  EXPECT_EQ(kept_with({&plane, &plane, &near_plane}), 0u);       // one for, two against
}

TEST(Visibility, AttributesFollowTheirPoints) {
  const RectifiedCamera camera = Camera();
  const PointCloud plane = PlaneSeenBy(camera, 400);
  PointCloud c;
  c.points_mm = {{0, 0, 380}, {0, 0, 400}};
  c.normals = {{0, 0, 1}, {0, 0, -1}};
  c.colors_rgb = {{1, 2, 3}, {4, 5, 6}};
  std::string error;
  const auto kept = RemoveFreeSpaceViolations({c, PointCloud{}}, {plane, plane}, Poses(), camera,
                                              {}, nullptr, &error);
  ASSERT_EQ(kept[0].size(), 1u);
  EXPECT_EQ(kept[0].normals[0], cv::Vec3f(0, 0, -1));
  EXPECT_EQ(kept[0].colors_rgb[0], cv::Vec3b(4, 5, 6));
}

TEST(Visibility, BadInputIsNamedAndChangesNothing) {
  const RectifiedCamera camera = Camera();
  PointCloud c;
  c.points_mm = {{0, 0, 380}};
  std::string error;
  auto kept = RemoveFreeSpaceViolations({c}, {c, c}, Poses(), camera, {}, nullptr, &error);
  EXPECT_NE(error.find("1 candidate clouds, 2 seen clouds and 2 poses"), std::string::npos)
      << error;
  EXPECT_EQ(kept[0].size(), 1u);
  RectifiedCamera bad = camera;
  bad.fx = 0;
  error.clear();
  RemoveFreeSpaceViolations({c, c}, {c, c}, Poses(), bad, {}, nullptr, &error);
  EXPECT_NE(error.find("focal"), std::string::npos) << error;
  VisibilityOptions options;
  options.tolerance_mm = -1;
  error.clear();
  RemoveFreeSpaceViolations({c, c}, {c, c}, Poses(), camera, options, nullptr, &error);
  EXPECT_NE(error.find("tolerance_mm"), std::string::npos) << error;
}

TEST(Visibility, ResultsDoNotDependOnTheThreadCount) {
  const RectifiedCamera camera = Camera();
  const PointCloud plane = PlaneSeenBy(camera, 400);
  PointCloud noisy;
  for (std::size_t i = 0; i < plane.size(); i += 3) {
    cv::Vec3f p = plane.points_mm[i];
    p[2] -= static_cast<float>((i * 7919) % 13);  // 0..12 mm in front
    noisy.points_mm.push_back(p);
  }
  VisibilityOptions one, two;
  two.num_threads = 2;
  std::string error;
  const auto a = RemoveFreeSpaceViolations({noisy, noisy}, {plane, plane}, Poses(), camera, one,
                                           nullptr, &error);
  const auto b = RemoveFreeSpaceViolations({noisy, noisy}, {plane, plane}, Poses(), camera, two,
                                           nullptr, &error);
  ASSERT_EQ(a[0].size(), b[0].size());
  EXPECT_EQ(a[0].points_mm, b[0].points_mm);
  EXPECT_LT(a[0].size(), noisy.size());
}

}  // namespace
}  // namespace craftscan
