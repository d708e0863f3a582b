// Board specs, validation of calibration data and options, board detection.
#include "craftscan/pipeline/calib/calibration.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/aruco.hpp>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <utility>
#include <vector>

#include "calibration_internal.h"

namespace craftscan {

using calib_internal::AllFinite;
using calib_internal::Fail;

namespace calib_internal {

bool IsRotation(const cv::Matx33d& r, double tolerance) {
  if (!AllFinite(r)) return false;
  const cv::Matx33d should_be_identity = r.t() * r;
  if (cv::norm(should_be_identity - cv::Matx33d::eye(), cv::NORM_INF) > tolerance) return false;
  return std::abs(cv::determinant(r) - 1.0) <= tolerance;
}

std::string Fixed(double value, int precision) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", precision, value);
  return buffer;
}

double Coverage(const std::vector<std::vector<cv::Point2f>>& points, cv::Size image_size,
                int grid) {
  if (grid < 1 || image_size.width <= 0 || image_size.height <= 0) return 0;
  std::vector<char> touched(static_cast<std::size_t>(grid * grid), 0);
  for (const auto& view : points) {
    for (const cv::Point2f& p : view) {
      const int cx = static_cast<int>(std::floor(p.x * grid / image_size.width));
      const int cy = static_cast<int>(std::floor(p.y * grid / image_size.height));
      if (cx < 0 || cy < 0 || cx >= grid || cy >= grid) continue;
      touched[static_cast<std::size_t>(cy * grid + cx)] = 1;
    }
  }
  const auto n = std::count(touched.begin(), touched.end(), 1);
  return static_cast<double>(n) / static_cast<double>(grid * grid);
}

int LensFlags(const LensModelOptions& lens) {
  int flags = 0;
  if (lens.fix_aspect_ratio) flags |= cv::CALIB_FIX_ASPECT_RATIO;
  if (lens.fix_principal_point) flags |= cv::CALIB_FIX_PRINCIPAL_POINT;
  if (lens.zero_tangential_distortion) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  if (lens.fix_k3) flags |= cv::CALIB_FIX_K3;
  if (lens.rational_model) {
    flags |= cv::CALIB_RATIONAL_MODEL;
    if (lens.fix_k4) flags |= cv::CALIB_FIX_K4;
    if (lens.fix_k5) flags |= cv::CALIB_FIX_K5;
    if (lens.fix_k6) flags |= cv::CALIB_FIX_K6;
  }
  return flags;
}

cv::Mat InitialCameraMatrix() { return cv::Mat::eye(3, 3, CV_64F); }

std::string CvErrorText(const cv::Exception& e) {
  std::string text = e.what();
  const std::size_t at = text.find("error: ");
  if (at != std::string::npos) text.erase(0, at + 7);
  while (!text.empty() && (text.back() == '\n' || text.back() == ' ')) text.pop_back();
  return text;
}

double RmsDistance(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b) {
  if (a.empty() || a.size() != b.size()) return kNaN;
  double sum = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double dx = a[i].x - b[i].x, dy = a[i].y - b[i].y;
    sum += dx * dx + dy * dy;
  }
  return std::sqrt(sum / static_cast<double>(a.size()));
}

}  // namespace calib_internal

