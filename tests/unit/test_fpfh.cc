// craftscan's FPFH (ComputeFpfh: one nanoflann radius search per point) against
// PCL's FPFHEstimationOMP on the same cloud: the same 33 floats, bit for bit.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "craftscan/pipeline/registration/registration.h"
#include "pcl_baseline.h"

namespace craftscan {
namespace {

// A bumpy surface z = f(x, y) with noise, its normals from the gradient (with
// noise too), a few points alone beyond the radius and one point twice.
PointCloud BumpySurface(int points, unsigned seed) {
  PointCloud cloud;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> across(-30, 30);
  std::normal_distribution<float> noise(0, 0.05f);
  for (int i = 0; i < points; ++i) {
    const float x = across(rng), y = across(rng);
    const float z = 4 * std::sin(x / 6) * std::cos(y / 9) + noise(rng);
    const cv::Vec3f gradient(4 * std::cos(x / 6) / 6 * std::cos(y / 9),
                             -4 * std::sin(x / 6) * std::sin(y / 9) / 9, 0);
    cv::Vec3f n(-gradient[0] + noise(rng), -gradient[1] + noise(rng), 1);
    cloud.points_mm.emplace_back(x, y, z);
    cloud.normals.push_back(n / cv::norm(n));
  }
  for (int i = 0; i < 3; ++i) {  // alone: no neighbour within the radius
    cloud.points_mm.emplace_back(100.f + 50 * i, 0.f, 0.f);
    cloud.normals.emplace_back(0.f, 0.f, 1.f);
  }
  cloud.points_mm.push_back(cloud.points_mm[7]);  // a point twice: distance 0
  cloud.normals.push_back(cloud.normals[7]);
  return cloud;
}

TEST(Fpfh, EqualsPclsFpfhEstimationBitForBit) {
  const PointCloud cloud = BumpySurface(3000, 5);
  for (const double radius : {4.0, 9.0}) {
    for (const int threads : {1, 2}) {
      SCOPED_TRACE(::testing::Message() << "radius " << radius << " threads " << threads);
      const std::vector<Fpfh> ours = ComputeFpfh(cloud, radius, threads);
      const std::vector<std::array<float, 33>> pcl = bench::PclFpfh(cloud, radius, threads);
      ASSERT_EQ(ours.size(), cloud.size());
      ASSERT_EQ(pcl.size(), cloud.size());
      long nonzero = 0;
      for (std::size_t i = 0; i < cloud.size(); ++i) {
        for (int b = 0; b < 33; ++b) {
          const float expected = std::isfinite(pcl[i][b]) ? pcl[i][b] : 0.f;
          ASSERT_EQ(ours[i][b], expected) << "point " << i << " bin " << b;
          nonzero += ours[i][b] != 0;
        }
      }
      EXPECT_GT(nonzero, 3000 * 9);  // features, not zeros
      for (std::size_t i = 3000; i < 3003; ++i)
        for (int b = 0; b < 33; ++b) ASSERT_EQ(ours[i][b], 0.f);  // alone: nothing
    }
  }
}

}  // namespace
}  // namespace craftscan
