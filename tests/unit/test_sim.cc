// The simulated station (drivers/sim): determinism, ground-truth
// consistency against OpenCV's camera model, turntable motion, boards, PLY
// meshes, the calibration scenes and option validation. Renders are small
// (320×256) except one at the default 1280×1024.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/sim/calibration_scenes.h"
#include "craftscan/sim/station.h"
#include "file_util.h"
#include "mat_util.h"

namespace craftscan::sim {
namespace {

namespace fs = std::filesystem;
using ::craftscan::testing::BitExact;
using ::craftscan::testing::TempDir;
constexpr double kPi = std::numbers::pi;

// The default rig scaled down to width × height (focal length and principal
// offsets scale with it, so the view is the same).
RigOptions SmallRig(int width = 320, int height = 256, int threads = 2) {
  RigOptions rig;
  const double s = static_cast<double>(width) / rig.image_size.width;
  rig.image_size = {width, height};
  rig.left.focal_px *= s;
  rig.right.focal_px *= s;
  rig.left.principal_offset_px *= s;
  rig.right.principal_offset_px *= s;
  rig.num_threads = threads;
  return rig;
}

std::unique_ptr<SimStation> MakeStation(const RigOptions& rig) {
  std::string error;
  auto station = SimStation::Create(rig, &error);
  EXPECT_TRUE(station) << error;
  return station;
}

std::unique_ptr<Scene> MakeScene(const SceneOptions& options) {
  std::string error;
  auto scene = Scene::Create(options, &error);
  EXPECT_TRUE(scene) << error;
  return scene;
}

void ExpectSameRender(const StereoRender& a, const StereoRender& b) {
  EXPECT_TRUE(BitExact(a.left, b.left));
  EXPECT_TRUE(BitExact(a.right, b.right));
  EXPECT_TRUE(BitExact(a.left_depth_mm, b.left_depth_mm));
  EXPECT_TRUE(BitExact(a.left_labels, b.left_labels));
  EXPECT_TRUE(BitExact(a.rectified_disparity, b.rectified_disparity));
  EXPECT_TRUE(BitExact(a.rectified_depth_mm, b.rectified_depth_mm));
  EXPECT_TRUE(BitExact(a.rectified_visible_right, b.rectified_visible_right));
}

cv::Vec3d Apply(const cv::Matx44d& T, const cv::Vec3d& p) {
  const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
  return {q[0], q[1], q[2]};
}

// Exact undistortion of one pixel to normalized coordinates (OpenCV's
// iterative solver run to convergence).
cv::Point2d Normalize(const CameraIntrinsics& camera, cv::Point2d pixel) {
  std::vector<cv::Point2d> in{pixel}, out;
  cv::undistortPoints(
      in, out, camera.camera_matrix, camera.distortion, cv::noArray(), cv::noArray(),
      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-14));
  return out[0];
}

cv::Vec3d Bilinear(const cv::Mat& bgr, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const double fx = x - x0, fy = y - y0;
  cv::Vec3d out(0, 0, 0);
  for (int dy = 0; dy < 2; ++dy)
    for (int dx = 0; dx < 2; ++dx) {
      const cv::Vec3b& v = bgr.at<cv::Vec3b>(y0 + dy, x0 + dx);
      const double w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy);
      out += cv::Vec3d(v[0], v[1], v[2]) * w;
    }
  return out;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? std::nan("") : v[v.size() / 2];
}

// Object pixels at least `margin` px inside the object mask.
std::vector<cv::Point> InteriorPixels(const cv::Mat& mask, int margin, int stride) {
  cv::Mat inner;
  cv::erode(mask, inner,
            cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * margin + 1, 2 * margin + 1)));
  std::vector<cv::Point> out;
  for (int y = margin; y < mask.rows - margin; y += stride)
    for (int x = margin; x < mask.cols - margin; x += stride)
      if (inner.at<std::uint8_t>(y, x)) out.emplace_back(x, y);
  return out;
}

// --- options ----------------------------------------------------------------

TEST(SimOptions, DefaultsAreValid) {
  std::string why;
  EXPECT_TRUE(RigOptions{}.IsValid(&why)) << why;
  EXPECT_TRUE(SceneOptions{}.IsValid(&why)) << why;
}

TEST(SimOptions, ValidationNamesTheBadField) {
  auto rig_error = [](auto change) {
    RigOptions rig = SmallRig();
    change(rig);
    std::string why;
    EXPECT_FALSE(rig.IsValid(&why));
    std::string error;
    EXPECT_EQ(SimStation::Create(rig, &error), nullptr);
    EXPECT_NE(error.find(why), std::string::npos) << error;
    return why;
  };
  EXPECT_NE(rig_error([](RigOptions& r) { r.baseline_mm = -1; }).find("baseline_mm"),
            std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) { r.left.focal_px = 0; }).find("left.focal_px"),
            std::string::npos);
  EXPECT_NE(
      rig_error([](RigOptions& r) { r.right.distortion[4] = NAN; }).find("right.distortion[4]"),
      std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) {
              r.image_size = {8, 8};
            }).find("image_size"),
            std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) { r.supersampling = 0; }).find("supersampling"),
            std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) { r.num_threads = 0; }).find("num_threads"),
            std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) { r.vergence_deg = 95; }).find("vergence_deg"),
            std::string::npos);
  EXPECT_NE(rig_error([](RigOptions& r) { r.noise_sigma = -1; }).find("noise_sigma"),
            std::string::npos);

  auto scene_error = [](auto change) {
    SceneOptions scene;
    change(scene);
    std::string why;
    EXPECT_FALSE(scene.IsValid(&why));
    std::string error;
    EXPECT_EQ(Scene::Create(scene, &error), nullptr);
    EXPECT_NE(error.find(why), std::string::npos) << error;
    return why;
  };
  EXPECT_NE(scene_error([](SceneOptions& s) {
              s.object.type = ObjectType::kEgg;
              s.object.egg.diameter_mm = 0;
            }).find("object.egg"),
            std::string::npos);
  EXPECT_NE(scene_error([](SceneOptions& s) {
              s.object.carved_box.relief_depth_mm = 30;
            }).find("object.carved_box.relief_depth_mm"),
            std::string::npos);
  EXPECT_NE(scene_error([](SceneOptions& s) {
              s.object.type = ObjectType::kMesh;
            }).find("object.mesh.path"),
            std::string::npos);
  EXPECT_NE(scene_error([](SceneOptions& s) {
              s.board.enabled = true;
              s.board.spec.type = BoardSpec::Type::kCharuco;
              s.board.spec.marker_mm = 40;
            }).find("board.spec.marker_mm"),
            std::string::npos);
  EXPECT_NE(scene_error([](SceneOptions& s) {
              s.lighting.direction_to_light = {0, 0, 0};
            }).find("lighting.direction_to_light"),
            std::string::npos);
  EXPECT_NE(scene_error([](SceneOptions& s) { s.platter_radius_mm = 1; }).find("platter_radius_mm"),
            std::string::npos);
}

TEST(SimOptions, EnumNamesRoundTrip) {
  for (ObjectType t : {ObjectType::kNone, ObjectType::kCarvedBox, ObjectType::kEgg,
                       ObjectType::kEmbroidery, ObjectType::kMesh}) {
    ObjectType back;
    ASSERT_TRUE(ObjectTypeFromString(ToString(t), &back));
    EXPECT_EQ(back, t);
  }
  ObjectType t;
  EXPECT_FALSE(ObjectTypeFromString("teapot", &t));
  Background b;
  EXPECT_TRUE(BackgroundFromString("textured", &b));
  EXPECT_EQ(b, Background::kTextured);
  PlatterTexture p;
  EXPECT_TRUE(PlatterTextureFromString("plain", &p));
  BoardPlacement placement;
  EXPECT_TRUE(BoardPlacementFromString("in_world", &placement));
  EXPECT_EQ(placement, BoardPlacement::kInWorld);
}

// --- determinism ------------------------------------------------------------

TEST(SimRender, SameSeedGivesBitIdenticalImagesAndOtherSeedsDiffer) {
  const RigOptions rig = SmallRig();
  SceneOptions options;
  options.seed = 7;
  auto station = MakeStation(rig);
  auto scene = MakeScene(options);
  const StereoRender a = station->Render(*scene);
  ASSERT_TRUE(a.IsUsable()) << a.message;
  // Same options, fresh objects: bit for bit.
  auto station2 = MakeStation(rig);
  auto scene2 = MakeScene(options);
  ExpectSameRender(a, station2->Render(*scene2));

  // Another texture seed changes the images but not the geometry.
  SceneOptions other = options;
  other.seed = 8;
  auto scene3 = MakeScene(other);
  const StereoRender c = station->Render(*scene3);
  EXPECT_FALSE(BitExact(a.left, c.left));
  EXPECT_TRUE(BitExact(a.left_labels, c.left_labels));

  // Another noise seed or frame index changes the noise only.
  RigOptions noisy = rig;
  noisy.seed = 2;
  const StereoRender d = MakeStation(noisy)->Render(*scene);
  EXPECT_FALSE(BitExact(a.left, d.left));
  EXPECT_TRUE(BitExact(a.left_depth_mm, d.left_depth_mm));
  const StereoRender e = station->Render(*scene, /*frame_index=*/1);
  EXPECT_FALSE(BitExact(a.right, e.right));
  // Noise of sigma 1 around the same mean.
  cv::Mat diff;
  cv::absdiff(a.left, e.left, diff);
  EXPECT_LT(cv::mean(diff)[0], 2.0);
}

