// Options of the sim driver plugin (craftscan-driver-sim.so): a stereo
// camera pair and a turntable sharing one sim::Scene, so a capture after a
// move shows the object turned.
//
// Config keys (all optional; unknown keys and values are refused, naming the key):
//   scene                   what the cameras see                      (object)
//     object                  the object on the turntable (`object`)
//     held_board              no object; a calibration board held in front of the
//                             rig: frame id i shows it at held pose i mod N
//                             (HeldPoses(board_type), N = 16: calibration_scenes.h),
//                             like a technician moving the board between
//                             captures; the platter still turns with the turntable
//     platter_board           no object; a chessboard (or ChArUco) lying on the
//                             platter (PlatterBoardScene: its centre 20 mm off
//                             the axis), turning with the turntable, so captures
//                             after MoveTo show it turned (turntable axis calibration)
//   object                  carved_box | egg | embroidery | mesh | none  (carved_box)
//                           (ignored by the board scenes, as are the object_* and
//                           mesh_* keys)
//   object_position_mm      x,y: where the object stands on the platter at turntable
//                           angle 0, world mm; within the platter's 150 mm radius (0,0)
//   object_yaw_deg          its turn about the axis there, degrees, |·| ≤ 360 (0)
//   object_rotation_deg     rx,ry,rz: the pose it is laid in (on its side: 90,0,0;
//                           upside down: 180,0,0): the object turned about x, then
//                           y, then z (fixed axes), degrees, each |·| ≤ 360, then
//                           seated on the platter, centred (ObjectOptions::
//                           rotation_rad, station.h), before object_yaw_deg (0,0,0)
//   turn                    which turn of a scan the cameras see, 1…999 (1): the
//                           daemon sets it when a scan adds a turn to a session
//                           (craftscanctl scan --add-to): the operator has laid
//                           the object in another pose. Turn 1: object_rotation_deg;
//                           turn t ≥ 2: the (t−1)-th pose of turn_rotations_deg
//                           (its last pose for later turns)
//   turn_rotations_deg      rx,ry,rz[;rx,ry,rz…]: the poses of turns 2, 3, … as
//                           object_rotation_deg (each angle |·| ≤ 360), at most 64
//                           (90,0,0: laid on its side)
// object mesh: a PLY triangle mesh (ply.h; e.g. ../shared/data/meshes/owl.ply),
// read when the driver instance is created:
//   mesh                    the PLY file's absolute path (required for object mesh)
//   mesh_size_mm            largest extent of the placed mesh, mm, (0, 1e4];
//                           or
//   mesh_scale              mm per file unit, (0, 1e6]   (1: the file is in mm)
//                           (not both)
//   mesh_rotation_deg       rx,ry,rz: the file's coordinates turned about x, then y,
//                           then z (fixed axes), degrees, before placing; 90,0,0
//                           turns a +Y-up file +Z-up                   (0,0,0)
//   mesh_surface            stone | wood | painted | fabric (MeshSurface, station.h),
//                           seeded by `seed`                           (stone)
// The mesh is then seated: its bounding box centred on the object's axis, its
// lowest point on the platter. mesh_* keys with another object are refused.
// List values are comma-separated numbers (the daemon passes scalars only).
//   projector               0|1: a pattern projector 30 mm above the middle of
//                           the camera bar, aimed at the rig's target
//                           (ProjectorOptions, station.h; scene object only) (0)
//   image_size              WxH, px; the default rig scaled to it     (1280x1024)
//   seed                    scene textures and sensor noise           (1)
//   threads                 render threads, 1…256                     (1)
//   technician              0|1: held_board: a simulated person holds the
//                           board instead of a new pose per frame: frame id i
//                           is i / technician_fps seconds into their moves
//                           (TechnicianAt, technician.h: moves blurred, holds,
//                           out of view, too close), frame stamps in that time;
//                           platter_board: the person lays the board on the
//                           platter first (PlatterTechnicianAt: empty platter,
//                           sliding, adjusting, then lying; leaning in once) (0)
//   technician_fps          frames per simulated second, (0, 60]           (8)
//   supersampling           s: s×s samples per pixel, 1…4 (1 = point sampled:
//                           a quarter of the rays, board corners ~2× noisier) (2)
//   turntable_speed_deg_s   0 = moves are instantaneous, else deg/s   (0)
// The board of the board scenes (ignored by `object`). It must be the board
// the detector is told about (the calibration's BoardSpec): nothing else
// tells a chessboard's square size.
//   board_type              chessboard | charuco                      (chessboard)
//   board_cols, board_rows  chessboard: inner corners per row / column;
//                           charuco: squares per row / column
//   board_square_mm         edge of a square, mm
//   board_marker_mm         charuco: marker edge, mm, < square  (square · 2/3)
//   board_dictionary        charuco: OpenCV predefined ArUco dictionary number
//                           (cv::aruco::PREDEFINED_DICTIONARY_NAME) (1 = DICT_4X4_100)
// Defaults (DefaultSimBoard; calibration_scenes.h), each key overriding one field:
//   held_board     chessboard 9×6, 8 mm (HeldChessboard: what the poses are made for)
//                  charuco 16×12, 12 mm, 8 mm markers (HeldCharuco)
//   platter_board  chessboard 9×6, 12 mm (PlatterChessboard)
//                  charuco 10×7, 15 mm, 10 mm markers (PlatterCharuco)
// The board must be a valid BoardSpec. On the platter it must also lie on it
// (PlatterBoardReachMm ≤ the 150 mm platter radius) and a chessboard must not
// be 180°-symmetric (board_cols + board_rows odd): the turntable axis needs
// its corner order. A held board too large for the view is accepted; its
// frames then show it cut off, as a real one would be.
// Errors name the key and, for the mesh keys, the file. A mesh that cannot be
// used (no such file, not PLY, malformed, no triangles) fails the driver
// instance's creation (CreateSimInstance: kInvalidArgument, "sim driver
// config key 'mesh': PLY '<path>': …").
// Fault knobs:
//   drop_frame_every N      frame ids that are multiples of N (N ≥ 2) are
//                           dropped: Capture returns the next id     (0 = off)
//   stall_ms T              each Capture takes T ms; over its timeout it
//                           returns kTimeout                          (0)
//   disconnect_after N      after N frames per connection, captures return
//                           kDeviceLost until Reconnect()             (0 = off)
//   reconnect_failures K    the first K reconnect attempts after each
//                           loss fail                                  (0)
//   turntable_alarm 0|1     every MoveTo fails with kFault (ALARM)     (0)
//   turntable_stall 0|1     moves never arrive: MoveTo times out       (0)
//   reconnect_attempts, reconnect_delay_ms, reconnect_max_delay_ms:
//                           the ReconnectPolicy (5, 200, 5000)
//
// Images: the render of frame id i uses SimStation::Render(scene, i) with
// the scene SimSceneOptions (held_board: SimHeldBoardSceneOptions(…, i)) at
// the turntable's angle, so a capture can be reproduced exactly from
// SimRigOptions and those (the driver renders images only, no ground truth).
// Exposure: the rig's linear exposure is exposure_us / 10000 · 10^(gain_db / 20)
// (10 ms at 0 dB = the renderer's default exposure 1.0); it must be ≤ 100.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/drivers/reconnect.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/sim/calibration_scenes.h"
#include "craftscan/sim/station.h"

