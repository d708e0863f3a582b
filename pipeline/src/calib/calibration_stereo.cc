// Monocular and stereo calibration, rectification, quality report.
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <string>
#include <utility>
#include <vector>

#include "calibration_internal.h"
#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan {

using calib_internal::Fail;
using calib_internal::Fixed;
using calib_internal::kNaN;

namespace {

// Fewest corners two cameras must share in a ChArUco view.
constexpr int kMinCommonCorners = 6;
// How many skipped views a "too few views" message lists before "…".
constexpr int kMaxListedViews = 5;

bool PointsInside(const std::vector<cv::Point2f>& points, cv::Size size) {
  for (const cv::Point2f& p : points) {
    if (!(p.x >= -0.5f && p.y >= -0.5f && p.x <= size.width - 0.5f && p.y <= size.height - 0.5f)) {
      return false;
    }
  }
  return true;
}

// Why a detection cannot be used, or empty.
std::string DetectionProblem(const BoardDetection& d, cv::Size image_size) {
  if (!d.found) return d.message.empty() ? "board not found" : d.message;
  if (d.image_points.size() != d.object_points.size() || d.image_points.size() < 4) {
    return "fewer than 4 corners or mismatched point lists";
  }
  if (!PointsInside(d.image_points, image_size)) {
    return "corners outside the " + std::to_string(image_size.width) + "x" +
           std::to_string(image_size.height) + " image (another image size?)";
  }
  return {};
}

bool AllFiniteMat(const cv::Mat& m) { return cv::checkRange(m); }

std::string ListSkipped(const std::vector<ViewReport>& views) {
  std::string text;
  int listed = 0;
  for (const ViewReport& v : views) {
    if (v.used) continue;
    if (listed == kMaxListedViews) {
      text += "; …";
      break;
    }
    text += (listed == 0 ? "" : "; ") + v.name + ": " + v.message;
    ++listed;
  }
  return text;
}

}  // namespace

CameraCalibrationResult CalibrateCamera(const std::vector<BoardDetection>& views,
                                        cv::Size image_size, const LensModelOptions& lens,
                                        int coverage_grid) {
  CameraCalibrationResult result;
  result.view_rms_px.assign(views.size(), kNaN);
  result.camera_from_board_R.assign(views.size(), cv::Matx33d::eye());
  result.camera_from_board_t_mm.assign(views.size(), cv::Vec3d(0, 0, 0));
  std::string why;
  if (image_size.width <= 0 || image_size.height <= 0) {
    result.message = "image size must be positive";
    return result;
  }
  if (!lens.IsValid(&why)) {
    result.message = why;
    return result;
  }

  std::vector<std::vector<cv::Point3f>> object_points;
  std::vector<std::vector<cv::Point2f>> image_points;
  std::vector<std::size_t> used;
  for (std::size_t i = 0; i < views.size(); ++i) {
    if (!DetectionProblem(views[i], image_size).empty()) continue;
    object_points.push_back(views[i].object_points);
    image_points.push_back(views[i].image_points);
    used.push_back(i);
  }
  if (static_cast<int>(used.size()) < kMinCalibrationViews) {
    result.status = CameraCalibrationResult::Status::kTooFewViews;
    result.message = "only " + std::to_string(used.size()) + " of " + std::to_string(views.size()) +
                     " views show the board; at least " + std::to_string(kMinCalibrationViews) +
                     " are needed";
    return result;
  }

  cv::Mat camera_matrix = calib_internal::InitialCameraMatrix(), distortion;
  std::vector<cv::Mat> rvecs, tvecs;
  cv::Mat std_intrinsics, std_extrinsics, per_view;
  double rms = 0;
  try {
    rms = cv::calibrateCamera(
        object_points, image_points, image_size, camera_matrix, distortion, rvecs, tvecs,
        std_intrinsics, std_extrinsics, per_view, calib_internal::LensFlags(lens),
        cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-7));
  } catch (const cv::Exception& e) {
    result.status = CameraCalibrationResult::Status::kFailed;
    result.message = std::string("cv::calibrateCamera failed: ") + calib_internal::CvErrorText(e);
    return result;
  }
  if (!std::isfinite(rms) || !AllFiniteMat(camera_matrix) || !AllFiniteMat(distortion)) {
    result.status = CameraCalibrationResult::Status::kFailed;
    result.message = "cv::calibrateCamera gave non-finite values (degenerate views?)";
    return result;
  }
  camera_matrix.convertTo(cv::Mat(result.intrinsics.camera_matrix, false), CV_64F);
  result.intrinsics.SetDistortionCoeffs(distortion);
  result.rms_px = rms;
  for (std::size_t k = 0; k < used.size(); ++k) {
    const std::size_t i = used[k];
    result.view_rms_px[i] = per_view.at<double>(static_cast<int>(k));
    cv::Rodrigues(rvecs[k], cv::Mat(result.camera_from_board_R[i], false));
    tvecs[k].convertTo(cv::Mat(result.camera_from_board_t_mm[i], false), CV_64F);
  }
  result.views_used = static_cast<int>(used.size());
  result.coverage = calib_internal::Coverage(image_points, image_size, coverage_grid);
  result.status = CameraCalibrationResult::Status::kOk;
  result.message =
      "calibrated from " + std::to_string(used.size()) + " views, RMS " + Fixed(rms, 3) + " px";
  return result;
}

