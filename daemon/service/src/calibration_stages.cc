// The calibration jobs' stages: calibrate, calibrate-turntable (stages.h).
#include <sys/stat.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <thread>
#include <utility>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/calibration_guide.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/live_preview.h"
#include "craftscan/daemon/stages.h"
#include "craftscan/pipeline/common/atomic_file.h"

namespace craftscan::daemon {
namespace {

constexpr double kDegToRad = CV_PI / 180;

std::string UtcStamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y%m%d-%H%M%S", &tm);
  return buffer;
}

CalibrationOutcome Failure(std::string message, nlohmann::json result = {}) {
  CalibrationOutcome out;
  out.status = StageOutcome::Error(ErrorCode::kFailedPrecondition, std::move(message), false);
  out.result = std::move(result);
  return out;
}

CalibrationOutcome Cancelled(const std::string& verb) {
  CalibrationOutcome out;
  out.status = StageOutcome::Cancelled();
  out.status.message = verb + " cancelled; nothing changed";
  return out;
}

void StorePng(const std::string& path, const cv::Mat& image) {
  std::vector<uchar> png;
  cv::imencode(".png", image, png);
  WriteFileAtomically(path, std::string(png.begin(), png.end()), nullptr);
}

// What a guide is fed for one frame: the detections, and for a chessboard
// found in the left image its blur (cv::estimateChessboardSharpness).
GuideInput GuideInputOf(const drivers::StereoFrame& frame, const StereoBoardView& view,
                        const BoardSpec& board) {
  GuideInput in;
  in.stamp_ns = frame.left.timestamp_ns;
  in.left_found = view.left.found;
  in.right_found = view.right.found;
  in.left = view.left.image_points;
  in.right = view.right.image_points;
  if (view.left.found && board.type == BoardSpec::Type::kChessboard) {
    cv::Mat grey = frame.left.image;
    if (grey.channels() == 3) cv::cvtColor(frame.left.image, grey, cv::COLOR_BGR2GRAY);
    try {
      in.blur_px = cv::estimateChessboardSharpness(grey, cv::Size(board.cols, board.rows),
                                                   view.left.image_points)[0];
    } catch (const cv::Exception&) {
      in.blur_px = 0;  // unknown: not judged
    }
  }
  return in;
}

// Streams guided-calibration frames with their overlay (JobSink::Preview)
// at about `fps`, and always when `now` is set.
class GuidePreview {
 public:
  GuidePreview(const StageContext& context, std::string job_id, double fps, int width)
      : context_(context),
        job_id_(std::move(job_id)),
        period_ns_(static_cast<std::int64_t>(1e9 / std::max(0.1, fps))),
        width_(width) {}

  bool Due(std::int64_t stamp_ns, bool now) const {
    return context_.sink && (now || last_ns_ < 0 || stamp_ns - last_ns_ >= period_ns_);
  }
  // The overlay's corners are in preview px: `scale` (preview / full px) is
  // passed to `overlay`.
  // `ready_ns`: when the capture returned (WallNow).
  template <typename OverlayFn>
  void Publish(const drivers::StereoFrame& frame, std::int64_t ready_ns, OverlayFn overlay) {
    PreviewFrame p = MakePreviewFrame(frame.left.image, frame.right.image, width_);
    p.job_id = job_id_;
    p.sequence = sequence_++;
    p.stamp_ns = WallStamp(frame.left.timestamp_ns);
    p.ready_ns = ready_ns;
    p.exposure_us = frame.settings.exposure_us;
    p.gain_db = frame.settings.gain_db;
    p.overlay = overlay(static_cast<double>(p.size.width) / frame.left.image.cols).dump();
    context_.sink->Preview(p);
    last_ns_ = frame.left.timestamp_ns;
  }

 private:
  const StageContext& context_;
  std::string job_id_;
  std::int64_t period_ns_;
  int width_;
  std::int64_t last_ns_ = -1;
  std::uint32_t sequence_ = 0;
};

}  // namespace

