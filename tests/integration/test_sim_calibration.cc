// Calibration on the simulated station (drivers/sim) against its exact
// ground truth: boards rendered at full size by the default rig (1280×1024,
// 2400 px lenses with distortion, sensor noise σ = 1 grey level), detected and
// calibrated by the pipeline's own code, compared with the calibration the
// station was built from.
//
// Tolerances of the calibration issue: focal length 0.2 %, principal point
// 1 px, baseline 0.1 mm, stereo RMS 0.2 px, turntable axis direction 0.1°,
// rectified rows 0.1 px (mean). The chessboard's principal point is held to
// 3 px only (see its test: a board seen whole cannot do better on this rig).
// Figures measured (default seeds, Release, 2 threads) are noted at each
// test; the whole file takes ~40 s, nearly all of it rendering (~1 s per
// 1280×1024 pair at 2×2 supersampling).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <opencv2/aruco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/pipeline/calibration.h"
#include "craftscan/pipeline/rectify.h"
#include "craftscan/sim/station.h"

namespace craftscan::sim {
namespace {

constexpr double kDegToRad = CV_PI / 180.0;
constexpr double kRadToDeg = 180.0 / CV_PI;

// --- small helpers -----------------------------------------------------------

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

cv::Vec3d Apply(const cv::Matx44d& T, const cv::Vec3d& p) {
  const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
  return {q[0], q[1], q[2]};
}

cv::Matx44d Rigid(const cv::Matx33d& R, const cv::Vec3d& t) {
  cv::Matx44d m = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m(i, j) = R(i, j);
    m(i, 3) = t[i];
  }
  return m;
}

cv::Matx33d Rotation(const cv::Matx44d& m) { return m.get_minor<3, 3>(0, 0); }

double AngleDeg(const cv::Vec3d& a, const cv::Vec3d& b) {
  return std::acos(std::clamp(a.dot(b) / (cv::norm(a) * cv::norm(b)), -1.0, 1.0)) * kRadToDeg;
}

double RotationAngleDeg(const cv::Matx33d& a, const cv::Matx33d& b) {
  cv::Vec3d r;
  cv::Rodrigues(a * b.t(), r);
  return cv::norm(r) * kRadToDeg;
}

std::vector<cv::Vec3d> ToVec3d(const std::vector<cv::Point3f>& points) {
  std::vector<cv::Vec3d> out;
  for (const cv::Point3f& p : points) out.emplace_back(p.x, p.y, p.z);
  return out;
}

// Exact projection of points (in some frame F) into a raw camera, given
// camera_from_F and the camera's exact intrinsics.
std::vector<cv::Point2f> Project(const cv::Matx44d& camera_from_f, const CameraIntrinsics& camera,
                                 const std::vector<cv::Vec3d>& p_in_f) {
  std::vector<cv::Point3d> p;
  for (const cv::Vec3d& q : p_in_f) p.emplace_back(Apply(camera_from_f, q));
  std::vector<cv::Point2d> image;
  cv::projectPoints(p, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), camera.camera_matrix,
                    camera.distortion, image);
  return std::vector<cv::Point2f>(image.begin(), image.end());
}

bool Inside(const cv::Point2f& p, cv::Size size, double margin_px) {
  return p.x >= margin_px && p.y >= margin_px && p.x <= size.width - 1 - margin_px &&
         p.y <= size.height - 1 - margin_px;
}

// Smallest distance (px) of the points from the image border; negative when
// one is outside.
double InsideMargin(const std::vector<cv::Point2f>& points, cv::Size size) {
  double margin = 1e9;
  for (const cv::Point2f& p : points) {
    margin = std::min({margin, static_cast<double>(p.x), static_cast<double>(p.y),
                       size.width - 1.0 - p.x, size.height - 1.0 - p.y});
  }
  return margin;
}

struct Stats {
  double mean = 0, max = 0;
  int count = 0;
};

Stats Summarize(const std::vector<double>& values) {
  Stats s;
  for (double v : values) {
    s.mean += v;
    s.max = std::max(s.max, v);
  }
  s.count = static_cast<int>(values.size());
  if (s.count > 0) s.mean /= s.count;
  return s;
}

// --- the station -------------------------------------------------------------

// The default rig, rendering on two threads; `supersampling` 2 for
// calibration views. With 2×2 samples on a regular grid an edge's position
// is resolved to ±1/4 px only where the edge runs along the pixel grid, so
// the boards below are held a little rolled, as hands hold them: the corner
// error against the exact projection is then ~0.06 px RMS (~0.15 px with
// unrolled boards; ~0.12 px rolled at 1×1, ~0.05 px at 3×3).
std::unique_ptr<SimStation> MakeStation(int supersampling) {
  RigOptions rig;
  rig.num_threads = 2;
  rig.supersampling = supersampling;
  std::string error;
  auto station = SimStation::Create(rig, &error);
  EXPECT_TRUE(station) << error;
  return station;
}

const SimStation& Station() {
  static const std::unique_ptr<SimStation> station = MakeStation(2);
  return *station;
}

// The white border around the squares: one square for the chessboard.
double MarginMm(const BoardSpec& spec) {
  return spec.type == BoardSpec::Type::kChessboard ? spec.square_mm : 10;
}

