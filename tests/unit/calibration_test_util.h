// The calibration tests' boards, synthetic stereo rigs, board poses and
// rendered boards. Ground truth is exact; noise is explicit.
#pragma once

#include <cmath>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>

#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan::testing {

// The boards the tests calibrate with.
inline BoardSpec Chessboard9x6() {
  BoardSpec board;
  board.type = BoardSpec::Type::kChessboard;
  board.cols = 9;
  board.rows = 6;
  board.square_mm = 25;
  return board;
}

inline BoardSpec Charuco7x5() {
  BoardSpec board;
  board.type = BoardSpec::Type::kCharuco;
  board.cols = 7;
  board.rows = 5;
  board.square_mm = 30;
  board.marker_mm = 22;
  board.aruco_dictionary = 0;  // DICT_4X4_50
  return board;
}

// A converging stereo pair, 1280×960, with real-looking lenses.
struct SyntheticRig {
  cv::Size image_size{1280, 960};
  CameraIntrinsics left, right;
  cv::Matx33d R;  // right_from_left
  cv::Vec3d T;    // mm
};

inline SyntheticRig MakeRig(bool with_distortion = true) {
  SyntheticRig rig;
  rig.left.camera_matrix = cv::Matx33d(1000, 0, 640.3, 0, 1002, 479.6, 0, 0, 1);
  rig.right.camera_matrix = cv::Matx33d(1008, 0, 628.7, 0, 1009, 486.2, 0, 0, 1);
  if (with_distortion) {
    rig.left.distortion = cv::Vec<double, 5>(-0.12, 0.08, 0.0005, -0.0003, 0);
    rig.right.distortion = cv::Vec<double, 5>(-0.10, 0.05, -0.0004, 0.0002, 0);
  }
  cv::Rodrigues(cv::Vec3d(0.01, -0.12, 0.004), rig.R);  // converging by ~7°
  rig.T = cv::Vec3d(-120.0, 0.6, 1.5);
  return rig;
}

// The rig as a calibration (ground truth), rectified.
inline StereoCalibration RigCalibration(const SyntheticRig& rig, const BoardSpec& board) {
  StereoCalibration c;
  c.image_size = rig.image_size;
  c.left = rig.left;
  c.right = rig.right;
  c.R = rig.R;
  c.T = rig.T;
  c.board = board;
  std::string error;
  ComputeRectification(RectificationOptions{}, &c, &error);
  return c;
}

// Rigid transform p_in_left = R · p_in_board + t.
struct BoardPose {
  cv::Matx33d R;
  cv::Vec3d t;
};

inline std::vector<cv::Point2f> ProjectPoints(const std::vector<cv::Point3f>& p_in_board,
                                              const cv::Matx33d& camera_from_board_R,
                                              const cv::Vec3d& camera_from_board_t,
                                              const CameraIntrinsics& camera) {
  cv::Vec3d rvec;
  cv::Rodrigues(camera_from_board_R, rvec);
  std::vector<cv::Point2f> out;
  cv::projectPoints(p_in_board, rvec, camera_from_board_t, cv::Mat(camera.camera_matrix),
                    camera.DistortionCoeffs(), out);
  return out;
}

inline bool AllInside(const std::vector<cv::Point2f>& points, cv::Size size, float margin) {
  for (const cv::Point2f& p : points) {
    if (p.x < margin || p.y < margin || p.x > size.width - 1 - margin ||
        p.y > size.height - 1 - margin) {
      return false;
    }
  }
  return true;
}

inline void AddNoise(double sigma_px, std::mt19937* rng, std::vector<cv::Point2f>* points) {
  if (sigma_px <= 0) return;
  std::normal_distribution<float> noise(0.f, static_cast<float>(sigma_px));
  for (cv::Point2f& p : *points) p += cv::Point2f(noise(*rng), noise(*rng));
}

// Random board poses in front of the rig, every corner inside both images
// (with a margin), board facing the cameras.
inline std::vector<BoardPose> RandomBoardPoses(const SyntheticRig& rig, const BoardSpec& board,
                                               int count, unsigned seed, float margin_px = 30) {
  const std::vector<cv::Point3f> corners = BoardCornersInBoard(board);
  cv::Point3f centre(0, 0, 0);
  for (const cv::Point3f& p : corners) centre += p;
  centre *= 1.f / static_cast<float>(corners.size());
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> tilt(-0.6, 0.6), spin(-0.4, 0.4), x(-180, 180),
      y(-130, 130), z(450, 800);
  std::vector<BoardPose> poses;
  for (int attempt = 0; attempt < 100000 && static_cast<int>(poses.size()) < count; ++attempt) {
    BoardPose pose;
    cv::Rodrigues(cv::Vec3d(tilt(rng), tilt(rng), spin(rng)), pose.R);
    const cv::Vec3d c(x(rng), y(rng), z(rng));
    pose.t = c - pose.R * cv::Vec3d(centre.x, centre.y, centre.z);
    const std::vector<cv::Point2f> l = ProjectPoints(corners, pose.R, pose.t, rig.left);
    const std::vector<cv::Point2f> r =
        ProjectPoints(corners, rig.R * pose.R, rig.R * pose.t + rig.T, rig.right);
    if (AllInside(l, rig.image_size, margin_px) && AllInside(r, rig.image_size, margin_px)) {
      poses.push_back(pose);
    }
  }
  return poses;
}