bool ComputeRectification(const RectificationOptions& options, StereoCalibration* calibration,
                          std::string* error) {
  std::string why;
  if (calibration == nullptr) return Fail(error, "ComputeRectification: no calibration");
  if (!options.IsValid(&why)) return Fail(error, why);
  StereoCalibration& c = *calibration;
  if (c.image_size.width <= 0 || c.image_size.height <= 0) {
    return Fail(error, "image_size: must be positive");
  }
  if (!calib_internal::IsRotation(c.R, 1e-5)) return Fail(error, "R: not a rotation matrix");
  if (!calib_internal::AllFinite(cv::Matx31d(c.T)) || cv::norm(c.T) == 0) {
    return Fail(error, "T: must be finite and non-zero");
  }
  cv::Mat r1, r2, p1, p2, q;
  try {
    cv::stereoRectify(
        cv::Mat(c.left.camera_matrix), c.left.DistortionCoeffs(), cv::Mat(c.right.camera_matrix),
        c.right.DistortionCoeffs(), c.image_size, cv::Mat(c.R), cv::Mat(c.T), r1, r2, p1, p2, q,
        options.zero_disparity ? cv::CALIB_ZERO_DISPARITY : 0, options.alpha, c.image_size);
  } catch (const cv::Exception& e) {
    return Fail(error, std::string("cv::stereoRectify failed: ") + calib_internal::CvErrorText(e));
  }
  if (!AllFiniteMat(r1) || !AllFiniteMat(r2) || !AllFiniteMat(p1) || !AllFiniteMat(p2) ||
      !AllFiniteMat(q)) {
    return Fail(error, "cv::stereoRectify gave non-finite values");
  }
  r1.convertTo(cv::Mat(c.R1, false), CV_64F);
  r2.convertTo(cv::Mat(c.R2, false), CV_64F);
  p1.convertTo(cv::Mat(c.P1, false), CV_64F);
  p2.convertTo(cv::Mat(c.P2, false), CV_64F);
  q.convertTo(cv::Mat(c.Q, false), CV_64F);
  return true;
}