namespace craftscan::sim {

enum class SimSceneType { kObject, kHeldBoard, kPlatterBoard };
std::string_view ToString(SimSceneType type);  // "object", "held_board", "platter_board"
bool SimSceneTypeFromString(std::string_view text, SimSceneType* type);

// The default board of a board scene (see board_* above).
BoardSpec DefaultSimBoard(SimSceneType scene, BoardSpec::Type type);

struct SimDriverOptions {
  SimSceneType scene = SimSceneType::kObject;
  ObjectType object = ObjectType::kCarvedBox;  // scene kObject only
  cv::Point2d object_position_mm{0, 0};        // on the platter at angle 0, world mm
  double object_yaw_deg = 0;                   // about the turntable axis
  cv::Vec3d object_rotation_deg{0, 0, 0};      // laid down: about x, then y, then z (fixed)
  int turn = 1;                                // the scan's turn being captured, ≥ 1
  std::vector<cv::Vec3d> turn_rotations_deg{{90, 0, 0}};  // the poses of turns 2, 3, …
  // object kMesh only:
  std::string mesh_path;                 // absolute
  double mesh_size_mm = 0;               // > 0: largest extent; 0: mesh_scale applies
  double mesh_scale = 1;                 // mm per file unit
  cv::Vec3d mesh_rotation_deg{0, 0, 0};  // about x, then y, then z (fixed axes)
  MeshSurface mesh_surface = MeshSurface::kStone;
  bool projector = false;  // scene kObject only: ProjectorOptions beside the rig
  // The board of the board scenes; SimDriverOptionsFromConfig fills in
  // DefaultSimBoard(scene, board_type) and applies the board_* keys.
  BoardSpec board = DefaultSimBoard(SimSceneType::kHeldBoard, BoardSpec::Type::kChessboard);
  cv::Size image_size{1280, 1024};  // px
  std::uint64_t seed = 1;
  int threads = 1;
  int supersampling = 2;             // 1…4
  bool technician = false;           // board scenes: a simulated person (technician.h)
  double technician_fps = 8;         // (0, 60]
  double turntable_speed_deg_s = 0;  // 0 = instantaneous
  int drop_frame_every = 0;          // 0 = off, else ≥ 2
  int stall_ms = 0;                  // ≥ 0
  int disconnect_after = 0;          // frames; 0 = off
  int reconnect_failures = 0;        // ≥ 0
  bool turntable_alarm = false;
  bool turntable_stall = false;
  drivers::ReconnectPolicy reconnect;

