// Calibration scenes for the simulated station: boards a technician holds in
// front of the rig (stereo calibration) and a chessboard lying on the
// platter (turntable axis), placed so that every view is usable: a whole
// chessboard inside both images and above the platter, a ChArUco board
// larger than the view reaching into the image corners. The calibration
// tests and the sim driver's `held_board` / `platter_board` scenes
// (driver_options.h) use them.
//
//   auto station = SimStation::Create(RigOptions{}, &error);
//   const BoardSpec spec = HeldChessboard();
//   const std::vector<HeldPose>& poses = HeldPoses(spec.type);
//   for (std::size_t i = 0; i < poses.size(); ++i) {
//     const HeldBoardPlacement p = PlaceHeldBoard(*station, spec, poses[i]);
//     auto scene = Scene::Create(HeldBoardScene(*station, spec, p.rig_from_board), &error);
//     const StereoRender frame = station->Render(*scene, i);  // then DetectStereoBoard …
//   }
//
// Frames and units as in station.h (mm, rad, px; degrees in *_deg fields).
// Every function here is pure and thread-safe; the pose lists are immutable.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/sim/station.h"

namespace craftscan::sim {

// ------------------------------------------------------------ the boards ---

// The held chessboard: 9×6 inner corners (odd + even: its corner order is
// unambiguous), 8 mm squares, one square of white margin (96 × 72 mm). With
// the default rig's 2400 px lenses the view at 400 mm is only 213 × 171 mm
// and past ~350 mm the platter fills its lower half, so 20 mm squares could
// not be seen whole at all and 10 mm ones only far away and unrolled; 8 mm
// squares (40–65 px on the images) fit rolled and tilted at 300–500 mm.
// ChessboardPoses() are made for it.
BoardSpec HeldChessboard();

// The held ChArUco board: 16×12 squares of 12 mm (192 × 144 mm, larger than
// the view), 8 mm markers from DICT_4X4_100, a 10 mm margin. ChArUco
// corners need not all be seen, so it reaches into the image corners where a
// whole chessboard cannot, which pins the principal point down.
// CharucoPoses() are made for it.
BoardSpec HeldCharuco();

// The chessboard lying on the platter: HeldChessboard() with 12 mm squares
// (nothing but the platter's rim limits its size).
BoardSpec PlatterChessboard();

// A ChArUco board for the platter: 10×7 squares of 15 mm, 10 mm markers from
// DICT_4X4_100, a 10 mm margin (170 × 125 mm: it lies on the platter).
BoardSpec PlatterCharuco();

// The white border these scenes print around the square grid (mm): one
// square for a chessboard, 10 mm for a ChArUco board.
double BoardMarginMm(const BoardSpec& spec);

// The printed board's outline in the board frame (mm, z = 0), four corners
// in order, margin included.
std::vector<cv::Vec3d> BoardOutline(const BoardSpec& spec);
cv::Vec3d BoardCentre(const BoardSpec& spec);  // centre of BoardOutline (mm, board frame)

// A scene with nothing but the board (spec, margin BoardMarginMm): no
// object, no cast shadows (nothing can shade the board, and they cost a
// fifth of the render time). The board's placement is left to the caller.
SceneOptions BoardScene(const BoardSpec& spec);

// -------------------------------------------------------- boards in hand ---

// A board pose in front of the rig: its centre on the ray from the midpoint
// of the optical centres towards the target (where the optical axes meet)
// turned by (right, down) half fields of view, `distance_mm` deep in the rig
// frame; the board faces the cameras, then is tilted and rolled (rotation
// roll · tilt_y · tilt_x about the rig's axes).
struct HeldPose {
  // Offset of the centre in the image, in half fields of view (+ = right,
  // down). PlaceWholeBoard slides a chessboard along this direction instead.
  double right = 0, down = 0;
  double distance_mm = 400;  // depth of the board centre in the rig frame
  double tilt_x_deg = 0;     // about the rig's x axis: > 0 turns the board's bottom away
  double tilt_y_deg = 0;     // about the rig's y axis: > 0 turns the board's left side away
  double roll_deg = 0;       // about the viewing direction
};

// A fully visible board keeps at least this far (px) from the image borders.
inline constexpr double kHeldBoardEdgePx = 12;

// Where a held board ends up, and how well both cameras see it.
struct HeldBoardPlacement {
  cv::Matx44d rig_from_board = cv::Matx44d::eye();
  double margin_px = 0;  // the outline's least distance from the borders of both images (< 0: out)
  double lowest_mm = 0;  // the outline's lowest point above the platter (world z at angle 0)
  // Corners inside both images (kHeldBoardEdgePx from the border) and ≥ 2 mm
  // above the platter. Occlusion by the platter is not considered.
  int corners_seen = 0;
  // The whole board in both images (kHeldBoardEdgePx) and ≥ 2 mm above the platter.
  bool fully_visible() const { return margin_px >= kHeldBoardEdgePx && lowest_mm >= 2; }
};

// The board at `pose` exactly, measured against `station`'s exact cameras
// (projection with distortion). Depends only on the rig's geometry, not on
// its exposure, noise or sampling.
HeldBoardPlacement PlaceBoard(const SimStation& station, const BoardSpec& spec,
                              const HeldPose& pose);

// `pose` raised in the image (in steps of 1 % of the half field, at most
// 200) until the board's outline is ≥ 2 mm above the platter: farther than
// ~350 mm the lower half of the view sees the platter top, so far boards are
// held high. Returns the last pose tried when 200 steps do not suffice.
HeldPose RaiseAbovePlatter(const SimStation& station, const BoardSpec& spec, HeldPose pose);

// A chessboard must be seen whole: from above the platter, slides the board
// along the pose's (right, down) direction to the farthest place (within
// 1.5× the pose's offset) where it is fully visible. When it is fully
// visible nowhere on that path, returns the centred pose raised above the
// platter (fully_visible() false: e.g. a board too large for the view).
HeldBoardPlacement PlaceWholeBoard(const SimStation& station, const BoardSpec& spec,
                                   const HeldPose& pose);

// A ChArUco board may overfill the view: `pose` raised above the platter.
HeldBoardPlacement PlaceBoardAbovePlatter(const SimStation& station, const BoardSpec& spec,
                                          const HeldPose& pose);

// PlaceWholeBoard for a chessboard, PlaceBoardAbovePlatter for a ChArUco board.
HeldBoardPlacement PlaceHeldBoard(const SimStation& station, const BoardSpec& spec,
                                  const HeldPose& pose);

// BoardScene(spec) with the board fixed in the world at `rig_from_board`
// (station's rig frame); it does not turn with the turntable.
SceneOptions HeldBoardScene(const SimStation& station, const BoardSpec& spec,
                            const cv::Matx44d& rig_from_board);

// 16 chessboard poses for HeldChessboard(): 310–500 mm deep, tilts up to 35°
// about both axes, rolled 15–30° (with 2×2 samples on a regular grid an
// edge's position is resolved to ±1/4 px only where it runs along the pixel
// grid, so boards are held a little rolled, as hands hold them), each meant
// to be pushed by PlaceWholeBoard as far as it goes towards a side or corner
// of the view (coverage 0.66 of the image on the default rig).
const std::vector<HeldPose>& ChessboardPoses();

// 16 ChArUco poses for HeldCharuco(): 300–480 mm, tilts up to 35°, rolled
// 5–30°, the centre where given (raised where the board would reach into the
// platter); coverage ~0.96 of the image on the default rig.
const std::vector<HeldPose>& CharucoPoses();

// ChessboardPoses() or CharucoPoses() by board type.
const std::vector<HeldPose>& HeldPoses(BoardSpec::Type type);

// ------------------------------------------------------ board on platter ---

// BoardScene(spec) lying on the platter, printed face up, `thickness_mm` (3)
// thick, turning with the turntable: at angle 0 its outline's centre lies at
// world (centre_off_axis_mm, 0) and it is turned by yaw_rad about the axis.
// With PlatterChessboard() on the default rig every corner stays ≥ 30 px
// inside the left image at every angle. An invalid spec gives options that
// Scene::Create refuses with the spec's error.
SceneOptions PlatterBoardScene(const BoardSpec& spec, double centre_off_axis_mm = 20,
                               double yaw_rad = 0.3);

// An upper bound (mm) of the distance of the board's outline from the axis
// in PlatterBoardScene(spec, centre_off_axis_mm): the board lies on the
// platter when this is ≤ its radius (SceneOptions::platter_radius_mm).
double PlatterBoardReachMm(const BoardSpec& spec, double centre_off_axis_mm = 20);

// ------------------------------------------------------------- geometry ---

// Exact projection of points (frame F, mm) into a raw camera with the
// distortion model: camera_from_F and the camera's intrinsics. Pixels (u, v)
// with centres at integer coordinates.
std::vector<cv::Point2f> ProjectIntoCamera(const cv::Matx44d& camera_from_f,
                                           const CameraIntrinsics& camera,
                                           const std::vector<cv::Vec3d>& p_in_f);

// Least distance (px) of the points from the border of an image of `size`
// (from pixel centre 0 to size − 1); negative when one lies outside, a huge
// value for no points.
double MarginInsideImagePx(const std::vector<cv::Point2f>& points, cv::Size size);

}  // namespace craftscan::sim