namespace {

constexpr int kNumPredefinedDictionaries = cv::aruco::DICT_APRILTAG_36h11 + 1;

cv::Ptr<cv::aruco::CharucoBoard> MakeCharucoBoard(const BoardSpec& board) {
  cv::Ptr<cv::aruco::Dictionary> dictionary =
      cv::aruco::getPredefinedDictionary(board.aruco_dictionary);
  return cv::aruco::CharucoBoard::create(board.cols, board.rows,
                                         static_cast<float>(board.square_mm),
                                         static_cast<float>(board.marker_mm), dictionary);
}

// 8-bit grey view of an image, or empty with *why.
cv::Mat ToGray8(const cv::Mat& image, std::string* why) {
  if (image.empty()) {
    *why = "empty image";
    return {};
  }
  cv::Mat gray;
  switch (image.type()) {
    case CV_8UC1:
      return image;
    case CV_8UC3:
      cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
      return gray;
    case CV_8UC4:
      cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
      return gray;
    case CV_16UC1:  // 10/12/16-bit sensors: stretch to the used range
      cv::normalize(image, gray, 0, 255, cv::NORM_MINMAX, CV_8U);
      return gray;
    default:
      *why = "unsupported image type " + cv::typeToString(image.type()) +
             " (CV_8UC1, CV_8UC3, CV_8UC4 or CV_16UC1)";
      return {};
  }
}

// Smallest distance between grid-neighbouring corners of a row-major
// cols × rows grid.
double MinGridSpacing(const std::vector<cv::Point2f>& corners, int cols, int rows) {
  double best = std::numeric_limits<double>::infinity();
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const cv::Point2f& p = corners[static_cast<std::size_t>(y * cols + x)];
      if (x + 1 < cols) best = std::min(best, cv::norm(p - corners[y * cols + x + 1]));
      if (y + 1 < rows) best = std::min(best, cv::norm(p - corners[(y + 1) * cols + x]));
    }
  }
  return best;
}

void RefineCorners(const cv::Mat& gray, int half_window, const BoardDetectionOptions& options,
                   std::vector<cv::Point2f>* corners) {
  cv::cornerSubPix(gray, *corners, cv::Size(half_window, half_window), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS,
                                    options.subpix_max_iterations, options.subpix_epsilon_px));
}

int AdaptiveHalfWindow(double spacing_px, const BoardDetectionOptions& options) {
  if (options.subpix_half_window_px > 0) return options.subpix_half_window_px;
  if (!std::isfinite(spacing_px)) return 2;
  return std::max(2, static_cast<int>(std::lround(options.subpix_window_fraction * spacing_px)));
}

// Ties a chessboard's corner order to the board (not to the image): corner 0
// is the one whose diagonal square inside the grid is black. OpenCV's classic
// detector already does so; its sector-based one starts at the other end.
// Only meaningful for boards that are not 180°-symmetric.
void CanonicalizeChessboardOrder(const cv::Mat& gray, int cols, double spacing_px,
                                 std::vector<cv::Point2f>* corners) {
  const std::vector<cv::Point2f>& c = *corners;
  const cv::Point2f p00 = c[0], du = c[1] - c[0], dv = c[static_cast<std::size_t>(cols)] - c[0];
  auto at = [&](float u, float v) { return p00 + u * du + v * dv; };
  const int patch = std::max(1, static_cast<int>(0.25 * spacing_px));
  auto mean = [&](cv::Point2f p) {
    cv::Mat sample;
    cv::getRectSubPix(gray, cv::Size(patch, patch), p, sample, CV_32F);
    return cv::mean(sample)[0];
  };
  const double diagonal = mean(at(0.5f, 0.5f));
  const double neighbours = 0.5 * (mean(at(1.5f, 0.5f)) + mean(at(0.5f, 1.5f)));
  if (diagonal > neighbours) std::reverse(corners->begin(), corners->end());
}

BoardDetection DetectChessboard(const cv::Mat& gray, const BoardSpec& board,
                                const BoardDetectionOptions& options) {
  BoardDetection detection;
  const cv::Size pattern(board.cols, board.rows);
  std::vector<cv::Point2f> corners;
  bool found = false;
  if (options.chessboard_detector == BoardDetectionOptions::ChessboardDetector::kClassic) {
    found = cv::findChessboardCorners(gray, pattern, corners,
                                      cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE |
                                          (options.fast_check ? cv::CALIB_CB_FAST_CHECK : 0));
  } else {
    found = cv::findChessboardCornersSB(gray, pattern, corners,
                                        cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_ACCURACY);
  }
  if (!found || corners.size() != static_cast<std::size_t>(board.NumCorners())) {
    detection.message = "board not found (" + Describe(board) + ")";
    return detection;
  }
  const double spacing = MinGridSpacing(corners, board.cols, board.rows);
  if (options.chessboard_detector == BoardDetectionOptions::ChessboardDetector::kClassic) {
    RefineCorners(gray, AdaptiveHalfWindow(spacing, options), options, &corners);
  }
  if (!board.IsRotationallySymmetric()) {
    CanonicalizeChessboardOrder(gray, board.cols, spacing, &corners);
  }
  const std::vector<cv::Point3f> model = BoardCornersInBoard(board);
  detection.found = true;
  detection.image_points = std::move(corners);
  detection.object_points = model;
  detection.ids.resize(model.size());
  for (std::size_t i = 0; i < model.size(); ++i) detection.ids[i] = static_cast<int>(i);
  return detection;
}

