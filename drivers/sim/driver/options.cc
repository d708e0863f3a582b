// Config parsing for the sim driver plugin.
#include <charconv>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/sim/calibration_scenes.h"
#include "craftscan/sim/driver_options.h"

namespace craftscan::sim {
namespace {

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
  if (scene != SimSceneType::kObject) {
    std::string board_why;
    if (!board.IsValid(&board_why)) {
      return Fail(why,
                  "board_type/board_cols/board_rows/board_square_mm/board_marker_mm/"
                  "board_dictionary: " +
                      board_why);
    }
  }
  if (scene == SimSceneType::kPlatterBoard) {
    if (board.IsRotationallySymmetric()) {
      return Fail(why, "board_cols + board_rows must be odd for scene platter_board: a " +
                           Describe(board) +
                           " looks the same turned by 180°, so it cannot calibrate the "
                           "turntable axis");
    }
    const double radius_mm = SceneOptions().platter_radius_mm;
    if (PlatterBoardReachMm(board) > radius_mm) {
      return Fail(why, "board_cols/board_rows/board_square_mm: the " + Describe(board) +
                           " does not fit on the platter (it reaches " +
                           std::to_string(PlatterBoardReachMm(board)) + " mm from the axis, " +
                           "the platter's radius is " + std::to_string(radius_mm) + " mm)");
    }
  }
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
  std::vector<std::pair<std::string, std::string>> board_keys;
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
    } else if (key == "object") {
      ok = ObjectTypeFromString(value, &o.object) && o.object != ObjectType::kMesh;
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
