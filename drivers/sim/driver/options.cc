// Config parsing for the sim driver plugin.
#include <charconv>
#include <cmath>
#include <string>

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

bool SimDriverOptions::IsValid(std::string* why) const {
  if (image_size.width < 16 || image_size.height < 16 || image_size.width > 8192 ||
      image_size.height > 8192) {
    return Fail(why, "image_size must be between 16x16 and 8192x8192");
  }
  if (threads < 1 || threads > 256) return Fail(why, "threads must be in [1, 256]");
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
  for (const auto& [key, value] : config) {
    bool ok = true;
    if (key == "object") {
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
  rig.seed = options.seed;
  rig.exposure = SimExposure(settings);
  return rig;
}

SceneOptions SimSceneOptions(const SimDriverOptions& options) {
  SceneOptions scene;
  scene.object.type = options.object;
  scene.seed = options.seed;
  return scene;
}

}  // namespace craftscan::sim