// The projector's pattern is on the object and moves with the rig, not the
// object; switched off, the scene renders as one without a projector; the
// texture frame gives the points their colours and changes no geometry.
TEST(SimRender, ProjectorPatternAndTextureFrame) {
  const RigOptions rig = SmallRig();
  SceneOptions options;
  options.object.type = ObjectType::kEgg;
  auto station = MakeStation(rig);
  auto plain = MakeScene(options);
  EXPECT_FALSE(plain->SetProjectorOn(false));  // none to switch
  options.lighting.projector.enabled = true;
  auto lit = MakeScene(options);
  const StereoRender a = station->Render(*lit);
  ASSERT_TRUE(a.IsUsable()) << a.message;
  const StereoRender none = station->Render(*plain);
  EXPECT_FALSE(BitExact(a.left, none.left));
  ASSERT_TRUE(lit->SetProjectorOn(false));
  EXPECT_FALSE(lit->projector_on());
  const StereoRender off = station->Render(*lit, 0, RenderOutputs::kLeftImageOnly);
  EXPECT_TRUE(BitExact(off.left, none.left));
  EXPECT_TRUE(off.right.empty());
  ASSERT_TRUE(lit->SetProjectorOn(true));

  ViewProcessorOptions view;
  view.num_threads = 1;
  ViewProcessor processor;
  std::string error;
  ASSERT_TRUE(processor.Init(a.calibration, view, &error)) << error;
  const ProcessedView pattern = processor.Process(a.left, a.right);
  ASSERT_TRUE(pattern.ok) << pattern.message;
  ASSERT_GT(pattern.cloud_in_rig.size(), 1000u);
  // A texture frame of one colour: every point takes it (BGR in, RGB out),
  // except where rectification samples outside the raw image.
  const cv::Mat flat(a.left.size(), a.left.type(), cv::Scalar(10, 20, 30));
  const ProcessedView textured = processor.Process(a.left, a.right, flat);
  ASSERT_TRUE(textured.ok) << textured.message;
  EXPECT_EQ(textured.cloud_in_rig.points_mm, pattern.cloud_in_rig.points_mm);
  const auto coloured = std::count(textured.cloud_in_rig.colors_rgb.begin(),
                                   textured.cloud_in_rig.colors_rgb.end(), cv::Vec3b(30, 20, 10));
  EXPECT_GT(coloured, static_cast<long>(textured.cloud_in_rig.size() * 99 / 100));
  const ProcessedView bad = processor.Process(a.left, a.right, cv::Mat(a.left.size(), CV_8UC1));
  EXPECT_FALSE(bad.ok);
  EXPECT_NE(bad.message.find("texture frame"), std::string::npos) << bad.message;
}

// The band reaches the far edge of the platter when told its radius: its
// disparity there is inside the band, and the band only grows downwards.
TEST(SimRender, TheBandReachesThePlattersFarEdge) {
  const RigOptions rig = SmallRig();
  auto station = MakeStation(rig);
  const StereoCalibration& c = station->calibration();
  ViewProcessorOptions volume_only;
  volume_only.num_threads = 1;
  ViewProcessorOptions with_platter = volume_only;
  with_platter.platter_radius_mm = 150;
  ViewProcessor a, b;
  std::string error;
  ASSERT_TRUE(a.Init(c, volume_only, &error)) << error;
  ASSERT_TRUE(b.Init(c, with_platter, &error)) << error;
  EXPECT_LT(b.min_disparity(), a.min_disparity());
  EXPECT_EQ(b.min_disparity() + b.num_disparities(), a.min_disparity() + a.num_disparities());
  // The platter's far edge (turntable frame: +y away from the rig) in the rig frame.
  const cv::Matx44d rig_from_world = station->rig_from_world();
  const cv::Vec4d far = rig_from_world * cv::Vec4d(0, 150, 0, 1);
  const cv::Vec3d l = c.P1 * far, r = c.P2 * far;
  const double d = l[0] / l[2] - r[0] / r[2];
  EXPECT_GE(d, b.min_disparity());
  ViewProcessorOptions bad = volume_only;
  bad.platter_radius_mm = -1;
  EXPECT_FALSE(a.Init(c, bad, &error));
  EXPECT_NE(error.find("platter_radius_mm"), std::string::npos) << error;
  bad = volume_only;
  bad.aggregation_iterations = 17;
  EXPECT_FALSE(a.Init(c, bad, &error));
  EXPECT_NE(error.find("aggregation_iterations must be in 0..16"), std::string::npos) << error;
}

TEST(SimRender, ThreadCountDoesNotChangeAnything) {
  SceneOptions options;
  options.object.type = ObjectType::kEmbroidery;
  options.background = Background::kTextured;
  auto scene = MakeScene(options);
  const StereoRender one = MakeStation(SmallRig(320, 256, 1))->Render(*scene);
  const StereoRender two = MakeStation(SmallRig(320, 256, 2))->Render(*scene);
  const StereoRender three = MakeStation(SmallRig(320, 256, 3))->Render(*scene);
  ExpectSameRender(one, two);
  ExpectSameRender(one, three);
}

// --- ground truth -------------------------------------------------------------

// The platter top is the plane z = 0 of the world: its depth, computed
// independently from the calibration (OpenCV undistortion) and the camera
// pose, must match the rendered ground truth.
TEST(SimGroundTruth, PlatterDepthMatchesTheCalibratedCameraModel) {
  auto station = MakeStation(SmallRig());
  SceneOptions options;
  options.object.type = ObjectType::kNone;
  const StereoRender r = station->Render(*MakeScene(options));
  const cv::Matx44d left_from_world = station->left_from_world();
  const cv::Matx44d world_from_left = left_from_world.inv();
  const cv::Vec3d centre = Apply(world_from_left, {0, 0, 0});
  int checked = 0;
  double worst = 0;
  for (int y = 0; y < r.left.rows; y += 3)
    for (int x = 0; x < r.left.cols; x += 3) {
      if (r.left_labels.at<std::uint8_t>(y, x) != static_cast<int>(SurfaceLabel::kPlatter))
        continue;
      const cv::Point2d n = Normalize(r.calibration.left, cv::Point2d(x, y));
      const cv::Vec3d ray = Apply(world_from_left, {n.x, n.y, 1}) - centre;  // camera z = 1
      const double z = -centre[2] / ray[2];  // hits world z = 0 at camera depth z
      worst = std::max(worst, std::abs(z - r.left_depth_mm.at<float>(y, x)));
      ++checked;
    }
  EXPECT_GT(checked, 1000);
  EXPECT_LT(worst, 2e-3) << "mm";  // float storage of ~400 mm is ~3e-5 mm
}

// Left depth → 3D point → cv::projectPoints into the right image (with the
// calibration's R, T, intrinsics and distortion): the right image shows the
// same colour there, and a shifted point does not.
TEST(SimGroundTruth, LeftDepthProjectsIntoTheRightImageOntoTheSameSurface) {
  RigOptions rig = SmallRig();
  rig.noise_sigma = 0;
  auto station = MakeStation(rig);
  SceneOptions options;
  options.turntable_angle_rad = 0.5;
  const StereoRender r = station->Render(*MakeScene(options));
  const StereoCalibration& c = r.calibration;
  std::vector<cv::Point3d> points;
  std::vector<cv::Point> pixels;
  for (const cv::Point& p : InteriorPixels(r.left_object_mask, 3, 2)) {
    const cv::Point2d n = Normalize(c.left, p);
    const double z = r.left_depth_mm.at<float>(p);
    points.emplace_back(n.x * z, n.y * z, z);
    pixels.push_back(p);
  }
  ASSERT_GT(points.size(), 500u);
  std::vector<cv::Point2d> in_right;
  cv::Vec3d rvec;
  cv::Rodrigues(c.R, rvec);
  cv::projectPoints(points, rvec, c.T, c.right.camera_matrix, c.right.distortion, in_right);
  // The wood's finest grain is below a pixel at this size: compare slightly
  // blurred images so that sampling (aliasing) differences between the
  // views do not dominate.
  cv::Mat left_image, right_image;
  cv::GaussianBlur(r.left, left_image, cv::Size(0, 0), 1.0);
  cv::GaussianBlur(r.right, right_image, cv::Size(0, 0), 1.0);
  // Median colour difference between the left pixel and the right image at
  // the projection shifted by (dx, dy) px.
  auto median_difference = [&](double dx, double dy) {
    std::vector<double> differences;
    for (std::size_t i = 0; i < points.size(); ++i) {
      const cv::Point2d q = in_right[i];
      if (q.x < 5 || q.y < 5 || q.x > r.right.cols - 6 || q.y > r.right.rows - 6) continue;
      const cv::Vec3b& l = left_image.at<cv::Vec3b>(pixels[i]);
      differences.push_back(cv::norm(
          Bilinear(right_image, q.x + dx, q.y + dy) - cv::Vec3d(l[0], l[1], l[2]), cv::NORM_INF));
    }
    EXPECT_GT(differences.size(), 500u);
    return Median(differences);
  };
  const double at_projection = median_difference(0, 0);
  EXPECT_LT(at_projection, 3.5) << "grey levels";
  // Half a pixel off in any direction is worse; two pixels off much worse.
  for (const cv::Point2d off :
       {cv::Point2d(0.5, 0), cv::Point2d(-0.5, 0), cv::Point2d(0, 0.5), cv::Point2d(0, -0.5)}) {
    EXPECT_GT(median_difference(off.x, off.y), at_projection) << off;
  }
  EXPECT_GT(median_difference(2, 0), 2 * at_projection);
}

