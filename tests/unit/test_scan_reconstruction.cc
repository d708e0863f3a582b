// ReconstructScan's handling of refused registrations with a calibrated
// turntable, on synthetic views: the open surface of a 40 × 30 × 20 mm box
// (its five visible faces, a 0.5 mm grid) turned about a known axis 400 mm in
// front of the rig, one cloud per commanded angle.
//   - a view replaced by an unrelated surface: its registrations are refused
//     and it keeps the turntable motion, said in the message and the report;
//   - registrations that stray from the commanded motion beyond
//     max_prior_deviation_deg/_mm are refused and the views keep it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/registration/registration.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan {
namespace {

constexpr int kViews = 6;
constexpr double kStepRad = std::numbers::pi / 3;
const cv::Vec3d kAxisDirection(0, -1, 0);  // up in the rig frame (y down)
const cv::Vec3d kAxisPoint(0, 0, 400);     // on the platter, 400 mm in front of the rig

TurntableAxis Axis() {
  TurntableAxis axis;
  axis.valid = true;
  axis.direction_in_rig = kAxisDirection;
  axis.point_in_rig_mm = kAxisPoint;
  return axis;
}

cv::Vec3f Apply(const cv::Matx44d& T, const cv::Vec3d& p) {
  const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
  return {static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2])};
}

// The box in the turntable frame (z up, base on the platter at z = 0) with
// 0.05 mm noise, in the rig frame after the table turned by `angle`.
PointCloud BoxView(double angle, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, 0.05);
  const cv::Matx44d rig_from_turntable = InvertRigid(TurntableFromRig(Axis()));
  const cv::Matx44d turned = RotationAboutAxis(kAxisDirection, kAxisPoint, angle);
  PointCloud cloud;
  const double w = 40, d = 30, h = 20, s = 0.5;
  auto add = [&](double x, double y, double z) {
    cloud.points_mm.push_back(
        Apply(turned * rig_from_turntable, {x + noise(rng), y + noise(rng), z + noise(rng)}));
  };
  for (double x = -w / 2; x <= w / 2; x += s)
    for (double y = -d / 2; y <= d / 2; y += s) add(x, y, h);
  for (double z = 0; z <= h; z += s) {
    for (double x = -w / 2; x <= w / 2; x += s) {
      add(x, -d / 2, z);
      add(x, d / 2, z);
    }
    for (double y = -d / 2; y <= d / 2; y += s) {
      add(-w / 2, y, z);
      add(w / 2, y, z);
    }
  }
  // A step on the top, so that no turn maps the box onto itself.
  for (double x = 5; x <= 15; x += s)
    for (double y = -10; y <= 0; y += s) add(x, y, h + 6);
  return cloud;
}

// A sphere of radius 15 mm beside the axis: nothing like the box.
PointCloud UnrelatedView() {
  PointCloud cloud;
  const cv::Matx44d rig_from_turntable = InvertRigid(TurntableFromRig(Axis()));
  for (int i = 0; i < 4000; ++i) {
    const double z = 1 - 2 * (i + 0.5) / 4000, r = std::sqrt(1 - z * z);
    const double a = std::numbers::pi * (3 - std::sqrt(5.0)) * i;
    cloud.points_mm.push_back(
        Apply(rig_from_turntable, {60 + 15 * r * std::cos(a), 15 * r * std::sin(a), 20 + 15 * z}));
  }
  return cloud;
}

std::vector<ScanView> Views(double true_step_rad) {
  std::vector<ScanView> views;
  for (int k = 0; k < kViews; ++k) {
    ScanView v;
    v.cloud_in_rig = BoxView(k * true_step_rad, 10 + k);
    v.commanded_angle_rad = k * kStepRad;
    views.push_back(std::move(v));
  }
  return views;
}

ScanOptions Options() {
  ScanOptions options;
  options.mesh = false;
  options.num_threads = 2;
  return options;
}

// Rotation (degrees) between view0_from_view and the turntable motion back
// by `angle`.
double PoseErrorDeg(const cv::Matx44d& view0_from_view, double angle) {
  const cv::Matx44d expected = RotationAboutAxis(kAxisDirection, kAxisPoint, -angle);
  const cv::Matx44d delta = InvertRigid(expected) * view0_from_view;
  const double c = (delta(0, 0) + delta(1, 1) + delta(2, 2) - 1) / 2;
  return std::acos(std::clamp(c, -1.0, 1.0)) * 180 / std::numbers::pi;
}

