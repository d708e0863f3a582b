// Stereo rig calibration (method.md §3–4): board descriptions, the
// calibration of a camera pair with its rectification, and the turntable
// axis. Units: millimetres, pixels, radians (degrees only at user edges).
// The rig frame is the rectified left camera.
//
// This header holds the data types shared by the calibration code, the
// simulated station and the daemon. Functions that compute, save and load
// calibrations are declared below the types.
//
// Workflow (what a technician's tool or the daemon does):
//   1. DetectBoard() on every raw left/right image (or DetectStereoBoard()).
//   2. CalibrateStereo(): monocular calibration of each camera, then the
//      stereo calibration (R, T) with joint refinement, rectification
//      (R1, R2, P1, P2, Q) and a CalibrationReport with a verdict.
//   3. CalibrateTurntableAxis() from a board lying on the platter, captured
//      at several commanded angles; ApplyTurntableAxis() stores it.
//   4. SaveCalibration() / LoadCalibration() (versioned OpenCV YAML).
//   5. Rectifier (rectify.h) builds the rectification maps once and
//      rectifies every captured pair.
//
// No function here throws for bad input: they return a result (or false)
// with a message naming the view, file, key or field that is wrong.
// All functions are thread-safe (they share no state).
#pragma once

#include <limits>
#include <opencv2/core.hpp>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan {

struct BoardSpec {
  enum class Type { kChessboard, kCharuco };
  Type type = Type::kChessboard;
  // Chessboard: inner corners per row (cols) and per column (rows).
  // ChArUco: squares per row (cols) and per column (rows).
  int cols = 9;
  int rows = 6;
  double square_mm = 25.0;   // edge of one square
  double marker_mm = 0.0;    // ChArUco only: edge of one ArUco marker (< square_mm)
  int aruco_dictionary = 0;  // ChArUco only: cv::aruco::PREDEFINED_DICTIONARY_NAME value

  // Chessboard: cols, rows ≥ 3 (OpenCV's detector needs more than 2).
  // ChArUco: cols, rows ≥ 2, 0 < marker_mm < square_mm, a known dictionary
  // with at least cols·rows/2 markers. square_mm finite and > 0.
  bool IsValid(std::string* why) const;
  // Corners the board provides: chessboard cols·rows; ChArUco (cols−1)·(rows−1).
  int NumCorners() const;
  // A chessboard whose corner order OpenCV cannot tie to the board (cols +
  // rows even: the pattern looks the same turned by 180°). Such a board still
  // calibrates cameras but cannot calibrate the turntable axis.
  bool IsRotationallySymmetric() const;
};
std::string_view ToString(BoardSpec::Type type);  // "chessboard", "charuco"
bool BoardTypeFromString(std::string_view text, BoardSpec::Type* type);
// One line for reports and messages, e.g. "chessboard 9x6 inner corners, 25.000 mm squares".
std::string Describe(const BoardSpec& board);
// Corner positions in the board frame (mm, z = 0, z pointing into the
// board), indexed by corner id. Chessboard: row-major, cols per row, corner 0
// the one whose diagonal square inside the grid is black (OpenCV's classic
// detector's choice; DetectBoard enforces it for both detectors on boards
// that are not 180°-symmetric). ChArUco: OpenCV's
// CharucoBoard::chessboardCorners. Empty for an invalid spec.
std::vector<cv::Point3f> BoardCornersInBoard(const BoardSpec& board);

struct CameraIntrinsics {
  cv::Matx33d camera_matrix = cv::Matx33d::eye();  // fx 0 cx; 0 fy cy; 0 0 1 (px)
  cv::Vec<double, 5> distortion{0, 0, 0, 0, 0};    // k1 k2 p1 p2 k3 (OpenCV order)
  // k4 k5 k6 of OpenCV's rational model (CALIB_RATIONAL_MODEL); all zero for
  // the usual 5-coefficient model.
  cv::Vec3d distortion_rational{0, 0, 0};

  bool UsesRationalModel() const { return distortion_rational != cv::Vec3d(0, 0, 0); }
  // The coefficients as OpenCV takes them: 1×5, or 1×8 with the rational
  // model (k1 k2 p1 p2 k3 k4 k5 k6), CV_64F.
  cv::Mat DistortionCoeffs() const;
  // Sets distortion (+ distortion_rational) from 4, 5, 8 (or more, when the
  // extra terms are zero) OpenCV coefficients. False if the layout is unsupported.
  bool SetDistortionCoeffs(const cv::Mat& coeffs);
};