// A scene with nothing but the board. No cast shadows: nothing can shade
// the board, and they cost a fifth of the render time.
SceneOptions BoardScene(const BoardSpec& spec) {
  SceneOptions options;
  options.object.type = ObjectType::kNone;
  options.lighting.shadows = false;
  options.board.enabled = true;
  options.board.spec = spec;
  options.board.margin_mm = MarginMm(spec);
  return options;
}

// --- boards held in front of the rig -----------------------------------------

// A 9×6 chessboard (odd + even: its corner order is unambiguous). With
// 2400 px lenses the view at 400 mm is only 213 × 171 mm, and past ~350 mm
// the platter fills its lower half, leaving ~80–120 mm of height above it:
// 20 mm squares (a 220 × 160 mm board with its margin) could not be seen
// whole at all; 10 mm ones (120 × 90 mm) fit far away only unrolled; 8 mm
// squares (96 × 72 mm, 40–65 px on the images) fit rolled and tilted at
// 300–500 mm.
BoardSpec Chessboard() {
  BoardSpec board;
  board.cols = 9;
  board.rows = 6;
  board.square_mm = 8;
  return board;
}

// A ChArUco board larger than the view (192 × 144 mm of squares): ChArUco
// corners need not all be seen, so it can reach into the image corners where
// a fully visible chessboard cannot, which pins the principal point down.
BoardSpec Charuco() {
  BoardSpec board;
  board.type = BoardSpec::Type::kCharuco;
  board.cols = 16;
  board.rows = 12;
  board.square_mm = 12;
  board.marker_mm = 8;
  board.aruco_dictionary = cv::aruco::DICT_4X4_100;
  return board;
}

// The printed board's outline in the board frame.
std::vector<cv::Vec3d> BoardOutline(const BoardSpec& spec) {
  const bool chess = spec.type == BoardSpec::Type::kChessboard;
  const double s = spec.square_mm;
  const double m = MarginMm(spec);
  const double x0 = (chess ? -s : 0) - m, y0 = (chess ? -s : 0) - m;
  const double x1 = spec.cols * s + m, y1 = spec.rows * s + m;
  return {{x0, y0, 0}, {x1, y0, 0}, {x1, y1, 0}, {x0, y1, 0}};
}

cv::Vec3d BoardCentre(const BoardSpec& spec) {
  const std::vector<cv::Vec3d> o = BoardOutline(spec);
  return (o[0] + o[2]) * 0.5;
}

// A board pose in front of the rig: its centre on the ray from the midpoint
// of the optical centres towards the target (where the optical axes meet)
// turned by (right, down) half fields of view, `distance_mm` deep in the rig
// frame; the board faces the cameras, then is tilted and rolled.
struct HeldPose {
  // Offset of the centre in the image, in half fields of view. A chessboard
  // is slid along this direction instead (PlaceWholeBoard).
  double right, down;
  double distance_mm;  // depth of the board centre in the rig frame
  double tilt_x_deg;   // about the rig's x axis: > 0 turns the board's bottom away
  double tilt_y_deg;   // about the rig's y axis: > 0 turns the board's left side away
  double roll_deg;     // about the viewing direction
};

constexpr double kEdgePx = 12;  // a fully visible board keeps this far from the image border

struct Placement {
  cv::Matx44d rig_from_board = cv::Matx44d::eye();
  double margin_px = 0;  // the outline's distance from the borders of both images
  double lowest_mm = 0;  // the outline's lowest point above the platter (world z)
  int corners_seen = 0;  // corners inside both images (kEdgePx) and above the platter
  bool fully_visible() const { return margin_px >= kEdgePx && lowest_mm >= 2; }
};

Placement PlaceBoard(const SimStation& station, const BoardSpec& spec, const HeldPose& pose,
                     double scale = 1) {
  const StereoCalibration& c = station.calibration();
  const cv::Matx44d world_from_rig = station.world_from_rig();
  const cv::Matx44d left_from_rig = station.left_from_world() * world_from_rig;
  const cv::Matx44d right_from_rig = station.right_from_world() * world_from_rig;
  const cv::Vec3d mid(c.baseline_mm() / 2, 0, 0);  // the rig's x axis runs along the baseline
  const cv::Vec3d target =
      Apply(station.rig_from_world(), {0, 0, station.options().target_height_mm});
  const cv::Vec3d towards = (target - mid) * (1.0 / (target - mid)[2]);
  const double f = c.rectified_focal_px();
  const cv::Vec3d offset(scale * pose.right * c.image_size.width / (2 * f),
                         scale * pose.down * c.image_size.height / (2 * f), 0);
  cv::Matx33d rx, ry, rz;
  cv::Rodrigues(cv::Vec3d(pose.tilt_x_deg * kDegToRad, 0, 0), rx);
  cv::Rodrigues(cv::Vec3d(0, pose.tilt_y_deg * kDegToRad, 0), ry);
  cv::Rodrigues(cv::Vec3d(0, 0, pose.roll_deg * kDegToRad), rz);
  const cv::Matx33d R = rz * ry * rx;  // board axes start as the rig's: facing the cameras
  const cv::Vec3d centre = mid + pose.distance_mm * (towards + offset);

  Placement p;
  p.rig_from_board = Rigid(R, centre - R * BoardCentre(spec));
  const std::vector<cv::Vec3d> outline = BoardOutline(spec);
  p.margin_px = std::min(
      InsideMargin(Project(left_from_rig * p.rig_from_board, c.left, outline), c.image_size),
      InsideMargin(Project(right_from_rig * p.rig_from_board, c.right, outline), c.image_size));
  const cv::Matx44d world_from_board = world_from_rig * p.rig_from_board;
  p.lowest_mm = 1e9;
  for (const cv::Vec3d& q : outline)
    p.lowest_mm = std::min(p.lowest_mm, Apply(world_from_board, q)[2]);
  const std::vector<cv::Vec3d> corners = ToVec3d(BoardCornersInBoard(spec));
  const std::vector<cv::Point2f> left = Project(left_from_rig * p.rig_from_board, c.left, corners);
  const std::vector<cv::Point2f> right =
      Project(right_from_rig * p.rig_from_board, c.right, corners);
  for (std::size_t i = 0; i < corners.size(); ++i) {
    if (Inside(left[i], c.image_size, kEdgePx) && Inside(right[i], c.image_size, kEdgePx) &&
        Apply(world_from_board, corners[i])[2] >= 2) {
      ++p.corners_seen;
    }
  }
  return p;
}