TEST(ScanReconstruction, ARefusedRegistrationKeepsTheTurntablePose) {
  std::vector<ScanView> views = Views(kStepRad);
  views[3].cloud_in_rig = UnrelatedView();
  const ScanResult r = ReconstructScan(views, Axis(), Options());
  ASSERT_TRUE(r.IsUsable()) << r.message;
  ASSERT_EQ(r.turntable_pose.size(), static_cast<std::size_t>(kViews));
  // View 3 onto 2 and view 4 onto 3 involve the sphere: both refused.
  for (int k = 1; k < kViews; ++k) {
    const bool involves_sphere = k == 3 || k == 4;
    EXPECT_EQ(r.turntable_pose[k], involves_sphere) << "view " << k;
    EXPECT_EQ(r.pairwise[k].IsUsable(), !involves_sphere) << "view " << k;
    EXPECT_LT(PoseErrorDeg(r.view0_from_view[k], k * kStepRad), 0.2) << "view " << k;
  }
  EXPECT_NE(r.message.find("view 3 kept its calibrated turntable pose"), std::string::npos)
      << r.message;
  const std::string report = ScanReportJson(r);
  EXPECT_NE(report.find("\"pose\": \"turntable\""), std::string::npos);
  EXPECT_NE(report.find("\"pose\": \"registered\""), std::string::npos);
  EXPECT_FALSE(r.fused.empty());
}

TEST(ScanReconstruction, RegistrationsStrayingBeyondTheLimitAreRefused) {
  ScanOptions options = Options();
  options.close_loop = false;  // the pairs alone
  // Within the default limits (2°, 3 mm) the registrations are kept.
  const ScanResult kept = ReconstructScan(Views(kStepRad), Axis(), options);
  ASSERT_TRUE(kept.IsUsable()) << kept.message;
  for (int k = 1; k < kViews; ++k) {
    EXPECT_FALSE(kept.turntable_pose[k]) << "view " << k;
    EXPECT_LT(PoseErrorDeg(kept.view0_from_view[k], k * kStepRad), 0.1) << "view " << k;
  }
  // Limits tighter than what the noise makes ICP move: every registration
  // strays, is refused, and its view keeps the commanded motion exactly.
  options.max_prior_deviation_deg = 1e-5;
  options.max_prior_deviation_mm = 1e-5;
  const ScanResult refused = ReconstructScan(Views(kStepRad), Axis(), options);
  ASSERT_TRUE(refused.IsUsable()) << refused.message;
  for (int k = 1; k < kViews; ++k) {
    EXPECT_TRUE(refused.turntable_pose[k]) << "view " << k;
    EXPECT_NE(refused.pairwise[k].message.find("from the calibrated turntable motion"),
              std::string::npos)
        << refused.pairwise[k].message;
    EXPECT_LT(PoseErrorDeg(refused.view0_from_view[k], k * kStepRad), 1e-6) << "view " << k;
  }
}

TEST(ScanReconstruction, TheLoopTurnsAboutTheCalibratedAxisUnlessTheScanContradictsIt) {
  // The calibration right: the loop closes about it.
  const ScanResult r = ReconstructScan(Views(kStepRad), Axis(), Options());
  ASSERT_TRUE(r.IsUsable()) << r.message;
  ASSERT_TRUE(r.loop && r.loop->IsUsable());
  EXPECT_TRUE(r.loop->calibrated_axis) << r.loop->axis_disagreement_deg << " deg";
  EXPECT_LT(r.loop->axis_disagreement_deg, 0.5);
  EXPECT_NE(r.message.find("loop closed (turntable_axis, about the calibrated axis)"),
            std::string::npos)
      << r.message;
  for (int k = 1; k < kViews; ++k)
    EXPECT_LT(PoseErrorDeg(r.view0_from_view[k], k * kStepRad), 0.1) << "view " << k;
  EXPECT_NE(ScanReportJson(r).find("\"axis\": \"calibrated\""), std::string::npos);

  // The turntable was knocked after calibration: its calibrated axis is
  // 0.8° off the one it turns about. The registrations' own axis is used,
  // and the message says to calibrate again.
  TurntableAxis stale = Axis();
  const double tilt = 0.8 * std::numbers::pi / 180;  // about the rig's x axis
  stale.direction_in_rig = cv::Vec3d(0, -std::cos(tilt), -std::sin(tilt));
  // The views as the true axis turned them, the frame from the stale one.
  // With the default options: the slide rule keeps the prior wherever ICP
  // moves the pose by more than 0.3° for less than 0.02 of fitness, and a
  // pose 0.8° off moves this box's points by under 0.4 mm, well inside the
  // 2 mm fitness gate, so every pair keeps the stale motion. The loop
  // checks the calibration against where ICP itself put the views.
  const ScanResult s = ReconstructScan(Views(kStepRad), stale, Options());
  int slid = 0;
  for (const RegistrationResult& pair : s.pairwise) slid += pair.slid_target_from_source ? 1 : 0;
  if (s.closing && s.closing->slid_target_from_source) ++slid;
  EXPECT_GE(slid, kViews - 1) << "pairs that slid and kept the stale motion";
  ASSERT_TRUE(s.IsUsable()) << s.message;
  ASSERT_TRUE(s.loop && s.loop->IsUsable());
  EXPECT_FALSE(s.loop->calibrated_axis);
  EXPECT_NEAR(s.loop->axis_disagreement_deg, 0.8, 0.15);
  EXPECT_NE(s.message.find("from the calibrated one"), std::string::npos) << s.message;
  EXPECT_NE(s.message.find("calibrate-turntable (run it again)"), std::string::npos) << s.message;
  std::printf("stale calibration: %s\n", s.message.c_str());
  for (int k = 1; k < kViews; ++k)
    EXPECT_LT(PoseErrorDeg(s.view0_from_view[k], k * kStepRad), 0.1) << "view " << k;
}