// The turntable's rotation axis in the rig frame: a unit direction and the
// point where the axis meets the platter surface.
// direction_in_rig is oriented so that a positive commanded turntable angle is
// a right-handed rotation about it.
struct TurntableAxis {
  bool valid = false;
  cv::Vec3d direction_in_rig{0, 0, 1};  // unit vector, +Z of the world (turntable) frame
  cv::Vec3d point_in_rig_mm{0, 0, 0};
};

enum class CalibrationVerdict { kNotEvaluated, kAccept, kReject };
std::string_view ToString(CalibrationVerdict verdict);  // "not_evaluated", "accept", "reject"
bool CalibrationVerdictFromString(std::string_view text, CalibrationVerdict* verdict);

// Errors of one board view (a stereo pair) in the calibration.
struct ViewReport {
  std::string name;     // as given to CalibrateStereo (e.g. "left03.jpg/right03.jpg")
  bool used = false;    // in the stereo calibration
  std::string message;  // why not used (e.g. "board not found in the right image"), else empty
  int num_points = 0;   // corners used per camera (ChArUco: seen by both)
  double rms_left_px = std::numeric_limits<double>::quiet_NaN();   // monocular, left camera
  double rms_right_px = std::numeric_limits<double>::quiet_NaN();  // monocular, right camera
  double rms_stereo_px =
      std::numeric_limits<double>::quiet_NaN();  // final stereo model, both cameras
};

// Quality of a calibration, meant for the technician: every figure says
// what to fix (a bad view to drop, image regions the board never covered).
struct CalibrationReport {
  double rms_left_px = std::numeric_limits<double>::quiet_NaN();    // monocular calibration, left
  double rms_right_px = std::numeric_limits<double>::quiet_NaN();   // monocular calibration, right
  double rms_stereo_px = std::numeric_limits<double>::quiet_NaN();  // stereo calibration, both
  // Board corners rectified with the final calibration: mean and max of
  // |y_left − y_right| in rectified pixels (0 for a perfect calibration).
  double epipolar_mean_px = std::numeric_limits<double>::quiet_NaN();
  double epipolar_max_px = std::numeric_limits<double>::quiet_NaN();
  // Fraction (0…1) of the cells of a coverage_grid × coverage_grid grid over
  // the image holding at least one board corner of a used view.
  int coverage_grid = 8;
  double coverage_left = 0;
  double coverage_right = 0;
  int views_used = 0;
  std::vector<ViewReport> views;  // one per input view, in input order

  CalibrationVerdict verdict = CalibrationVerdict::kNotEvaluated;
  std::string verdict_reason;  // why rejected (all failed limits), or a summary when accepted

  // Turntable axis (CalibrateTurntableAxis), NaN / 0 until calibrated.
  int turntable_steps = 0;
  double turntable_residual_mm = std::numeric_limits<double>::quiet_NaN();
  double turntable_max_angle_error_deg = std::numeric_limits<double>::quiet_NaN();
};

struct StereoCalibration {
  static constexpr int kFormatVersion = 1;

  cv::Size image_size;
  CameraIntrinsics left, right;
  // right_from_left: p_in_right = R · p_in_left + T (T in mm).
  cv::Matx33d R = cv::Matx33d::eye();
  cv::Vec3d T{0, 0, 0};
  // Rectification (cv::stereoRectify): rectified_left_from_left = R1, etc.;
  // P1, P2 project rig-frame points; Q reprojects (x, y, d, 1) to mm.
  cv::Matx33d R1 = cv::Matx33d::eye(), R2 = cv::Matx33d::eye();
  cv::Matx34d P1 = cv::Matx34d::zeros(), P2 = cv::Matx34d::zeros();
  cv::Matx44d Q = cv::Matx44d::zeros();
  TurntableAxis turntable;
  BoardSpec board;
  CalibrationReport report;  // how the calibration was obtained; not needed to use it

  double baseline_mm() const { return cv::norm(T); }
  // The rectified images have image_size; their focal length (px).
  double rectified_focal_px() const { return P1(0, 0); }

  // Checks everything needed to use the calibration: image size > 0; camera
  // matrices finite with fx, fy > 0; distortion finite; R, R1, R2 rotations;
  // T finite and non-zero; P1, P2, Q finite and consistent with a
  // rectification (P1(0,0) > 0, Q(3,2) ≠ 0); a valid turntable axis has a
  // unit direction; the board is valid. *why (may be null) names the field.
  bool IsValid(std::string* why) const;
};

