// Reprojection of disparity to points with Q (stereo/reproject.h): planes
// through hand-built and stereoRectify Q matrices, invalid disparities, the
// depth and texture filters, colour, and mismatched inputs; the erosion at
// depth discontinuities that runs before it (view_processing.h).
#include "craftscan/pipeline/stereo/reproject.h"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/stereo/view_processing.h"

namespace craftscan {
namespace {

constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

// The points of a usable result (a failed one fails the test).
std::vector<ColoredPoint> Points(const ReprojectResult& result) {
  EXPECT_TRUE(result.IsUsable()) << result.message;
  return result.points;
}

// Inputs that used to throw std::invalid_argument: a failed result that
// names the function and the problem, and no points.
void ExpectInvalidInput(const ReprojectResult& result) {
  EXPECT_EQ(result.status, ReprojectResult::Status::kInvalidInput);
  EXPECT_EQ(result.message.rfind("ReprojectToPoints: ", 0), 0u) << result.message;
  EXPECT_GT(result.message.size(), std::string("ReprojectToPoints: ").size());
  EXPECT_TRUE(result.points.empty());
}

// A plane n·p = offset_mm in the rig (rectified left camera) frame.
struct Plane {
  cv::Vec3d n;
  double offset_mm;
  double Residual(const ColoredPoint& p) const {
    return n[0] * p.x + n[1] * p.y + n[2] * p.z - offset_mm;
  }
};

// Rectified pinhole pair: focal f_px, principal point (cx, cy) in both views,
// baseline_mm along +x.
struct RectifiedRig {
  double f_px, cx, cy, baseline_mm;
};

// Disparity of the plane seen by `rig`: the ray through pixel (x, y) is
// z·((x − cx)/f, (y − cy)/f, 1); d = f·B/z.
cv::Mat PlaneDisparity(const RectifiedRig& rig, const Plane& plane, cv::Size size) {
  cv::Mat disparity(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const cv::Vec3d ray((x - rig.cx) / rig.f_px, (y - rig.cy) / rig.f_px, 1.0);
      const double z = plane.offset_mm / plane.n.dot(ray);
      disparity.at<float>(y, x) = static_cast<float>(rig.f_px * rig.baseline_mm / z);
    }
  }
  return disparity;
}

// Q as documented for cv::stereoRectify with CALIB_ZERO_DISPARITY
// (Tx = −baseline: the right camera sits at +x).
cv::Mat HandQ(const RectifiedRig& rig) {
  return (cv::Mat_<double>(4, 4) << 1, 0, 0, -rig.cx,  //
          0, 1, 0, -rig.cy,                            //
          0, 0, 0, rig.f_px,                           //
          0, 0, 1.0 / rig.baseline_mm, 0);
}

const Plane kTiltedPlane{cv::normalize(cv::Vec3d(0.2, -0.1, 1.0)), 850.0};

void ExpectOnPlane(const std::vector<ColoredPoint>& points, const Plane& plane, double tol_mm) {
  double worst = 0;
  for (const ColoredPoint& p : points) worst = std::max(worst, std::abs(plane.Residual(p)));
  EXPECT_LT(worst, tol_mm);
}

TEST(Reproject, PlaneWithHandBuiltQ) {
  const RectifiedRig rig{700.0, 319.5, 239.5, 120.0};
  const cv::Size size(640, 480);
  const cv::Mat disparity = PlaneDisparity(rig, kTiltedPlane, size);
  const std::vector<ColoredPoint> points =
      Points(ReprojectToPoints(disparity, HandQ(rig), cv::Mat()));
  ASSERT_EQ(points.size(), static_cast<std::size_t>(size.area()));
  ExpectOnPlane(points, kTiltedPlane, 1e-3);
  // Row-major order: the first point is pixel (0, 0), on its ray.
  EXPECT_NEAR(points[0].x / points[0].z, (0 - rig.cx) / rig.f_px, 1e-6);
  EXPECT_NEAR(points[0].y / points[0].z, (0 - rig.cy) / rig.f_px, 1e-6);
  EXPECT_EQ(points[0].r, 255);
}

TEST(Reproject, PlaneWithStereoRectifyQ) {
  const cv::Size size(640, 480);
  const cv::Matx33d k(690.0, 0, 322.0, 0, 690.0, 241.0, 0, 0, 1);
  const cv::Mat no_distortion = cv::Mat::zeros(1, 5, CV_64F);
  const cv::Matx33d r = cv::Matx33d::eye();
  const cv::Vec3d t(-95.0, 0, 0);  // right camera 95 mm to the right: p_right = p_left + t
  cv::Mat r1, r2, p1, p2, q;
  cv::stereoRectify(k, no_distortion, k, no_distortion, size, r, t, r1, r2, p1, p2, q,
                    cv::CALIB_ZERO_DISPARITY);
  ASSERT_LT(cv::norm(r1, cv::Mat::eye(3, 3, CV_64F)), 1e-12);  // rig frame = rectified left
  const RectifiedRig rig{p1.at<double>(0, 0), p1.at<double>(0, 2), p1.at<double>(1, 2),
                         -p2.at<double>(0, 3) / p2.at<double>(0, 0)};
  ASSERT_NEAR(rig.baseline_mm, 95.0, 1e-9);

  const cv::Mat disparity = PlaneDisparity(rig, kTiltedPlane, size);
  const std::vector<ColoredPoint> points = Points(ReprojectToPoints(disparity, q, cv::Mat()));
  ASSERT_EQ(points.size(), static_cast<std::size_t>(size.area()));
  ExpectOnPlane(points, kTiltedPlane, 1e-3);

  // Agrees with OpenCV's own reprojection.
  cv::Mat xyz;
  cv::reprojectImageTo3D(disparity, xyz, q);
  const cv::Vec3f ref = xyz.at<cv::Vec3f>(100, 200);
  const ColoredPoint& p = points[100 * size.width + 200];
  EXPECT_NEAR(p.x, ref[0], 1e-3);
  EXPECT_NEAR(p.y, ref[1], 1e-3);
  EXPECT_NEAR(p.z, ref[2], 1e-3);
}

TEST(Reproject, SkipsInvalidDisparitiesAndPointsAtInfinity) {
  const RectifiedRig rig{500.0, 2.0, 1.0, 100.0};
  cv::Mat disparity(3, 4, CV_32FC1, cv::Scalar(50.0f));
  disparity.at<float>(0, 0) = kInvalidDisparity;
  disparity.at<float>(1, 1) = kNan;
  disparity.at<float>(2, 2) = std::numeric_limits<float>::infinity();
  disparity.at<float>(2, 3) = 0.0f;  // W = 0 with this Q
  const std::vector<ColoredPoint> points =
      Points(ReprojectToPoints(disparity, HandQ(rig), cv::Mat()));
  EXPECT_EQ(points.size(), 12u - 4u);
  for (const ColoredPoint& p : points) {
    EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
    EXPECT_NEAR(p.z, 500.0 * 100.0 / 50.0, 1e-3);
  }
}

TEST(Reproject, DepthFilter) {
  const RectifiedRig rig{500.0, 1.0, 0.0, 100.0};
  // z = f·B/d = 50000/d: 1000, 500, 250 mm.
  const cv::Mat disparity = (cv::Mat_<float>(1, 3) << 50, 100, 200);
  ReprojectOptions options;
  options.min_depth_mm = 300;
  options.max_depth_mm = 600;
  const std::vector<ColoredPoint> points =
      Points(ReprojectToPoints(disparity, HandQ(rig), cv::Mat(), options));
  ASSERT_EQ(points.size(), 1u);
  EXPECT_NEAR(points[0].z, 500.0, 1e-3);
}

TEST(Reproject, CarriesColour) {
  const RectifiedRig rig{500.0, 1.0, 1.0, 100.0};
  cv::Mat disparity(2, 3, CV_32FC1, cv::Scalar(40.0f));
  disparity.at<float>(0, 1) = kNan;
  cv::Mat bgr(2, 3, CV_8UC3);
  for (int i = 0; i < 6; ++i) {
    bgr.at<cv::Vec3b>(i / 3, i % 3) = cv::Vec3b(10 * i + 1, 10 * i + 2, 10 * i + 3);
  }
  std::vector<ColoredPoint> points = Points(ReprojectToPoints(disparity, HandQ(rig), bgr));
  ASSERT_EQ(points.size(), 5u);
  // Pixel 0 → point 0; pixel 1 skipped; pixel 2 → point 1.
  EXPECT_EQ(points[0].b, 1);
  EXPECT_EQ(points[0].g, 2);
  EXPECT_EQ(points[0].r, 3);
  EXPECT_EQ(points[1].b, 21);
  EXPECT_EQ(points[1].g, 22);
  EXPECT_EQ(points[1].r, 23);

  cv::Mat grey(2, 3, CV_8UC1);
  for (int i = 0; i < 6; ++i) {
    grey.at<std::uint8_t>(i / 3, i % 3) = static_cast<std::uint8_t>(7 * i);
  }
  points = Points(ReprojectToPoints(disparity, HandQ(rig), grey));
  ASSERT_EQ(points.size(), 5u);
  EXPECT_EQ(points[4].r, 35);
  EXPECT_EQ(points[4].g, 35);
  EXPECT_EQ(points[4].b, 35);
}

TEST(Reproject, RejectsMismatchedInputs) {
  const RectifiedRig rig{500.0, 1.0, 1.0, 100.0};
  const cv::Mat q = HandQ(rig);
  const cv::Mat disparity(4, 4, CV_32FC1, cv::Scalar(10.0f));
  ExpectInvalidInput(ReprojectToPoints(cv::Mat(), q, cv::Mat()));
  ExpectInvalidInput(ReprojectToPoints(cv::Mat(4, 4, CV_16SC1), q, cv::Mat()));
  ExpectInvalidInput(ReprojectToPoints(disparity, cv::Mat::eye(3, 3, CV_64F), cv::Mat()));
  ExpectInvalidInput(ReprojectToPoints(disparity, q, cv::Mat(3, 4, CV_8UC3)));
  ExpectInvalidInput(ReprojectToPoints(disparity, q, cv::Mat(4, 4, CV_16UC1)));
  cv::Mat not_finite = q.clone();
  not_finite.at<double>(0, 3) = std::numeric_limits<double>::infinity();
  ExpectInvalidInput(ReprojectToPoints(disparity, not_finite, cv::Mat()));
  ReprojectOptions bad;
  bad.min_depth_mm = 10;
  bad.max_depth_mm = 5;
  std::string why;
  EXPECT_FALSE(bad.IsValid(&why));
  EXPECT_FALSE(why.empty());
  ExpectInvalidInput(ReprojectToPoints(disparity, q, cv::Mat(), bad));
}

TEST(Reproject, TextureFilterDropsFlatRegions) {
  const RectifiedRig rig{500.0, 1.0, 1.0, 100.0};
  const cv::Mat q = HandQ(rig);
  const cv::Mat disparity(40, 80, CV_32FC1, cv::Scalar(10.0f));
  // Left half: dark and flat with σ = 1 grey-level noise (a black backdrop);
  // right half: random texture (σ ≈ 70).
  cv::Mat color(40, 80, CV_8UC3);
  cv::RNG rng(3);
  for (int y = 0; y < 40; ++y)
    for (int x = 0; x < 80; ++x) {
      const int v = x < 40 ? cv::saturate_cast<uchar>(12 + rng.gaussian(1.0)) : rng.uniform(0, 256);
      color.at<cv::Vec3b>(y, x) = cv::Vec3b(v, v, v);
    }
  ReprojectOptions options;
  options.min_texture_std = 2.5;
  const auto points = Points(ReprojectToPoints(disparity, q, color, options));
  // The 7×7 window straddles the border 3 px into the flat half.
  std::size_t left = 0, right = 0;
  const double f = rig.f_px, cx = rig.cx;
  for (const auto& p : points) (p.x * f / p.z + cx < 36.5 ? left : right)++;
  EXPECT_EQ(left, 0u);
  EXPECT_GE(right, 40u * 40u - 40u * 6u);  // all but the image border rows/cols' edge effects
  EXPECT_EQ(Points(ReprojectToPoints(disparity, q, color)).size(), 80u * 40u);  // off by default
  ExpectInvalidInput(ReprojectToPoints(disparity, q, cv::Mat(), options));
  // Exempt pixels stay whatever their texture (the station exempts what it
  // sees over the platter): the flat half's top rows come back.
  options.texture_exempt = cv::Mat::zeros(40, 80, CV_8UC1);
  options.texture_exempt.rowRange(0, 10).setTo(255);
  std::size_t exempt_left = 0, lower_left = 0;
  for (const auto& p : Points(ReprojectToPoints(disparity, q, color, options))) {
    if (p.x * f / p.z + cx >= 36.5) continue;
    const double y = p.y * f / p.z + rig.cy;
    (y < 9.5 ? exempt_left : lower_left)++;
  }
  EXPECT_EQ(exempt_left, 10u * 37u);
  EXPECT_EQ(lower_left, 0u);
  options.texture_exempt = cv::Mat::zeros(40, 79, CV_8UC1);  // not the disparity's size
  ExpectInvalidInput(ReprojectToPoints(disparity, q, color, options));
  options.texture_exempt = cv::Mat::zeros(40, 80, CV_32FC1);
  ExpectInvalidInput(ReprojectToPoints(disparity, q, color, options));
  options.texture_exempt = cv::Mat();
  options.texture_window = 4;
  ExpectInvalidInput(ReprojectToPoints(disparity, q, color, options));
}

// A silhouette: an object at disparity 60 in front of a background at 40,
// its right half a ramp of 0.5 px per pixel (a slanted surface, no edge),
// and a hole. Only the background's pixels within the radius of the 20 px
// jump go; the object's edge, the ramp, the hole's rim and everything
// farther stay.
TEST(DepthEdgeErosion, ErasesThePixelsBesideAJumpOnlyAndCountsThem) {
  cv::Mat d(40, 60, CV_32FC1, cv::Scalar(40));
  for (int y = 0; y < d.rows; ++y)
    for (int x = 20; x < 60; ++x) d.at<float>(y, x) = x < 40 ? 60.f : 60.f + 0.5f * (x - 40);
  for (int y = 28; y < 32; ++y)
    for (int x = 44; x < 48; ++x) d.at<float>(y, x) = kNan;  // a hole in the ramp
  cv::Mat eroded = d.clone();
  EXPECT_EQ(EraseNearDepthEdges(1, 3, &eroded), std::size_t{40});  // column 19
  int invalid = 0;
  for (int y = 0; y < eroded.rows; ++y)
    for (int x = 0; x < eroded.cols; ++x) invalid += std::isnan(eroded.at<float>(y, x)) ? 1 : 0;
  EXPECT_EQ(invalid, 40 + 16);  // + the hole
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const bool beside = x == 19;
      const bool hole = y >= 28 && y < 32 && x >= 44 && x < 48;
      if (beside || hole)
        EXPECT_TRUE(std::isnan(eroded.at<float>(y, x))) << x << "," << y;
      else
        EXPECT_EQ(eroded.at<float>(y, x), d.at<float>(y, x)) << x << "," << y;
    }
  }
  // Radius 2 takes two columns (18 and 19); a jump under the threshold or
  // radius 0 takes nothing.
  eroded = d.clone();
  EXPECT_EQ(EraseNearDepthEdges(2, 3, &eroded), std::size_t{2 * 40});
  EXPECT_TRUE(std::isnan(eroded.at<float>(5, 18)));
  EXPECT_EQ(eroded.at<float>(5, 20), 60.f);
  eroded = d.clone();
  EXPECT_EQ(EraseNearDepthEdges(1, 25, &eroded), std::size_t{0});
  EXPECT_EQ(EraseNearDepthEdges(0, 3, &eroded), std::size_t{0});
  cv::Mat empty;
  EXPECT_EQ(EraseNearDepthEdges(1, 3, &empty), std::size_t{0});
}