std::string NewCalibrationDir(const std::string& data_dir, std::string* id, std::string* error) {
  const std::string root = data_dir + "/calibration";
  ::mkdir(root.c_str(), 0755);
  std::string candidate = UtcStamp();
  for (int i = 2; i < 1000; ++i) {
    const std::string dir = root + "/" + candidate;
    if (::mkdir(dir.c_str(), 0755) == 0) {
      *id = candidate;
      return dir;
    }
    if (errno != EEXIST) {
      Fail(error, "'" + dir + "': " + std::strerror(errno));
      return {};
    }
    candidate = UtcStamp() + "-" + std::to_string(i);
  }
  Fail(error, "'" + root + "': no free calibration name");
  return {};
}

// --- calibrate -----------------------------------------------------------------

CalibrationOutcome CalibrateStage::Run() {
  if (const drivers::DriverStatus s =
          devices_->ShowCalibrationTarget(CalibrationTarget::kHeldBoard, options_.board);
      !s.ok()) {
    return Failure("calibrate: " + s.message);
  }
  std::string error, id;
  const std::string dir = NewCalibrationDir(options_.data_dir, &id, &error);
  if (dir.empty()) {
    devices_->ShowObject();
    return Failure("calibrate: " + error);
  }
  if (options_.guided) {
    CalibrationOutcome out = RunGuided(dir, id);
    devices_->ShowObject();
    return out;
  }
  std::vector<StereoBoardView> views;
  cv::Size image_size;
  const int wanted = options_.views;
  for (int attempt = 0; attempt < options_.max_attempts &&
                        static_cast<int>(views.size()) < wanted && !context_.Stopping();
       ++attempt) {
    drivers::StereoFrame frame;
    const drivers::DriverStatus s = devices_->Capture(&frame, context_.StopFlag());
    if (!s.ok()) {
      error = s.message;
      break;
    }
    image_size = frame.left.image.size();
    StereoBoardView view = DetectStereoBoard("view" + std::to_string(attempt), frame.left.image,
                                             frame.right.image, options_.board);
    const bool found = view.left.found && view.right.found;
    if (found) {
      char name[32];
      std::snprintf(name, sizeof name, "/%03zu_", views.size());
      StorePng(dir + name + "left.png", frame.left.image);
      StorePng(dir + name + "right.png", frame.right.image);
      views.push_back(std::move(view));
    }
    context_.Progress("capture", static_cast<int>(views.size()), wanted,
                      found ? "board found" : "board not found in both images; move the board");
  }
  devices_->ShowObject();
  if (context_.Stopping()) return Cancelled("calibrate");
  if (static_cast<int>(views.size()) < wanted) {
    return Failure("calibrate: the board was found in " + std::to_string(views.size()) + " of " +
                   std::to_string(wanted) + " views" + (error.empty() ? "" : " (" + error + ")"));
  }
  return Solve(views, image_size, dir, id);
}

