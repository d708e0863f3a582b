#include "config_fields.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/aruco/dictionary.hpp>
#include <utility>

#include "craftscan/daemon/yaml_document.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"

namespace craftscan::daemon::config_internal {
namespace {

template <typename T>
using Ref = std::function<T&(DaemonConfig&)>;

// Read access through the same accessor as writes; the accessor only forms a
// reference, the value is not modified.
template <typename T>
const T& Read(Ref<T> ref, const DaemonConfig& config) {
  return ref(const_cast<DaemonConfig&>(config));
}

bool ParseInteger(std::string_view text, long long* value) {
  return ParseConfigInteger(text, value);
}

bool ParseReal(std::string_view text, double* value) {
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, *value, std::chars_format::general);
  return !text.empty() && ec == std::errc() && ptr == end && std::isfinite(*value);
}

bool ParseBool(std::string_view text, bool* value) { return ParseConfigBool(text, value); }

Field IntField(std::string path, Ref<int> ref, int lo, int hi) {
  const std::string expect =
      "must be an integer in " + std::to_string(lo) + ".." + std::to_string(hi);
  Field f;
  f.path = std::move(path);
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    long long v = 0;
    if (!ParseInteger(text, &v) || v < lo || v > hi) {
      *what = expect + ", got " + Got(text);
      return false;
    }
    ref(c) = static_cast<int>(v);
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    const int v = Read(ref, c);
    if (v >= lo && v <= hi) return true;
    *what = expect + ", got " + Got(std::to_string(v));
    return false;
  };
  f.get = [=](const DaemonConfig& c) { return std::to_string(Read(ref, c)); };
  return f;
}

// A closed or half-open interval of doubles.
struct Interval {
  double lo, hi;
  bool lo_open = false;  // lo itself excluded
  bool Contains(double v) const {
    return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  }
  std::string Describe() const {
    return (lo_open ? "(" : "[") + FormatNumber(lo) + ", " + FormatNumber(hi) + "]";
  }
};

Field RealField(std::string path, Ref<double> ref, Interval range) {
  const std::string expect = "must be a number in " + range.Describe();
  Field f;
  f.path = std::move(path);
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    double v = 0;
    if (!ParseReal(text, &v) || !range.Contains(v)) {
      *what = expect + ", got " + Got(text);
      return false;
    }
    ref(c) = v;
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    const double v = Read(ref, c);
    if (range.Contains(v)) return true;
    *what = expect + ", got " + Got(FormatNumber(v));
    return false;
  };
  f.get = [=](const DaemonConfig& c) { return FormatNumber(Read(ref, c)); };
  return f;
}

Field BoolField(std::string path, Ref<bool> ref) {
  Field f;
  f.path = std::move(path);
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    bool v = false;
    if (!ParseBool(text, &v)) {
      *what = "must be true or false, got " + Got(text);
      return false;
    }
    ref(c) = v;
    return true;
  };
  f.check = [](const DaemonConfig&, std::string*) { return true; };
  f.get = [=](const DaemonConfig& c) { return std::string(Read(ref, c) ? "true" : "false"); };
  return f;
}

// A string field whose values `valid` accepts; `expect` completes "must be …".
Field StringField(std::string path, Ref<std::string> ref, bool (*valid)(std::string_view),
                  std::string expect) {
  expect = "must be " + expect;
  Field f;
  f.path = std::move(path);
  f.quoted = true;
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    if (!valid(text)) {
      *what = expect + ", got " + Got(text);
      return false;
    }
    ref(c) = std::string(text);
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    if (valid(Read(ref, c))) return true;
    *what = expect + ", got " + Got(Read(ref, c));
    return false;
  };
  f.get = [=](const DaemonConfig& c) { return Read(ref, c); };
  return f;
}