// Raises a pose in the image (in steps of 1 % of the half field) until the
// board clears the platter: farther than ~350 mm the lower half of the view
// sees the platter top, so far boards are held high.
HeldPose AbovePlatter(const SimStation& station, const BoardSpec& spec, HeldPose pose) {
  for (int i = 0; i < 200 && PlaceBoard(station, spec, pose).lowest_mm < 2; ++i) pose.down -= 0.01;
  return pose;
}

// A chessboard must be seen whole: from above the platter, slide the board
// along the pose's (right, down) direction to the farthest place where it is
// fully visible in both images and above the platter.
Placement PlaceWholeBoard(const SimStation& station, const BoardSpec& spec, const HeldPose& pose) {
  HeldPose centred = pose;
  centred.right = centred.down = 0;
  const double lift = AbovePlatter(station, spec, centred).down;
  auto slid = [&](double s) {
    HeldPose p = pose;
    p.right = s * pose.right;
    p.down = lift + s * pose.down;
    return PlaceBoard(station, spec, p);
  };
  constexpr int kSteps = 150;
  int last = -1;
  for (int i = 0; i <= kSteps; ++i) {
    if (slid(1.5 * i / kSteps).fully_visible()) last = i;
  }
  if (last < 0) return slid(0);
  double lo = 1.5 * last / kSteps, hi = 1.5 * (last + 1) / kSteps;
  for (int i = 0; i < 20; ++i) {
    const double s = (lo + hi) / 2;
    (slid(s).fully_visible() ? lo : hi) = s;
  }
  return slid(lo);
}

// A ChArUco board overfills the view: it only has to clear the platter.
Placement PlaceBoardAbovePlatter(const SimStation& station, const BoardSpec& spec,
                                 const HeldPose& pose) {
  return PlaceBoard(station, spec, AbovePlatter(station, spec, pose));
}

SceneOptions HeldBoardScene(const SimStation& station, const BoardSpec& spec,
                            const cv::Matx44d& rig_from_board) {
  SceneOptions options = BoardScene(spec);
  options.board.placement = BoardPlacement::kInWorld;
  const cv::Matx44d world_from_board = station.world_from_rig() * rig_from_board;
  cv::Rodrigues(Rotation(world_from_board), options.board.rotation_rad);
  options.board.translation_mm = {world_from_board(0, 3), world_from_board(1, 3),
                                  world_from_board(2, 3)};
  return options;
}

// 16 chessboard poses: 310–500 mm deep, tilts up to 35° about both axes,
// rolled 15–30°, each pushed as far as it goes towards a side or corner of
// the view (coverage 0.66 of the image: a whole board cannot reach further
// into the corners).
const std::vector<HeldPose>& ChessboardPoses() {
  static const std::vector<HeldPose> poses = {
      {0, -1, 400, -10, -10, 20},    {-1, -1, 450, -25, 20, 25},    {1, -1, 450, -25, -25, -25},
      {-1, 1, 320, -30, 15, -20},    {1, 1, 320, -30, -15, 20},     {0, -1, 500, -35, 0, -15},
      {0, 1, 320, 35, 0, 25},        {-1, 0, 330, 0, 35, -20},      {1, 0, 330, 0, -35, 20},
      {-0.5, -1, 500, -20, 30, 15},  {0.5, -1, 500, -20, -30, -15}, {0.3, -1, 470, -30, -20, -20},
      {-1, 0.6, 310, 25, -20, 15},   {1, 0.6, 310, 25, 20, -15},    {-1, -0.8, 400, -15, 10, 30},
      {1, -0.8, 400, -15, -10, -30},
  };
  return poses;
}