CalibrationOutcome CalibrateStage::RunGuided(const std::string& dir, const std::string& id) {
  std::vector<StereoBoardView> views;
  cv::Size image_size;
  std::unique_ptr<CalibrationGuide> guide;
  std::int64_t first_ns = -1;
  std::string error, last_advice;
  GuidePreview preview(context_, options_.job_id, options_.guided_preview_fps,
                       options_.guided_preview_width);
  while (!context_.Stopping()) {
    drivers::StereoFrame frame;
    const drivers::DriverStatus s = devices_->Capture(&frame, context_.StopFlag());
    if (context_.Stopping()) break;
    if (!s.ok()) return Failure("calibrate: " + s.message);
    const std::int64_t ready_ns = WallNow();
    const std::int64_t stamp = frame.left.timestamp_ns;
    if (first_ns < 0) first_ns = stamp;
    if (!guide) {
      image_size = frame.left.image.size();
      CalibrationGuideOptions o;
      o.image_size = image_size;
      o.chessboard = options_.board.type == BoardSpec::Type::kChessboard;
      o.board_cols = options_.board.cols;
      o.board_rows = options_.board.rows;
      o.views_needed = options_.views;
      o.max_views = std::max(options_.views * 2, options_.views + 10);
      guide = std::make_unique<CalibrationGuide>(o);
    }
    StereoBoardView view = DetectStereoBoard("view" + std::to_string(views.size()),
                                             frame.left.image, frame.right.image, options_.board);
    const GuideInput in = GuideInputOf(frame, view, options_.board);
    GuideDecision d = guide->Feed(in);
    const bool taken = d.take;
    if (d.take) {
      char name[32];
      std::snprintf(name, sizeof name, "/%03zu_", views.size());
      StorePng(dir + name + "left.png", frame.left.image);
      StorePng(dir + name + "right.png", frame.right.image);
      views.push_back(std::move(view));
      guide->Taken(in);
      d = guide->Feed(in);  // "captured": the next advice
      d.state = "captured";
      d.take = taken;
    }
    if (d.take || d.advice != last_advice) {
      std::string message = d.rejected.empty() ? d.advice : d.rejected + ": " + d.advice;
      if (d.take) {
        const std::array<double, 4> bars = guide->Bars();
        char text[160];
        std::snprintf(text, sizeof text,
                      "view %d taken; diversity x %.2f y %.2f size %.2f skew %.2f, coverage "
                      "%.0f %%; ",
                      guide->views(), bars[0], bars[1], bars[2], bars[3], 100 * guide->Coverage());
        message = text + d.advice;
      }
      context_.Progress("capture", guide->views(), options_.views, message);
      last_advice = d.advice;
    }
    if (preview.Due(stamp, d.state == "captured")) {
      preview.Publish(frame, ready_ns, [&](double scale) { return guide->Overlay(d, in, scale); });
    }
    if (guide->Done()) break;
    const double elapsed_s = static_cast<double>(stamp - first_ns) * 1e-9;
    if (elapsed_s > options_.guided_max_s) {
      const std::array<double, 4> bars = guide->Bars();
      char text[200];
      std::snprintf(text, sizeof text,
                    "calibrate: not enough views after %.0f s: %d taken of %d; diversity x %.2f "
                    "y %.2f size %.2f skew %.2f, coverage %.2f",
                    elapsed_s, guide->views(), options_.views, bars[0], bars[1], bars[2], bars[3],
                    guide->Coverage());
      return Failure(text);
    }
  }
  if (context_.Stopping()) return Cancelled("calibrate");
  CalibrationOutcome out = Solve(views, image_size, dir, id);
  const std::array<double, 4> bars = guide ? guide->Bars() : std::array<double, 4>{};
  out.result["guided"] = {
      {"views", views.size()},
      {"coverage", guide ? guide->Coverage() : 0.0},
      {"diversity", {{"x", bars[0]}, {"y", bars[1]}, {"size", bars[2]}, {"skew", bars[3]}}}};
  return out;
}

CalibrationOutcome CalibrateStage::Solve(const std::vector<StereoBoardView>& views,
                                         cv::Size image_size, const std::string& dir,
                                         const std::string& id) {
  context_.Progress("calibrate", 0, 1, "solving");
  StereoCalibrationResult r =
      CalibrateStereo(views, image_size, options_.board, options_.calibration);
  if (r.status != StereoCalibrationResult::Status::kOk) return Failure("calibrate: " + r.message);
  const CalibrationReport& report = r.report();
  nlohmann::json result = {
      {"calibration_id", id},
      {"rms_stereo_px", report.rms_stereo_px},
      {"rms_left_px", report.rms_left_px},
      {"rms_right_px", report.rms_right_px},
      {"epipolar_mean_px", report.epipolar_mean_px},
      {"views_used", report.views_used},
      {"verdict", std::string(ToString(report.verdict))},
      {"verdict_reason", report.verdict_reason},
      {"focal_px", r.calibration.P1(0, 0)},
      {"baseline_mm", std::abs(r.calibration.P2(0, 3) / r.calibration.P2(0, 0))}};
  std::string error;
  if (!SaveCalibration(dir + "/calibration.yaml", r.calibration, &error) ||
      !WriteFileAtomically(dir + "/report.json", result.dump(2), &error)) {
    return Failure("calibrate: " + error, result);
  }
  const bool accepted = r.IsUsable() && report.rms_stereo_px <= options_.max_rms_px;
  result["accepted"] = accepted;
  if (!accepted) {
    return Failure("calibrate: rejected (rms " + std::to_string(report.rms_stereo_px) + " px; " +
                       report.verdict_reason + "); the current calibration is unchanged",
                   result);
  }
  CalibrationOutcome out;
  out.result = std::move(result);
  out.accepted = r.calibration;
  out.id = id;
  out.summary = "calibration " + id + " accepted and current (rms " +
                std::to_string(report.rms_stereo_px) + " px); run calibrate-turntable next";
  return out;
}