TEST(SimGroundTruth, RectifiedDisparityAgreesWithDepthThroughQ) {
  auto station = MakeStation(SmallRig());
  SceneOptions options;
  options.object.type = ObjectType::kEgg;
  const StereoRender r = station->Render(*MakeScene(options));
  const cv::Matx44d& Q = r.calibration.Q;
  int checked = 0;
  double worst_px = 0;
  for (int y = 0; y < r.left.rows; ++y)
    for (int x = 0; x < r.left.cols; ++x) {
      const float d = r.rectified_disparity.at<float>(y, x);
      if (!std::isfinite(d)) continue;
      const cv::Vec4d p = Q * cv::Vec4d(x, y, d, 1);
      const double z = r.rectified_depth_mm.at<float>(y, x);
      // Disparity that Q maps to depth z: z = Q23 / (Q32·d + Q33).
      const double d_from_z = (Q(2, 3) / z - Q(3, 3)) / Q(3, 2);
      worst_px = std::max(worst_px, std::abs(d_from_z - d));
      EXPECT_NEAR(p[2] / p[3], z, 0.01);
      ++checked;
    }
  EXPECT_GT(checked, r.left.total() / 2);
  EXPECT_LT(worst_px, 1e-3);
  EXPECT_GT(cv::countNonZero(r.rectified_object_mask), 1000);
}

// Rectifying with the calibration's R1/P1 and R2/P2 puts both views of a
// ground-truth point on the same row; the remapped images agree there.
TEST(SimGroundTruth, RectifiedMatchesLieOnTheSameRow) {
  RigOptions rig = SmallRig();
  rig.noise_sigma = 0;
  auto station = MakeStation(rig);
  SceneOptions options;
  options.turntable_angle_rad = 0.5;
  const StereoRender r = station->Render(*MakeScene(options));
  const StereoCalibration& c = r.calibration;

  std::vector<cv::Point2d> left_pixels;
  std::vector<cv::Point3d> points;
  for (const cv::Point& p : InteriorPixels(r.left_object_mask, 2, 3)) {
    const cv::Point2d n = Normalize(c.left, p);
    const double z = r.left_depth_mm.at<float>(p);
    points.emplace_back(n.x * z, n.y * z, z);
    left_pixels.emplace_back(p.x, p.y);
  }
  ASSERT_GT(points.size(), 300u);
  std::vector<cv::Point2d> right_pixels, left_rect, right_rect;
  cv::Vec3d rvec;
  cv::Rodrigues(c.R, rvec);
  cv::projectPoints(points, rvec, c.T, c.right.camera_matrix, c.right.distortion, right_pixels);
  const cv::TermCriteria exact(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-14);
  cv::undistortPoints(left_pixels, left_rect, c.left.camera_matrix, c.left.distortion, c.R1, c.P1,
                      exact);
  cv::undistortPoints(right_pixels, right_rect, c.right.camera_matrix, c.right.distortion, c.R2,
                      c.P2, exact);
  double worst_row = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    worst_row = std::max(worst_row, std::abs(left_rect[i].y - right_rect[i].y));
  }
  EXPECT_LT(worst_row, 0.1) << "px";

  // The images, rectified with cv::initUndistortRectifyMap, agree along the
  // ground-truth disparity on non-occluded object pixels.
  cv::Mat lx, ly, rx, ry, left, right;
  cv::initUndistortRectifyMap(c.left.camera_matrix, c.left.distortion, c.R1, c.P1, c.image_size,
                              CV_32FC1, lx, ly);
  cv::initUndistortRectifyMap(c.right.camera_matrix, c.right.distortion, c.R2, c.P2, c.image_size,
                              CV_32FC1, rx, ry);
  cv::remap(r.left, left, lx, ly, cv::INTER_LINEAR);
  cv::remap(r.right, right, rx, ry, cv::INTER_LINEAR);
  cv::Mat usable = r.rectified_object_mask & r.rectified_visible_right;
  std::vector<double> diffs;
  for (const cv::Point& p : InteriorPixels(usable, 3, 2)) {
    const double xr = p.x - r.rectified_disparity.at<float>(p);
    if (xr < 2 || xr > right.cols - 3) continue;
    const cv::Vec3b& l = left.at<cv::Vec3b>(p);
    diffs.push_back(cv::norm(Bilinear(right, xr, p.y) - cv::Vec3d(l[0], l[1], l[2]), cv::NORM_INF));
  }
  ASSERT_GT(diffs.size(), 300u);
  EXPECT_LT(Median(diffs), 5.0) << "grey levels";
}

TEST(SimGroundTruth, TurningTheTurntableRotatesObjectPointsAboutTheAxis) {
  auto station = MakeStation(SmallRig());
  SceneOptions options;
  options.object.type = ObjectType::kEgg;
  options.object.position_mm = {20, 10};  // off the axis, so it moves
  auto scene = MakeScene(options);
  const StereoCalibration& c = station->calibration();
  const cv::Matx44d rig_from_world = station->rig_from_world();
  const cv::Vec3d corner(22.5, 0, 30);  // a point on the egg's equator (object frame)
  const cv::Vec3d at_zero = Apply(rig_from_world * scene->world_from_object(), corner);
  for (double angle : {0.1, 1.0, -2.5, kPi}) {
    scene->SetTurntableAngle(angle);
    const cv::Vec3d moved = Apply(rig_from_world * scene->world_from_object(), corner);
    // Rotation about the calibrated axis by the angle.
    cv::Matx33d R;
    cv::Rodrigues(c.turntable.direction_in_rig * angle, R);
    const cv::Vec3d expected =
        R * (at_zero - c.turntable.point_in_rig_mm) + c.turntable.point_in_rig_mm;
    EXPECT_LT(cv::norm(moved - expected), 1e-6) << "angle " << angle;
  }

  // Rendered: a surface point seen at angle 0, carried by the turntable, is
  // where the ground-truth depth at angle 0.3 says.
  scene->SetTurntableAngle(0);
  const StereoRender r0 = station->Render(*scene);
  const cv::Matx44d world_from_left = station->left_from_world().inv();
  const cv::Matx44d object_from_left = r0.world_from_object.inv() * world_from_left;
  scene->SetTurntableAngle(0.3);
  const StereoRender r1 = station->Render(*scene);
  EXPECT_DOUBLE_EQ(r1.turntable_angle_rad, 0.3);
  const cv::Matx44d left_from_object = station->left_from_world() * r1.world_from_object;
  int checked = 0;
  for (const cv::Point& p : InteriorPixels(r0.left_object_mask, 4, 4)) {
    const cv::Point2d n = Normalize(r0.calibration.left, p);
    const double z = r0.left_depth_mm.at<float>(p);
    const cv::Vec3d p_object = Apply(object_from_left, {n.x * z, n.y * z, z});
    const cv::Vec3d p_left = Apply(left_from_object, p_object);
    std::vector<cv::Point2d> image;
    cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(p_left)}, cv::Vec3d(0, 0, 0),
                      cv::Vec3d(0, 0, 0), r0.calibration.left.camera_matrix,
                      r0.calibration.left.distortion, image);
    const cv::Point q(static_cast<int>(std::lround(image[0].x)),
                      static_cast<int>(std::lround(image[0].y)));
    if (q.x < 4 || q.y < 4 || q.x >= r1.left.cols - 4 || q.y >= r1.left.rows - 4) continue;
    // Only where the point stays well inside the egg's outline in view 2.
    cv::Mat window = r1.left_object_mask(cv::Rect(q.x - 4, q.y - 4, 9, 9));
    if (cv::countNonZero(window) != 81) continue;
    // Depth of the ray through the projected point: bilinear in the GT map.
    const double fx = image[0].x - std::floor(image[0].x), fy = image[0].y - std::floor(image[0].y);
    const int x0 = static_cast<int>(std::floor(image[0].x)),
              y0 = static_cast<int>(std::floor(image[0].y));
    const cv::Mat& D = r1.left_depth_mm;
    const double depth =
        (D.at<float>(y0, x0) * (1 - fx) + D.at<float>(y0, x0 + 1) * fx) * (1 - fy) +
        (D.at<float>(y0 + 1, x0) * (1 - fx) + D.at<float>(y0 + 1, x0 + 1) * fx) * fy;
    // The point may have turned away from the camera: then the GT depth is
    // nearer (another part of the egg), never farther.
    if (depth < p_left[2] - 0.05) continue;
    EXPECT_NEAR(depth, p_left[2], 0.05) << "pixel " << p << " → " << q;
    ++checked;
  }
  EXPECT_GT(checked, 30);
}

// --- boards ---------------------------------------------------------------------