BoardDetection DetectCharuco(const cv::Mat& gray, const BoardSpec& board,
                             const BoardDetectionOptions& options) {
  BoardDetection detection;
  cv::Ptr<cv::aruco::CharucoBoard> charuco = MakeCharucoBoard(board);
  cv::Ptr<cv::aruco::DetectorParameters> parameters = cv::aruco::DetectorParameters::create();
  std::vector<std::vector<cv::Point2f>> marker_corners, rejected;
  std::vector<int> marker_ids;
  cv::aruco::detectMarkers(gray, charuco->dictionary, marker_corners, marker_ids, parameters,
                           rejected);
  if (marker_ids.empty()) {
    detection.message = "board not found: no ArUco markers (" + Describe(board) + ")";
    return detection;
  }
  cv::aruco::refineDetectedMarkers(gray, charuco, marker_corners, marker_ids, rejected);
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, gray, charuco, corners, ids);
  if (static_cast<int>(ids.size()) < options.min_charuco_corners) {
    detection.message = "board not found: " + std::to_string(ids.size()) +
                        " ChArUco corner(s), need " + std::to_string(options.min_charuco_corners) +
                        " (" + Describe(board) + ")";
    return detection;
  }
  if (cv::aruco::testCharucoCornersCollinear(charuco, ids)) {
    detection.message = "board not usable: the " + std::to_string(ids.size()) +
                        " ChArUco corners found lie on one line";
    return detection;
  }

  // Refine again: OpenCV 4.6 returns ChArUco corners shifted by about
  // (+0.5, +0.5) px against cornerSubPix's pixel-centre convention (the one
  // findChessboardCorners and cv::projectPoints use; opencv_contrib PR 3024,
  // undone upstream in opencv PR 28380), and stops at 0.1 px. cornerSubPix
  // converges in absolute coordinates, so refining removes the shift. The
  // window stays inside the marker margin: a marker edge inside it would
  // bias the corner. Any two corners are at least one square apart on the
  // board, so the closest pair gives the square size in pixels.
  double spacing = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < corners.size(); ++i) {
    for (std::size_t j = i + 1; j < corners.size(); ++j) {
      spacing = std::min(spacing, cv::norm(corners[i] - corners[j]));
    }
  }
  int half = AdaptiveHalfWindow(spacing, options);
  if (options.subpix_half_window_px == 0) {
    const double margin_px = spacing * (board.square_mm - board.marker_mm) / (2 * board.square_mm);
    half = std::max(1, std::min(half, static_cast<int>(std::floor(margin_px - 1))));
  }
  RefineCorners(gray, half, options, &corners);

  const std::vector<cv::Point3f> model = BoardCornersInBoard(board);
  detection.found = true;
  detection.image_points = std::move(corners);
  detection.ids = std::move(ids);
  detection.object_points.reserve(detection.ids.size());
  for (int id : detection.ids)
    detection.object_points.push_back(model[static_cast<std::size_t>(id)]);
  return detection;
}

}  // namespace

// --- BoardSpec ----------------------------------------------------------------