// --- calibrate-turntable -------------------------------------------------------

CalibrationOutcome CalibrateTurntableStage::Run() {
  if (const drivers::DriverStatus s =
          devices_->ShowCalibrationTarget(CalibrationTarget::kPlatterBoard, options_.board);
      !s.ok()) {
    return Failure("calibrate-turntable: " + s.message);
  }
  if (const drivers::DriverStatus s = devices_->PrepareTurntable(); !s.ok()) {
    devices_->ShowObject();
    return Failure("calibrate-turntable: " + s.message);
  }
  std::vector<TurntableStep> steps;
  std::string error;
  const auto& angles = options_.angles_deg;
  if (options_.guided) {
    const bool ok = RunGuided(&steps, &error);
    devices_->MoveTo(0);
    devices_->ShowObject();
    if (context_.Stopping()) return Cancelled("calibrate-turntable");
    if (!ok) return Failure("calibrate-turntable: " + error);
    return Solve(steps);
  }
  for (std::size_t i = 0; i < angles.size() && !context_.Stopping(); ++i) {
    if (moving_) *moving_ = true;
    const drivers::DriverStatus moved = devices_->MoveTo(angles[i]);
    if (moving_) *moving_ = false;
    if (!moved.ok()) {
      error = moved.message;
      break;
    }
    std::this_thread::sleep_for(options_.settle);
    drivers::StereoFrame frame;
    const drivers::DriverStatus captured = devices_->Capture(&frame, context_.StopFlag());
    if (!captured.ok()) {
      error = captured.message;
      break;
    }
    TurntableStep step;
    step.commanded_angle_rad = angles[i] * kDegToRad;
    step.left = DetectBoard(frame.left.image, options_.board);
    context_.Progress("capture", static_cast<int>(i + 1), static_cast<int>(angles.size()),
                      step.left.found ? "board found" : "board not found: " + step.left.message);
    steps.push_back(std::move(step));
  }
  devices_->MoveTo(0);
  devices_->ShowObject();
  if (context_.Stopping()) return Cancelled("calibrate-turntable");
  if (steps.size() < angles.size()) return Failure("calibrate-turntable: " + error);
  return Solve(steps);
}