// An enum field with ToString / FromString functions and its value names.
template <typename E>
Field EnumField(std::string path, Ref<E> ref, std::string_view (*to_string)(E),
                bool (*from_string)(std::string_view, E*), std::vector<E> values) {
  std::string expect = "must be one of";
  for (std::size_t i = 0; i < values.size(); ++i) {
    expect += (i == 0 ? " " : ", ") + std::string(to_string(values[i]));
  }
  Field f;
  f.path = std::move(path);
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    E v{};
    if (!from_string(text, &v)) {
      *what = expect + "; got " + Got(text);
      return false;
    }
    ref(c) = v;
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    if (std::find(values.begin(), values.end(), Read(ref, c)) != values.end()) return true;
    *what = expect + "; got value " + std::to_string(static_cast<int>(Read(ref, c)));
    return false;
  };
  f.get = [=](const DaemonConfig& c) { return std::string(to_string(Read(ref, c))); };
  return f;
}

bool IsAbsolutePath(std::string_view text) { return !text.empty() && text.front() == '/'; }
bool IsEmptyOrAbsolutePath(std::string_view text) { return text.empty() || IsAbsolutePath(text); }

bool IsIdentifier(std::string_view text, std::size_t max_length) {
  if (text.empty() || text.size() > max_length) return false;
  return std::all_of(text.begin(), text.end(), [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
           ch == '_';
  });
}
// Starting with a letter: the station id is a token of DDS/ROS 2 topic names
// (dds::IsValidStationId), where a leading digit is refused.
bool IsStationId(std::string_view text) {
  return IsIdentifier(text, 32) &&
         ((text[0] >= 'a' && text[0] <= 'z') || (text[0] >= 'A' && text[0] <= 'Z'));
}
bool IsDriverName(std::string_view text) { return IsIdentifier(text, 64); }
// As craftscan::dds::IsValidSiteId (a DDS partition name).
bool IsSiteName(std::string_view text) {
  if (text.empty() || text.size() > 64) return false;
  return std::all_of(text.begin(), text.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-';
  });
}

// Valid UTF-8 (shortest forms, no surrogates) without control characters,
// at most 1024 bytes: text written into every model's metadata.
bool IsRightsText(std::string_view text) {
  if (text.size() > 1024) return false;
  for (std::size_t i = 0; i < text.size();) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c < 0x20 || c == 0x7f) return false;
    if (c < 0x80) {
      ++i;
      continue;
    }
    const int extra = c >= 0xc2 && c <= 0xdf   ? 1
                      : c >= 0xe0 && c <= 0xef ? 2
                      : c >= 0xf0 && c <= 0xf4 ? 3
                                               : -1;
    if (extra < 0 || i + static_cast<std::size_t>(extra) >= text.size()) return false;
    unsigned code = c & (0x3fu >> extra);
    for (int k = 1; k <= extra; ++k) {
      const auto t = static_cast<unsigned char>(text[i + static_cast<std::size_t>(k)]);
      if ((t & 0xc0) != 0x80) return false;
      code = (code << 6) | (t & 0x3fu);
    }
    if ((extra == 2 && (code < 0x800 || (code >= 0xd800 && code <= 0xdfff))) ||
        (extra == 3 && (code < 0x10000 || code > 0x10ffff)) || (code >= 0x80 && code < 0xa0))
      return false;
    i += static_cast<std::size_t>(extra) + 1;
  }
  return true;
}

Field PluginPathField() {
  auto check_items = [](const std::vector<std::string>& items, std::string* what) {
    if (items.empty()) {
      *what = "must list at least one directory";
      return false;
    }
    for (std::size_t i = 0; i < items.size(); ++i) {
      if (!IsAbsolutePath(items[i]) || items[i].find(':') != std::string::npos) {
        *what = "entry " + std::to_string(i + 1) +
                " must be an absolute directory without ':', got " + Got(items[i]);
        return false;
      }
    }
    return true;
  };
  Field f;
  f.path = "plugins.path";
  f.is_list = true;
  f.quoted = true;
  f.set_list = [=](const std::vector<std::string>& items, DaemonConfig& c, std::string* what) {
    if (!check_items(items, what)) return false;
    c.plugins.path = items;
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    return check_items(c.plugins.path, what);
  };
  f.get_list = [](const DaemonConfig& c) { return c.plugins.path; };
  return f;
}