// --- Board detection --------------------------------------------------------

struct BoardDetectionOptions {
  enum class ChessboardDetector {
    kClassic,      // findChessboardCorners + cornerSubPix
    kSectorBased,  // findChessboardCornersSB (sub-pixel built in)
  };
  ChessboardDetector chessboard_detector = ChessboardDetector::kClassic;
  // Classic detector: CALIB_CB_FAST_CHECK, a quick test for a chessboard
  // first. Without it an image with no board can take seconds (5 s for a
  // 640×480 noise image, 0.06 s with it).
  bool fast_check = true;
  // cornerSubPix half window (px). 0: adaptive, subpix_window_fraction × the
  // smallest distance between neighbouring corners in the view (at least
  // 2 px). A window reaching neighbouring corners biases the corner: on the
  // OpenCV sample images the samples' fixed 11 px more than doubles the RMS
  // error (left camera 0.408 px against 0.178 px).
  int subpix_half_window_px = 0;
  double subpix_window_fraction = 0.3;
  int subpix_max_iterations = 30;
  double subpix_epsilon_px = 0.001;
  // ChArUco: fewest interpolated corners for a usable view (≥ 4).
  int min_charuco_corners = 6;

  bool IsValid(std::string* why) const;
};

std::string_view ToString(
    BoardDetectionOptions::ChessboardDetector detector);  // "classic", "sector_based"
bool ChessboardDetectorFromString(std::string_view text,
                                  BoardDetectionOptions::ChessboardDetector* detector);

// One board seen in one image.
struct BoardDetection {
  bool found = false;
  std::string message;  // why not found, e.g. "board not found (chessboard 9x6 ...)"
  std::vector<cv::Point2f> image_points;   // px, raw (distorted) image
  std::vector<cv::Point3f> object_points;  // mm, board frame, same order
  std::vector<int> ids;                    // corner ids (BoardCornersInBoard index)

  bool IsUsable() const { return found; }
};

// Finds the board in `image` (CV_8UC1, CV_8UC3 BGR, CV_8UC4 BGRA or CV_16UC1)
// and refines the corners to sub-pixel accuracy. Chessboards give all corners
// or none; ChArUco boards give the corners next to at least one detected
// marker (at least options.min_charuco_corners, not all on one line).
// Never throws; an invalid board/options or image gives found = false with
// the reason in message.
BoardDetection DetectBoard(const cv::Mat& image, const BoardSpec& board,
                           const BoardDetectionOptions& options = {});

// --- Monocular and stereo calibration ---------------------------------------

// The lens model and which parameters are estimated. The defaults suit real
// lenses: fx, fy, cx, cy, k1, k2, p1, p2, k3 all estimated.
struct LensModelOptions {
  bool fix_aspect_ratio = false;                        // fx/fy = 1
  bool fix_principal_point = false;                     // cx, cy at the image centre
  bool zero_tangential_distortion = false;              // p1 = p2 = 0
  bool fix_k3 = false;                                  // k3 = 0 (narrow lenses, few views)
  bool rational_model = false;                          // add k4, k5, k6 (wide-angle lenses)
  bool fix_k4 = false, fix_k5 = false, fix_k6 = false;  // with rational_model: keep at 0
  bool same_focal_length = false;  // stereo refinement: both cameras share fx, fy

  // The flags of OpenCV's samples/cpp/stereo_calib.cpp (FIX_ASPECT_RATIO |
  // ZERO_TANGENT_DIST | SAME_FOCAL_LENGTH | RATIONAL_MODEL | FIX_K3 | FIX_K4 |
  // FIX_K5): k1, k2, k6 estimated. For comparisons with its 0.634 px.
  static LensModelOptions OpenCvStereoSample();
  bool IsValid(std::string* why) const;
};

struct RectificationOptions {
  // cv::stereoRectify's alpha: 0 = rectified images show only valid pixels
  // (zoomed in), 1 = keep every source pixel (black borders), −1 = OpenCV's
  // default scaling.
  double alpha = 0;
  // CALIB_ZERO_DISPARITY: equal principal points in both rectified images.
  // Off by default: on a verged museum rig (cameras toed in) it zooms the
  // rectified images (1.9× on the simulated 14° rig) and pushes disparities
  // to hundreds of pixels; off, the rectified principal points differ and the
  // object's disparities sit in a narrow band around zero (d = x_l − x_r
  // either way; Q accounts for the offset).
  bool zero_disparity = false;
  bool IsValid(std::string* why) const;
};

