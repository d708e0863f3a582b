// Turntable axis calibration on synthetic poses: a board lying on the platter,
// turned about a known axis by commanded angles, projected into the left
// camera of a known rig.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/calib3d.hpp>
#include <random>
#include <string>
#include <vector>

#include "calibration_test_util.h"
#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan {
namespace {

using testing::Chessboard9x6;

constexpr double kDegToRad = CV_PI / 180.0;
constexpr double kRadToDeg = 180.0 / CV_PI;

struct Scene {
  StereoCalibration calibration;  // ground-truth rig, rectified
  TurntableAxis truth;            // in the rig frame
  std::vector<double> angles_rad;
};

// The platter is seen from ~40° above; the axis runs up (−y, towards the
// camera) in the rig frame and meets the platter 600 mm away.
Scene MakeScene() {
  Scene s;
  s.calibration = testing::RigCalibration(testing::MakeRig(), Chessboard9x6());
  s.truth.valid = true;
  s.truth.direction_in_rig = cv::normalize(cv::Vec3d(0.03, -0.766, -0.643));
  s.truth.point_in_rig_mm = cv::Vec3d(12, 70, 620);
  for (int deg = 0; deg < 360; deg += 30) s.angles_rad.push_back(deg * kDegToRad);
  return s;
}

// Board corners in the rig frame when the platter has turned by `angle_rad`
// (right-handed about the axis). The board lies `height_mm` above the platter,
// corner 0 offset from the axis, facing up (its z into the platter).
std::vector<cv::Vec3d> BoardInRig(const Scene& s, const BoardSpec& board, double angle_rad,
                                  double height_mm) {
  const cv::Vec3d z = s.truth.direction_in_rig;
  const cv::Vec3d x = cv::normalize(z.cross(cv::Vec3d(0, 0, 1)));
  const cv::Vec3d y = z.cross(x);
  const double psi = 0.4;  // board's heading on the platter
  const cv::Vec3d bx(std::cos(psi), std::sin(psi), 0), bz(0, 0, -1);
  const cv::Vec3d by = bz.cross(bx);
  const cv::Vec3d origin_world(-70, -40, height_mm);
  const double c = std::cos(angle_rad), sn = std::sin(angle_rad);
  auto turn = [&](const cv::Vec3d& v) {
    return cv::Vec3d(c * v[0] - sn * v[1], sn * v[0] + c * v[1], v[2]);
  };
  std::vector<cv::Vec3d> out;
  for (const cv::Point3f& p : BoardCornersInBoard(board)) {
    const cv::Vec3d w = turn(origin_world + p.x * bx + p.y * by + p.z * bz);
    out.push_back(s.truth.point_in_rig_mm + w[0] * x + w[1] * y + w[2] * z);
  }
  return out;
}

std::vector<TurntableStep> MakeSteps(const Scene& s, const BoardSpec& board, double noise_px,
                                     double height_mm = 0) {
  std::mt19937 rng(42);
  std::vector<TurntableStep> steps;
  const cv::Matx33d left_from_rig = s.calibration.R1.t();
  for (double angle : s.angles_rad) {
    std::vector<cv::Point3f> p_in_left;
    for (const cv::Vec3d& p : BoardInRig(s, board, angle, height_mm)) {
      const cv::Vec3d q = left_from_rig * p;
      p_in_left.emplace_back(static_cast<float>(q[0]), static_cast<float>(q[1]),
                             static_cast<float>(q[2]));
    }
    std::vector<cv::Point2f> image = testing::ProjectPoints(p_in_left, cv::Matx33d::eye(),
                                                            cv::Vec3d(0, 0, 0), s.calibration.left);
    EXPECT_TRUE(testing::AllInside(image, s.calibration.image_size, 5))
        << "step at " << angle * kRadToDeg << "° leaves the image";
    testing::AddNoise(noise_px, &rng, &image);
    TurntableStep step;
    step.commanded_angle_rad = angle;
    step.left = testing::DetectionFromPoints(board, std::move(image));
    steps.push_back(std::move(step));
  }
  return steps;
}

double AngleDeg(const cv::Vec3d& a, const cv::Vec3d& b) {
  return std::acos(std::clamp(a.dot(b) / (cv::norm(a) * cv::norm(b)), -1.0, 1.0)) * kRadToDeg;
}

// Distance of point p from the line through c along unit d.
double DistanceFromAxis(const cv::Vec3d& p, const cv::Vec3d& c, const cv::Vec3d& d) {
  const cv::Vec3d v = p - c;
  return cv::norm(v - v.dot(d) * d);
}

TEST(TurntableAxis, RecoversAKnownAxis) {
  const Scene s = MakeScene();
  const std::vector<TurntableStep> steps = MakeSteps(s, Chessboard9x6(), 0.05);
  const TurntableAxisResult r = CalibrateTurntableAxis(s.calibration, steps);
  ASSERT_EQ(r.status, TurntableAxisResult::Status::kOk) << r.message;
  const double direction_error = AngleDeg(r.axis.direction_in_rig, s.truth.direction_in_rig);
  const double point_error = cv::norm(r.axis.point_in_rig_mm - s.truth.point_in_rig_mm);
  std::printf(
      "turntable: direction error %.4f°, point error %.3f mm (off-axis %.3f mm), "
      "residual %.4f mm, max angle error %.4f°\n",
      direction_error, point_error,
      DistanceFromAxis(s.truth.point_in_rig_mm, r.axis.point_in_rig_mm, r.axis.direction_in_rig),
      r.residual_mm, r.max_abs_angle_error_deg);
  EXPECT_LT(direction_error, 0.1);
  EXPECT_LT(point_error, 1.0);
  EXPECT_EQ(r.steps_used, 12);
  ASSERT_EQ(r.steps.size(), 12u);
  for (std::size_t i = 0; i < r.steps.size(); ++i) {
    EXPECT_TRUE(r.steps[i].used);
    EXPECT_LT(std::abs(r.steps[i].angle_error_deg), 0.05) << "step " << i;
    EXPECT_LT(r.steps[i].reprojection_rms_px, 0.15) << "step " << i;
  }
  EXPECT_NEAR(r.steps[3].estimated_angle_rad, 90 * kDegToRad, 0.05 * kDegToRad);
  EXPECT_LT(r.residual_mm, 0.5);
  EXPECT_EQ(r.verdict, CalibrationVerdict::kAccept) << r.verdict_reason;
  EXPECT_TRUE(r.IsUsable());

  StereoCalibration c = s.calibration;
  ASSERT_TRUE(ApplyTurntableAxis(r, &c));
  EXPECT_TRUE(c.turntable.valid);
  EXPECT_EQ(c.report.turntable_steps, 12);
  std::string why;
  EXPECT_TRUE(c.IsValid(&why)) << why;
}

TEST(TurntableAxis, DirectionFollowsTheCommandSign) {
  Scene s = MakeScene();
  const std::vector<TurntableStep> steps = MakeSteps(s, Chessboard9x6(), 0.0);
  std::vector<TurntableStep> reversed = steps;
  for (TurntableStep& step : reversed) step.commanded_angle_rad = -step.commanded_angle_rad;
  const TurntableAxisResult r = CalibrateTurntableAxis(s.calibration, reversed);
  ASSERT_EQ(r.status, TurntableAxisResult::Status::kOk) << r.message;
  EXPECT_LT(AngleDeg(r.axis.direction_in_rig, -s.truth.direction_in_rig), 0.01);
  EXPECT_LT(r.max_abs_angle_error_deg, 0.01);
}

TEST(TurntableAxis, WrongCommandedAngleShowsInItsStep) {
  const Scene s = MakeScene();
  std::vector<TurntableStep> steps = MakeSteps(s, Chessboard9x6(), 0.05);
  steps[5].commanded_angle_rad += 2 * kDegToRad;  // the turntable really went to 150°
  const TurntableAxisResult r = CalibrateTurntableAxis(s.calibration, steps);
  ASSERT_EQ(r.status, TurntableAxisResult::Status::kOk) << r.message;
  EXPECT_NEAR(r.steps[5].angle_error_deg, -2.0, 0.05);
  for (std::size_t i = 0; i < r.steps.size(); ++i) {
    if (i != 5) {
      EXPECT_LT(std::abs(r.steps[i].angle_error_deg), 0.05) << "step " << i;
    }
  }
  EXPECT_LT(AngleDeg(r.axis.direction_in_rig, s.truth.direction_in_rig), 0.1)
      << "the axis fit does not depend on the commanded angles";
  EXPECT_EQ(r.verdict, CalibrationVerdict::kReject);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.verdict_reason.find("step 5"), std::string::npos) << r.verdict_reason;
}