TEST(ScanReconstruction, PriorDeviationLimitsAreValidated) {
  ScanOptions options = Options();
  options.max_prior_deviation_mm = 0;
  const ScanResult r = ReconstructScan(Views(kStepRad), Axis(), options);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("max_prior_deviation"), std::string::npos) << r.message;
}

// Fed view by view, as the daemon feeds it while the turntable turns, the
// scan makes the model ReconstructScan makes of the same views.
TEST(IncrementalScan, ViewByViewGivesTheModelOfTheWholeScan) {
  const std::vector<ScanView> views = Views(kStepRad);
  const ScanResult whole = ReconstructScan(views, Axis(), Options());
  ASSERT_TRUE(whole.IsUsable()) << whole.message;
  IncrementalScan scan(Axis(), Options());
  for (std::size_t k = 0; k < views.size(); ++k) {
    ScanView copy = views[k];
    ASSERT_TRUE(scan.Add(std::move(copy))) << "view " << k;
    EXPECT_EQ(scan.views(), static_cast<int>(k + 1));
  }
  const ScanResult r = scan.Finish();
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_EQ(r.fused.points_mm, whole.fused.points_mm);
  ASSERT_EQ(r.view0_from_view.size(), whole.view0_from_view.size());
  for (std::size_t k = 0; k < r.view0_from_view.size(); ++k)
    EXPECT_EQ(cv::norm(r.view0_from_view[k] - whole.view0_from_view[k]), 0) << "view " << k;
  EXPECT_TRUE(r.closing && r.closing->IsUsable()) << "a full turn closes its loop";
  EXPECT_GT(r.register_ms, 0);
  // Finish is once.
  const ScanResult again = scan.Finish();
  EXPECT_FALSE(again.IsUsable());
  EXPECT_NE(again.message.find("already finished"), std::string::npos) << again.message;
  EXPECT_FALSE(scan.Add(views[0]));
}

// A view that conditions to nothing stops the scan there: later views are
// not taken, and Finish says which view failed, keeping what was done.
TEST(IncrementalScan, AViewThatFailsStopsTheScanAndFinishNamesIt) {
  std::vector<ScanView> views = Views(kStepRad);
  views[2].cloud_in_rig = PointCloud();
  IncrementalScan scan(Axis(), Options());
  EXPECT_TRUE(scan.Add(views[0]));
  EXPECT_TRUE(scan.Add(views[1]));
  EXPECT_FALSE(scan.Add(views[2]));
  EXPECT_FALSE(scan.Add(views[3]));
  EXPECT_EQ(scan.views(), 3);
  const ScanResult r = scan.Finish();
  EXPECT_FALSE(r.IsUsable());
  EXPECT_EQ(r.message.rfind("view 2: ", 0), 0u) << r.message;
  EXPECT_EQ(r.views.size(), 3u);
  EXPECT_TRUE(r.pairwise[1].IsUsable()) << "view 1 was registered before view 2 came";

  // Invalid options: the first view is refused already.
  ScanOptions options = Options();
  options.max_prior_deviation_deg = -1;
  IncrementalScan invalid(Axis(), options);
  EXPECT_FALSE(invalid.Add(views[0]));
  const ScanResult bad = invalid.Finish();
  EXPECT_NE(bad.message.find("max_prior_deviation"), std::string::npos) << bad.message;

  // One view is not a scan.
  IncrementalScan one(Axis(), Options());
  EXPECT_TRUE(one.Add(views[0]));
  EXPECT_NE(one.Finish().message.find("at least 2 views"), std::string::npos);
}

}  // namespace
}  // namespace craftscan