namespace {

// Pairs the left and right detections of one view into common point lists.
// Returns an empty string on success, else why the view is not used.
std::string PairView(const StereoBoardView& view, const BoardSpec& board, cv::Size image_size,
                     std::vector<cv::Point3f>* object_points, std::vector<cv::Point2f>* left,
                     std::vector<cv::Point2f>* right) {
  const std::string left_problem = DetectionProblem(view.left, image_size);
  const std::string right_problem = DetectionProblem(view.right, image_size);
  if (!left_problem.empty() && !right_problem.empty()) {
    return "left image: " + left_problem + "; right image: " + right_problem;
  }
  if (!left_problem.empty()) return "left image: " + left_problem;
  if (!right_problem.empty()) return "right image: " + right_problem;

  if (board.type == BoardSpec::Type::kChessboard) {
    if (view.left.image_points.size() != view.right.image_points.size()) {
      return "left and right corner counts differ";
    }
    *object_points = view.left.object_points;
    *left = view.left.image_points;
    *right = view.right.image_points;
    // A 180°-symmetric board's corner order is tied to the image, not the
    // board; make the right one run the same way as the left one.
    if (board.IsRotationallySymmetric()) {
      const cv::Point2f dl = left->back() - left->front(), dr = right->back() - right->front();
      if (dl.dot(dr) < 0) std::reverse(right->begin(), right->end());
    }
    return {};
  }
  for (std::size_t i = 0; i < view.left.ids.size(); ++i) {
    const auto it = std::find(view.right.ids.begin(), view.right.ids.end(), view.left.ids[i]);
    if (it == view.right.ids.end()) continue;
    const auto j = static_cast<std::size_t>(it - view.right.ids.begin());
    object_points->push_back(view.left.object_points[i]);
    left->push_back(view.left.image_points[i]);
    right->push_back(view.right.image_points[j]);
  }
  if (static_cast<int>(object_points->size()) < kMinCommonCorners) {
    return "only " + std::to_string(object_points->size()) +
           " ChArUco corner(s) seen by both cameras (need " + std::to_string(kMinCommonCorners) +
           ")";
  }
  return {};
}

void Verdict(const StereoCalibrationOptions& options, CalibrationReport* report) {
  const CalibrationLimits& limits = options.limits;
  std::vector<std::string> failures;
  bool rms_failed = false;
  if (report->views_used < limits.min_views) {
    failures.push_back(std::to_string(report->views_used) + " views used, at least " +
                       std::to_string(limits.min_views) + " required (capture more board poses)");
  }
  auto check_rms = [&](const char* what, double value) {
    if (!(value <= limits.max_rms_px)) {
      failures.push_back(std::string(what) + " RMS " + Fixed(value, 3) + " px > " +
                         Fixed(limits.max_rms_px, 3) + " px");
      rms_failed = true;
    }
  };
  check_rms("stereo", report->rms_stereo_px);
  check_rms("left", report->rms_left_px);
  check_rms("right", report->rms_right_px);
  if (!(report->epipolar_mean_px <= limits.max_epipolar_px)) {
    failures.push_back("epipolar error " + Fixed(report->epipolar_mean_px, 3) + " px > " +
                       Fixed(limits.max_epipolar_px, 3) + " px");
  }
  auto check_coverage = [&](const char* camera, double value) {
    if (!(value >= limits.min_coverage)) {
      failures.push_back(std::string(camera) + " coverage " + Fixed(value, 2) + " < " +
                         Fixed(limits.min_coverage, 2) +
                         " (show the board near the image edges and corners)");
    }
  };
  check_coverage("left", report->coverage_left);
  check_coverage("right", report->coverage_right);

  if (failures.empty()) {
    report->verdict = CalibrationVerdict::kAccept;
    report->verdict_reason =
        "accepted: " + std::to_string(report->views_used) + " views, stereo RMS " +
        Fixed(report->rms_stereo_px, 3) + " px, epipolar " + Fixed(report->epipolar_mean_px, 3) +
        " px, coverage " + Fixed(report->coverage_left, 2) + "/" + Fixed(report->coverage_right, 2);
    return;
  }
  std::string reason = "rejected: ";
  for (std::size_t i = 0; i < failures.size(); ++i) reason += (i ? "; " : "") + failures[i];
  if (rms_failed) {
    const ViewReport* worst = nullptr;
    for (const ViewReport& v : report->views) {
      if (v.used && (worst == nullptr || v.rms_stereo_px > worst->rms_stereo_px)) worst = &v;
    }
    if (worst != nullptr) {
      reason += "; worst view '" + worst->name + "' (" + Fixed(worst->rms_stereo_px, 3) +
                " px): check or drop it";
    }
  }
  report->verdict = CalibrationVerdict::kReject;
  report->verdict_reason = std::move(reason);
}

}  // namespace