// Limits for the verdict. A calibration outside any of them is rejected.
struct CalibrationLimits {
  int min_views = 10;            // stereo views used (the paper: 20)
  double max_rms_px = 1.0;       // per camera (monocular) and stereo
  double max_epipolar_px = 0.5;  // mean |y_l − y_r| after rectification
  double min_coverage = 0.5;     // per camera, fraction of grid cells touched
  bool IsValid(std::string* why) const;
};

struct StereoCalibrationOptions {
  LensModelOptions lens;
  // After the monocular calibrations, refine both cameras' intrinsics with R
  // and T (OpenCV's USE_INTRINSIC_GUESS); false keeps them (FIX_INTRINSIC).
  bool refine_intrinsics_in_stereo = true;
  RectificationOptions rectification;
  CalibrationLimits limits;
  int coverage_grid = 8;     // cells per image side for the coverage figure (2…64)
  int max_iterations = 100;  // Levenberg–Marquardt iterations (OpenCV's solver)
  double epsilon = 1e-6;     // its relative change stop criterion
  bool IsValid(std::string* why) const;
};

// A board pose seen by both cameras (one stereo pair).
struct StereoBoardView {
  std::string name;            // for messages and the report (e.g. "left03.jpg/right03.jpg")
  BoardDetection left, right;  // on the raw images
};

// Detects the board in both raw images of a pair (DetectBoard on each).
StereoBoardView DetectStereoBoard(std::string name, const cv::Mat& left, const cv::Mat& right,
                                  const BoardSpec& board,
                                  const BoardDetectionOptions& options = {});

// Fewest board views a calibration is computed from (below it: kTooFewViews).
// The verdict uses CalibrationLimits::min_views, normally larger.
inline constexpr int kMinCalibrationViews = 3;

struct CameraCalibrationResult {
  enum class Status { kOk, kInvalidInput, kTooFewViews, kFailed };
  Status status = Status::kInvalidInput;
  std::string message;  // what is wrong, naming the view; summary when ok
  CameraIntrinsics intrinsics;
  double rms_px = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> view_rms_px;               // per input view; NaN where not used
  std::vector<cv::Matx33d> camera_from_board_R;  // per input view (identity where not used)
  std::vector<cv::Vec3d> camera_from_board_t_mm;
  int views_used = 0;
  double coverage = 0;  // fraction of grid cells touched by corners

  bool IsUsable() const { return status == Status::kOk; }
};
std::string_view ToString(CameraCalibrationResult::Status status);

// Calibrates one camera from board detections in images of `image_size`
// (views not found are skipped; at least kMinCalibrationViews needed).
// `same_focal_length` is ignored. `coverage_grid` as in the options above.
CameraCalibrationResult CalibrateCamera(const std::vector<BoardDetection>& views,
                                        cv::Size image_size, const LensModelOptions& lens,
                                        int coverage_grid = 8);

struct StereoCalibrationResult {
  enum class Status {
    kOk,            // calibration computed; see calibration.report.verdict
    kInvalidInput,  // bad options, board or image size (message names it)
    kTooFewViews,   // under kMinCalibrationViews usable views (message: why each was skipped)
    kFailed,        // OpenCV's solver failed or gave non-finite values
  };
  Status status = Status::kInvalidInput;
  std::string message;
  StereoCalibration calibration;  // with calibration.report; valid when status == kOk

  const CalibrationReport& report() const { return calibration.report; }
  // Computed and accepted by the limits. A rejected calibration is still
  // filled in (status kOk) so its report can be shown.
  bool IsUsable() const {
    return status == Status::kOk && calibration.report.verdict == CalibrationVerdict::kAccept;
  }
};
std::string_view ToString(StereoCalibrationResult::Status status);

// Monocular calibration of each camera (from every view where that camera
// found the board), then stereo calibration from the views where both found
// it (ChArUco: the corners both saw), rectification, report and verdict.
// `image_size` is the size of the raw images; `board` is stored in the result.
// Chessboards whose corner order is ambiguous (IsRotationallySymmetric) have
// the right view's order reversed when it runs against the left one's.
StereoCalibrationResult CalibrateStereo(const std::vector<StereoBoardView>& views,
                                        cv::Size image_size, const BoardSpec& board,
                                        const StereoCalibrationOptions& options = {});