Field ExposureBracketField() {
  auto check_items = [](const std::vector<double>& items, std::string* what) {
    return IsValidExposureBracket(items, what);
  };
  Field f;
  f.path = "scan.exposure_bracket";
  f.is_list = true;
  f.set_list = [=](const std::vector<std::string>& items, DaemonConfig& c, std::string* what) {
    std::vector<double> values;
    for (std::size_t i = 0; i < items.size(); ++i) {
      double v = 0;
      if (!ParseReal(items[i], &v)) {
        *what = "entry " + std::to_string(i + 1) + " must be a number, got " + Got(items[i]);
        return false;
      }
      values.push_back(v);
    }
    if (!check_items(values, what)) return false;
    c.scan.exposure_bracket = values;
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    return check_items(c.scan.exposure_bracket, what);
  };
  f.get_list = [](const DaemonConfig& c) {
    std::vector<std::string> items;
    for (double v : c.scan.exposure_bracket) items.push_back(FormatNumber(v));
    return items;
  };
  return f;
}

// OpenCV's predefined ArUco dictionaries, by the names of its enum.
struct NamedDictionary {
  std::string_view name;
  int id;
};
constexpr std::array<NamedDictionary, 21> kDictionaries = {{
    {"DICT_4X4_50", cv::aruco::DICT_4X4_50},
    {"DICT_4X4_100", cv::aruco::DICT_4X4_100},
    {"DICT_4X4_250", cv::aruco::DICT_4X4_250},
    {"DICT_4X4_1000", cv::aruco::DICT_4X4_1000},
    {"DICT_5X5_50", cv::aruco::DICT_5X5_50},
    {"DICT_5X5_100", cv::aruco::DICT_5X5_100},
    {"DICT_5X5_250", cv::aruco::DICT_5X5_250},
    {"DICT_5X5_1000", cv::aruco::DICT_5X5_1000},
    {"DICT_6X6_50", cv::aruco::DICT_6X6_50},
    {"DICT_6X6_100", cv::aruco::DICT_6X6_100},
    {"DICT_6X6_250", cv::aruco::DICT_6X6_250},
    {"DICT_6X6_1000", cv::aruco::DICT_6X6_1000},
    {"DICT_7X7_50", cv::aruco::DICT_7X7_50},
    {"DICT_7X7_100", cv::aruco::DICT_7X7_100},
    {"DICT_7X7_250", cv::aruco::DICT_7X7_250},
    {"DICT_7X7_1000", cv::aruco::DICT_7X7_1000},
    {"DICT_ARUCO_ORIGINAL", cv::aruco::DICT_ARUCO_ORIGINAL},
    {"DICT_APRILTAG_16h5", cv::aruco::DICT_APRILTAG_16h5},
    {"DICT_APRILTAG_25h9", cv::aruco::DICT_APRILTAG_25h9},
    {"DICT_APRILTAG_36h10", cv::aruco::DICT_APRILTAG_36h10},
    {"DICT_APRILTAG_36h11", cv::aruco::DICT_APRILTAG_36h11},
}};

Field DictionaryField(const std::string& prefix, Ref<BoardSpec> board) {
  const std::string expect = "must be an ArUco dictionary name (DICT_4X4_50 … " +
                             std::string(kDictionaries.back().name) + ") or its number 0.." +
                             std::to_string(kDictionaries.size() - 1);
  auto known = [](int id) { return id >= 0 && id < static_cast<int>(kDictionaries.size()); };
  Field f;
  f.path = prefix + ".dictionary";
  f.set = [=](std::string_view text, DaemonConfig& c, std::string* what) {
    for (const NamedDictionary& d : kDictionaries) {
      if (d.name == text) {
        board(c).aruco_dictionary = d.id;
        return true;
      }
    }
    long long id = -1;
    if (!ParseInteger(text, &id) || !known(static_cast<int>(id)) || id != static_cast<int>(id)) {
      *what = expect + ", got " + Got(text);
      return false;
    }
    board(c).aruco_dictionary = static_cast<int>(id);
    return true;
  };
  f.check = [=](const DaemonConfig& c, std::string* what) {
    const int id = board(const_cast<DaemonConfig&>(c)).aruco_dictionary;
    if (known(id)) return true;
    *what = expect + ", got " + Got(std::to_string(id));
    return false;
  };
  f.get = [=](const DaemonConfig& c) {
    const int id = board(const_cast<DaemonConfig&>(c)).aruco_dictionary;
    return known(id) ? std::string(kDictionaries[static_cast<std::size_t>(id)].name)
                     : std::to_string(id);
  };
  return f;
}