// A slanted surface (a ramp of 0.5 px per pixel over 40×40 pixels) with a
// hole, and noise: three small patches at unrelated disparities, one of them
// touching the ramp. The patches go (all 4 + 9 + 6 pixels), the ramp and its
// values stay exactly; a patch at least as large as the limit stays.
TEST(DisparitySpeckles, SmallPatchesGoAndSurfacesStayUnchanged) {
  cv::Mat d(60, 80, CV_32FC1, cv::Scalar(kNan));
  for (int y = 10; y < 50; ++y)
    for (int x = 10; x < 50; ++x) d.at<float>(y, x) = 100.25f + 0.5f * static_cast<float>(x);
  for (int y = 28; y < 32; ++y)
    for (int x = 30; x < 34; ++x) d.at<float>(y, x) = kNan;
  auto patch = [&d](int x0, int y0, int w, int h, float value) {
    for (int y = y0; y < y0 + h; ++y)
      for (int x = x0; x < x0 + w; ++x) d.at<float>(y, x) = value;
  };
  patch(60, 5, 2, 2, 7.5f);    // 4 px, alone
  patch(60, 40, 3, 3, 300.f);  // 9 px, alone
  patch(50, 20, 2, 3, -20.f);  // 6 px, beside the ramp but 145 px off it
  cv::Mat filtered = d.clone();
  EXPECT_EQ(RemoveDisparitySpeckles(10, 2.0, &filtered), std::size_t{4 + 9 + 6});
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const bool ramp =
          x >= 10 && x < 50 && y >= 10 && y < 50 && !(y >= 28 && y < 32 && x >= 30 && x < 34);
      if (ramp)
        EXPECT_EQ(filtered.at<float>(y, x), d.at<float>(y, x)) << x << "," << y;
      else
        EXPECT_TRUE(std::isnan(filtered.at<float>(y, x))) << x << "," << y;
    }
  }
  // Patches of at most the limit go: a limit of 8 keeps the 9-pixel patch.
  filtered = d.clone();
  EXPECT_EQ(RemoveDisparitySpeckles(8, 2.0, &filtered), std::size_t{4 + 6});
  EXPECT_EQ(filtered.at<float>(41, 61), 300.f);
  EXPECT_EQ(filtered.at<float>(20, 20), d.at<float>(20, 20));
  // Off, or nothing valid: nothing changes.
  filtered = d.clone();
  EXPECT_EQ(RemoveDisparitySpeckles(0, 2.0, &filtered), std::size_t{0});
  cv::Mat none(10, 10, CV_32FC1, cv::Scalar(kNan));
  EXPECT_EQ(RemoveDisparitySpeckles(10, 2.0, &none), std::size_t{0});
  cv::Mat empty;
  EXPECT_EQ(RemoveDisparitySpeckles(10, 2.0, &empty), std::size_t{0});
}

}  // namespace
}  // namespace craftscan
