// Guided calibration (the calibrate job with calibration.guided): watches
// the board in the live stream and decides, frame by frame, what a person
// holding it should do and when a view is taken, as ROS's
// camera_calibration does. Pure logic (no devices): fed detections and
// frame stamps, it answers with the state, a rejection if any, advice and
// the feedback the console draws (CalibrationGuide::Overlay).
//
// A view is taken when the board is found whole in both images, has been
// still (no corner of the left image moving more than still_px between
// frames) for hold_s by the frames' own stamps, is sharp (chessboards:
// cv::estimateChessboardSharpness ≤ max_blur_px) and differs from every
// view already taken: its pose parameters (x, y: the corners' mean position
// over the image size; size: √ of the outer quadrilateral's area over the
// image's; skew: 2·|90° − the angle at the top right outer corner| in
// radians, capped at 1) are at least min_param_distance apart in their sum
// of absolute differences. The diversity bars are each parameter's range
// over the taken views divided by the range wanted; coverage: the cells of
// a grid over the left image that corners of taken views fell in.
// The ranges wanted are smaller than ROS's monocular 0.7, 0.7, 0.4, 0.5 in
// x, y and size: a stereo pair needs the whole board in both images, so its
// centre stays within their overlap (with the station's 100 mm baseline at
// 300–500 mm, x spans about 0.45 of the left image), and a board a person
// can hold steady fills a fifth to a third of the picture. Done when at least views_needed views
// are taken, every bar reaches bar_done and coverage reaches coverage_done; or when max_views are
// taken.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

namespace craftscan::daemon {

struct CalibrationGuideOptions {
  cv::Size image_size;
  int board_cols = 9, board_rows = 6;  // inner corners (chessboard), for the outer quad
  bool chessboard = true;              // ChArUco: partial views, no sharpness estimate
  int views_needed = 12;
  int max_views = 30;
  double hold_s = 1.0;
  double still_px = 1.0;
  double max_blur_px = 3.0;
  double min_param_distance = 0.2;
  std::array<double, 4> ranges{0.35, 0.35, 0.1, 0.5};  // x, y, size, skew
  double bar_done = 1.0;
  int grid_cols = 4, grid_rows = 3;
  double coverage_done = 0.75;
};

struct GuideInput {
  std::int64_t stamp_ns = 0;
  bool left_found = false, right_found = false;
  std::vector<cv::Point2f> left, right;  // corners (full-resolution px)
  double blur_px = 0;                    // chessboard sharpness; 0 = unknown
};

struct GuideDecision {
  bool take = false;     // store this frame's pair as a calibration view
  std::string state;     // searching | moving | holding | captured | rejected
  std::string rejected;  // why a still board was not taken ("" = not rejected)
  std::string advice;    // what the person should do now
};

// How long a board's corners (left image) have stayed still: no corner
// moving more than still_px between consecutive frames, timed by the
// frames' stamps.
class BoardStillness {
 public:
  // This frame's corners; false if they moved (the hold starts again).
  bool Feed(std::int64_t stamp_ns, const std::vector<cv::Point2f>& corners, double still_px);
  void Reset();  // the board is gone
  double hold_s() const { return hold_s_; }

 private:
  std::vector<cv::Point2f> last_;
  std::int64_t since_ns_ = -1;
  double hold_s_ = 0;
};

class CalibrationGuide {
 public:
  explicit CalibrationGuide(CalibrationGuideOptions options);

  GuideDecision Feed(const GuideInput& frame);
  // Call after storing a view Feed said to take.
  void Taken(const GuideInput& frame);

  int views() const { return static_cast<int>(params_.size()); }
  bool Done() const;
  std::array<double, 4> Bars() const;  // x, y, size, skew progress, 0..1
  double Coverage() const;             // share of grid cells covered, 0..1
  double hold_s() const { return still_.hold_s(); }
  // The console's overlay (API.md "preview"): state, corners scaled by
  // `scale` (preview px per full px), hold, coverage, diversity, counts,
  // rejection and advice.
  nlohmann::json Overlay(const GuideDecision& decision, const GuideInput& frame,
                         double scale) const;

  // x, y, size, skew of a whole chessboard view (left image).
  std::array<double, 4> Params(const std::vector<cv::Point2f>& corners) const;

 private:
  std::string Advice() const;

  CalibrationGuideOptions o_;
  std::vector<std::array<double, 4>> params_;
  std::vector<bool> covered_;
  BoardStillness still_;
  bool need_move_ = false;  // after a capture, the board must move before the next
};

// Guided turntable-axis calibration (calibrate-turntable with
// calibration.guided): a person lays the board on the platter, and the
// guide decides when it may turn and, at each angle, which frame to use.
//
// Placing: the turntable waits until the board is found whole in both
// images, at least min_margin (of the image's width and height) inside
// every edge of the left image (it must stay in the picture as it turns),
// sharp, and still (no corner moving more than still_px between frames)
// for hold_s by the frames' stamps: a hand still on the board or a board
// still settling keeps it waiting. Then "ready": hands off, it turns.
// Turning: after each move, the frame used is the first whose board (left
// image) lies still against the previous frame of that angle, so a board
// sliding on a jerky platter or a hand reaching in is not measured; a
// board not found still within angle_wait_s is recorded as missed at that
// angle and the guide goes on.
struct PlatterGuideOptions {
  cv::Size image_size;
  int angles = 6;
  double hold_s = 1.0;
  double still_px = 0.5;
  double max_blur_px = 3.0;
  double min_margin = 0.03;
  double angle_wait_s = 4;
};

class PlatterGuide {
 public:
  explicit PlatterGuide(PlatterGuideOptions options) : o_(std::move(options)) {}

  // Placing. take = true: the board lies still in view; start turning.
  GuideDecision Place(const GuideInput& frame);
  // Turning: call at each new angle (its index and degrees) before its frames.
  void StartAngle(int index, double angle_deg, std::int64_t stamp_ns);
  // take = true: use this frame's board at the current angle;
  // state "missed": give up on this angle (the board was not found still).
  GuideDecision Turn(const GuideInput& frame);

  int found() const { return found_; }
  int missed() const { return missed_; }
  bool placing() const { return angle_index_ < 0; }
  nlohmann::json Overlay(const GuideDecision& decision, const GuideInput& frame,
                         double scale) const;

 private:
  PlatterGuideOptions o_;
  BoardStillness still_;
  std::vector<cv::Point2f> last_left_;  // turning: the previous frame's at this angle
  std::int64_t angle_start_ns_ = -1;
  int angle_index_ = -1, found_ = 0, missed_ = 0;
  double angle_deg_ = 0;
  std::vector<nlohmann::json> steps_;  // {angle_deg, found}
};

}  // namespace craftscan::daemon