bool BoardSpec::IsValid(std::string* why) const {
  if (!std::isfinite(square_mm) || square_mm <= 0) {
    return Fail(why, "board: square_mm must be > 0 (got " + std::to_string(square_mm) + ")");
  }
  if (type == Type::kChessboard) {
    if (cols < 3 || rows < 3) {
      return Fail(why, "board: a chessboard needs at least 3x3 inner corners (got " +
                           std::to_string(cols) + "x" + std::to_string(rows) + ")");
    }
    if (cols > 1000 || rows > 1000) return Fail(why, "board: more than 1000 corners per side");
    return true;
  }
  if (type != Type::kCharuco) return Fail(why, "board: unknown type");
  if (cols < 2 || rows < 2) {
    return Fail(why, "board: a ChArUco board needs at least 2x2 squares (got " +
                         std::to_string(cols) + "x" + std::to_string(rows) + ")");
  }
  if (!std::isfinite(marker_mm) || marker_mm <= 0 || marker_mm >= square_mm) {
    return Fail(why, "board: ChArUco marker_mm must be > 0 and < square_mm (got " +
                         std::to_string(marker_mm) + ")");
  }
  if (aruco_dictionary < 0 || aruco_dictionary >= kNumPredefinedDictionaries) {
    return Fail(why, "board: unknown aruco_dictionary " + std::to_string(aruco_dictionary) +
                         " (0…" + std::to_string(kNumPredefinedDictionaries - 1) + ")");
  }
  const int markers_needed = cols * rows / 2;
  const int available = cv::aruco::getPredefinedDictionary(aruco_dictionary)->bytesList.rows;
  if (markers_needed > available) {
    return Fail(why, "board: " + std::to_string(cols) + "x" + std::to_string(rows) +
                         " ChArUco squares need " + std::to_string(markers_needed) +
                         " markers, dictionary " + std::to_string(aruco_dictionary) + " has " +
                         std::to_string(available));
  }
  return true;
}

int BoardSpec::NumCorners() const {
  return type == Type::kChessboard ? cols * rows : (cols - 1) * (rows - 1);
}

bool BoardSpec::IsRotationallySymmetric() const {
  return type == Type::kChessboard && (cols + rows) % 2 == 0;
}

std::string_view ToString(BoardSpec::Type type) {
  switch (type) {
    case BoardSpec::Type::kChessboard:
      return "chessboard";
    case BoardSpec::Type::kCharuco:
      return "charuco";
  }
  return "unknown";
}

bool BoardTypeFromString(std::string_view text, BoardSpec::Type* type) {
  if (text == "chessboard") {
    *type = BoardSpec::Type::kChessboard;
  } else if (text == "charuco") {
    *type = BoardSpec::Type::kCharuco;
  } else {
    return false;
  }
  return true;
}

std::string Describe(const BoardSpec& board) {
  const std::string size = std::to_string(board.cols) + "x" + std::to_string(board.rows);
  const std::string square = calib_internal::Fixed(board.square_mm, 3);
  if (board.type == BoardSpec::Type::kChessboard) {
    return "chessboard " + size + " inner corners, " + square + " mm squares";
  }
  return "charuco " + size + " squares, " + square + " mm squares, " +
         calib_internal::Fixed(board.marker_mm, 3) + " mm markers, dictionary " +
         std::to_string(board.aruco_dictionary);
}

std::vector<cv::Point3f> BoardCornersInBoard(const BoardSpec& board) {
  if (!board.IsValid(nullptr)) return {};
  if (board.type == BoardSpec::Type::kCharuco) return MakeCharucoBoard(board)->chessboardCorners;
  std::vector<cv::Point3f> corners;
  corners.reserve(static_cast<std::size_t>(board.NumCorners()));
  for (int y = 0; y < board.rows; ++y) {
    for (int x = 0; x < board.cols; ++x) {
      corners.emplace_back(static_cast<float>(x * board.square_mm),
                           static_cast<float>(y * board.square_mm), 0.f);
    }
  }
  return corners;
}

// --- CameraIntrinsics ---------------------------------------------------------

cv::Mat CameraIntrinsics::DistortionCoeffs() const {
  const bool rational = UsesRationalModel();
  cv::Mat coeffs(1, rational ? 8 : 5, CV_64F);
  for (int i = 0; i < 5; ++i) coeffs.at<double>(0, i) = distortion[i];
  if (rational) {
    for (int i = 0; i < 3; ++i) coeffs.at<double>(0, 5 + i) = distortion_rational[i];
  }
  return coeffs;
}