bool CalibrateTurntableStage::RunGuided(std::vector<TurntableStep>* steps, std::string* error) {
  std::unique_ptr<PlatterGuide> guide;
  GuidePreview preview(context_, options_.job_id, options_.guided_preview_fps,
                       options_.guided_preview_width);
  std::int64_t first_ns = -1;
  std::string last_advice;
  const auto& angles = options_.angles_deg;
  int angle = -1;  // placing
  while (!context_.Stopping()) {
    drivers::StereoFrame frame;
    const drivers::DriverStatus s = devices_->Capture(&frame, context_.StopFlag());
    if (context_.Stopping()) return false;
    if (!s.ok()) return Fail(error, s.message);
    const std::int64_t ready_ns = WallNow();
    const std::int64_t stamp = frame.left.timestamp_ns;
    if (first_ns < 0) first_ns = stamp;
    if (!guide) {
      PlatterGuideOptions o;
      o.image_size = frame.left.image.size();
      o.angles = static_cast<int>(angles.size());
      guide = std::make_unique<PlatterGuide>(o);
    }
    // Placing needs both images (the board whole in both); turning only the left.
    StereoBoardView view;
    if (angle < 0) {
      view = DetectStereoBoard("platter", frame.left.image, frame.right.image, options_.board);
    } else {
      view.left = DetectBoard(frame.left.image, options_.board);
    }
    const GuideInput in = GuideInputOf(frame, view, options_.board);
    const GuideDecision d = angle < 0 ? guide->Place(in) : guide->Turn(in);
    if (preview.Due(stamp, d.state == "captured" || d.state == "missed")) {
      preview.Publish(frame, ready_ns, [&](double scale) { return guide->Overlay(d, in, scale); });
    }
    if (d.advice != last_advice || d.take || d.state == "missed") {
      const std::string message = d.rejected.empty() ? d.advice : d.rejected + ": " + d.advice;
      context_.Progress(angle < 0 ? "place" : "capture", guide->found(),
                        static_cast<int>(angles.size()), message);
      last_advice = d.advice;
    }
    if (angle >= 0 && (d.take || d.state == "missed")) {
      TurntableStep step;
      step.commanded_angle_rad = angles[static_cast<std::size_t>(angle)] * kDegToRad;
      step.left = view.left;
      if (!d.take) {
        step.left.found = false;
        step.left.message = d.rejected;
      }
      steps->push_back(std::move(step));
    }
    if (d.take || d.state == "missed") {
      if (++angle >= static_cast<int>(angles.size())) return true;
      if (moving_) *moving_ = true;
      const drivers::DriverStatus moved = devices_->MoveTo(angles[static_cast<std::size_t>(angle)]);
      if (moving_) *moving_ = false;
      if (!moved.ok()) return Fail(error, moved.message);
      std::this_thread::sleep_for(options_.settle);
      guide->StartAngle(angle, angles[static_cast<std::size_t>(angle)], -1);
    }
    const double elapsed_s = static_cast<double>(stamp - first_ns) * 1e-9;
    if (elapsed_s > options_.guided_max_s) {
      char text[160];
      std::snprintf(
          text, sizeof text, "gave up after %.0f s (%s): ", elapsed_s,
          angle < 0 ? "the board was not laid still in view" : "the turns were not finished");
      return Fail(error, text + last_advice);
    }
  }
  return false;
}

CalibrationOutcome CalibrateTurntableStage::Solve(const std::vector<TurntableStep>& steps) {
  TurntableAxisOptions axis_options;
  axis_options.board_thickness_mm = options_.board_thickness_mm;
  const TurntableAxisResult r = CalibrateTurntableAxis(calibration_, steps, axis_options);
  nlohmann::json result = {{"status", std::string(ToString(r.status))},
                           {"steps_used", r.steps_used},
                           {"residual_mm", r.residual_mm},
                           {"max_abs_angle_error_deg", r.max_abs_angle_error_deg},
                           {"verdict", std::string(ToString(r.verdict))},
                           {"verdict_reason", r.verdict_reason}};
  StereoCalibration calibration = calibration_;
  if (!r.IsUsable() || !ApplyTurntableAxis(r, &calibration)) {
    std::string missed;
    for (const TurntableStep& step : steps) {
      if (step.left.found) continue;
      char at[32];
      std::snprintf(at, sizeof at, "%s%.0f°", missed.empty() ? "" : ", ",
                    step.commanded_angle_rad / kDegToRad);
      missed += at;
    }
    if (!missed.empty()) {
      missed = "; the board was not measured at " + missed +
               ": lay it nearer the middle of the platter, printed side up, and keep clear "
               "while it turns";
    }
    return Failure("calibrate-turntable: rejected: " +
                       (r.message.empty() ? r.verdict_reason : r.message) + missed,
                   result);
  }
  std::string id;
  std::string error;
  const std::string dir = NewCalibrationDir(options_.data_dir, &id, &error);
  if (dir.empty() || !SaveCalibration(dir + "/calibration.yaml", calibration, &error) ||
      !WriteFileAtomically(dir + "/report.json", result.dump(2), &error)) {
    return Failure("calibrate-turntable: " + error, result);
  }
  result["calibration_id"] = id;
  CalibrationOutcome out;
  out.result = std::move(result);
  out.accepted = calibration;
  out.id = id;
  out.summary = "turntable axis accepted (residual " + std::to_string(r.residual_mm) +
                " mm); calibration " + id + " is current";
  return out;
}

}  // namespace craftscan::daemon