// A board held in front of the left camera, a little tilted, its centre
// 280 mm ahead on the optical axis (clear of the platter).
SceneOptions BoardFacingLeftCamera(const SimStation& station, BoardSpec spec) {
  SceneOptions options;
  options.object.type = ObjectType::kNone;
  options.board.enabled = true;
  options.board.spec = spec;
  options.board.placement = BoardPlacement::kInWorld;
  const int nx = spec.type == BoardSpec::Type::kChessboard ? spec.cols + 1 : spec.cols;
  const int ny = spec.type == BoardSpec::Type::kChessboard ? spec.rows + 1 : spec.rows;
  // Board frame seen from the front: x right, y down, z away from the
  // camera, i.e. the camera's axes; then tilted.
  cv::Matx33d tilt;
  cv::Rodrigues(cv::Vec3d(0.25, -0.2, 0.1), tilt);
  const double grid_origin = spec.type == BoardSpec::Type::kChessboard ? -spec.square_mm : 0.0;
  const cv::Vec3d centre_in_board(grid_origin + nx * spec.square_mm / 2,
                                  grid_origin + ny * spec.square_mm / 2, 0);
  const cv::Vec3d t = cv::Vec3d(0, 0, 280) - tilt * centre_in_board;
  cv::Matx44d left_from_board = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) left_from_board(i, j) = tilt(i, j);
    left_from_board(i, 3) = t[i];
  }
  const cv::Matx44d world_from_board = station.left_from_world().inv() * left_from_board;
  cv::Matx33d R;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R(i, j) = world_from_board(i, j);
  cv::Rodrigues(R, options.board.rotation_rad);
  options.board.translation_mm = {world_from_board(0, 3), world_from_board(1, 3),
                                  world_from_board(2, 3)};
  return options;
}

std::vector<cv::Point2d> ProjectBoardPoints(const SimStation& station, const StereoRender& r,
                                            const std::vector<cv::Point3f>& board_points) {
  const cv::Matx44d left_from_board = station.left_from_world() * r.world_from_board;
  std::vector<cv::Point3d> in_left;
  for (const cv::Point3f& p : board_points)
    in_left.emplace_back(cv::Point3d(Apply(left_from_board, cv::Vec3d(p.x, p.y, p.z))));
  std::vector<cv::Point2d> image;
  cv::projectPoints(in_left, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0),
                    r.calibration.left.camera_matrix, r.calibration.left.distortion, image);
  return image;
}

// An object laid down (ObjectOptions::rotation_rad): the object frame's
// points land where world_from_object says, the lowest point rests on the
// platter and the seated bounding box is centred on the axis.
TEST(SimGroundTruth, RotatedObjectIsSeatedWhereItsTransformSays) {
  const cv::Vec3d z_axis(0, 0, 1);
  {  // the carved box on its side (90° about x), yawed and turned
    SceneOptions options;
    options.object.rotation_rad = {kPi / 2, 0, 0};
    options.object.yaw_rad = 0.4;
    auto scene = MakeScene(options);
    const cv::Matx44d T = scene->world_from_object();
    const CarvedBoxOptions& b = options.object.carved_box;
    double lo = 1e9, hi = -1e9;
    cv::Vec3d centre(0, 0, 0);
    for (int i = 0; i < 8; ++i) {
      const cv::Vec3d corner((i & 1 ? 0.5 : -0.5) * b.width_mm, (i & 2 ? 0.5 : -0.5) * b.depth_mm,
                             (i & 4 ? 1.0 : 0.0) * b.height_mm);
      const cv::Vec3d w = Apply(T, corner);
      lo = std::min(lo, w[2]);
      hi = std::max(hi, w[2]);
      centre += w / 8;
    }
    EXPECT_NEAR(lo, 0, 1e-9) << "the lowest corner on the platter";
    EXPECT_NEAR(hi, b.depth_mm, 1e-9) << "on its side the box stands its depth high";
    EXPECT_NEAR(centre[0], 0, 1e-9);
    EXPECT_NEAR(centre[1], 0, 1e-9);
    // The base's centre (flat, uncarved): a ray along the base's inward
    // normal from 20 mm outside meets the box exactly there.
    const cv::Vec3d base = Apply(T, {0, 0, 0});
    const cv::Vec3d inward = Apply(T, {0, 0, 1}) - base;
    EXPECT_NEAR(inward.dot(z_axis), 0, 1e-9) << "the base faces sideways";
    double t = 0;
    SurfaceLabel label = SurfaceLabel::kNothing;
    ASSERT_TRUE(scene->Intersect(base - 20 * inward, inward, &t, &label));
    EXPECT_EQ(label, SurfaceLabel::kObject);
    EXPECT_NEAR(t, 20, 1e-5);
    // The transform turns with the turntable about the axis.
    scene->SetTurntableAngle(1.0);
    const cv::Vec3d turned = Apply(scene->world_from_object(), {0, 0, 0});
    EXPECT_NEAR(turned[2], base[2], 1e-9);
    EXPECT_NEAR(std::hypot(turned[0], turned[1]), std::hypot(base[0], base[1]), 1e-9);
  }
  {  // the egg on its side, tilted about two axes: its top and its centre
    SceneOptions options;
    options.object.type = ObjectType::kEgg;
    options.object.rotation_rad = {0.3, kPi / 2, 0.2};
    options.object.position_mm = {10, -5};
    auto scene = MakeScene(options);
    const EggOptions& e = options.object.egg;
    const cv::Vec3d centre = Apply(scene->world_from_object(), {0, 0, e.height_mm / 2});
    EXPECT_NEAR(centre[0], 10, 1e-9);
    EXPECT_NEAR(centre[1], -5, 1e-9);
    // The ellipsoid's lowest point (object frame: centre − A·n/√(nᵀA·n) with
    // A = diag(a², a², c²), n world up in the object frame) lands on the
    // platter, and a ray from below the platter's top meets it there.
    const cv::Matx33d R = scene->world_from_object().get_minor<3, 3>(0, 0);
    const cv::Vec3d n = R.t() * z_axis;
    const double a = e.diameter_mm / 2, c = e.height_mm / 2;
    const cv::Vec3d An(a * a * n[0], a * a * n[1], c * c * n[2]);
    const cv::Vec3d lowest = cv::Vec3d(0, 0, c) - An / std::sqrt(n.dot(An));
    const cv::Vec3d lowest_world = Apply(scene->world_from_object(), lowest);
    EXPECT_NEAR(lowest_world[2], 0, 1e-9);
    // and the platter's plane touches it there: just above it, a horizontal
    // ray through the egg's lowest point meets the egg within a millimetre.
    double t = 0;
    SurfaceLabel label = SurfaceLabel::kNothing;
    const cv::Vec3d start = lowest_world + cv::Vec3d(-30, 0, 0.01);
    ASSERT_TRUE(scene->Intersect(start, {1, 0, 0}, &t, &label));
    EXPECT_EQ(label, SurfaceLabel::kObject);
    EXPECT_NEAR(t, 30, 1.0);
  }
  {  // a rotation the object cannot take is refused with the field named
    SceneOptions options;
    options.object.rotation_rad = {NAN, 0, 0};
    std::string error;
    EXPECT_EQ(Scene::Create(options, &error), nullptr);
    EXPECT_NE(error.find("object.rotation_rad"), std::string::npos) << error;
  }
}

TEST(SimBoard, ChessboardCornersAreWhereTheBoardFrameSays) {
  RigOptions rig = SmallRig(640, 512);
  auto station = MakeStation(rig);
  BoardSpec spec;  // 9 × 6 inner corners, 25 mm
  spec.square_mm = 15;
  const StereoRender r = station->Render(*MakeScene(BoardFacingLeftCamera(*station, spec)));
  EXPECT_EQ(r.calibration.board.square_mm, 15);
  cv::Mat grey;
  cv::cvtColor(r.left, grey, cv::COLOR_BGR2GRAY);
  std::vector<cv::Point2f> found;
  ASSERT_TRUE(cv::findChessboardCorners(grey, cv::Size(spec.cols, spec.rows), found));
  cv::cornerSubPix(grey, found, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-3));
  std::vector<cv::Point3f> board_points;
  for (int j = 0; j < spec.rows; ++j)
    for (int i = 0; i < spec.cols; ++i)
      board_points.emplace_back(i * spec.square_mm, j * spec.square_mm, 0);
  const std::vector<cv::Point2d> expected = ProjectBoardPoints(*station, r, board_points);
  // The detector's ordering is its own: compare each expected corner with
  // the nearest detection.
  std::vector<double> errors;
  for (const cv::Point2d& e : expected) {
    double best = 1e9;
    for (const cv::Point2f& f : found) best = std::min(best, cv::norm(cv::Point2d(f) - e));
    errors.push_back(best);
  }
  EXPECT_LT(Median(errors), 0.15) << "px";
  EXPECT_LT(*std::max_element(errors.begin(), errors.end()), 0.5) << "px";
}