std::vector<Field> MakeFields() {
  constexpr double kMax = 1e4;  // mm: larger than any station
  std::vector<Field> f;
  f.push_back(StringField(
      "station", [](DaemonConfig& c) -> std::string& { return c.station; }, IsStationId,
      "1 to 32 characters of A-Z, a-z, 0-9, _, starting with a letter"));
  f.push_back(StringField(
      "site", [](DaemonConfig& c) -> std::string& { return c.site; }, IsSiteName,
      "1 to 64 characters of A-Z, a-z, 0-9, _, -"));
  f.push_back(StringField(
      "data_dir", [](DaemonConfig& c) -> std::string& { return c.data_dir; }, IsAbsolutePath,
      "an absolute path"));
  f.push_back(EnumField<LogLevel>(
      "log_level", [](DaemonConfig& c) -> LogLevel& { return c.log_level; }, drivers::ToString,
      LogLevelFromString,
      {LogLevel::kDebug, LogLevel::kInfo, LogLevel::kWarning, LogLevel::kError}));
  f.push_back(IntField(
      "dds.domain", [](DaemonConfig& c) -> int& { return c.dds.domain; }, 0,
      230));  // dds::kMaxDomainId: the participant refuses more
  f.push_back(StringField(
      "dds.config_file", [](DaemonConfig& c) -> std::string& { return c.dds.config_file; },
      IsEmptyOrAbsolutePath, "an absolute path or \"\""));
  f.push_back(StringField(
      "auth.tokens_file", [](DaemonConfig& c) -> std::string& { return c.auth.tokens_file; },
      IsAbsolutePath, "an absolute path"));
  f.push_back(PluginPathField());
  f.push_back(StringField(
      "devices.camera.driver",
      [](DaemonConfig& c) -> std::string& { return c.devices.camera.driver; }, IsDriverName,
      "a driver name of 1 to 64 characters of A-Z, a-z, 0-9, _"));
  f.push_back(StringField(
      "devices.turntable.driver",
      [](DaemonConfig& c) -> std::string& { return c.devices.turntable.driver; }, IsDriverName,
      "a driver name of 1 to 64 characters of A-Z, a-z, 0-9, _"));
  // The board held in front of the cameras (calibrate) and the one lying on
  // the platter (calibrate-turntable): same fields.
  auto board_fields = [&](const std::string& prefix, Ref<BoardSpec> board) {
    f.push_back(EnumField<BoardSpec::Type>(
        prefix + ".type", [board](DaemonConfig& c) -> BoardSpec::Type& { return board(c).type; },
        craftscan::ToString, BoardTypeFromString,
        {BoardSpec::Type::kChessboard, BoardSpec::Type::kCharuco}));
    f.push_back(IntField(
        prefix + ".cols", [board](DaemonConfig& c) -> int& { return board(c).cols; }, 2, 100));
    f.push_back(IntField(
        prefix + ".rows", [board](DaemonConfig& c) -> int& { return board(c).rows; }, 2, 100));
    f.push_back(RealField(prefix + ".square_mm",
                          [board](DaemonConfig& c) -> double& { return board(c).square_mm; },
                          {0, 1000, true}));
    f.push_back(RealField(prefix + ".marker_mm",
                          [board](DaemonConfig& c) -> double& { return board(c).marker_mm; },
                          {0, 1000}));
    f.push_back(DictionaryField(prefix, board));
  };
  board_fields("calibration.board",
               [](DaemonConfig& c) -> BoardSpec& { return c.calibration.board; });
  board_fields("calibration.turntable_board",
               [](DaemonConfig& c) -> BoardSpec& { return c.calibration.turntable_board; });
  f.push_back(RealField(
      "calibration.turntable_board_thickness_mm",
      [](DaemonConfig& c) -> double& { return c.calibration.turntable_board_thickness_mm; },
      {0, 100}));
  f.push_back(IntField(
      "calibration.views", [](DaemonConfig& c) -> int& { return c.calibration.views; },
      kMinCalibrationViews, 1000));
  f.push_back(RealField("calibration.max_rms_px",
                        [](DaemonConfig& c) -> double& { return c.calibration.max_rms_px; },
                        {0, 10, true}));
  f.push_back(BoolField("calibration.guided",
                        [](DaemonConfig& c) -> bool& { return c.calibration.guided; }));
  f.push_back(RealField("calibration.guided_max_s",
                        [](DaemonConfig& c) -> double& { return c.calibration.guided_max_s; },
                        {10, 3600}));
  f.push_back(IntField(
      "scan.views", [](DaemonConfig& c) -> int& { return c.scan.views; }, 2, 360));
  f.push_back(RealField("scan.step_deg", [](DaemonConfig& c) -> double& { return c.scan.step_deg; },
                        {0, 360, true}));
  f.push_back(IntField(
      "scan.settle_ms", [](DaemonConfig& c) -> int& { return c.scan.settle_ms; }, 0, 60000));
  f.push_back(RealField("scan.exposure_us",
                        [](DaemonConfig& c) -> double& { return c.scan.exposure_us; },
                        {0, 1e7, true}));
  f.push_back(RealField("scan.gain_db", [](DaemonConfig& c) -> double& { return c.scan.gain_db; },
                        {0, 48}));
  f.push_back(ExposureBracketField());
  f.push_back(
      BoolField("scan.auto_bracket", [](DaemonConfig& c) -> bool& { return c.scan.auto_bracket; }));
  f.push_back(IntField(
      "pipeline.threads", [](DaemonConfig& c) -> int& { return c.pipeline.threads; }, 1, 256));
  f.push_back(IntField(
      "pipeline.min_disparity", [](DaemonConfig& c) -> int& { return c.pipeline.min_disparity; },
      -4096, 4096));
  f.push_back(IntField(
      "pipeline.num_disparities",
      [](DaemonConfig& c) -> int& { return c.pipeline.num_disparities; }, 0, 4096));
  f.push_back(RealField("pipeline.min_texture_std",
                        [](DaemonConfig& c) -> double& { return c.pipeline.min_texture_std; },
                        {0, 255}));
  f.push_back(RealField("pipeline.match_gamma",
                        [](DaemonConfig& c) -> double& { return c.pipeline.match_gamma; }, {1, 4}));
  f.push_back(RealField("pipeline.volume_radius_mm",
                        [](DaemonConfig& c) -> double& { return c.pipeline.volume.radius_mm; },
                        {0, kMax, true}));
  f.push_back(RealField("pipeline.volume_min_height_mm",
                        [](DaemonConfig& c) -> double& { return c.pipeline.volume.min_height_mm; },
                        {-1000, kMax}));
  f.push_back(RealField("pipeline.volume_max_height_mm",
                        [](DaemonConfig& c) -> double& { return c.pipeline.volume.max_height_mm; },
                        {-1000, kMax}));
  f.push_back(RealField("pipeline.platter_radius_mm",
                        [](DaemonConfig& c) -> double& { return c.pipeline.platter_radius_mm; },
                        {0, kMax}));
  f.push_back(RealField("pipeline.platter_band_mm",
                        [](DaemonConfig& c) -> double& { return c.pipeline.platter_band_mm; },
                        {0, 1000}));
  f.push_back(RealField("pipeline.platter_normal_deg",
                        [](DaemonConfig& c) -> double& { return c.pipeline.platter_normal_deg; },
                        {0, 90}));
  f.push_back(IntField(
      "pipeline.depth_edge_radius_px",
      [](DaemonConfig& c) -> int& { return c.pipeline.depth_edge_radius_px; }, 0, 5));
  f.push_back(RealField("pipeline.depth_edge_jump_px",
                        [](DaemonConfig& c) -> double& { return c.pipeline.depth_edge_jump_px; },
                        {0, 1000, true}));
  f.push_back(IntField(
      "pipeline.aggregation_iterations",
      [](DaemonConfig& c) -> int& { return c.pipeline.aggregation_iterations; }, 0, 16));
  f.push_back(BoolField("pipeline.coarse_to_fine",
                        [](DaemonConfig& c) -> bool& { return c.pipeline.coarse_to_fine; }));
  f.push_back(RealField("pipeline.speckle_max_area_pct",
                        [](DaemonConfig& c) -> double& { return c.pipeline.speckle_max_area_pct; },
                        {0, 1}));
  f.push_back(RealField("pipeline.speckle_range_px",
                        [](DaemonConfig& c) -> double& { return c.pipeline.speckle_range_px; },
                        {0, 64, true}));
  f.push_back(RealField(
      "pipeline.free_space_tolerance_mm",
      [](DaemonConfig& c) -> double& { return c.pipeline.free_space_tolerance_mm; }, {0, 100}));
  f.push_back(BoolField("pipeline.mesh", [](DaemonConfig& c) -> bool& { return c.pipeline.mesh; }));
  f.push_back(EnumField<MeshMethod>(
      "pipeline.mesh_method", [](DaemonConfig& c) -> MeshMethod& { return c.pipeline.mesh_method; },
      craftscan::ToString, MeshMethodFromString, {MeshMethod::kPoisson, MeshMethod::kImplicit}));
  f.push_back(BoolField("pipeline.measure_box",
                        [](DaemonConfig& c) -> bool& { return c.pipeline.measure_box; }));
  f.push_back(IntField(
      "limits.max_command_bytes",
      [](DaemonConfig& c) -> int& { return c.limits.max_command_bytes; }, 1024, 16 << 20));
  f.push_back(IntField(
      "limits.queue_capacity", [](DaemonConfig& c) -> int& { return c.limits.queue_capacity; }, 1,
      16));
  f.push_back(
      BoolField("watchdog.enabled", [](DaemonConfig& c) -> bool& { return c.watchdog.enabled; }));
  f.push_back(EnumField<ReconstructionMode>(
      "reconstruction.mode",
      [](DaemonConfig& c) -> ReconstructionMode& { return c.reconstruction.mode; }, ToString,
      ReconstructionModeFromString,
      {ReconstructionMode::kLocal, ReconstructionMode::kRemote, ReconstructionMode::kAuto}));
  f.push_back(IntField(
      "reconstruction.offer_timeout_ms",
      [](DaemonConfig& c) -> int& { return c.reconstruction.offer_timeout_ms; }, 100, 600000));
  f.push_back(IntField(
      "reconstruction.max_remote_s",
      [](DaemonConfig& c) -> int& { return c.reconstruction.max_remote_s; }, 10, 86400));
  f.push_back(StringField(
      "deliverables.rights", [](DaemonConfig& c) -> std::string& { return c.deliverables.rights; },
      IsRightsText, "UTF-8 text without control characters, at most 1024 bytes"));
  return f;
}

}  // namespace