// 16 ChArUco poses, 300–480 mm, tilts up to 35°, rolled 5–30°, the centre
// where given (raised where the board would reach into the platter).
const std::vector<HeldPose>& CharucoPoses() {
  static const std::vector<HeldPose> poses = {
      {0, -0.3, 330, -20, 25, 15},    {0, -0.3, 330, -20, -25, -15},
      {0, 0, 300, 30, 30, 20},        {0, 0, 300, 30, -30, -20},
      {-0.5, -0.5, 400, -35, 25, 10}, {0.5, -0.5, 400, -35, -25, -10},
      {0, -0.8, 480, -35, 20, 25},    {0, -0.8, 480, -35, -20, -25},
      {-0.5, 0.5, 300, 20, 35, 5},    {0.5, 0.5, 300, 20, -35, -5},
      {0, -0.5, 380, -30, 0, 30},     {0, 0.2, 320, 35, 0, -30},
      {-0.6, 0, 340, -10, 35, 15},    {0.6, 0, 340, -10, -35, -15},
      {-0.5, -0.5, 300, 35, 35, 15},  {0.5, 0.5, 300, -35, -35, 15},
  };
  return poses;
}

// Distances (px) of detected corners from their exact projections, both
// cameras, appended to *errors.
void AddDetectionErrors(const SimStation& station, const StereoRender& frame,
                        const StereoBoardView& view, std::vector<double>* errors) {
  for (int camera = 0; camera < 2; ++camera) {
    const BoardDetection& d = camera ? view.right : view.left;
    if (!d.found) continue;
    const cv::Matx44d camera_from_world =
        camera ? station.right_from_world() : station.left_from_world();
    const std::vector<cv::Point2f> truth = Project(
        camera_from_world * frame.world_from_board,
        camera ? frame.calibration.right : frame.calibration.left, ToVec3d(d.object_points));
    for (std::size_t i = 0; i < truth.size(); ++i) {
      errors->push_back(cv::norm(d.image_points[i] - truth[i]));
    }
  }
}

// The pipeline's defaults except the rectification, which is the station's:
// without CALIB_ZERO_DISPARITY. With it, the 14° toe-in of the cameras makes
// the rectified images (alpha 0) a 1.9× zoom (rectified focal length
// 4570 px against 2400 px) that shows only the middle of the raw views.
StereoCalibrationOptions CalibrationOptions() {
  StereoCalibrationOptions options;
  options.rectification.zero_disparity = false;
  return options;
}

struct CalibrationRun {
  StereoCalibrationResult result;
  Stats detection_px;   // detected corners against their exact projections
  int min_corners = 0;  // fewest corners both cameras found in a view
  double render_s = 0, detect_s = 0, calibrate_s = 0;
};

CalibrationRun CalibrateFromHeldBoards(const BoardSpec& spec, const std::vector<HeldPose>& poses) {
  const SimStation& station = Station();
  const bool whole = spec.type == BoardSpec::Type::kChessboard;
  CalibrationRun run;
  run.min_corners = spec.NumCorners();
  std::vector<double> errors;
  std::vector<StereoBoardView> views;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const Placement placement = whole ? PlaceWholeBoard(station, spec, poses[i])
                                      : PlaceBoardAbovePlatter(station, spec, poses[i]);
    if (whole) {
      EXPECT_TRUE(placement.fully_visible())
          << "pose " << i << ": the chessboard is " << placement.margin_px
          << " px from the image border and " << placement.lowest_mm
          << " mm above the platter at best";
    } else {
      EXPECT_GE(placement.lowest_mm, 2) << "pose " << i << " reaches into the platter";
      EXPECT_GE(placement.corners_seen, 60) << "pose " << i;
    }
    std::string error;
    auto scene = Scene::Create(HeldBoardScene(station, spec, placement.rig_from_board), &error);
    if (!scene) {
      ADD_FAILURE() << error;
      continue;
    }
    auto start = std::chrono::steady_clock::now();
    const StereoRender frame = station.Render(*scene, /*frame_index=*/i);
    run.render_s += SecondsSince(start);
    EXPECT_TRUE(frame.IsUsable()) << frame.message;
    start = std::chrono::steady_clock::now();
    views.push_back(DetectStereoBoard("pose" + std::to_string(i), frame.left, frame.right, spec));
    run.detect_s += SecondsSince(start);
    const StereoBoardView& view = views.back();
    EXPECT_TRUE(view.left.found && view.right.found)
        << "pose " << i << ": " << view.left.message << " / " << view.right.message;
    run.min_corners = std::min({run.min_corners, static_cast<int>(view.left.ids.size()),
                                static_cast<int>(view.right.ids.size())});
    AddDetectionErrors(station, frame, view, &errors);
  }
  run.detection_px = Summarize(errors);
  const auto start = std::chrono::steady_clock::now();
  run.result = CalibrateStereo(views, station.calibration().image_size, spec, CalibrationOptions());
  run.calibrate_s = SecondsSince(start);
  return run;
}

struct CalibrationErrors {
  double focal_pct = 0;        // largest |Δf| / f of fx, fy of both cameras
  double principal_px = 0;     // largest |Δ(cx, cy)| of both cameras
  double baseline_mm = 0;      // | |T| − |T_true| |
  double rotation_deg = 0;     // angle of R · R_trueᵀ
  double translation_deg = 0;  // angle between T and T_true
};