bool CameraIntrinsics::SetDistortionCoeffs(const cv::Mat& coeffs) {
  if (coeffs.empty() || (coeffs.rows != 1 && coeffs.cols != 1) || coeffs.channels() != 1) {
    return false;
  }
  cv::Mat flat;
  coeffs.reshape(1, 1).convertTo(flat, CV_64F);
  const int n = flat.cols;
  if (n != 4 && n != 5 && n < 8) return false;
  for (int i = 8; i < n; ++i) {  // thin prism / tilt terms are not modelled
    if (flat.at<double>(0, i) != 0) return false;
  }
  distortion = cv::Vec<double, 5>(0, 0, 0, 0, 0);
  distortion_rational = cv::Vec3d(0, 0, 0);
  for (int i = 0; i < std::min(n, 5); ++i) distortion[i] = flat.at<double>(0, i);
  for (int i = 5; i < std::min(n, 8); ++i) distortion_rational[i - 5] = flat.at<double>(0, i);
  return true;
}

// --- StereoCalibration --------------------------------------------------------

namespace {

// Rotation matrices typed or stored with ~6 decimals still pass.
constexpr double kRotationTolerance = 1e-5;

bool CheckIntrinsics(const CameraIntrinsics& camera, const std::string& name, std::string* why) {
  const cv::Matx33d& k = camera.camera_matrix;
  if (!AllFinite(k)) return Fail(why, name + ".camera_matrix: not finite");
  if (!(k(0, 0) > 0) || !(k(1, 1) > 0)) {
    return Fail(why, name + ".camera_matrix: fx and fy must be > 0");
  }
  if (k(1, 0) != 0 || k(2, 0) != 0 || k(2, 1) != 0 || k(2, 2) != 1) {
    return Fail(why, name + ".camera_matrix: last row must be 0 0 1 and k(1,0) = 0");
  }
  for (int i = 0; i < 5; ++i) {
    if (!std::isfinite(camera.distortion[i])) return Fail(why, name + ".distortion: not finite");
  }
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(camera.distortion_rational[i])) {
      return Fail(why, name + ".distortion_rational: not finite");
    }
  }
  return true;
}

}  // namespace

bool StereoCalibration::IsValid(std::string* why) const {
  if (image_size.width <= 0 || image_size.height <= 0) {
    return Fail(why, "image_size: must be positive (got " + std::to_string(image_size.width) + "x" +
                         std::to_string(image_size.height) + ")");
  }
  if (!CheckIntrinsics(left, "left", why) || !CheckIntrinsics(right, "right", why)) return false;
  if (!calib_internal::IsRotation(R, kRotationTolerance))
    return Fail(why, "R: not a rotation matrix");
  if (!AllFinite(cv::Matx31d(T)) || cv::norm(T) == 0) {
    return Fail(why, "T: must be finite and non-zero (the baseline)");
  }
  if (!calib_internal::IsRotation(R1, kRotationTolerance))
    return Fail(why, "R1: not a rotation matrix");
  if (!calib_internal::IsRotation(R2, kRotationTolerance))
    return Fail(why, "R2: not a rotation matrix");
  if (!AllFinite(P1) || !(P1(0, 0) > 0) || !(P1(1, 1) > 0) || P1(2, 2) != 1) {
    return Fail(why, "P1: not a rectified projection (missing rectification?)");
  }
  if (!AllFinite(P2) || !(P2(0, 0) > 0) || !(P2(1, 1) > 0) || P2(2, 2) != 1) {
    return Fail(why, "P2: not a rectified projection (missing rectification?)");
  }
  if (!AllFinite(Q) || Q(3, 2) == 0 || Q(2, 3) == 0) {
    return Fail(why, "Q: not a reprojection matrix (Q(2,3) and Q(3,2) must be non-zero)");
  }
  if (turntable.valid) {
    if (!AllFinite(cv::Matx31d(turntable.direction_in_rig)) ||
        std::abs(cv::norm(turntable.direction_in_rig) - 1) > 1e-6) {
      return Fail(why, "turntable.direction_in_rig: must be a unit vector");
    }
    if (!AllFinite(cv::Matx31d(turntable.point_in_rig_mm))) {
      return Fail(why, "turntable.point_in_rig_mm: not finite");
    }
  }
  return board.IsValid(why);
}