const std::vector<Field>& Fields() {
  static const std::vector<Field> fields = MakeFields();
  return fields;
}

const Field* FindField(std::string_view path) {
  for (const Field& f : Fields()) {
    if (f.path == path) return &f;
  }
  return nullptr;
}

const std::vector<std::string>& Sections() {
  static const std::vector<std::string> sections = {"dds",
                                                    "auth",
                                                    "plugins",
                                                    "devices",
                                                    "devices.camera",
                                                    "devices.turntable",
                                                    "calibration",
                                                    "calibration.board",
                                                    "calibration.turntable_board",
                                                    "scan",
                                                    "pipeline",
                                                    "limits",
                                                    "watchdog",
                                                    "reconstruction",
                                                    "deliverables"};
  return sections;
}

std::string EnvironmentVariable(std::string_view path) {
  std::string name = "CRAFTSCAN_";
  for (char ch : path) {
    name += ch == '.' ? '_' : static_cast<char>(ch >= 'a' && ch <= 'z' ? ch - 'a' + 'A' : ch);
  }
  return name;
}

std::string Got(std::string_view text) {
  return text.empty() ? "nothing" : "'" + std::string(text) + "'";
}

std::string FormatNumber(double value) {
  if (std::isfinite(value) && value == std::floor(value) && std::abs(value) < 1e15) {
    return std::to_string(static_cast<long long>(value));
  }
  std::array<char, 64> buffer{};
  auto [ptr, ec] = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return ec == std::errc() ? std::string(buffer.data(), ptr) : std::to_string(value);
}

}  // namespace craftscan::daemon::config_internal