CalibrationErrors Compare(const StereoCalibration& estimate, const StereoCalibration& truth) {
  CalibrationErrors e;
  for (const auto& [est, tru] :
       {std::pair{&estimate.left, &truth.left}, std::pair{&estimate.right, &truth.right}}) {
    const cv::Matx33d& k = est->camera_matrix;
    const cv::Matx33d& t = tru->camera_matrix;
    e.focal_pct = std::max({e.focal_pct, 100 * std::abs(k(0, 0) / t(0, 0) - 1),
                            100 * std::abs(k(1, 1) / t(1, 1) - 1)});
    e.principal_px = std::max(e.principal_px, std::hypot(k(0, 2) - t(0, 2), k(1, 2) - t(1, 2)));
  }
  e.baseline_mm = std::abs(estimate.baseline_mm() - truth.baseline_mm());
  e.rotation_deg = RotationAngleDeg(estimate.R, truth.R);
  e.translation_deg = AngleDeg(estimate.T, truth.T);
  return e;
}

CalibrationErrors ReportCalibration(const char* what, const CalibrationRun& run) {
  const StereoCalibrationResult& r = run.result;
  const CalibrationErrors e = Compare(r.calibration, Station().calibration());
  std::printf(
      "%s: %d views (≥ %d corners each); corners vs exact projection mean %.3f max %.3f px; "
      "focal %.4f %%, principal point %.3f px, baseline %.4f mm, R %.4f°, T direction %.4f°; "
      "RMS left %.4f right %.4f stereo %.4f px; epipolar mean %.4f max %.4f px; coverage "
      "%.2f/%.2f; render %.1f s, detect %.1f s, calibrate %.1f s\n",
      what, r.report().views_used, run.min_corners, run.detection_px.mean, run.detection_px.max,
      e.focal_pct, e.principal_px, e.baseline_mm, e.rotation_deg, e.translation_deg,
      r.report().rms_left_px, r.report().rms_right_px, r.report().rms_stereo_px,
      r.report().epipolar_mean_px, r.report().epipolar_max_px, r.report().coverage_left,
      r.report().coverage_right, run.render_s, run.detect_s, run.calibrate_s);
  return e;
}

// --- the board on the turntable ------------------------------------------------

// The chessboard lying on the platter, its centre 20 mm off the axis, at
// commanded angles 0, 60, …, 300°: every step keeps all corners in the left
// image. Rendered 1×1 (point sampled) to save time: each step's pose still
// rests on 54 corners (the fit is good to 0.01°, see the tests).
const std::vector<double>& TurntableAnglesDeg() {
  static const std::vector<double> angles = {0, 60, 120, 180, 240, 300};
  return angles;
}

// 9×6 (not 180°-symmetric), 12 mm squares: larger than the held board, as
// nothing but the platter's rim limits it.
BoardSpec PlatterChessboard() {
  BoardSpec board = Chessboard();
  board.square_mm = 12;
  return board;
}

SceneOptions PlatterBoardScene(const BoardSpec& spec) {
  SceneOptions options = BoardScene(spec);
  options.board.placement = BoardPlacement::kOnPlatter;
  options.board.platter_yaw_rad = 0.3;
  // Put the board's centre at world (20, 0) at angle 0.
  options.board.platter_position_mm = {0, 0};
  std::string error;
  auto probe = Scene::Create(options, &error);
  EXPECT_TRUE(probe) << error;
  if (!probe) return options;
  const cv::Vec3d centre = Apply(probe->world_from_board(), BoardCentre(spec));
  options.board.platter_position_mm = {20 - centre[0], 0 - centre[1]};
  return options;
}

struct TurntableCapture {
  std::vector<TurntableStep> steps;
  double board_thickness_mm = 0;
  double render_s = 0;
};

const TurntableCapture& PlatterBoardCapture() {
  static const TurntableCapture capture = [] {
    TurntableCapture out;
    // Point sampled: the same rig (geometry and calibration) as Station().
    const std::unique_ptr<SimStation> station = MakeStation(1);
    EXPECT_EQ(station->rig_from_world(), Station().rig_from_world());
    const BoardSpec spec = PlatterChessboard();
    const SceneOptions options = PlatterBoardScene(spec);
    out.board_thickness_mm = options.board.thickness_mm;
    std::string error;
    auto scene = Scene::Create(options, &error);
    EXPECT_TRUE(scene) << error;
    if (!scene) return out;
    const std::vector<cv::Vec3d> corners = ToVec3d(BoardCornersInBoard(spec));
    for (double angle_deg : TurntableAnglesDeg()) {
      scene->SetTurntableAngle(angle_deg * kDegToRad);
      EXPECT_GE(InsideMargin(Project(station->left_from_world() * scene->world_from_board(),
                                     station->calibration().left, corners),
                             station->calibration().image_size),
                30)
          << "at " << angle_deg << "° the board leaves the left image";
      const auto start = std::chrono::steady_clock::now();
      const StereoRender frame = station->Render(*scene, static_cast<std::uint64_t>(angle_deg));
      out.render_s += SecondsSince(start);
      TurntableStep step;
      step.commanded_angle_rad = angle_deg * kDegToRad;
      step.left = DetectBoard(frame.left, spec);
      EXPECT_TRUE(step.left.found) << "at " << angle_deg << "°: " << step.left.message;
      out.steps.push_back(std::move(step));
    }
    return out;
  }();
  return capture;
}