TEST(SimBoard, CharucoMarkersAndCornersAreDetectedWhereTheBoardFrameSays) {
  auto station = MakeStation(SmallRig(640, 512));
  BoardSpec spec;
  spec.type = BoardSpec::Type::kCharuco;
  spec.cols = 7;
  spec.rows = 5;
  spec.square_mm = 16;
  spec.marker_mm = 12;
  spec.aruco_dictionary = cv::aruco::DICT_4X4_50;
  const StereoRender r = station->Render(*MakeScene(BoardFacingLeftCamera(*station, spec)));
  cv::Ptr<cv::aruco::Dictionary> dictionary =
      cv::aruco::getPredefinedDictionary(spec.aruco_dictionary);
  cv::Ptr<cv::aruco::CharucoBoard> board =
      cv::aruco::CharucoBoard::create(spec.cols, spec.rows, static_cast<float>(spec.square_mm),
                                      static_cast<float>(spec.marker_mm), dictionary);
  std::vector<std::vector<cv::Point2f>> marker_corners;
  std::vector<int> marker_ids;
  cv::aruco::detectMarkers(r.left, dictionary, marker_corners, marker_ids);
  EXPECT_EQ(marker_ids.size(), board->ids.size());
  cv::Mat corners, ids;
  const int n =
      cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, r.left, board, corners, ids);
  ASSERT_EQ(n, (spec.cols - 1) * (spec.rows - 1));
  // interpolateCornersCharuco's own refinement is coarse; refine as a
  // calibration would.
  cv::Mat grey;
  cv::cvtColor(r.left, grey, cv::COLOR_BGR2GRAY);
  cv::cornerSubPix(grey, corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-3));
  const std::vector<cv::Point2d> expected =
      ProjectBoardPoints(*station, r, board->chessboardCorners);
  std::vector<double> errors;
  for (int i = 0; i < n; ++i) {
    const int id = ids.at<int>(i);
    const cv::Point2f f = corners.at<cv::Point2f>(i);
    errors.push_back(cv::norm(cv::Point2d(f) - expected[static_cast<std::size_t>(id)]));
  }
  EXPECT_LT(Median(errors), 0.15) << "px";
  EXPECT_LT(*std::max_element(errors.begin(), errors.end()), 0.5) << "px";
}

TEST(SimBoard, BoardOnThePlatterTurnsWithIt) {
  auto station = MakeStation(SmallRig());
  SceneOptions options;
  options.object.type = ObjectType::kNone;
  options.board.enabled = true;
  const auto scene = MakeScene(options);
  const cv::Vec3d origin_at_zero = Apply(scene->world_from_board(), {0, 0, 0});
  EXPECT_NEAR(origin_at_zero[2], options.board.thickness_mm, 1e-12);
  // Printed face up: the board's z axis points down.
  EXPECT_NEAR(scene->world_from_board()(2, 2), -1, 1e-12);
  scene->SetTurntableAngle(kPi / 2);
  const cv::Vec3d origin_turned = Apply(scene->world_from_board(), {0, 0, 0});
  EXPECT_NEAR(origin_turned[0], -origin_at_zero[1], 1e-9);
  EXPECT_NEAR(origin_turned[1], origin_at_zero[0], 1e-9);
  const StereoRender r = station->Render(*scene);
  EXPECT_GT(cv::countNonZero(r.left_labels == static_cast<int>(SurfaceLabel::kBoard)), 1000);
}

// --- calibration scenes (calibration_scenes.h) -------------------------------

// The default rig, point sampled (the ray caches are 4× smaller; the
// geometry the placements use is the same).
std::unique_ptr<SimStation> DefaultRigPointSampled() {
  RigOptions rig;
  rig.supersampling = 1;
  rig.num_threads = 2;
  return MakeStation(rig);
}

std::vector<cv::Vec3d> CornersInBoard(const BoardSpec& spec) {
  std::vector<cv::Vec3d> out;
  for (const cv::Point3f& p : BoardCornersInBoard(spec)) out.emplace_back(p.x, p.y, p.z);
  return out;
}

TEST(SimCalibrationScenes, HeldPosesShowTheBoardsOnTheDefaultRig) {
  const auto station = DefaultRigPointSampled();
  ASSERT_TRUE(station);
  ASSERT_EQ(ChessboardPoses().size(), 16u);
  ASSERT_EQ(CharucoPoses().size(), 16u);
  EXPECT_EQ(&HeldPoses(BoardSpec::Type::kChessboard), &ChessboardPoses());
  EXPECT_EQ(&HeldPoses(BoardSpec::Type::kCharuco), &CharucoPoses());
  const BoardSpec chess = HeldChessboard();
  const BoardSpec charuco = HeldCharuco();
  std::string why;
  ASSERT_TRUE(chess.IsValid(&why)) << why;
  ASSERT_TRUE(charuco.IsValid(&why)) << why;
  EXPECT_FALSE(chess.IsRotationallySymmetric());
  for (std::size_t i = 0; i < ChessboardPoses().size(); ++i) {
    const HeldBoardPlacement p = PlaceHeldBoard(*station, chess, ChessboardPoses()[i]);
    EXPECT_TRUE(p.fully_visible())
        << "pose " << i << ": " << p.margin_px << " px, " << p.lowest_mm << " mm";
    EXPECT_EQ(p.corners_seen, chess.NumCorners()) << "pose " << i;
    // Pushed as far as it goes: to the edge margin or down to the platter.
    EXPECT_TRUE(p.margin_px < kHeldBoardEdgePx + 1 || p.lowest_mm < 3)
        << "pose " << i << ": " << p.margin_px << " px, " << p.lowest_mm << " mm";
  }
  for (std::size_t i = 0; i < CharucoPoses().size(); ++i) {
    const HeldBoardPlacement p = PlaceHeldBoard(*station, charuco, CharucoPoses()[i]);
    EXPECT_GE(p.lowest_mm, 2) << "pose " << i;
    EXPECT_GE(p.corners_seen, 60) << "pose " << i;
    EXPECT_LT(p.margin_px, 0) << "pose " << i << ": the ChArUco board overfills the view";
  }
  // A chessboard too large to be seen whole (220 × 160 mm): the centred
  // pose raised above the platter, reaching out of the images.
  BoardSpec large = chess;
  large.square_mm = 20;
  const HeldBoardPlacement p = PlaceWholeBoard(*station, large, ChessboardPoses()[0]);
  EXPECT_FALSE(p.fully_visible());
  EXPECT_LT(p.margin_px, kHeldBoardEdgePx);
  EXPECT_GE(p.lowest_mm, 2);
}

TEST(SimCalibrationScenes, HeldBoardSceneFixesTheBoardInTheRigFrame) {
  const auto station = DefaultRigPointSampled();
  ASSERT_TRUE(station);
  const BoardSpec spec = HeldChessboard();
  const HeldBoardPlacement p = PlaceHeldBoard(*station, spec, ChessboardPoses()[3]);
  const SceneOptions options = HeldBoardScene(*station, spec, p.rig_from_board);
  EXPECT_EQ(options.object.type, ObjectType::kNone);
  EXPECT_FALSE(options.lighting.shadows);
  EXPECT_EQ(options.board.placement, BoardPlacement::kInWorld);
  EXPECT_DOUBLE_EQ(options.board.margin_mm, BoardMarginMm(spec));
  const auto scene = MakeScene(options);
  ASSERT_TRUE(scene);
  const cv::Matx44d expected = station->world_from_rig() * p.rig_from_board;
  EXPECT_LT(cv::norm(scene->world_from_board() - expected, cv::NORM_INF), 1e-9);
  scene->SetTurntableAngle(1.0);  // held in the hand: it does not turn
  EXPECT_LT(cv::norm(scene->world_from_board() - expected, cv::NORM_INF), 1e-9);
  // The outline's centre is where BoardCentre says, 96 × 72 mm around it.
  const std::vector<cv::Vec3d> outline = BoardOutline(spec);
  EXPECT_NEAR(outline[2][0] - outline[0][0], 96, 1e-12);
  EXPECT_NEAR(outline[2][1] - outline[0][1], 72, 1e-12);
  EXPECT_LT(cv::norm(BoardCentre(spec) - cv::Vec3d(32, 20, 0)), 1e-12);
}

// Both platter boards lie on the platter, their centre 20 mm off the axis,
// and stay in the left image while the turntable turns: every chessboard
// corner ≥ 30 px inside at 0, 60, …, 300°, and all ChArUco corners inside.
TEST(SimCalibrationScenes, PlatterBoardsLieOnThePlatterInView) {
  const auto station = DefaultRigPointSampled();
  ASSERT_TRUE(station);
  const StereoCalibration& c = station->calibration();
  for (const BoardSpec& spec : {PlatterChessboard(), PlatterCharuco()}) {
    SCOPED_TRACE(Describe(spec));
    std::string why;
    ASSERT_TRUE(spec.IsValid(&why)) << why;
    EXPECT_FALSE(spec.IsRotationallySymmetric());
    const SceneOptions options = PlatterBoardScene(spec);
    EXPECT_EQ(options.board.placement, BoardPlacement::kOnPlatter);
    EXPECT_LE(PlatterBoardReachMm(spec), options.platter_radius_mm);
    const auto scene = MakeScene(options);
    ASSERT_TRUE(scene);
    const cv::Vec3d centre = Apply(scene->world_from_board(), BoardCentre(spec));
    EXPECT_LT(cv::norm(centre - cv::Vec3d(20, 0, options.board.thickness_mm)), 1e-9);
    for (const cv::Vec3d& q : BoardOutline(spec)) {
      const cv::Vec3d p = Apply(scene->world_from_board(), q);
      EXPECT_LE(std::hypot(p[0], p[1]), PlatterBoardReachMm(spec) + 1e-9);
    }
    for (int angle_deg = 0; angle_deg < 360; angle_deg += 60) {
      scene->SetTurntableAngle(angle_deg * kPi / 180);
      const double margin = MarginInsideImagePx(
          ProjectIntoCamera(station->left_from_world() * scene->world_from_board(), c.left,
                            CornersInBoard(spec)),
          c.image_size);
      EXPECT_GE(margin, spec.type == BoardSpec::Type::kChessboard ? 30 : 0)
          << "at " << angle_deg << "°";
    }
  }
  // An invalid spec: options Scene::Create refuses with the spec's error.
  BoardSpec bad = PlatterChessboard();
  bad.cols = 1;
  std::string error;
  EXPECT_FALSE(Scene::Create(PlatterBoardScene(bad), &error));
  EXPECT_NE(error.find("board"), std::string::npos) << error;
}

