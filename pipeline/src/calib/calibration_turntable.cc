// Turntable axis calibration from a board lying on the platter.
#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/calib3d.hpp>
#include <string>
#include <utility>
#include <vector>

#include "calibration_internal.h"
#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan {

using calib_internal::Fixed;
using calib_internal::kNaN;

namespace {

constexpr double kRadToDeg = 180.0 / CV_PI;

// Below this |cos| between board normal and axis the board is taken as not
// lying on the platter (more than 60° tilted), so the platter height is unknown.
constexpr double kMinNormalAxisCos = 0.5;

struct Pose {  // rig_from_board
  cv::Matx33d R;
  cv::Vec3d t;
};

double WrapAngle(double a) {
  a = std::fmod(a + CV_PI, 2 * CV_PI);
  if (a < 0) a += 2 * CV_PI;
  return a - CV_PI;
}

// Signed rotation angle of `r` about the unit axis `d` (right-handed).
double AngleAbout(const cv::Matx33d& r, const cv::Vec3d& d) {
  const cv::Vec3d helper = std::abs(d[0]) < 0.9 ? cv::Vec3d(1, 0, 0) : cv::Vec3d(0, 1, 0);
  const cv::Vec3d v = cv::normalize(d.cross(helper));
  cv::Vec3d w = r * v;
  w -= w.dot(d) * d;
  return std::atan2(d.dot(v.cross(w)), v.dot(w));
}

// Board poses in the rig frame (rectified left camera) for every step that
// sees the board; fills result->steps and *used. False (result->message set)
// for a step whose commanded angle is not finite.
bool BoardPosesInRig(const StereoCalibration& calibration, const std::vector<TurntableStep>& steps,
                     TurntableAxisResult* result_out, std::vector<Pose>* poses_out,
                     std::vector<std::size_t>* used_out) {
  TurntableAxisResult& result = *result_out;
  std::vector<Pose>& poses = *poses_out;
  std::vector<std::size_t>& used = *used_out;
  const cv::Mat k(calibration.left.camera_matrix);
  const cv::Mat dist = calibration.left.DistortionCoeffs();
  poses.assign(steps.size(), Pose{});
  for (std::size_t i = 0; i < steps.size(); ++i) {
    TurntableAxisResult::Step& s = result.steps[i];
    const TurntableStep& step = steps[i];
    s.commanded_angle_rad = step.commanded_angle_rad;
    const std::string name = "step " + std::to_string(i);
    if (!std::isfinite(step.commanded_angle_rad)) {
      result.message = name + ": commanded angle is not finite";
      return false;
    }
    if (!step.left.found) {
      s.message = step.left.message.empty() ? "board not found" : step.left.message;
      continue;
    }
    if (step.left.image_points.size() != step.left.object_points.size() ||
        step.left.image_points.size() < 4 ||
        step.left.ids.size() != step.left.image_points.size()) {
      s.message = "fewer than 4 corners or mismatched point/id lists";
      continue;
    }
    cv::Mat rvec, tvec;
    try {
      if (!cv::solvePnP(step.left.object_points, step.left.image_points, k, dist, rvec, tvec, false,
                        cv::SOLVEPNP_IPPE)) {
        s.message = "board pose not found (solvePnP)";
        continue;
      }
      cv::solvePnPRefineLM(step.left.object_points, step.left.image_points, k, dist, rvec, tvec);
      std::vector<cv::Point2f> projected;
      cv::projectPoints(step.left.object_points, rvec, tvec, k, dist, projected);
      s.reprojection_rms_px = calib_internal::RmsDistance(projected, step.left.image_points);
    } catch (const cv::Exception& e) {
      s.message = std::string("board pose failed: ") + calib_internal::CvErrorText(e);
      continue;
    }
    cv::Matx33d left_from_board;
    cv::Rodrigues(rvec, left_from_board);
    cv::Vec3d t_left(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
    poses[i].R = calibration.R1 * left_from_board;
    poses[i].t = calibration.R1 * t_left;
    s.used = true;
    used.push_back(i);
  }
  return true;
}

// The axis direction: the vector every relative rotation leaves fixed,
// argmin Σ |(R_rel − I)·d|² (weights large rotations more), oriented so that
// positive commanded angles turn right-handed about it. False when the poses
// do not rotate about a common axis.
bool FitAxisDirection(const std::vector<Pose>& poses, const std::vector<std::size_t>& used,
                      const std::vector<TurntableStep>& steps, cv::Vec3d* direction) {
  const std::size_t first = used.front();
  const Pose& p0 = poses[first];
  cv::Matx33d m = cv::Matx33d::zeros();
  for (std::size_t i : used) {
    const cv::Matx33d a = poses[i].R * p0.R.t() - cv::Matx33d::eye();
    m += a.t() * a;
  }
  cv::Mat eigenvalues, eigenvectors;
  cv::eigen(cv::Mat(m), eigenvalues, eigenvectors);  // descending
  if (!(eigenvalues.at<double>(1) > 1e-6)) {
    return false;
  }
  cv::Vec3d d(eigenvectors.at<double>(2, 0), eigenvectors.at<double>(2, 1),
              eigenvectors.at<double>(2, 2));
  d = cv::normalize(d);
  // Orient d so that positive commanded angles turn right-handed about it:
  // compare the turns with the commands both ways round (cosines, so that
  // commands beyond 180° compare correctly).
  double same_way = 0, other_way = 0;
  for (std::size_t i : used) {
    const double commanded = steps[i].commanded_angle_rad - steps[first].commanded_angle_rad;
    const double turned = AngleAbout(poses[i].R * p0.R.t(), d);
    same_way += std::cos(turned - commanded);
    other_way += std::cos(-turned - commanded);
  }
  if (other_way > same_way) d = -d;

  *direction = d;
  return true;
}

// A point on the axis: (I − R_rel)·c = t_rel for every step, plus dᵀc = 0 to
// pin the free position along the axis; then slid onto the platter (or to
// the board's height, with *note saying so, when the board is not lying
// flat). False when the system cannot be solved.
bool FitAxisPoint(const std::vector<Pose>& poses, const std::vector<std::size_t>& used,
                  const cv::Vec3d& d, const TurntableAxisOptions& options, cv::Vec3d* point,
                  std::string* note) {
  const Pose& p0 = poses[used.front()];
  const int rows = 3 * static_cast<int>(used.size()) + 1;
  cv::Mat a(rows, 3, CV_64F), b(rows, 1, CV_64F);
  int row = 0;
  for (std::size_t i : used) {
    const cv::Matx33d r_rel = poses[i].R * p0.R.t();
    const cv::Vec3d t_rel = poses[i].t - r_rel * p0.t;
    const cv::Matx33d lhs = cv::Matx33d::eye() - r_rel;
    for (int j = 0; j < 3; ++j, ++row) {
      for (int c = 0; c < 3; ++c) a.at<double>(row, c) = lhs(j, c);
      b.at<double>(row) = t_rel[j];
    }
  }
  for (int c = 0; c < 3; ++c) a.at<double>(row, c) = d[c];
  b.at<double>(row) = 0;
  cv::Mat c_mat;
  if (!cv::solve(a, b, c_mat, cv::DECOMP_SVD) || !cv::checkRange(c_mat)) {
    return false;
  }
  cv::Vec3d c(c_mat.at<double>(0), c_mat.at<double>(1), c_mat.at<double>(2));

  const cv::Vec3d normal = p0.R * cv::Vec3d(0, 0, 1);
  if (std::abs(normal.dot(d)) >= kMinNormalAxisCos) {
    // The platter lies behind the board as the camera sees it.
    const cv::Vec3d away = normal.dot(p0.t) > 0 ? normal : -normal;
    const cv::Vec3d on_platter = p0.t + options.board_thickness_mm * away;
    c += (normal.dot(on_platter - c) / normal.dot(d)) * d;
  } else {
    // Not lying flat: take the height of the board's origin instead.
    c += d.dot(p0.t - c) * d;
    *note = "; the board is not lying on the platter (normal " +
            Fixed(std::acos(std::min(1.0, std::abs(normal.dot(d)))) * kRadToDeg, 1) +
            "° from the axis): point_in_rig_mm is at the board's height, not the platter's";
  }

  *point = c;
  return true;
}

// Each used step's turn about the axis against its command (relative to the
// first used step); returns the step with the largest error.
std::size_t MeasureAngles(const std::vector<Pose>& poses, const std::vector<std::size_t>& used,
                          const std::vector<TurntableStep>& steps, const cv::Vec3d& d,
                          TurntableAxisResult* result) {
  const std::size_t first = used.front();
  const Pose& p0 = poses[first];
  double max_error = 0;
  std::size_t worst_step = first;
  for (std::size_t i : used) {
    TurntableAxisResult::Step& s = result->steps[i];
    s.estimated_angle_rad = AngleAbout(poses[i].R * p0.R.t(), d);
    const double commanded = steps[i].commanded_angle_rad - steps[first].commanded_angle_rad;
    s.angle_error_deg = WrapAngle(s.estimated_angle_rad - commanded) * kRadToDeg;
    if (std::abs(s.angle_error_deg) > max_error) {
      max_error = std::abs(s.angle_error_deg);
      worst_step = i;
    }
  }
  result->max_abs_angle_error_deg = max_error;

  return worst_step;
}

// Residuals: each corner (by id) should travel on a circle about the axis.
void AxisResiduals(const std::vector<Pose>& poses, const std::vector<std::size_t>& used,
                   const std::vector<TurntableStep>& steps, const cv::Vec3d& d, const cv::Vec3d& c,
                   TurntableAxisResult* result) {
  struct Track {
    std::vector<std::pair<std::size_t, cv::Vec3d>> positions;  // (step, p_in_rig)
  };
  std::map<int, Track> tracks;
  for (std::size_t i : used) {
    const BoardDetection& det = steps[i].left;
    for (std::size_t j = 0; j < det.ids.size(); ++j) {
      const cv::Point3f& o = det.object_points[j];
      const cv::Vec3d p = poses[i].R * cv::Vec3d(o.x, o.y, o.z) + poses[i].t;
      tracks[det.ids[j]].positions.emplace_back(i, p);
    }
  }
  std::vector<double> step_sum(steps.size(), 0.0);
  std::vector<int> step_count(steps.size(), 0);
  double sum = 0;
  int count = 0;
  for (const auto& [id, track] : tracks) {
    if (track.positions.size() < 2) continue;
    double mean_height = 0, mean_radius = 0;
    std::vector<std::pair<double, double>> hr;
    for (const auto& [step, p] : track.positions) {
      const cv::Vec3d rel = p - c;
      const double h = d.dot(rel);
      const double r = cv::norm(rel - h * d);
      hr.emplace_back(h, r);
      mean_height += h;
      mean_radius += r;
    }
    mean_height /= static_cast<double>(hr.size());
    mean_radius /= static_cast<double>(hr.size());
    for (std::size_t j = 0; j < hr.size(); ++j) {
      const double dh = hr[j].first - mean_height, dr = hr[j].second - mean_radius;
      const double e2 = dh * dh + dr * dr;
      sum += e2;
      ++count;
      step_sum[track.positions[j].first] += e2;
      ++step_count[track.positions[j].first];
    }
  }
  result->residual_mm = count > 0 ? std::sqrt(sum / count) : kNaN;
  for (std::size_t i : used) {
    if (step_count[i] > 0) result->steps[i].residual_mm = std::sqrt(step_sum[i] / step_count[i]);
  }
}

// Accepts or rejects the fit against the options' limits.
void JudgeAxis(const std::vector<TurntableStep>& steps, std::size_t used_steps,
               std::size_t worst_step, const TurntableAxisOptions& options,
               TurntableAxisResult* result_out) {
  TurntableAxisResult& result = *result_out;
  const double max_error = result.max_abs_angle_error_deg;
  std::vector<std::string> failures;
  if (!(result.residual_mm <= options.max_residual_mm)) {
    failures.push_back("residual " + Fixed(result.residual_mm, 3) + " mm > " +
                       Fixed(options.max_residual_mm, 3) +
                       " mm (board moved on the platter, or a wobbling turntable?)");
  }
  if (!(max_error <= options.max_angle_error_deg)) {
    failures.push_back("step " + std::to_string(worst_step) + " (commanded " +
                       Fixed(steps[worst_step].commanded_angle_rad * kRadToDeg, 2) + "°) turned " +
                       Fixed(result.steps[worst_step].angle_error_deg, 3) +
                       "° off the command (limit " + Fixed(options.max_angle_error_deg, 3) +
                       "°): check the commanded angle, steps per degree or backlash");
  }
  if (failures.empty()) {
    result.verdict = CalibrationVerdict::kAccept;
    result.verdict_reason = "accepted: " + std::to_string(used_steps) + " steps, residual " +
                            Fixed(result.residual_mm, 3) + " mm, max angle error " +
                            Fixed(max_error, 3) + "°";
  } else {
    result.verdict = CalibrationVerdict::kReject;
    result.verdict_reason = "rejected: ";
    for (std::size_t i = 0; i < failures.size(); ++i) {
      result.verdict_reason += (i ? "; " : "") + failures[i];
    }
  }
}

}  // namespace

TurntableAxisResult CalibrateTurntableAxis(const StereoCalibration& calibration,
                                           const std::vector<TurntableStep>& steps,
                                           const TurntableAxisOptions& options) {
  using Status = TurntableAxisResult::Status;
  TurntableAxisResult result;
  result.steps.resize(steps.size());
  std::string why;
  if (!options.IsValid(&why)) {
    result.message = "options: " + why;
    return result;
  }
  if (!calibration.IsValid(&why)) {
    result.message = "calibration: " + why;
    return result;
  }
  if (calibration.board.IsRotationallySymmetric()) {
    result.message = "the " + Describe(calibration.board) +
                     " looks the same turned by 180° (cols + rows even), so its corner order "
                     "cannot follow the turntable; use a board with one odd and one even side "
                     "(e.g. 9x6) or a ChArUco board";
    return result;
  }

  std::vector<Pose> poses;
  std::vector<std::size_t> used;
  if (!BoardPosesInRig(calibration, steps, &result, &poses, &used)) return result;
  result.steps_used = static_cast<int>(used.size());
  if (result.steps_used < options.min_steps) {
    result.status = Status::kTooFewSteps;
    result.message = "too few turntable steps with the board: " + std::to_string(used.size()) +
                     " of " + std::to_string(steps.size()) + ", need " +
                     std::to_string(options.min_steps);
    for (std::size_t i = 0; i < steps.size(); ++i) {
      if (!result.steps[i].used) {
        result.message += "; step " + std::to_string(i) + ": " + result.steps[i].message;
      }
    }
    return result;
  }
  const std::size_t first = used.front();
  double span = 0;
  for (std::size_t i : used) {
    span =
        std::max(span, std::abs(steps[i].commanded_angle_rad - steps[first].commanded_angle_rad));
  }
  if (span < options.min_span_rad) {
    result.message = "commanded angles span only " + Fixed(span * kRadToDeg, 2) + "°, need " +
                     Fixed(options.min_span_rad * kRadToDeg, 2) + "° for a well-defined axis";
    return result;
  }

  cv::Vec3d d;
  if (!FitAxisDirection(poses, used, steps, &d)) {
    result.status = Status::kFailed;
    result.message = "the board poses do not rotate about a common axis (did the turntable turn?)";
    return result;
  }
  cv::Vec3d c;
  std::string note;
  if (!FitAxisPoint(poses, used, d, options, &c, &note)) {
    result.status = Status::kFailed;
    result.message = "cannot solve for a point on the axis";
    return result;
  }
  const std::size_t worst_step = MeasureAngles(poses, used, steps, d, &result);
  AxisResiduals(poses, used, steps, d, c, &result);

  result.axis.valid = true;
  result.axis.direction_in_rig = d;
  result.axis.point_in_rig_mm = c;
  result.status = Status::kOk;
  JudgeAxis(steps, used.size(), worst_step, options, &result);
  result.message = result.verdict_reason + note;
  return result;
}

bool ApplyTurntableAxis(const TurntableAxisResult& result, StereoCalibration* calibration) {
  if (calibration == nullptr || result.status != TurntableAxisResult::Status::kOk ||
      !result.axis.valid) {
    return false;
  }
  calibration->turntable = result.axis;
  calibration->report.turntable_steps = result.steps_used;
  calibration->report.turntable_residual_mm = result.residual_mm;
  calibration->report.turntable_max_angle_error_deg = result.max_abs_angle_error_deg;
  return true;
}

}  // namespace craftscan