struct AxisErrors {
  double direction_deg = 0;
  double point_mm = 0;     // distance between the fitted and the true platter point
  double off_axis_mm = 0;  // distance of the true point from the fitted axis line
  double max_angle_error_deg = 0;
  double residual_mm = 0;
};

// Fits the axis with `calibration` (its board set to the platter's) and
// compares it with the truth in the left camera frame (the rig frame is the
// calibration's own rectified left camera, so two calibrations' rig frames
// differ by their R1).
AxisErrors FitAxis(const char* what, StereoCalibration calibration) {
  const TurntableCapture& capture = PlatterBoardCapture();
  calibration.board = PlatterChessboard();
  TurntableAxisOptions options;
  options.board_thickness_mm = capture.board_thickness_mm;
  const TurntableAxisResult r = CalibrateTurntableAxis(calibration, capture.steps, options);
  AxisErrors e;
  EXPECT_EQ(r.status, TurntableAxisResult::Status::kOk) << what << ": " << r.message;
  EXPECT_TRUE(r.IsUsable()) << what << ": " << r.verdict_reason;
  EXPECT_EQ(r.steps_used, static_cast<int>(capture.steps.size())) << what;
  if (r.status != TurntableAxisResult::Status::kOk) return e;

  const StereoCalibration& truth = Station().calibration();
  const cv::Vec3d true_direction = truth.R1.t() * truth.turntable.direction_in_rig;
  const cv::Vec3d true_point = truth.R1.t() * truth.turntable.point_in_rig_mm;
  const cv::Vec3d direction = calibration.R1.t() * r.axis.direction_in_rig;
  const cv::Vec3d point = calibration.R1.t() * r.axis.point_in_rig_mm;
  e.direction_deg = AngleDeg(direction, true_direction);
  e.point_mm = cv::norm(point - true_point);
  const cv::Vec3d v = true_point - point;
  e.off_axis_mm = cv::norm(v - v.dot(direction) * direction);
  e.max_angle_error_deg = r.max_abs_angle_error_deg;
  e.residual_mm = r.residual_mm;
  std::printf(
      "turntable axis (%s calibration): %d steps; direction %.4f°, point %.3f mm (off the "
      "axis %.3f mm), max step angle error %.4f°, residual %.4f mm; render %.1f s\n",
      what, r.steps_used, e.direction_deg, e.point_mm, e.off_axis_mm, e.max_angle_error_deg,
      e.residual_mm, capture.render_s);
  return e;
}

// --- rectification -------------------------------------------------------------

// Rows of corresponding points after rectification: raw pixels of the same
// 3D points in both cameras, rectified with the Rectifier's point mapping;
// |y_left − y_right| per point.
std::vector<double> RowErrors(const Rectifier& rectifier, const std::vector<cv::Point2f>& raw_left,
                              const std::vector<cv::Point2f>& raw_right) {
  const std::vector<cv::Point2f> left = rectifier.RectifyLeftPoints(raw_left);
  const std::vector<cv::Point2f> right = rectifier.RectifyRightPoints(raw_right);
  std::vector<double> errors;
  for (std::size_t i = 0; i < left.size(); ++i) errors.push_back(std::abs(left[i].y - right[i].y));
  return errors;
}

// Rows throughout the working volume: points on the rays of a 40 px grid
// over the exact rectified left image, 300–500 mm deep, that both raw images
// see, projected exactly and rectified with `rectifier`.
Stats VolumeRowErrors(const Rectifier& rectifier) {
  const SimStation& station = Station();
  const StereoCalibration& truth = station.calibration();
  std::vector<cv::Vec3d> points_in_rig;
  const cv::Matx34d& P1 = truth.P1;
  for (double z = 300; z <= 500; z += 50) {
    for (int v = 0; v < truth.image_size.height; v += 40) {
      for (int u = 0; u < truth.image_size.width; u += 40) {
        points_in_rig.push_back(z *
                                cv::Vec3d((u - P1(0, 2)) / P1(0, 0), (v - P1(1, 2)) / P1(1, 1), 1));
      }
    }
  }
  const cv::Matx44d world_from_rig = station.world_from_rig();
  const std::vector<cv::Point2f> left =
      Project(station.left_from_world() * world_from_rig, truth.left, points_in_rig);
  const std::vector<cv::Point2f> right =
      Project(station.right_from_world() * world_from_rig, truth.right, points_in_rig);
  std::vector<cv::Point2f> seen_left, seen_right;
  for (std::size_t i = 0; i < points_in_rig.size(); ++i) {
    if (Inside(left[i], truth.image_size, 0) && Inside(right[i], truth.image_size, 0)) {
      seen_left.push_back(left[i]);
      seen_right.push_back(right[i]);
    }
  }
  EXPECT_GT(seen_left.size(), 2000u);
  return Summarize(RowErrors(rectifier, seen_left, seen_right));
}

// A chessboard pose not among the calibration views.
constexpr HeldPose kHeldOutPose{0.35, -0.15, 360, -20, 15, 12};