  // The pose the object lies in for `turn` (see the keys above).
  cv::Vec3d ObjectRotationDeg() const {
    if (turn <= 1 || turn_rotations_deg.empty()) return object_rotation_deg;
    const std::size_t i =
        std::min<std::size_t>(static_cast<std::size_t>(turn - 2), turn_rotations_deg.size() - 1);
    return turn_rotations_deg[i];
  }

  // Names the offending key (board problems name the board_* keys, mesh
  // problems the mesh_* key and the file). Does not open the file.
  bool IsValid(std::string* why) const;
};

// Parses and validates a driver config; false with *why naming the key.
bool SimDriverOptionsFromConfig(const drivers::DriverConfig& config, SimDriverOptions* options,
                                std::string* why);

// The rig the driver renders with (the default rig scaled to image_size,
// exposure from the camera settings) and the scene it shares.
RigOptions SimRigOptions(const SimDriverOptions& options,
                         const drivers::CameraSettings& settings = {});
// The shared scene: the object (placed; a mesh with its MeshOptions); the
// board on the platter; for held_board the board scene with the board
// disabled (each frame places it: below).
SceneOptions SimSceneOptions(const SimDriverOptions& options);
// held_board: the scene of frame `frame_id`, the board at held pose
// frame_id mod N placed for `station`'s rig (PlaceHeldBoard; it depends only
// on the rig's geometry, i.e. image_size), at turntable angle 0. Costs
// ~2 ms (the placement search); thread-safe.
SceneOptions SimHeldBoardSceneOptions(const SimDriverOptions& options, const SimStation& station,
                                      std::uint64_t frame_id);
double SimExposure(const drivers::CameraSettings& settings);  // the rig's linear exposure

}  // namespace craftscan::sim