TEST(SimRender, ImagesOnlyRenderHasTheSameImagesAndNoGroundTruth) {
  auto station = MakeStation(SmallRig());
  const auto scene = MakeScene(SceneOptions{});
  const StereoRender full = station->Render(*scene, 5);
  const StereoRender images = station->Render(*scene, 5, RenderOutputs::kImagesOnly);
  ASSERT_TRUE(full.IsUsable() && images.IsUsable()) << images.message;
  EXPECT_TRUE(BitExact(full.left, images.left));
  EXPECT_TRUE(BitExact(full.right, images.right));
  EXPECT_TRUE(images.left_depth_mm.empty());
  EXPECT_TRUE(images.rectified_disparity.empty());
  EXPECT_TRUE(images.rectified_visible_right.empty());
  EXPECT_EQ(images.rig_from_world, full.rig_from_world);
  EXPECT_EQ(images.world_from_object, full.world_from_object);
}

// --- meshes -------------------------------------------------------------------

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// A UV-tessellated ellipsoid with semi-axes (a, a, c), centred at z = c;
// vertices at the poles and on the equator so its bounding box is exact.
TriangleMesh Ellipsoid(double a, double c, int segments, int rings) {
  TriangleMesh m;
  m.vertices_mm.emplace_back(0.0f, 0.0f, static_cast<float>(2 * c));
  for (int j = 1; j < rings; ++j) {
    const double theta = kPi * j / rings;
    for (int i = 0; i < segments; ++i) {
      const double phi = 2 * kPi * i / segments;
      m.vertices_mm.emplace_back(static_cast<float>(a * std::sin(theta) * std::cos(phi)),
                                 static_cast<float>(a * std::sin(theta) * std::sin(phi)),
                                 static_cast<float>(c + c * std::cos(theta)));
    }
  }
  m.vertices_mm.emplace_back(0.0f, 0.0f, 0.0f);
  const int south = static_cast<int>(m.vertices_mm.size()) - 1;
  auto ring = [&](int j, int i) { return 1 + (j - 1) * segments + (i % segments); };
  for (int i = 0; i < segments; ++i) m.faces.emplace_back(0, ring(1, i), ring(1, i + 1));
  for (int j = 1; j < rings - 1; ++j)
    for (int i = 0; i < segments; ++i) {
      m.faces.emplace_back(ring(j, i), ring(j + 1, i), ring(j + 1, i + 1));
      m.faces.emplace_back(ring(j, i), ring(j + 1, i + 1), ring(j, i + 1));
    }
  for (int i = 0; i < segments; ++i)
    m.faces.emplace_back(south, ring(rings - 1, i + 1), ring(rings - 1, i));
  return m;
}

TEST(SimMesh, FineMeshOfTheEggRendersTheEggsDepth) {
  TempDir dir;
  // ~72k triangles: the 70k-triangle case of the issue.
  const TriangleMesh mesh = Ellipsoid(22.5, 30, 256, 142);
  ASSERT_GT(mesh.faces.size(), 70000u);
  std::string error;
  ASSERT_TRUE(WriteMeshPly(dir.File("egg.ply"), mesh, /*binary=*/true, &error)) << error;

  auto station = MakeStation(SmallRig());
  SceneOptions analytic;
  analytic.object.type = ObjectType::kEgg;
  analytic.object.position_mm = {15, -5};
  SceneOptions meshed = analytic;
  meshed.object.type = ObjectType::kMesh;
  meshed.object.mesh.path = dir.File("egg.ply");
  meshed.object.mesh.scale = 1.0;
  const auto mesh_scene = MakeScene(meshed);
  EXPECT_EQ(mesh_scene->mesh_triangle_count(), mesh.faces.size());
  const StereoRender a = station->Render(*MakeScene(analytic));
  const StereoRender m = station->Render(*mesh_scene);
  int both = 0;
  double worst = 0;
  for (const cv::Point& p : InteriorPixels(a.left_object_mask, 2, 1)) {
    if (!m.left_object_mask.at<std::uint8_t>(p)) continue;
    worst = std::max(worst, static_cast<double>(std::abs(a.left_depth_mm.at<float>(p) -
                                                         m.left_depth_mm.at<float>(p))));
    ++both;
  }
  EXPECT_GT(both, 1500);
  // Chord error of the tessellation: a·(1 − cos(π/256)) ≈ 2e-3 mm.
  EXPECT_LT(worst, 0.01) << "mm";
  // Same silhouette up to edge pixels.
  cv::Mat diff = a.left_object_mask ^ m.left_object_mask;
  EXPECT_LT(cv::countNonZero(diff), cv::countNonZero(a.left_object_mask) / 50);
}

TEST(SimMesh, PlacementScalesRotatesAndSeatsTheMesh) {
  TempDir dir;
  // A unit cube from (0,0,0) to (1,2,3) in file units, +Y up in the file.
  TriangleMesh cube;
  for (int i = 0; i < 8; ++i)
    cube.vertices_mm.emplace_back(static_cast<float>(i & 1), static_cast<float>(2 * ((i >> 1) & 1)),
                                  static_cast<float>(3 * ((i >> 2) & 1)));
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    cube.faces.emplace_back(q[0], q[1], q[2]);
    cube.faces.emplace_back(q[0], q[2], q[3]);
  }
  std::string error;
  ASSERT_TRUE(WriteMeshPly(dir.File("cube.ply"), cube, /*binary=*/false, &error)) << error;
  SceneOptions options;
  options.object.type = ObjectType::kMesh;
  options.object.mesh.path = dir.File("cube.ply");
  options.object.mesh.size_mm = 60;                    // largest extent (3) → 60 mm
  options.object.mesh.rotation_rad = {kPi / 2, 0, 0};  // file +Y → +Z
  const auto scene = MakeScene(options);
  // The seated box spans x ∈ [−10, 10], z ∈ [0, 40] (file y: 2 → 40 mm),
  // y ∈ [−30, 30]: a ray straight down the axis hits its top at z = 40.
  double t = 0;
  SurfaceLabel label;
  ASSERT_TRUE(scene->Intersect({0, 0, 100}, {0, 0, -1}, &t, &label));
  EXPECT_EQ(label, SurfaceLabel::kObject);
  EXPECT_NEAR(t, 60, 1e-9);
  ASSERT_TRUE(scene->Intersect({-100, 0, 20}, {1, 0, 0}, &t, &label));
  EXPECT_NEAR(t, 90, 1e-9);
  ASSERT_TRUE(scene->Intersect({0, -100, 20}, {0, 1, 0}, &t, &label));
  EXPECT_NEAR(t, 70, 1e-9);
}

// Every mesh surface gives the matcher texture: fine colour variation inside
// the object (the standard deviation of the image minus its 7×7 Gaussian
// blur, which removes the smooth shading; no sensor noise), the surfaces
// differ in mean colour, and each renders bit-identically on 1 and 3
// threads.
TEST(SimMesh, EverySurfaceRendersWithColourVariation) {
  TempDir dir;
  std::string error;
  ASSERT_TRUE(WriteMeshPly(dir.File("egg.ply"), Ellipsoid(22.5, 30, 96, 48), true, &error))
      << error;
  RigOptions rig = SmallRig(320, 256, 1);
  rig.noise_sigma = 0;
  auto serial = MakeStation(rig);
  rig.num_threads = 3;
  auto parallel = MakeStation(rig);
  std::vector<cv::Vec3d> means;
  for (MeshSurface surface :
       {MeshSurface::kStone, MeshSurface::kWood, MeshSurface::kPainted, MeshSurface::kFabric}) {
    SCOPED_TRACE(ToString(surface));
    SceneOptions options;
    options.object.type = ObjectType::kMesh;
    options.object.mesh.path = dir.File("egg.ply");
    options.object.mesh.surface = surface;
    const auto scene = MakeScene(options);
    const StereoRender r = serial->Render(*scene);
    ASSERT_TRUE(r.IsUsable()) << r.message;
    ExpectSameRender(r, parallel->Render(*scene));
    cv::Mat image, smooth, detail;
    r.left.convertTo(image, CV_32FC3);
    cv::GaussianBlur(image, smooth, cv::Size(7, 7), 0);
    detail = image - smooth;
    const std::vector<cv::Point> inside = InteriorPixels(r.left_object_mask, 4, 1);
    ASSERT_GT(inside.size(), 2000u);
    cv::Vec3d sum(0, 0, 0), detail_sq(0, 0, 0);
    for (const cv::Point& p : inside) {
      const cv::Vec3f c = image.at<cv::Vec3f>(p), d = detail.at<cv::Vec3f>(p);
      for (int k = 0; k < 3; ++k) {
        sum[k] += c[k];
        detail_sq[k] += d[k] * d[k];
      }
    }
    const double n = static_cast<double>(inside.size());
    const cv::Vec3d mean = sum / n;
    const double detail_sigma = std::sqrt((detail_sq[0] + detail_sq[1] + detail_sq[2]) / (3 * n));
    std::printf(
        "mesh surface %-7s: %zu object pixels, mean BGR (%.1f, %.1f, %.1f), fine detail "
        "sigma %.2f grey levels\n",
        std::string(ToString(surface)).c_str(), inside.size(), mean[0], mean[1], mean[2],
        detail_sigma);
    EXPECT_GT(detail_sigma, 3.0) << "grey levels";
    for (const cv::Vec3d& other : means) EXPECT_GT(cv::norm(mean - other), 10) << "grey levels";
    means.push_back(mean);
  }
}