TEST(TurntableAxis, BoardThicknessPutsThePointOnThePlatter) {
  const Scene s = MakeScene();
  const std::vector<TurntableStep> steps = MakeSteps(s, Chessboard9x6(), 0.0, /*height_mm=*/4.0);
  TurntableAxisOptions options;
  options.board_thickness_mm = 4.0;
  const TurntableAxisResult r = CalibrateTurntableAxis(s.calibration, steps, options);
  ASSERT_EQ(r.status, TurntableAxisResult::Status::kOk) << r.message;
  EXPECT_LT(cv::norm(r.axis.point_in_rig_mm - s.truth.point_in_rig_mm), 0.05);
  const TurntableAxisResult no_thickness = CalibrateTurntableAxis(s.calibration, steps);
  const double along =
      (no_thickness.axis.point_in_rig_mm - s.truth.point_in_rig_mm).dot(s.truth.direction_in_rig);
  EXPECT_NEAR(along, 4.0, 0.05) << "without the thickness the point is on the board's surface";
}

TEST(TurntableAxis, ClearErrors) {
  const Scene s = MakeScene();
  std::vector<TurntableStep> steps = MakeSteps(s, Chessboard9x6(), 0.05);

  // Boards not found in most steps.
  std::vector<TurntableStep> few(steps.begin(), steps.begin() + 4);
  few[1].left = BoardDetection{};
  few[1].left.message = "board not found (chessboard 9x6 inner corners, 25.000 mm squares)";
  few[2].left = few[1].left;
  TurntableAxisResult r = CalibrateTurntableAxis(s.calibration, few);
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kTooFewSteps);
  EXPECT_NE(r.message.find("2 of 4"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find("step 1: board not found"), std::string::npos) << r.message;

  // Too small a turn.
  std::vector<TurntableStep> small = steps;
  for (std::size_t i = 0; i < small.size(); ++i) small[i].commanded_angle_rad = i * kDegToRad;
  r = CalibrateTurntableAxis(s.calibration, small);
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kInvalidInput);
  EXPECT_NE(r.message.find("span only 11.00°"), std::string::npos) << r.message;

  // A 180°-symmetric chessboard cannot follow the turntable.
  StereoCalibration symmetric = s.calibration;
  symmetric.board.cols = 8;
  r = CalibrateTurntableAxis(symmetric, steps);
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kInvalidInput);
  EXPECT_NE(r.message.find("180°"), std::string::npos) << r.message;

  // No calibration.
  r = CalibrateTurntableAxis(StereoCalibration{}, steps);
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kInvalidInput);
  EXPECT_NE(r.message.find("calibration:"), std::string::npos) << r.message;

  // The platter did not turn although commanded.
  std::vector<TurntableStep> still = steps;
  for (TurntableStep& step : still) step.left = steps[0].left;
  r = CalibrateTurntableAxis(s.calibration, still);
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kFailed);
  EXPECT_NE(r.message.find("did the turntable turn"), std::string::npos) << r.message;
  StereoCalibration unchanged = s.calibration;
  EXPECT_FALSE(ApplyTurntableAxis(r, &unchanged));
  EXPECT_FALSE(unchanged.turntable.valid);
}

}  // namespace
}  // namespace craftscan