struct RectificationErrors {
  Stats rows_px;           // exact corner projections, rectified: |y_l − y_r|
  Stats detected_rows_px;  // corners detected in the rectified images: |y_l − y_r|
  Stats maps_px;           // detected rectified corners vs the rectified exact projections
  Stats volume_rows_px;    // points throughout the working volume: |y_l − y_r|
};

// Renders the held-out pose, rectifies the pair with `calibration` and
// measures rows (see RectificationErrors).
RectificationErrors CheckRectification(const StereoCalibration& calibration) {
  RectificationErrors out;
  const SimStation& station = Station();
  const StereoCalibration& truth = station.calibration();
  Rectifier rectifier;
  std::string error;
  EXPECT_TRUE(rectifier.Init(calibration, &error)) << error;
  if (!rectifier.IsReady()) return out;

  const BoardSpec spec = Chessboard();
  const Placement placement = PlaceBoard(station, spec, kHeldOutPose);
  EXPECT_TRUE(placement.fully_visible())
      << placement.margin_px << " px, " << placement.lowest_mm << " mm";
  auto scene = Scene::Create(HeldBoardScene(station, spec, placement.rig_from_board), &error);
  EXPECT_TRUE(scene) << error;
  if (!scene) return out;
  const StereoRender frame = station.Render(*scene, /*frame_index=*/100);
  cv::Mat left, right;
  EXPECT_TRUE(rectifier.Rectify(frame.left, frame.right, &left, &right, &error)) << error;

  // Ground truth: the board's corners projected exactly into both raw images.
  const std::vector<cv::Vec3d> corners = ToVec3d(BoardCornersInBoard(spec));
  const std::vector<cv::Point2f> raw_left =
      Project(station.left_from_world() * frame.world_from_board, truth.left, corners);
  const std::vector<cv::Point2f> raw_right =
      Project(station.right_from_world() * frame.world_from_board, truth.right, corners);
  out.rows_px = Summarize(RowErrors(rectifier, raw_left, raw_right));

  // The rectified images: the board found there lies where the point mapping
  // puts the exact corners, on shared rows.
  const BoardDetection in_left = DetectBoard(left, spec), in_right = DetectBoard(right, spec);
  EXPECT_TRUE(in_left.found) << in_left.message;
  EXPECT_TRUE(in_right.found) << in_right.message;
  if (in_left.found && in_right.found) {
    const std::vector<cv::Point2f> exact_left = rectifier.RectifyLeftPoints(raw_left);
    const std::vector<cv::Point2f> exact_right = rectifier.RectifyRightPoints(raw_right);
    std::vector<double> rows, maps;
    std::vector<cv::Point2f> found_right(corners.size(), cv::Point2f(NAN, NAN));
    for (std::size_t i = 0; i < in_right.ids.size(); ++i) {
      found_right[static_cast<std::size_t>(in_right.ids[i])] = in_right.image_points[i];
      maps.push_back(cv::norm(in_right.image_points[i] - exact_right[in_right.ids[i]]));
    }
    for (std::size_t i = 0; i < in_left.ids.size(); ++i) {
      const auto id = static_cast<std::size_t>(in_left.ids[i]);
      maps.push_back(cv::norm(in_left.image_points[i] - exact_left[id]));
      rows.push_back(std::abs(in_left.image_points[i].y - found_right[id].y));
    }
    out.detected_rows_px = Summarize(rows);
    out.maps_px = Summarize(maps);
  }

  out.volume_rows_px = VolumeRowErrors(rectifier);
  std::printf(
      "rectified rows: board corners (exact) mean %.4f max %.4f px; detected in the rectified "
      "images mean %.4f max %.4f px, %.4f px (max %.4f) from the mapped exact corners; "
      "working volume (%d points) mean %.4f max %.4f px\n",
      out.rows_px.mean, out.rows_px.max, out.detected_rows_px.mean, out.detected_rows_px.max,
      out.maps_px.mean, out.maps_px.max, out.volume_rows_px.count, out.volume_rows_px.mean,
      out.volume_rows_px.max);
  return out;
}

// --- tests ---------------------------------------------------------------------