TEST(SimOptions, MeshSurfaceNamesRoundTrip) {
  for (MeshSurface s :
       {MeshSurface::kStone, MeshSurface::kWood, MeshSurface::kPainted, MeshSurface::kFabric}) {
    MeshSurface back = MeshSurface::kStone;
    ASSERT_TRUE(MeshSurfaceFromString(ToString(s), &back));
    EXPECT_EQ(back, s);
  }
  MeshSurface s;
  EXPECT_FALSE(MeshSurfaceFromString("glass", &s));
  SceneOptions options;
  options.object.type = ObjectType::kMesh;
  options.object.mesh.path = "/any.ply";
  options.object.mesh.surface = static_cast<MeshSurface>(17);
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("object.mesh.surface"), std::string::npos) << why;
}

TEST(SimPly, BinaryAndAsciiRoundTripAndQuadsBecomeFans) {
  TempDir dir;
  const TriangleMesh mesh = Ellipsoid(1, 2, 8, 5);
  std::string error;
  for (bool binary : {true, false}) {
    const std::string path = dir.File(binary ? "b.ply" : "a.ply");
    ASSERT_TRUE(WriteMeshPly(path, mesh, binary, &error)) << error;
    TriangleMesh back;
    ASSERT_TRUE(ReadMeshPly(path, &back, &error)) << error;
    ASSERT_EQ(back.vertices_mm.size(), mesh.vertices_mm.size());
    ASSERT_EQ(back.faces.size(), mesh.faces.size());
    for (std::size_t i = 0; i < mesh.vertices_mm.size(); ++i)
      EXPECT_LT(cv::norm(back.vertices_mm[i] - mesh.vertices_mm[i]), 1e-6);
    for (std::size_t i = 0; i < mesh.faces.size(); ++i) EXPECT_EQ(back.faces[i], mesh.faces[i]);
  }
  // Extra properties and elements are skipped; a quad becomes two triangles.
  WriteText(dir.File("quad.ply"),
            "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\n"
            "property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
            "element face 1\nproperty list uchar int vertex_indices\nproperty int flags\n"
            "element edge 1\nproperty int a\nproperty int b\nend_header\n"
            "0 0 0 255\n1 0 0 255\n1 1 0 255\n0 1 0 255\n4 0 1 2 3 7\n0 1\n");
  TriangleMesh quad;
  ASSERT_TRUE(ReadMeshPly(dir.File("quad.ply"), &quad, &error)) << error;
  ASSERT_EQ(quad.faces.size(), 2u);
  EXPECT_EQ(quad.faces[0], cv::Vec3i(0, 1, 2));
  EXPECT_EQ(quad.faces[1], cv::Vec3i(0, 2, 3));
}

