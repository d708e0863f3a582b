#include "craftscan/sim/calibration_scenes.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <opencv2/aruco.hpp>
#include <opencv2/calib3d.hpp>

namespace craftscan::sim {
namespace {

constexpr double kDegToRad = CV_PI / 180.0;

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

bool Inside(const cv::Point2f& p, cv::Size size, double margin_px) {
  return p.x >= margin_px && p.y >= margin_px && p.x <= size.width - 1 - margin_px &&
         p.y <= size.height - 1 - margin_px;
}

}  // namespace

// --- boards --------------------------------------------------------------------

BoardSpec HeldChessboard() {
  return {.type = BoardSpec::Type::kChessboard, .cols = 9, .rows = 6, .square_mm = 8};
}

BoardSpec HeldCharuco() {
  return {.type = BoardSpec::Type::kCharuco,
          .cols = 16,
          .rows = 12,
          .square_mm = 12,
          .marker_mm = 8,
          .aruco_dictionary = cv::aruco::DICT_4X4_100};
}

BoardSpec PlatterChessboard() {
  BoardSpec board = HeldChessboard();
  board.square_mm = 12;
  return board;
}

BoardSpec PlatterCharuco() {
  BoardSpec board = HeldCharuco();
  board.cols = 10;
  board.rows = 7;
  board.square_mm = 15;
  board.marker_mm = 10;
  return board;
}

double BoardMarginMm(const BoardSpec& spec) {
  return spec.type == BoardSpec::Type::kChessboard ? spec.square_mm : 10;
}

std::vector<cv::Vec3d> BoardOutline(const BoardSpec& spec) {
  const bool chess = spec.type == BoardSpec::Type::kChessboard;
  const double s = spec.square_mm;
  const double m = BoardMarginMm(spec);
  const double x0 = (chess ? -s : 0) - m, y0 = (chess ? -s : 0) - m;
  const double x1 = spec.cols * s + m, y1 = spec.rows * s + m;
  return {{x0, y0, 0}, {x1, y0, 0}, {x1, y1, 0}, {x0, y1, 0}};
}

cv::Vec3d BoardCentre(const BoardSpec& spec) {
  const std::vector<cv::Vec3d> o = BoardOutline(spec);
  return (o[0] + o[2]) * 0.5;
}

SceneOptions BoardScene(const BoardSpec& spec) {
  SceneOptions options;
  options.object.type = ObjectType::kNone;
  options.lighting.shadows = false;
  options.board.enabled = true;
  options.board.spec = spec;
  options.board.margin_mm = BoardMarginMm(spec);
  return options;
}

// --- boards in hand ------------------------------------------------------------

HeldBoardPlacement PlaceBoard(const SimStation& station, const BoardSpec& spec,
                              const HeldPose& pose) {
  const StereoCalibration& c = station.calibration();
  const cv::Matx44d world_from_rig = station.world_from_rig();
  const cv::Matx44d left_from_rig = station.left_from_world() * world_from_rig;
  const cv::Matx44d right_from_rig = station.right_from_world() * world_from_rig;
  const cv::Vec3d mid(c.baseline_mm() / 2, 0, 0);  // the rig's x axis runs along the baseline
  const cv::Vec3d target =
      Apply(station.rig_from_world(), {0, 0, station.options().target_height_mm});
  const cv::Vec3d towards = (target - mid) * (1.0 / (target - mid)[2]);
  const double f = c.rectified_focal_px();
  const cv::Vec3d offset(pose.right * c.image_size.width / (2 * f),
                         pose.down * c.image_size.height / (2 * f), 0);
  cv::Matx33d rx, ry, rz;
  cv::Rodrigues(cv::Vec3d(pose.tilt_x_deg * kDegToRad, 0, 0), rx);
  cv::Rodrigues(cv::Vec3d(0, pose.tilt_y_deg * kDegToRad, 0), ry);
  cv::Rodrigues(cv::Vec3d(0, 0, pose.roll_deg * kDegToRad), rz);
  const cv::Matx33d R = rz * ry * rx;  // board axes start as the rig's: facing the cameras
  const cv::Vec3d centre = mid + pose.distance_mm * (towards + offset);

  HeldBoardPlacement p;
  p.rig_from_board = Rigid(R, centre - R * BoardCentre(spec));
  const std::vector<cv::Vec3d> outline = BoardOutline(spec);
  p.margin_px = std::min(
      MarginInsideImagePx(ProjectIntoCamera(left_from_rig * p.rig_from_board, c.left, outline),
                          c.image_size),
      MarginInsideImagePx(ProjectIntoCamera(right_from_rig * p.rig_from_board, c.right, outline),
                          c.image_size));
  const cv::Matx44d world_from_board = world_from_rig * p.rig_from_board;
  p.lowest_mm = 1e9;
  for (const cv::Vec3d& q : outline) {
    p.lowest_mm = std::min(p.lowest_mm, Apply(world_from_board, q)[2]);
  }
  std::vector<cv::Vec3d> corners;
  for (const cv::Point3f& q : BoardCornersInBoard(spec)) corners.emplace_back(q.x, q.y, q.z);
  const std::vector<cv::Point2f> left =
      ProjectIntoCamera(left_from_rig * p.rig_from_board, c.left, corners);
  const std::vector<cv::Point2f> right =
      ProjectIntoCamera(right_from_rig * p.rig_from_board, c.right, corners);
  for (std::size_t i = 0; i < corners.size(); ++i) {
    if (Inside(left[i], c.image_size, kHeldBoardEdgePx) &&
        Inside(right[i], c.image_size, kHeldBoardEdgePx) &&
        Apply(world_from_board, corners[i])[2] >= 2) {
      ++p.corners_seen;
    }
  }
  return p;
}

HeldPose RaiseAbovePlatter(const SimStation& station, const BoardSpec& spec, HeldPose pose) {
  for (int i = 0; i < 200 && PlaceBoard(station, spec, pose).lowest_mm < 2; ++i) pose.down -= 0.01;
  return pose;
}

HeldBoardPlacement PlaceWholeBoard(const SimStation& station, const BoardSpec& spec,
                                   const HeldPose& pose) {
  HeldPose centred = pose;
  centred.right = centred.down = 0;
  const double lift = RaiseAbovePlatter(station, spec, centred).down;
  auto slid = [&](double s) {
    HeldPose p = pose;
    p.right = s * pose.right;
    p.down = lift + s * pose.down;
    return PlaceBoard(station, spec, p);
  };
  // A coarse scan for the last fully visible step, then bisection.
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

HeldBoardPlacement PlaceBoardAbovePlatter(const SimStation& station, const BoardSpec& spec,
                                          const HeldPose& pose) {
  return PlaceBoard(station, spec, RaiseAbovePlatter(station, spec, pose));
}

HeldBoardPlacement PlaceHeldBoard(const SimStation& station, const BoardSpec& spec,
                                  const HeldPose& pose) {
  return spec.type == BoardSpec::Type::kChessboard ? PlaceWholeBoard(station, spec, pose)
                                                   : PlaceBoardAbovePlatter(station, spec, pose);
}

SceneOptions HeldBoardScene(const SimStation& station, const BoardSpec& spec,
                            const cv::Matx44d& rig_from_board) {
  SceneOptions options = BoardScene(spec);
  options.board.placement = BoardPlacement::kInWorld;
  const cv::Matx44d world_from_board = station.world_from_rig() * rig_from_board;
  cv::Rodrigues(cv::Matx33d(world_from_board.get_minor<3, 3>(0, 0)), options.board.rotation_rad);
  options.board.translation_mm = {world_from_board(0, 3), world_from_board(1, 3),
                                  world_from_board(2, 3)};
  return options;
}

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

const std::vector<HeldPose>& HeldPoses(BoardSpec::Type type) {
  return type == BoardSpec::Type::kChessboard ? ChessboardPoses() : CharucoPoses();
}

// --- board on the platter --------------------------------------------------------

SceneOptions PlatterBoardScene(const BoardSpec& spec, double centre_off_axis_mm, double yaw_rad) {
  SceneOptions options = BoardScene(spec);
  options.board.placement = BoardPlacement::kOnPlatter;
  options.board.platter_yaw_rad = yaw_rad;
  // Where the board frame's origin must go for the outline's centre to lie
  // at (centre_off_axis_mm, 0): measured on the scene built with it at (0, 0).
  options.board.platter_position_mm = {0, 0};
  auto probe = Scene::Create(options, nullptr);
  if (!probe) return options;
  const cv::Vec3d centre = Apply(probe->world_from_board(), BoardCentre(spec));
  options.board.platter_position_mm = {centre_off_axis_mm - centre[0], 0 - centre[1]};
  return options;
}

double PlatterBoardReachMm(const BoardSpec& spec, double centre_off_axis_mm) {
  const std::vector<cv::Vec3d> outline = BoardOutline(spec);
  return std::abs(centre_off_axis_mm) + cv::norm(outline[2] - outline[0]) / 2;
}

// --- geometry --------------------------------------------------------------------

std::vector<cv::Point2f> ProjectIntoCamera(const cv::Matx44d& camera_from_f,
                                           const CameraIntrinsics& camera,
                                           const std::vector<cv::Vec3d>& p_in_f) {
  if (p_in_f.empty()) return {};
  std::vector<cv::Point3d> p;
  for (const cv::Vec3d& q : p_in_f) p.emplace_back(Apply(camera_from_f, q));
  std::vector<cv::Point2d> image;
  cv::projectPoints(p, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), camera.camera_matrix,
                    camera.distortion, image);
  return std::vector<cv::Point2f>(image.begin(), image.end());
}

double MarginInsideImagePx(const std::vector<cv::Point2f>& points, cv::Size size) {
  double margin = 1e9;
  for (const cv::Point2f& p : points) {
    margin = std::min({margin, static_cast<double>(p.x), static_cast<double>(p.y),
                       size.width - 1.0 - p.x, size.height - 1.0 - p.y});
  }
  return margin;
}

}  // namespace craftscan::sim