// A detection made from known projections (chessboard: every corner).
inline BoardDetection DetectionFromPoints(const BoardSpec& board,
                                          std::vector<cv::Point2f> image_points) {
  BoardDetection d;
  d.found = true;
  d.object_points = BoardCornersInBoard(board);
  d.image_points = std::move(image_points);
  for (std::size_t i = 0; i < d.object_points.size(); ++i) d.ids.push_back(static_cast<int>(i));
  return d;
}

// Stereo views of `poses` with Gaussian noise on every corner.
inline std::vector<StereoBoardView> SyntheticViews(const SyntheticRig& rig, const BoardSpec& board,
                                                   const std::vector<BoardPose>& poses,
                                                   double noise_px, unsigned seed) {
  const std::vector<cv::Point3f> corners = BoardCornersInBoard(board);
  std::mt19937 rng(seed);
  std::vector<StereoBoardView> views;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    std::vector<cv::Point2f> l = ProjectPoints(corners, poses[i].R, poses[i].t, rig.left);
    std::vector<cv::Point2f> r =
        ProjectPoints(corners, rig.R * poses[i].R, rig.R * poses[i].t + rig.T, rig.right);
    AddNoise(noise_px, &rng, &l);
    AddNoise(noise_px, &rng, &r);
    StereoBoardView v;
    v.name = "synthetic" + std::to_string(i);
    v.left = DetectionFromPoints(board, std::move(l));
    v.right = DetectionFromPoints(board, std::move(r));
    views.push_back(std::move(v));
  }
  return views;
}

// A flat image of the board, `px_per_mm` pixels per millimetre, no margin:
// texture pixel (u, v) covers board millimetres [u, u+1)/px_per_mm × [v, v+1)/px_per_mm.
inline cv::Mat BoardTexture(const BoardSpec& board, double px_per_mm) {
  if (board.type == BoardSpec::Type::kCharuco) {
    cv::Ptr<cv::aruco::CharucoBoard> charuco =
        cv::aruco::CharucoBoard::create(board.cols, board.rows, static_cast<float>(board.square_mm),
                                        static_cast<float>(board.marker_mm),
                                        cv::aruco::getPredefinedDictionary(board.aruco_dictionary));
    cv::Mat texture;
    charuco->draw(cv::Size(static_cast<int>(std::lround(board.cols * board.square_mm * px_per_mm)),
                           static_cast<int>(std::lround(board.rows * board.square_mm * px_per_mm))),
                  texture, 0, 1);
    return texture;
  }
  // Chessboard: (cols+1) × (rows+1) squares, the corner square at inner
  // corner 0's end black; inner corner (i, j) at board ((i+1)·s, (j+1)·s)
  // in texture millimetres, i.e. (i·s, j·s) in BoardCornersInBoard's frame.
  const int sq = static_cast<int>(std::lround(board.square_mm * px_per_mm));
  cv::Mat texture((board.rows + 1) * sq, (board.cols + 1) * sq, CV_8U, cv::Scalar(255));
  for (int j = 0; j <= board.rows; ++j) {
    for (int i = 0; i <= board.cols; ++i) {
      if ((i + j) % 2 == 0) {
        texture(cv::Rect(i * sq, j * sq, sq, sq)).setTo(cv::Scalar(0));
      }
    }
  }
  return texture;
}

// Board millimetres (BoardCornersInBoard frame) → texture pixel centres.
inline cv::Matx33d TextureFromBoard(const BoardSpec& board, double px_per_mm) {
  // ChArUco corners are given in texture millimetres; chessboard corners are
  // offset by one square (the outer row/column of squares).
  const double offset_mm = board.type == BoardSpec::Type::kChessboard ? board.square_mm : 0.0;
  return cv::Matx33d(px_per_mm, 0, offset_mm * px_per_mm - 0.5, 0, px_per_mm,
                     offset_mm * px_per_mm - 0.5, 0, 0, 1);
}

// Renders the board seen by a pinhole camera (distortion ignored) at pose
// camera_from_board, 3× supersampled then area-averaged, on a light grey background.
inline cv::Mat RenderBoard(const cv::Mat& texture, const BoardSpec& board, double px_per_mm,
                           const CameraIntrinsics& camera, const cv::Matx33d& camera_from_board_R,
                           const cv::Vec3d& camera_from_board_t, cv::Size size) {
  constexpr int kSuper = 3;
  const cv::Matx33d& k = camera.camera_matrix;
  const cv::Matx33d image_from_board_plane =
      k * cv::Matx33d(camera_from_board_R(0, 0), camera_from_board_R(0, 1), camera_from_board_t[0],
                      camera_from_board_R(1, 0), camera_from_board_R(1, 1), camera_from_board_t[1],
                      camera_from_board_R(2, 0), camera_from_board_R(2, 1), camera_from_board_t[2]);
  // Pixel centres: low-res x ↔ high-res kSuper·x + (kSuper − 1)/2 under INTER_AREA.
  const double shift = (kSuper - 1) / 2.0;
  const cv::Matx33d super(kSuper, 0, shift, 0, kSuper, shift, 0, 0, 1);
  const cv::Matx33d high_from_texture =
      super * image_from_board_plane * TextureFromBoard(board, px_per_mm).inv();
  cv::Mat high;
  cv::warpPerspective(texture, high, cv::Mat(high_from_texture),
                      cv::Size(size.width * kSuper, size.height * kSuper), cv::INTER_LINEAR,
                      cv::BORDER_CONSTANT, cv::Scalar(200));
  cv::Mat low;
  cv::resize(high, low, size, 0, 0, cv::INTER_AREA);
  return low;
}

}  // namespace craftscan::testing