StereoCalibrationResult CalibrateStereo(const std::vector<StereoBoardView>& views,
                                        cv::Size image_size, const BoardSpec& board,
                                        const StereoCalibrationOptions& options) {
  using Status = StereoCalibrationResult::Status;
  StereoCalibrationResult result;
  std::string why;
  if (!options.IsValid(&why) || !board.IsValid(&why)) {
    result.message = why;
    return result;
  }
  if (image_size.width <= 0 || image_size.height <= 0) {
    result.message = "image size must be positive (got " + std::to_string(image_size.width) + "x" +
                     std::to_string(image_size.height) + ")";
    return result;
  }
  StereoCalibration& calibration = result.calibration;
  CalibrationReport& report = calibration.report;
  calibration.image_size = image_size;
  calibration.board = board;
  report.coverage_grid = options.coverage_grid;
  report.views.resize(views.size());

  // Views both cameras saw.
  std::vector<std::vector<cv::Point3f>> object_points;
  std::vector<std::vector<cv::Point2f>> left_points, right_points;
  std::vector<std::size_t> used;
  for (std::size_t i = 0; i < views.size(); ++i) {
    ViewReport& vr = report.views[i];
    vr.name = views[i].name.empty() ? "view " + std::to_string(i) : views[i].name;
    std::vector<cv::Point3f> obj;
    std::vector<cv::Point2f> l, r;
    vr.message = PairView(views[i], board, image_size, &obj, &l, &r);
    if (!vr.message.empty()) continue;
    vr.used = true;
    vr.num_points = static_cast<int>(obj.size());
    object_points.push_back(std::move(obj));
    left_points.push_back(std::move(l));
    right_points.push_back(std::move(r));
    used.push_back(i);
  }
  report.views_used = static_cast<int>(used.size());
  if (report.views_used < kMinCalibrationViews) {
    result.status = Status::kTooFewViews;
    result.message = "too few board views: " + std::to_string(used.size()) + " of " +
                     std::to_string(views.size()) + " pair(s) show the board in both images, " +
                     "at least " + std::to_string(kMinCalibrationViews) + " are needed";
    if (used.size() < views.size()) result.message += " (" + ListSkipped(report.views) + ")";
    return result;
  }

  // Monocular calibrations, each from every view where that camera found the board.
  std::vector<BoardDetection> left_views, right_views;
  for (const StereoBoardView& v : views) {
    left_views.push_back(v.left);
    right_views.push_back(v.right);
  }
  const CameraCalibrationResult left =
      CalibrateCamera(left_views, image_size, options.lens, options.coverage_grid);
  const CameraCalibrationResult right =
      CalibrateCamera(right_views, image_size, options.lens, options.coverage_grid);
  for (const auto& [mono, name] : {std::pair{&left, "left"}, std::pair{&right, "right"}}) {
    if (!mono->IsUsable()) {
      result.status = mono->status == CameraCalibrationResult::Status::kFailed
                          ? Status::kFailed
                          : Status::kTooFewViews;
      result.message = std::string(name) + " camera: " + mono->message;
      return result;
    }
  }
  for (std::size_t i = 0; i < views.size(); ++i) {
    report.views[i].rms_left_px = left.view_rms_px[i];
    report.views[i].rms_right_px = right.view_rms_px[i];
  }
  report.rms_left_px = left.rms_px;
  report.rms_right_px = right.rms_px;
  report.coverage_left = left.coverage;
  report.coverage_right = right.coverage;

  // Stereo, starting from the monocular intrinsics.
  cv::Mat k1 = cv::Mat(left.intrinsics.camera_matrix).clone();
  cv::Mat k2 = cv::Mat(right.intrinsics.camera_matrix).clone();
  cv::Mat d1 = left.intrinsics.DistortionCoeffs(), d2 = right.intrinsics.DistortionCoeffs();
  if (options.lens.rational_model) {  // keep 8 coefficients even if k4..k6 came out 0
    if (d1.cols == 5) cv::hconcat(d1, cv::Mat::zeros(1, 3, CV_64F), d1);
    if (d2.cols == 5) cv::hconcat(d2, cv::Mat::zeros(1, 3, CV_64F), d2);
  }
  int flags = calib_internal::LensFlags(options.lens);
  flags |=
      options.refine_intrinsics_in_stereo ? cv::CALIB_USE_INTRINSIC_GUESS : cv::CALIB_FIX_INTRINSIC;
  if (options.lens.same_focal_length && options.refine_intrinsics_in_stereo) {
    flags |= cv::CALIB_SAME_FOCAL_LENGTH;
  }
  cv::Mat r, t, e, f, per_view;
  double rms = 0;
  try {
    rms = cv::stereoCalibrate(object_points, left_points, right_points, k1, d1, k2, d2, image_size,
                              r, t, e, f, per_view, flags,
                              cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS,
                                               options.max_iterations, options.epsilon));
  } catch (const cv::Exception& ex) {
    result.status = Status::kFailed;
    result.message = std::string("cv::stereoCalibrate failed: ") + calib_internal::CvErrorText(ex);
    return result;
  }
  if (!std::isfinite(rms) || !AllFiniteMat(k1) || !AllFiniteMat(k2) || !AllFiniteMat(d1) ||
      !AllFiniteMat(d2) || !AllFiniteMat(r) || !AllFiniteMat(t)) {
    result.status = Status::kFailed;
    result.message = "cv::stereoCalibrate gave non-finite values (degenerate views?)";
    return result;
  }
  k1.convertTo(cv::Mat(calibration.left.camera_matrix, false), CV_64F);
  k2.convertTo(cv::Mat(calibration.right.camera_matrix, false), CV_64F);
  calibration.left.SetDistortionCoeffs(d1);
  calibration.right.SetDistortionCoeffs(d2);
  r.convertTo(cv::Mat(calibration.R, false), CV_64F);
  t.reshape(1, 3).convertTo(cv::Mat(calibration.T, false), CV_64F);
  report.rms_stereo_px = rms;
  for (std::size_t k = 0; k < used.size(); ++k) {
    const double el = per_view.at<double>(static_cast<int>(k), 0);
    const double er = per_view.at<double>(static_cast<int>(k), 1);
    report.views[used[k]].rms_stereo_px = std::sqrt(0.5 * (el * el + er * er));
  }

  if (!ComputeRectification(options.rectification, &calibration, &why)) {
    result.status = Status::kFailed;
    result.message = why;
    return result;
  }

  // Epipolar error: the board corners after rectification should share rows.
  double sum = 0, worst = 0;
  std::size_t count = 0;
  for (std::size_t k = 0; k < used.size(); ++k) {
    std::vector<cv::Point2f> rl, rr;
    cv::undistortPoints(left_points[k], rl, k1, d1, cv::Mat(calibration.R1),
                        cv::Mat(calibration.P1));
    cv::undistortPoints(right_points[k], rr, k2, d2, cv::Mat(calibration.R2),
                        cv::Mat(calibration.P2));
    for (std::size_t j = 0; j < rl.size(); ++j) {
      const double dy = std::abs(rl[j].y - rr[j].y);
      sum += dy;
      worst = std::max(worst, dy);
      ++count;
    }
  }
  report.epipolar_mean_px = count > 0 ? sum / static_cast<double>(count) : kNaN;
  report.epipolar_max_px = count > 0 ? worst : kNaN;

  if (!calibration.IsValid(&why)) {
    result.status = Status::kFailed;
    result.message = "calibration result is not valid: " + why;
    return result;
  }
  Verdict(options, &report);
  result.status = Status::kOk;
  result.message = report.verdict_reason;
  return result;
}

}  // namespace craftscan