// Fills R1, R2, P1, P2, Q of `calibration` from its intrinsics, R and T
// (cv::stereoRectify on image_size). For calibrations built by hand (e.g.
// the simulated station). False with *error (may be null) on invalid input.
bool ComputeRectification(const RectificationOptions& options, StereoCalibration* calibration,
                          std::string* error);

// --- Turntable axis ---------------------------------------------------------

// The board lying on the platter, captured at one commanded angle.
struct TurntableStep {
  double commanded_angle_rad = 0;  // as sent to the turntable
  BoardDetection left;             // in the raw left image
};

struct TurntableAxisOptions {
  // The board's top surface lies this far above the platter (its thickness);
  // point_in_rig_mm is moved down onto the platter by it.
  double board_thickness_mm = 0;
  int min_steps = 3;                 // usable steps needed (≥ 3)
  double min_span_rad = 0.35;        // largest |angle − first angle| needed (~20°)
  double max_residual_mm = 0.5;      // verdict: RMS distance of corners from their circles
  double max_angle_error_deg = 0.2;  // verdict: largest per-step angle error
  bool IsValid(std::string* why) const;
};

struct TurntableAxisResult {
  enum class Status { kOk, kInvalidInput, kTooFewSteps, kFailed };
  Status status = Status::kInvalidInput;
  std::string message;
  TurntableAxis axis;  // valid when status == kOk

  struct Step {
    bool used = false;
    std::string message;             // why not used
    double commanded_angle_rad = 0;  // as given
    // Rotation of the board from the first used step, about axis.direction
    // (right-handed), and its difference to the commanded one, both relative
    // to the first used step (so the first is 0).
    double estimated_angle_rad = std::numeric_limits<double>::quiet_NaN();
    double angle_error_deg = std::numeric_limits<double>::quiet_NaN();  // estimated − commanded
    double reprojection_rms_px = std::numeric_limits<double>::quiet_NaN();  // board pose fit
    double residual_mm =
        std::numeric_limits<double>::quiet_NaN();  // this step's corners vs circles
  };
  std::vector<Step> steps;  // one per input step, in input order
  int steps_used = 0;
  // RMS distance (mm) of the board corners, over all used steps, from the
  // circle each corner should travel on about the fitted axis.
  double residual_mm = std::numeric_limits<double>::quiet_NaN();
  double max_abs_angle_error_deg = std::numeric_limits<double>::quiet_NaN();
  CalibrationVerdict verdict = CalibrationVerdict::kNotEvaluated;
  std::string verdict_reason;

  bool IsUsable() const { return status == Status::kOk && verdict == CalibrationVerdict::kAccept; }
};
std::string_view ToString(TurntableAxisResult::Status status);

// Fits the turntable axis in the rig frame. Each step's board pose comes from
// solvePnP with the left camera and is taken into the rig frame (R1); the
// direction is the common rotation axis of the poses relative to the first
// step (oriented by the commanded angles), the point solves
// (I − R_rel)·c = t_rel in least squares and lies on the platter. Needs a
// valid calibration (intrinsics and R1) and a board that is not
// rotationally symmetric.
TurntableAxisResult CalibrateTurntableAxis(const StereoCalibration& calibration,
                                           const std::vector<TurntableStep>& steps,
                                           const TurntableAxisOptions& options = {});

// Stores a computed axis (status kOk) and its figures in `calibration`
// (turntable and report.turntable_*). Returns false and changes nothing otherwise.
bool ApplyTurntableAxis(const TurntableAxisResult& result, StereoCalibration* calibration);

// --- Files ------------------------------------------------------------------

// Writes `calibration` (which must pass IsValid) as OpenCV YAML: a
// `format: craftscan-stereo-calibration` and `format_version` key
// (StereoCalibration::kFormatVersion), image size, board, both cameras'
// intrinsics and distortion, R, T, R1, R2, P1, P2, Q, the turntable axis and
// the report. Atomic: written to a temporary file in the same folder,
// fsynced, renamed over `path`, and the folder fsynced; on failure `path` is
// untouched. Returns false with *error (naming the path; may be null).
bool SaveCalibration(const std::string& path, const StereoCalibration& calibration,
                     std::string* error);

// Reads a file written by SaveCalibration. Fails (false, *error naming the
// file and the key or problem; *calibration unchanged) for a missing or
// unreadable file, malformed YAML, another format or format_version, a
// missing key, a matrix of the wrong size or with non-finite values, or a
// calibration that fails IsValid. The report is optional (older writers).
bool LoadCalibration(const std::string& path, StereoCalibration* calibration, std::string* error);

}  // namespace craftscan