TEST(SimPly, ErrorsNameTheFileAndTheProblem) {
  TempDir dir;
  TriangleMesh mesh;
  std::string error;
  auto expect_error = [&](const std::string& path, const std::string& needle) {
    error.clear();
    EXPECT_FALSE(ReadMeshPly(path, &mesh, &error));
    EXPECT_NE(error.find(path), std::string::npos) << error;
    EXPECT_NE(error.find(needle), std::string::npos) << "'" << needle << "' not in: " << error;
  };
  expect_error(dir.File("missing.ply"), "no such file");
  WriteText(dir.File("garbage.ply"), "hello world\nthis is not a mesh\n");
  expect_error(dir.File("garbage.ply"), "not a PLY file");
  WriteText(dir.File("middle.ply"),
            "ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n");
  expect_error(dir.File("middle.ply"), "unsupported format 'binary_middle_endian'");
  WriteText(dir.File("noend.ply"), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n");
  expect_error(dir.File("noend.ply"), "without 'end_header'");
  WriteText(dir.File("badprop.ply"),
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty quaternion x\nend_header\n");
  expect_error(dir.File("badprop.ply"), "header line 4: unknown property type 'quaternion'");
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  WriteText(dir.File("range.ply"), header + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n");
  expect_error(dir.File("range.ply"), "face 0 refers to vertex 7 but there are 3 vertices");
  WriteText(dir.File("short_ascii.ply"), header + "0 0 0\n1 0 0\n0 1\n");
  expect_error(dir.File("short_ascii.ply"), "element 'vertex' entry 2 of 3");
  expect_error(dir.File("short_ascii.ply"), "truncated file");
  WriteText(dir.File("two.ply"), header + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n");
  expect_error(dir.File("two.ply"), "face 0 has 2 vertices");
  WriteText(dir.File("cloud.ply"),
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n0 0 0\n");
  expect_error(dir.File("cloud.ply"), "no faces");
  WriteText(dir.File("word.ply"), header + "0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n");
  expect_error(dir.File("word.ply"), "element 'vertex' entry 0 of 3, property 'z'");
  expect_error(dir.File("word.ply"), "'zero' is not a number");
  WriteText(dir.File("nan.ply"), header + "0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n");
  expect_error(dir.File("nan.ply"), "mesh vertex 1 is not finite");

  // Truncated binary: a valid file cut short inside the face list.
  ASSERT_TRUE(WriteMeshPly(dir.File("full.ply"), Ellipsoid(1, 1, 6, 4), true, &error));
  std::ifstream in(dir.File("full.ply"), std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  WriteText(dir.File("cut.ply"), bytes.substr(0, bytes.size() - 7));
  expect_error(dir.File("cut.ply"), "element 'face' entry");
  expect_error(dir.File("cut.ply"), "truncated file");

  // Through the scene: the option is named, then the file's problem.
  SceneOptions options;
  options.object.type = ObjectType::kMesh;
  options.object.mesh.path = dir.File("range.ply");
  EXPECT_EQ(Scene::Create(options, &error), nullptr);
  EXPECT_EQ(error.rfind("object.mesh: PLY '", 0), 0u) << error;
  EXPECT_NE(error.find("refers to vertex 7"), std::string::npos) << error;
}

// --- full size ----------------------------------------------------------------

// One render at the default 1280×1024 on two threads: the carved box is in
// view, its disparities are in the band the rectification promises (near 0
// at the target, the box within ±~120 px), and the calibration is the rig's.
TEST(SimRender, DefaultRigCarvedBoxAtFullSize) {
  RigOptions rig;
  rig.num_threads = 2;
  auto station = MakeStation(rig);
  const StereoRender r = station->Render(*MakeScene(SceneOptions{}));
  ASSERT_TRUE(r.IsUsable());
  EXPECT_EQ(r.left.size(), cv::Size(1280, 1024));
  EXPECT_EQ(r.left.type(), CV_8UC3);
  EXPECT_NEAR(r.calibration.baseline_mm(), 100, 1e-9);
  EXPECT_TRUE(r.calibration.turntable.valid);
  const int object_pixels = cv::countNonZero(r.left_object_mask);
  EXPECT_GT(object_pixels, 150000);
  double lo, hi;
  cv::minMaxLoc(r.rectified_disparity, &lo, &hi, nullptr, nullptr, r.rectified_object_mask);
  EXPECT_GT(lo, -120);
  EXPECT_LT(hi, 120);
  EXPECT_LT(lo, 0);  // the box spans the target depth
  EXPECT_GT(hi, 0);
  double zlo, zhi;
  cv::minMaxLoc(r.left_depth_mm, &zlo, &zhi, nullptr, nullptr, r.left_object_mask);
  EXPECT_GT(zlo, 330);
  EXPECT_LT(zhi, 470);
  // Where the optical axes meet (the target on the turntable axis) the
  // rectified disparity is near 0 (f·B/Z alone would be ~600 px).
  const cv::Vec3d target = Apply(r.rig_from_world, {0, 0, rig.target_height_mm});
  const cv::Matx44d& Q = r.calibration.Q;
  const double d_target = (Q(2, 3) / target[2] - Q(3, 3)) / Q(3, 2);
  EXPECT_LT(std::abs(d_target), 30) << "px";
  std::printf("1280x1024 stereo render on 2 threads: %.0f ms\n", r.render_ms);
}

// Automatic bracketing's measure on the simulated station: the platter's
// region in the raw left image holds the platter and what stands on it,
// never the black backdrop; the embroidery on dark cloth (seed 5151) is
// bracketed, the carved box and the embroidery on light linen (seed 77) are
// not. (1280x1024, craftscan-bench sim-depth: 7.73, 0.00 and 0.20 %.)
// The texture filter's exemption (ViewProcessor): the platter disc in the
// rectified left view holds the platter and the egg standing on it, and
// none of the backdrop the filter exists for.
TEST(SimStation, RectifiedPlatterRegionHoldsThePlatterAndTheObjectNeverTheBackdrop) {
  auto station = MakeStation(SmallRig(640, 512));
  ASSERT_TRUE(station);
  const StereoCalibration& c = station->calibration();
  SceneOptions options;
  options.object.type = ObjectType::kEgg;
  options.seed = 7;
  auto scene = MakeScene(options);
  ASSERT_TRUE(scene);
  const StereoRender r = station->Render(*scene);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  const cv::Mat region = RectifiedPlatterRegion(c, options.platter_radius_mm);
  ASSERT_EQ(region.size(), c.image_size);
  ASSERT_EQ(region.type(), CV_8UC1);
  long inside[5] = {0, 0, 0, 0, 0}, total[5] = {0, 0, 0, 0, 0};
  for (int y = 0; y < region.rows; ++y)
    for (int x = 0; x < region.cols; ++x) {
      const int label = r.rectified_labels.at<std::uint8_t>(y, x);
      ASSERT_LT(label, 5);
      ++total[label];
      inside[label] += region.at<std::uint8_t>(y, x) != 0;
    }
  const auto pct = [&](SurfaceLabel l) {
    const int k = static_cast<int>(l);
    return total[k] > 0 ? 100.0 * inside[k] / total[k] : -1.0;
  };
  std::printf("inside the disc: platter %.2f %%, egg %.2f %%, backdrop and table %.3f %%\n",
              pct(SurfaceLabel::kPlatter), pct(SurfaceLabel::kObject),
              pct(SurfaceLabel::kBackground));
  ASSERT_GT(total[static_cast<int>(SurfaceLabel::kBackground)], 10000);
  // The platter's top is inside; its rim (the disc's 20 mm side) is not.
  EXPECT_GT(pct(SurfaceLabel::kPlatter), 90.0);
  EXPECT_GT(pct(SurfaceLabel::kObject), 99.0);
  // Pixels on the outline, half platter and half backdrop, at most.
  EXPECT_LT(pct(SurfaceLabel::kBackground), 0.5);
  // A smaller disc holds less; no turntable axis or no radius, no region.
  EXPECT_LT(cv::countNonZero(RectifiedPlatterRegion(c, 50)), cv::countNonZero(region));
  StereoCalibration no_axis = c;
  no_axis.turntable.valid = false;
  EXPECT_TRUE(RectifiedPlatterRegion(no_axis, 150).empty());
  EXPECT_TRUE(RectifiedPlatterRegion(c, 0).empty());
}

TEST(SimStation, AutoBracketingJudgesThePlatterNotTheBackdrop) {
  auto station = MakeStation(SmallRig(640, 512));
  ASSERT_TRUE(station);
  const StereoCalibration& c = station->calibration();
  const cv::Mat region = PlatterRegionMask(c, 150);
  ASSERT_EQ(region.size(), c.image_size);
  // The axis' foot is inside; the top rows (the backdrop above the platter's
  // far edge) are not.
  std::vector<cv::Point2d> foot;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(c.R1.t() * c.turntable.point_in_rig_mm)},
                    cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), c.left.camera_matrix, c.left.distortion,
                    foot);
  EXPECT_EQ(region.at<std::uint8_t>(cvRound(foot[0].y), cvRound(foot[0].x)), 255);
  EXPECT_EQ(cv::countNonZero(region.rowRange(0, 40)), 0);
  const double share = 100.0 * cv::countNonZero(region) / static_cast<double>(region.total());
  EXPECT_GT(share, 20.0);
  EXPECT_LT(share, 90.0);
  // No turntable axis, no region.
  StereoCalibration no_axis = c;
  no_axis.turntable.valid = false;
  EXPECT_TRUE(PlatterRegionMask(no_axis, 150).empty());

  const AutoBracketOptions automatic;
  struct Case {
    ObjectType object;
    std::uint64_t seed;
    bool bracketed;
  };
  for (const Case& k :
       {Case{ObjectType::kEmbroidery, 5151, true}, Case{ObjectType::kEmbroidery, 77, false},
        Case{ObjectType::kCarvedBox, 5151, false}}) {
    SceneOptions options;
    options.object.type = k.object;
    options.seed = k.seed;
    auto scene = MakeScene(options);
    ASSERT_TRUE(scene);
    const StereoRender r = station->Render(*scene, 0, RenderOutputs::kLeftImageOnly);
    ASSERT_TRUE(r.IsUsable()) << r.message;
    const double dark = DarkUntexturedSharePct(r.left, region, automatic);
    // The whole image would count the black backdrop.
    EXPECT_GT(DarkUntexturedSharePct(r.left, cv::Mat(), automatic), 15.0);
    std::printf("object %d seed %llu: %.2f %% of the platter dark without texture\n",
                static_cast<int>(k.object), static_cast<unsigned long long>(k.seed), dark);
    EXPECT_EQ(dark >= automatic.min_share_pct, k.bracketed) << dark;
  }
}

// The matcher's gamma (ViewProcessorOptions::match_gamma): a linear pair
// is encoded for the matcher once (a pair that says it is encoded already,
// an exposure merge, is matched as given), the pair's own image (colours,
// texture test) is left alone, and bad gammas are refused by name.
TEST(SimStation, ViewProcessorEncodesTheMatchersPairOnce) {
  auto station = MakeStation(SmallRig(320, 256, 1));
  ASSERT_TRUE(station);
  SceneOptions options;
  options.object.type = ObjectType::kEmbroidery;
  auto scene = MakeScene(options);
  ASSERT_TRUE(scene);
  const StereoRender a = station->Render(*scene);
  ASSERT_TRUE(a.IsUsable()) << a.message;
  const auto make = [&](double match_gamma) {
    ViewProcessorOptions view;
    view.num_threads = 1;
    view.match_gamma = match_gamma;
    auto processor = std::make_unique<ViewProcessor>();
    std::string error;
    EXPECT_TRUE(processor->Init(a.calibration, view, &error)) << error;
    return processor;
  };
  auto linear = make(1.0), encoding = make(2.2);
  cv::Mat table(1, 256, CV_8U), left, right;
  for (int i = 0; i < 256; ++i)
    table.at<std::uint8_t>(i) = cv::saturate_cast<std::uint8_t>(255 * std::pow(i / 255.0, 1 / 2.2));
  cv::LUT(a.left, table, left);
  cv::LUT(a.right, table, right);
  const ProcessedView encoded_here = encoding->Process(a.left, a.right);
  const ProcessedView encoded_before = encoding->Process(left, right, cv::Mat(), 2.2);
  const ProcessedView as_captured = linear->Process(a.left, a.right);
  const ProcessedView said_encoded = encoding->Process(a.left, a.right, cv::Mat(), 2.2);
  ASSERT_TRUE(encoded_here.ok && encoded_before.ok && as_captured.ok && said_encoded.ok)
      << encoded_here.message;
  // Matched as given: the same as the linear processor's.
  EXPECT_TRUE(BitExact(said_encoded.disparity, as_captured.disparity));
  EXPECT_FALSE(BitExact(encoded_here.disparity, as_captured.disparity));
  // Encoded before or after rectification (which interpolates): nearly the
  // same disparities.
  long both = 0, close = 0;
  for (int y = 0; y < encoded_here.disparity.rows; ++y) {
    for (int x = 0; x < encoded_here.disparity.cols; ++x) {
      const float d0 = encoded_here.disparity.at<float>(y, x);
      const float d1 = encoded_before.disparity.at<float>(y, x);
      if (!std::isfinite(d0) || !std::isfinite(d1)) continue;
      ++both;
      close += std::abs(d0 - d1) <= 1.0f;
    }
  }
  ASSERT_GT(both, 1000);
  EXPECT_GT(static_cast<double>(close) / static_cast<double>(both), 0.95);
  // The texture test and the colours judge the pair as given: captured
  // linear, the colours are the linear image's.
  EXPECT_EQ(encoded_here.rectified_left.at<cv::Vec3b>(128, 160),
            as_captured.rectified_left.at<cv::Vec3b>(128, 160));

  const ProcessedView bad = encoding->Process(a.left, a.right, cv::Mat(), 0.5);
  EXPECT_FALSE(bad.ok);
  EXPECT_NE(bad.message.find("gamma"), std::string::npos) << bad.message;
  ViewProcessorOptions view;
  view.match_gamma = 5;
  std::string error;
  ViewProcessor refused;
  EXPECT_FALSE(refused.Init(a.calibration, view, &error));
  EXPECT_NE(error.find("match_gamma"), std::string::npos) << error;
}

}  // namespace
}  // namespace craftscan::sim