// --- Options ------------------------------------------------------------------

bool BoardDetectionOptions::IsValid(std::string* why) const {
  if (chessboard_detector != ChessboardDetector::kClassic &&
      chessboard_detector != ChessboardDetector::kSectorBased) {
    return Fail(why, "chessboard_detector: unknown value");
  }
  if (subpix_half_window_px < 0 || subpix_half_window_px > 100) {
    return Fail(why, "subpix_half_window_px: must be 0 (adaptive) … 100");
  }
  if (!(subpix_window_fraction > 0 && subpix_window_fraction <= 0.5)) {
    return Fail(why, "subpix_window_fraction: must be in (0, 0.5]");
  }
  if (subpix_max_iterations < 1) return Fail(why, "subpix_max_iterations: must be ≥ 1");
  if (!(subpix_epsilon_px > 0)) return Fail(why, "subpix_epsilon_px: must be > 0");
  if (min_charuco_corners < 4) return Fail(why, "min_charuco_corners: must be ≥ 4");
  return true;
}

LensModelOptions LensModelOptions::OpenCvStereoSample() {
  LensModelOptions lens;
  lens.fix_aspect_ratio = true;
  lens.zero_tangential_distortion = true;
  lens.same_focal_length = true;
  lens.rational_model = true;
  lens.fix_k3 = true;
  lens.fix_k4 = true;
  lens.fix_k5 = true;
  return lens;
}

bool LensModelOptions::IsValid(std::string* why) const {
  if (!rational_model && (fix_k4 || fix_k5 || fix_k6)) {
    return Fail(why, "lens: fix_k4/fix_k5/fix_k6 need rational_model");
  }
  return true;
}

bool RectificationOptions::IsValid(std::string* why) const {
  if (!(alpha == -1 || (alpha >= 0 && alpha <= 1))) {
    return Fail(why, "rectification.alpha: must be -1 or in [0, 1]");
  }
  return true;
}

bool CalibrationLimits::IsValid(std::string* why) const {
  if (min_views < kMinCalibrationViews) {
    return Fail(why, "limits.min_views: must be ≥ " + std::to_string(kMinCalibrationViews));
  }
  if (!(max_rms_px > 0)) return Fail(why, "limits.max_rms_px: must be > 0");
  if (!(max_epipolar_px > 0)) return Fail(why, "limits.max_epipolar_px: must be > 0");
  if (!(min_coverage >= 0 && min_coverage <= 1)) {
    return Fail(why, "limits.min_coverage: must be in [0, 1]");
  }
  return true;
}

bool StereoCalibrationOptions::IsValid(std::string* why) const {
  if (!lens.IsValid(why) || !rectification.IsValid(why) || !limits.IsValid(why)) return false;
  if (coverage_grid < 2 || coverage_grid > 64) return Fail(why, "coverage_grid: must be 2…64");
  if (max_iterations < 1) return Fail(why, "max_iterations: must be ≥ 1");
  if (!(epsilon > 0)) return Fail(why, "epsilon: must be > 0");
  return true;
}

bool TurntableAxisOptions::IsValid(std::string* why) const {
  if (!std::isfinite(board_thickness_mm) || board_thickness_mm < 0) {
    return Fail(why, "board_thickness_mm: must be ≥ 0");
  }
  if (min_steps < 3) return Fail(why, "min_steps: must be ≥ 3");
  if (!(min_span_rad > 0 && min_span_rad <= CV_PI)) {
    return Fail(why, "min_span_rad: must be in (0, π]");
  }
  if (!(max_residual_mm > 0)) return Fail(why, "max_residual_mm: must be > 0");
  if (!(max_angle_error_deg > 0)) return Fail(why, "max_angle_error_deg: must be > 0");
  return true;
}

