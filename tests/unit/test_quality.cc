// The report's model figures without ground truth: points far from the mesh
// and the mesh's holes, on a grid plane whose answers are known.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "craftscan/pipeline/surface/quality.h"

namespace craftscan {
namespace {

// A 20 × 20 mm plane at z = 0 of 1 mm squares (two triangles each), without
// the squares listed in `holes` (column, row).
TriangleMesh Plane(const std::vector<std::pair<int, int>>& holes) {
  TriangleMesh m;
  constexpr int kN = 20;
  for (int y = 0; y <= kN; ++y)
    for (int x = 0; x <= kN; ++x)
      m.vertices_mm.emplace_back(static_cast<float>(x), static_cast<float>(y), 0.f);
  auto at = [](int x, int y) { return y * (kN + 1) + x; };
  for (int y = 0; y < kN; ++y)
    for (int x = 0; x < kN; ++x) {
      if (std::find(holes.begin(), holes.end(), std::make_pair(x, y)) != holes.end()) continue;
      m.faces.emplace_back(at(x, y), at(x + 1, y), at(x + 1, y + 1));
      m.faces.emplace_back(at(x, y), at(x + 1, y + 1), at(x, y + 1));
    }
  return m;
}

TEST(Quality, FarPointsAreCountedAgainstTheMesh) {
  PointCloud cloud;
  // 90 points on or within 0.5 mm of the plane (between vertices, where
  // only the triangles are near), 10 floaters 2 to 11 mm off it.
  for (int i = 0; i < 90; ++i)
    cloud.points_mm.emplace_back(2.3f + 0.17f * static_cast<float>(i % 90), 7.7f,
                                 static_cast<float>((i % 5) * 0.1));
  for (int i = 0; i < 10; ++i)
    cloud.points_mm.emplace_back(10.5f, 10.5f, 2.f + static_cast<float>(i));
  const CloudQuality q = AssessQuality(cloud, Plane({}), {});
  ASSERT_TRUE(q.ok) << q.message;
  EXPECT_EQ(q.points, 100u);
  EXPECT_EQ(q.far_points, 10u);
  EXPECT_NEAR(q.far_pct, 10.0, 1e-9);
  EXPECT_NEAR(q.median_to_mesh_mm, 0.2, 1e-5);
  EXPECT_GT(q.p95_to_mesh_mm, 2.0);
  EXPECT_EQ(q.gate_mm, 1.0);
}

TEST(Quality, HolesAreTheOpenBoundariesBesidesTheLongest) {
  PointCloud cloud;
  cloud.points_mm.emplace_back(5.f, 5.f, 0.f);
  CloudQuality q = AssessQuality(cloud, Plane({}), {});
  ASSERT_TRUE(q.ok) << q.message;
  EXPECT_EQ(q.holes, 0u);
  EXPECT_NEAR(q.base_opening_mm, 80.0, 1e-6);  // the plane's rim
  // One missing square (4 mm around) and a missing 2 × 1 block (6 mm).
  q = AssessQuality(cloud, Plane({{5, 5}, {12, 12}, {13, 12}}), {});
  ASSERT_TRUE(q.ok) << q.message;
  EXPECT_EQ(q.holes, 2u);
  EXPECT_NEAR(q.largest_hole_mm, 6.0, 1e-6);
  EXPECT_NEAR(q.base_opening_mm, 80.0, 1e-6);
}

TEST(Quality, WithoutAMeshItSaysSo) {
  PointCloud cloud;
  cloud.points_mm.emplace_back(5.f, 5.f, 0.f);
  CloudQuality q = AssessQuality(cloud, TriangleMesh{}, {});
  EXPECT_FALSE(q.ok);
  EXPECT_NE(q.message.find("no mesh"), std::string::npos) << q.message;
  QualityOptions bad;
  bad.gate_mm = 0;
  q = AssessQuality(cloud, Plane({}), bad);
  EXPECT_FALSE(q.ok);
  EXPECT_NE(q.message.find("gate_mm"), std::string::npos) << q.message;
  TriangleMesh broken = Plane({});
  broken.faces.emplace_back(0, 1, 100000);
  q = AssessQuality(cloud, broken, {});
  EXPECT_FALSE(q.ok);
  EXPECT_NE(q.message.find("invalid"), std::string::npos) << q.message;
}

}  // namespace
}  // namespace craftscan