// 16 chessboard views, 310–500 mm. Measured: corners 0.054 px mean (max
// 0.18) off their exact projections; focal 0.010 %, principal point 0.87 px,
// baseline 0.003 mm, R 0.018°, stereo RMS 0.061 px; render 15 s, detection
// 3.6 s.
//
// The principal point is checked to 3 px, not the 1 px: a
// chessboard must be seen whole, and on this rig (2400 px lenses, a 30°
// view) whole boards leave the principal point uncertain by ~1 px per axis
// with all nine lens parameters free (p1, p2 trade against cx, cy). These
// same 16 poses with Gaussian corner noise of the measured size (σ = 0.045
// px), 30 seeds: median 1.6 px, 90th percentile 2.3 px, worst 2.35 px. The
// 0.87 px here is luck of the noise. The ChArUco test below holds 1 px.
//
// Each CTest test runs in its own process and these views take ~20 s to
// render and detect, so what uses this calibration is checked here too:
// the turntable axis found with it (measured: direction 0.017°, platter
// point 0.17 mm, step angles within 0.010°) and its rectification of a new
// pair (corner rows mean 0.0065 px, max 0.019 px; see below).
TEST(SimCalibration, ChessboardCalibrationRecoversTheRigTheAxisAndTheRows) {
  const CalibrationRun run = CalibrateFromHeldBoards(Chessboard(), ChessboardPoses());
  const StereoCalibrationResult& r = run.result;
  ASSERT_EQ(r.status, StereoCalibrationResult::Status::kOk) << r.message;
  const CalibrationErrors e = ReportCalibration("chessboard", run);
  EXPECT_EQ(r.report().views_used, static_cast<int>(ChessboardPoses().size()));
  EXPECT_TRUE(r.IsUsable()) << r.report().verdict_reason;
  EXPECT_LT(run.detection_px.mean, 0.1) << "px";
  EXPECT_LT(e.focal_pct, 0.2) << "%";
  EXPECT_LT(e.principal_px, 3.0) << "px";
  EXPECT_LT(e.baseline_mm, 0.1) << "mm";
  EXPECT_LT(r.report().rms_stereo_px, 0.2) << "px";

  {
    SCOPED_TRACE("turntable axis with the chessboard calibration");
    const AxisErrors axis = FitAxis("chessboard", r.calibration);
    EXPECT_LT(axis.direction_deg, 0.1);
    EXPECT_LT(axis.point_mm, 0.5);
    EXPECT_LT(axis.max_angle_error_deg, 0.05);
  }
  {
    // Measured: the held-out board's exact corners, rectified, share rows to
    // 0.0065 px mean (max 0.019 px); the corners detected in the rectified
    // images to 0.041 px (max 0.12), and lie 0.055 px from where the point
    // mapping puts the exact corners (the maps agree with it). Throughout the
    // working volume: mean 0.030 px, max 0.88 px in the image corners, which
    // no whole chessboard reached (coverage 0.66: the distortion there is
    // extrapolated).
    SCOPED_TRACE("rectification with the chessboard calibration");
    const RectificationErrors rect = CheckRectification(r.calibration);
    EXPECT_EQ(rect.rows_px.count, Chessboard().NumCorners());
    EXPECT_LT(rect.rows_px.mean, 0.1) << "px";
    EXPECT_LT(rect.rows_px.max, 0.1) << "px";
    EXPECT_EQ(rect.detected_rows_px.count, Chessboard().NumCorners());
    EXPECT_LT(rect.detected_rows_px.mean, 0.1) << "px";
    EXPECT_LT(rect.maps_px.mean, 0.1) << "px";
    EXPECT_LT(rect.volume_rows_px.mean, 0.1) << "px";
    EXPECT_LT(rect.volume_rows_px.max, 1.5) << "px";
  }
}

// 16 views of a board larger than the view, 300–480 mm, ≥ 70 corners each.
// Measured: corners 0.074 px mean (max 0.46) off their exact projections;
// focal 0.003 %, principal point 0.69 px, baseline 0.002 mm, R 0.020°,
// stereo RMS 0.088 px; rows throughout the working volume after its
// rectification mean 0.005 px, max 0.05 px (the board reached every part of
// the image: coverage 0.97); render 14 s. These poses with
// Gaussian corner noise σ = 0.06 px, 30 seeds: principal point median
// 0.41 px, 90th percentile 0.72 px, worst 0.80 px.
TEST(SimCalibration, CharucoCalibrationRecoversTheRig) {
  const CalibrationRun run = CalibrateFromHeldBoards(Charuco(), CharucoPoses());
  const StereoCalibrationResult& r = run.result;
  ASSERT_EQ(r.status, StereoCalibrationResult::Status::kOk) << r.message;
  const CalibrationErrors e = ReportCalibration("charuco", run);
  EXPECT_EQ(r.report().views_used, static_cast<int>(CharucoPoses().size()));
  EXPECT_TRUE(r.IsUsable()) << r.report().verdict_reason;
  EXPECT_LT(run.detection_px.mean, 0.1) << "px";
  EXPECT_LT(e.focal_pct, 0.2) << "%";
  EXPECT_LT(e.principal_px, 1.0) << "px";
  EXPECT_LT(e.baseline_mm, 0.1) << "mm";
  EXPECT_LT(r.report().rms_stereo_px, 0.2) << "px";

  Rectifier rectifier;
  std::string error;
  ASSERT_TRUE(rectifier.Init(r.calibration, &error)) << error;
  const Stats rows = VolumeRowErrors(rectifier);
  std::printf("charuco rectification: working volume (%d points) rows mean %.4f max %.4f px\n",
              rows.count, rows.mean, rows.max);
  EXPECT_LT(rows.mean, 0.1) << "px";
  EXPECT_LT(rows.max, 0.2) << "px";
}

// The platter board at 6 angles, fitted with the station's exact
// calibration. Measured: direction 0.0084°, platter point 0.034 mm (0.028 mm
// off the fitted axis), step angles within 0.0092°, residual 0.040 mm.
TEST(SimCalibration, TurntableAxisWithTheExactCalibration) {
  const AxisErrors e = FitAxis("exact", Station().calibration());
  EXPECT_LT(e.direction_deg, 0.1);
  EXPECT_LT(e.point_mm, 0.2);
  EXPECT_LT(e.max_angle_error_deg, 0.05);
}

}  // namespace
}  // namespace craftscan::sim
