// Stereo rig calibration (method.md §3–4): board descriptions, the
// calibration of a camera pair with its rectification, and the turntable
// axis. Units: millimetres, pixels, radians (degrees only at user edges).
// The rig frame is the rectified left camera.
//
// This header holds the data types shared by the calibration code, the
// simulated station and the daemon. Functions that compute, save and load
// calibrations are declared below the types.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core.hpp>

namespace craftscan {

struct BoardSpec {
  enum class Type { kChessboard, kCharuco };
  Type type = Type::kChessboard;
  // Chessboard: inner corners per row (cols) and per column (rows).
  // ChArUco: squares per row (cols) and per column (rows).
  int cols = 9;
  int rows = 6;
  double square_mm = 25.0;  // edge of one square
  double marker_mm = 0.0;   // ChArUco only: edge of one ArUco marker (< square_mm)
  int aruco_dictionary = 0; // ChArUco only: cv::aruco::PREDEFINED_DICTIONARY_NAME value

  bool IsValid(std::string* why) const;
};
std::string_view ToString(BoardSpec::Type type);
bool BoardTypeFromString(std::string_view text, BoardSpec::Type* type);

struct CameraIntrinsics {
  cv::Matx33d camera_matrix = cv::Matx33d::eye();  // fx 0 cx; 0 fy cy; 0 0 1 (px)
  cv::Vec<double, 5> distortion{0, 0, 0, 0, 0};    // k1 k2 p1 p2 k3 (OpenCV order)
};

// The turntable's rotation axis in the rig frame: a unit direction and the
// point where the axis meets the platter surface.
struct TurntableAxis {
  bool valid = false;
  cv::Vec3d direction_in_rig{0, 0, 1};  // unit vector, +Z of the world (turntable) frame
  cv::Vec3d point_in_rig_mm{0, 0, 0};
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

  double baseline_mm() const { return cv::norm(T); }
};

}  // namespace craftscan
