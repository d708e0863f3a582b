// Config parsing for the sim driver plugin.
#include <charconv>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/calib3d.hpp>

#include "craftscan/sim/calibration_scenes.h"
#include "craftscan/sim/driver_options.h"

namespace craftscan::sim {
namespace {

constexpr double kRadPerDeg = std::numbers::pi / 180;

bool Fail(std::string* why, std::string message) {
  if (why) *why = std::move(message);
  return false;
}

template <typename T>
bool ParseNumber(const std::string& text, T* value) {
  const char* end = text.data() + text.size();
  auto [ptr, error] = std::from_chars(text.data(), end, *value);
  return error == std::errc() && ptr == end;
}

bool ParseBool(const std::string& text, bool* value) {
  const bool yes = text == "1" || text == "true" || text == "yes";
  const bool no = text == "0" || text == "false" || text == "no";
  if (yes || no) *value = yes;
  return yes || no;
}

// `count` comma-separated numbers, spaces around them allowed ("90, 0, 0").
bool ParseNumbers(const std::string& text, int count, double* values) {
  std::size_t begin = 0;
  for (int i = 0; i < count; ++i) {
    const std::size_t end = i + 1 < count ? text.find(',', begin) : text.size();
    if (end == std::string::npos) return false;
    std::string item = text.substr(begin, end - begin);
    item.erase(0, item.find_first_not_of(' '));
    item.erase(item.find_last_not_of(' ') + 1);
    if (!ParseNumber(item, &values[i])) return false;  // also refuses a further comma
    begin = end + 1;
  }
  return true;
}

// `turn_rotations_deg`: one or more "rx,ry,rz" separated by ';'.
bool ParseRotationList(const std::string& text, std::vector<cv::Vec3d>* rotations) {
  rotations->clear();
  std::size_t begin = 0;
  while (true) {
    const std::size_t end = text.find(';', begin);
    cv::Vec3d r;
    if (!ParseNumbers(text.substr(begin, end - begin), 3, r.val)) return false;
    rotations->push_back(r);
    if (end == std::string::npos) return rotations->size() <= 64;
    begin = end + 1;
  }
}

using KeyValues = std::vector<std::pair<std::string, std::string>>;

// " (mesh '<path>')" for messages about the mesh keys, once the file is known.
std::string OfMesh(const std::string& path) {
  return path.empty() ? std::string() : " (mesh '" + path + "')";
}

// The mesh keys, once `object` is known (they are refused with another object).
bool ApplyMeshKeys(const KeyValues& keys, SimDriverOptions* o, std::string* why) {
  for (const auto& [key, value] : keys) {
    if (key == "mesh") o->mesh_path = value;
  }
  if (!keys.empty() && o->object != ObjectType::kMesh) {
    return Fail(why, "sim driver config key '" + keys.front().first +
                         "' is only for object mesh (object is " +
                         std::string(ToString(o->object)) +
                         (o->mesh_path.empty() ? "" : "; mesh '" + o->mesh_path + "'") + ")");
  }
  const std::string of_mesh = OfMesh(o->mesh_path);
  bool size_given = false, scale_given = false;
  for (const auto& [key, value] : keys) {
    bool ok = true;
    if (key == "mesh") {
      continue;
    } else if (key == "mesh_size_mm") {
      ok = ParseNumber(value, &o->mesh_size_mm);
      size_given = true;
    } else if (key == "mesh_scale") {
      ok = ParseNumber(value, &o->mesh_scale);
      scale_given = true;
    } else if (key == "mesh_rotation_deg") {
      ok = ParseNumbers(value, 3, o->mesh_rotation_deg.val);
    } else if (key == "mesh_surface") {
      if (!MeshSurfaceFromString(value, &o->mesh_surface)) {
        return Fail(why, "sim driver config key 'mesh_surface': unknown surface '" + value + "'" +
                             of_mesh + "; expected stone, wood, painted or fabric");
      }
    } else {
      return Fail(why, "unknown sim driver config key '" + key + "'" + of_mesh);
    }
    if (!ok) {
      return Fail(why,
                  "bad value '" + value + "' for sim driver config key '" + key + "'" + of_mesh);
    }
  }
  if (size_given && scale_given) {
    return Fail(why, "sim driver config keys 'mesh_size_mm' and 'mesh_scale': give one, not both" +
                         of_mesh);
  }
  return true;
}

// The file's coordinates turned about x, then y, then z (fixed axes), as a
// Rodrigues vector (MeshOptions::rotation_rad).
cv::Vec3d RodriguesFromXyzDeg(const cv::Vec3d& deg) {
  auto axis = [&](int a) {
    const double c = std::cos(deg[a] * kRadPerDeg), s = std::sin(deg[a] * kRadPerDeg);
    cv::Matx33d r = cv::Matx33d::eye();
    const int i = (a + 1) % 3, j = (a + 2) % 3;
    r(i, i) = c;
    r(i, j) = -s;
    r(j, i) = s;
    r(j, j) = c;
    return r;
  };
  const cv::Matx33d R = axis(2) * axis(1) * axis(0);
  cv::Vec3d rotation_rad;
  cv::Rodrigues(R, rotation_rad);
  return rotation_rad;
}

// The mesh keys' values (object mesh); the file is read by Scene::Create.
bool MeshIsValid(const SimDriverOptions& o, std::string* why) {
  if (o.mesh_path.empty()) {
    return Fail(why,
                "sim driver config key 'mesh' is missing: object mesh needs the PLY file's "
                "absolute path");
  }
  const std::string of_mesh = OfMesh(o.mesh_path);
  if (!std::filesystem::path(o.mesh_path).is_absolute()) {
    return Fail(why, "sim driver config key 'mesh': '" + o.mesh_path +
                         "' is not an absolute path (the daemon's working folder is not "
                         "defined)");
  }
  if (!(o.mesh_size_mm == 0 || (o.mesh_size_mm > 0 && o.mesh_size_mm <= 1e4))) {
    return Fail(why, "mesh_size_mm must be in (0, 1e4]" + of_mesh);
  }
  if (o.mesh_size_mm == 0 && !(o.mesh_scale > 0 && o.mesh_scale <= 1e6)) {
    return Fail(why, "mesh_scale must be in (0, 1e6]" + of_mesh);
  }
  for (int i = 0; i < 3; ++i) {
    if (!(std::abs(o.mesh_rotation_deg[i]) <= 360)) {
      return Fail(why, "mesh_rotation_deg: each angle must be in [-360, 360]" + of_mesh);
    }
  }
  if (ToString(o.mesh_surface) == "unknown") {
    return Fail(why, "mesh_surface is not a known surface" + of_mesh);
  }
  return true;
}

}  // namespace

std::string_view ToString(SimSceneType type) {
  switch (type) {
    case SimSceneType::kObject:
      return "object";
    case SimSceneType::kHeldBoard:
      return "held_board";
    case SimSceneType::kPlatterBoard:
      return "platter_board";
  }
  return "unknown";
}

bool SimSceneTypeFromString(std::string_view text, SimSceneType* type) {
  for (SimSceneType t :
       {SimSceneType::kObject, SimSceneType::kHeldBoard, SimSceneType::kPlatterBoard}) {
    if (text == ToString(t)) {
      *type = t;
      return true;
    }
  }
  return false;
}

BoardSpec DefaultSimBoard(SimSceneType scene, BoardSpec::Type type) {
  const bool chess = type == BoardSpec::Type::kChessboard;
  if (scene == SimSceneType::kPlatterBoard) return chess ? PlatterChessboard() : PlatterCharuco();
  return chess ? HeldChessboard() : HeldCharuco();
}

bool SimDriverOptions::IsValid(std::string* why) const {
  if (image_size.width < 16 || image_size.height < 16 || image_size.width > 8192 ||
      image_size.height > 8192) {
    return Fail(why, "image_size must be between 16x16 and 8192x8192");
  }
  if (threads < 1 || threads > 256) return Fail(why, "threads must be in [1, 256]");
  if (supersampling < 1 || supersampling > 4) return Fail(why, "supersampling must be in [1, 4]");
  if (!(technician_fps > 0 && technician_fps <= 60)) {
    return Fail(why, "technician_fps must be in (0, 60]");
  }
  if (scene != SimSceneType::kObject) {
    std::string board_why;
    if (!board.IsValid(&board_why)) {
      return Fail(why,
                  "board_type/board_cols/board_rows/board_square_mm/board_marker_mm/"
                  "board_dictionary: " +
                      board_why);
    }
  }
  const double platter_radius_mm = SceneOptions().platter_radius_mm;
  if (scene == SimSceneType::kPlatterBoard) {
    if (board.IsRotationallySymmetric()) {
      return Fail(why, "board_cols + board_rows must be odd for scene platter_board: a " +
                           Describe(board) +
                           " looks the same turned by 180°, so it cannot calibrate the "
                           "turntable axis");
    }
    if (PlatterBoardReachMm(board) > platter_radius_mm) {
      return Fail(why, "board_cols/board_rows/board_square_mm: the " + Describe(board) +
                           " does not fit on the platter (it reaches " +
                           std::to_string(PlatterBoardReachMm(board)) + " mm from the axis, " +
                           "the platter's radius is " + std::to_string(platter_radius_mm) + " mm)");
    }
  }
  if (!(std::hypot(object_position_mm.x, object_position_mm.y) <= platter_radius_mm)) {
    return Fail(why, "object_position_mm must be finite and on the platter (within " +
                         std::to_string(platter_radius_mm) + " mm of the axis)");
  }
  if (!(std::abs(object_yaw_deg) <= 360)) return Fail(why, "object_yaw_deg must be in [-360, 360]");
  for (int i = 0; i < 3; ++i) {
    if (!(std::abs(object_rotation_deg[i]) <= 360)) {
      return Fail(why, "object_rotation_deg: each angle must be in [-360, 360] (rx,ry,rz)");
    }
  }
  if (turn < 1 || turn > 999) return Fail(why, "turn must be in [1, 999]");
  if (turn_rotations_deg.empty()) return Fail(why, "turn_rotations_deg: needs at least one pose");
  for (const cv::Vec3d& r : turn_rotations_deg) {
    for (int i = 0; i < 3; ++i) {
      if (!(std::abs(r[i]) <= 360)) {
        return Fail(why,
                    "turn_rotations_deg: each angle must be in [-360, 360] (rx,ry,rz;rx,ry,rz...)");
      }
    }
  }
  if (object == ObjectType::kMesh && !MeshIsValid(*this, why)) return false;
  if (!(turntable_speed_deg_s >= 0 && std::isfinite(turntable_speed_deg_s))) {
    return Fail(why, "turntable_speed_deg_s must be >= 0");
  }
  if (drop_frame_every != 0 && drop_frame_every < 2) {
    return Fail(why, "drop_frame_every must be 0 (off) or >= 2");
  }
  if (stall_ms < 0) return Fail(why, "stall_ms must be >= 0");
  if (disconnect_after < 0) return Fail(why, "disconnect_after must be >= 0");
  if (reconnect_failures < 0) return Fail(why, "reconnect_failures must be >= 0");
  std::string policy_why;
  if (!reconnect.IsValid(&policy_why)) return Fail(why, "reconnect: " + policy_why);
  return true;
}

bool SimDriverOptionsFromConfig(const drivers::DriverConfig& config, SimDriverOptions* options,
                                std::string* why) {
  SimDriverOptions o;
  // The board keys override fields of the scene's default board, known only
  // once `scene` and `board_type` are read: collect them first.
  BoardSpec::Type board_type = BoardSpec::Type::kChessboard;
  KeyValues board_keys;
  KeyValues mesh_keys;  // once `object` is known
  for (const auto& [key, value] : config) {
    bool ok = true;
    if (key == "scene") {
      ok = SimSceneTypeFromString(value, &o.scene);
    } else if (key == "board_type") {
      ok = BoardTypeFromString(value, &board_type);
    } else if (key.rfind("board_", 0) == 0) {
      board_keys.emplace_back(key, value);
      continue;
    } else if (key == "supersampling") {
      ok = ParseNumber(value, &o.supersampling);
    } else if (key == "technician") {
      int flag = 0;
      ok = ParseNumber(value, &flag) && (flag == 0 || flag == 1);
      o.technician = flag == 1;
    } else if (key == "technician_fps") {
      ok = ParseNumber(value, &o.technician_fps);
    } else if (key == "object") {
      ok = ObjectTypeFromString(value, &o.object);
    } else if (key == "mesh" || key.rfind("mesh_", 0) == 0) {
      mesh_keys.emplace_back(key, value);
      continue;
    } else if (key == "object_position_mm") {
      double xy[2];
      ok = ParseNumbers(value, 2, xy);
      o.object_position_mm = {xy[0], xy[1]};
    } else if (key == "object_yaw_deg") {
      ok = ParseNumber(value, &o.object_yaw_deg);
    } else if (key == "object_rotation_deg") {
      ok = ParseNumbers(value, 3, o.object_rotation_deg.val);
    } else if (key == "turn") {
      ok = ParseNumber(value, &o.turn);
    } else if (key == "turn_rotations_deg") {
      ok = ParseRotationList(value, &o.turn_rotations_deg);
    } else if (key == "image_size") {
      const auto x = value.find('x');
      ok = x != std::string::npos && ParseNumber(value.substr(0, x), &o.image_size.width) &&
           ParseNumber(value.substr(x + 1), &o.image_size.height);
    } else if (key == "seed") {
      ok = ParseNumber(value, &o.seed);
    } else if (key == "threads") {
      ok = ParseNumber(value, &o.threads);
    } else if (key == "turntable_speed_deg_s") {
      ok = ParseNumber(value, &o.turntable_speed_deg_s);
    } else if (key == "drop_frame_every") {
      ok = ParseNumber(value, &o.drop_frame_every);
    } else if (key == "stall_ms") {
      ok = ParseNumber(value, &o.stall_ms);
    } else if (key == "disconnect_after") {
      ok = ParseNumber(value, &o.disconnect_after);
    } else if (key == "reconnect_failures") {
      ok = ParseNumber(value, &o.reconnect_failures);
    } else if (key == "projector") {
      ok = ParseBool(value, &o.projector);
    } else if (key == "turntable_alarm") {
      ok = ParseBool(value, &o.turntable_alarm);
    } else if (key == "turntable_stall") {
      ok = ParseBool(value, &o.turntable_stall);
    } else if (key == "reconnect_attempts") {
      ok = ParseNumber(value, &o.reconnect.max_attempts);
    } else if (key == "reconnect_delay_ms" || key == "reconnect_max_delay_ms") {
      std::int64_t ms = 0;
      ok = ParseNumber(value, &ms);
      (key == "reconnect_delay_ms" ? o.reconnect.initial_delay : o.reconnect.max_delay) =
          std::chrono::milliseconds(ms);
    } else {
      return Fail(why, "unknown sim driver config key '" + key + "'");
    }
    if (!ok) return Fail(why, "bad value '" + value + "' for sim driver config key '" + key + "'");
  }
  if (!ApplyMeshKeys(mesh_keys, &o, why)) return false;
  o.board = DefaultSimBoard(o.scene, board_type);
  bool marker_given = false;
  for (const auto& [key, value] : board_keys) {
    bool ok = true;
    if (key == "board_cols") {
      ok = ParseNumber(value, &o.board.cols);
    } else if (key == "board_rows") {
      ok = ParseNumber(value, &o.board.rows);
    } else if (key == "board_square_mm") {
      ok = ParseNumber(value, &o.board.square_mm);
    } else if (key == "board_marker_mm") {
      ok = ParseNumber(value, &o.board.marker_mm);
      marker_given = true;
    } else if (key == "board_dictionary") {
      ok = ParseNumber(value, &o.board.aruco_dictionary);
    } else {
      return Fail(why, "unknown sim driver config key '" + key + "'");
    }
    if (!ok) return Fail(why, "bad value '" + value + "' for sim driver config key '" + key + "'");
  }
  if (o.board.type == BoardSpec::Type::kCharuco && !marker_given) {
    o.board.marker_mm = o.board.square_mm * 2 / 3;
  }
  if (!o.IsValid(why)) return false;
  *options = o;
  return true;
}

double SimExposure(const drivers::CameraSettings& settings) {
  return settings.exposure_us / 10000.0 * std::pow(10.0, settings.gain_db / 20.0);
}

RigOptions SimRigOptions(const SimDriverOptions& options, const drivers::CameraSettings& settings) {
  RigOptions rig;
  const double s = static_cast<double>(options.image_size.width) / rig.image_size.width;
  rig.image_size = options.image_size;
  rig.left.focal_px *= s;
  rig.right.focal_px *= s;
  rig.left.principal_offset_px *= s;
  rig.right.principal_offset_px *= s;
  rig.num_threads = options.threads;
  rig.supersampling = options.supersampling;
  rig.seed = options.seed;
  rig.exposure = SimExposure(settings);
  return rig;
}

SceneOptions SimSceneOptions(const SimDriverOptions& options) {
  SceneOptions scene;
  switch (options.scene) {
    case SimSceneType::kObject:
      scene.object.type = options.object;
      scene.object.position_mm = options.object_position_mm;
      scene.object.yaw_rad = options.object_yaw_deg * kRadPerDeg;
      if (const cv::Vec3d pose = options.ObjectRotationDeg(); pose != cv::Vec3d(0, 0, 0))
        scene.object.rotation_rad = RodriguesFromXyzDeg(pose);
      if (options.object == ObjectType::kMesh) {
        MeshOptions& mesh = scene.object.mesh;
        mesh.path = options.mesh_path;
        mesh.size_mm = options.mesh_size_mm;
        mesh.scale = options.mesh_scale;
        mesh.rotation_rad = RodriguesFromXyzDeg(options.mesh_rotation_deg);
        mesh.surface = options.mesh_surface;
      }
      if (options.projector) scene.lighting.projector = ProjectorOnCameraHead(RigOptions{});
      break;
    case SimSceneType::kHeldBoard:
      scene = BoardScene(options.board);
      scene.board.enabled = false;
      break;
    case SimSceneType::kPlatterBoard:
      scene = PlatterBoardScene(options.board);
      break;
  }
  scene.seed = options.seed;
  return scene;
}

SceneOptions SimHeldBoardSceneOptions(const SimDriverOptions& options, const SimStation& station,
                                      std::uint64_t frame_id) {
  const std::vector<HeldPose>& poses = HeldPoses(options.board.type);
  const HeldPose& pose = poses[frame_id % poses.size()];
  const HeldBoardPlacement placement = PlaceHeldBoard(station, options.board, pose);
  SceneOptions scene = HeldBoardScene(station, options.board, placement.rig_from_board);
  scene.seed = options.seed;
  return scene;
}

}  // namespace craftscan::sim