// --- Enums --------------------------------------------------------------------

std::string_view ToString(CalibrationVerdict verdict) {
  switch (verdict) {
    case CalibrationVerdict::kNotEvaluated:
      return "not_evaluated";
    case CalibrationVerdict::kAccept:
      return "accept";
    case CalibrationVerdict::kReject:
      return "reject";
  }
  return "unknown";
}

bool CalibrationVerdictFromString(std::string_view text, CalibrationVerdict* verdict) {
  for (CalibrationVerdict v : {CalibrationVerdict::kNotEvaluated, CalibrationVerdict::kAccept,
                               CalibrationVerdict::kReject}) {
    if (text == ToString(v)) {
      *verdict = v;
      return true;
    }
  }
  return false;
}

std::string_view ToString(BoardDetectionOptions::ChessboardDetector detector) {
  switch (detector) {
    case BoardDetectionOptions::ChessboardDetector::kClassic:
      return "classic";
    case BoardDetectionOptions::ChessboardDetector::kSectorBased:
      return "sector_based";
  }
  return "unknown";
}

bool ChessboardDetectorFromString(std::string_view text,
                                  BoardDetectionOptions::ChessboardDetector* detector) {
  for (auto d : {BoardDetectionOptions::ChessboardDetector::kClassic,
                 BoardDetectionOptions::ChessboardDetector::kSectorBased}) {
    if (text == ToString(d)) {
      *detector = d;
      return true;
    }
  }
  return false;
}

std::string_view ToString(CameraCalibrationResult::Status status) {
  switch (status) {
    case CameraCalibrationResult::Status::kOk:
      return "ok";
    case CameraCalibrationResult::Status::kInvalidInput:
      return "invalid_input";
    case CameraCalibrationResult::Status::kTooFewViews:
      return "too_few_views";
    case CameraCalibrationResult::Status::kFailed:
      return "failed";
  }
  return "unknown";
}

std::string_view ToString(StereoCalibrationResult::Status status) {
  switch (status) {
    case StereoCalibrationResult::Status::kOk:
      return "ok";
    case StereoCalibrationResult::Status::kInvalidInput:
      return "invalid_input";
    case StereoCalibrationResult::Status::kTooFewViews:
      return "too_few_views";
    case StereoCalibrationResult::Status::kFailed:
      return "failed";
  }
  return "unknown";
}

std::string_view ToString(TurntableAxisResult::Status status) {
  switch (status) {
    case TurntableAxisResult::Status::kOk:
      return "ok";
    case TurntableAxisResult::Status::kInvalidInput:
      return "invalid_input";
    case TurntableAxisResult::Status::kTooFewSteps:
      return "too_few_steps";
    case TurntableAxisResult::Status::kFailed:
      return "failed";
  }
  return "unknown";
}

// --- Detection ----------------------------------------------------------------

BoardDetection DetectBoard(const cv::Mat& image, const BoardSpec& board,
                           const BoardDetectionOptions& options) {
  BoardDetection detection;
  std::string why;
  if (!board.IsValid(&why) || !options.IsValid(&why)) {
    detection.message = why;
    return detection;
  }
  cv::Mat gray = ToGray8(image, &why);
  if (gray.empty()) {
    detection.message = why;
    return detection;
  }
  try {
    return board.type == BoardSpec::Type::kChessboard ? DetectChessboard(gray, board, options)
                                                      : DetectCharuco(gray, board, options);
  } catch (const cv::Exception& e) {  // OpenCV rejects odd inputs by throwing
    detection = BoardDetection{};
    detection.message = "board detection failed: " + calib_internal::CvErrorText(e);
    return detection;
  }
}

StereoBoardView DetectStereoBoard(std::string name, const cv::Mat& left, const cv::Mat& right,
                                  const BoardSpec& board, const BoardDetectionOptions& options) {
  StereoBoardView view;
  view.name = std::move(name);
  view.left = DetectBoard(left, board, options);
  view.right = DetectBoard(right, board, options);
  return view;
}

}  // namespace craftscan
