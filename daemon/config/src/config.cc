#include "craftscan/daemon/config.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <utility>

#include "config_fields.h"
#include "craftscan/daemon/yaml_document.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"

extern char** environ;

namespace craftscan::daemon {
namespace {

using config_internal::Field;
using config_internal::Fields;
using config_internal::FindField;

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

std::string AtLine(const YAML::Node& node) { return AtYamlLine(node); }

std::string Join(const std::vector<std::string>& items, std::string_view separator) {
  std::string out;
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i > 0) out += separator;
    out += items[i];
  }
  return out;
}

std::size_t EditDistance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] != b[j - 1] ? 1 : 0)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

std::string LastSegment(std::string_view path) {
  const std::size_t dot = path.rfind('.');
  return std::string(dot == std::string_view::npos ? path : path.substr(dot + 1));
}

// Every key path the schema knows (fields, sections, device configs).
std::vector<std::string> KnownPaths() {
  std::vector<std::string> paths = {"version", "devices.camera.config", "devices.turntable.config"};
  for (const Field& f : Fields()) paths.push_back(f.path);
  for (const std::string& s : config_internal::Sections()) paths.push_back(s);
  return paths;
}

// " (did you mean 'x'?)" for a mistyped or misplaced key, else "".
std::string Suggestion(const std::string& path) {
  std::vector<std::string> same_leaf;
  std::string closest;
  std::size_t best = 3;  // suggest only within 2 edits
  for (const std::string& known : KnownPaths()) {
    if (LastSegment(known) == LastSegment(path)) same_leaf.push_back("'" + known + "'");
    const std::size_t d = EditDistance(known, path);
    if (d < best) {
      best = d;
      closest = known;
    }
  }
  if (!closest.empty()) return " (did you mean '" + closest + "'?)";
  if (!same_leaf.empty()) return " (did you mean " + Join(same_leaf, " or ") + "?)";
  return "";
}

bool IsSection(const std::string& path) {
  const auto& sections = config_internal::Sections();
  return std::find(sections.begin(), sections.end(), path) != sections.end();
}

// Walks the YAML document into a DaemonConfig with the field table.
class YamlReader {
 public:
  explicit YamlReader(DaemonConfig* config) : config_(config) {}

  bool ReadRoot(const YAML::Node& root, std::string* error) {
    if (!CheckConfigRoot(root, kConfigVersion, "craftscand", error)) return false;
    if (!ReadMap(root, "", error)) return false;
    return CheckDevices(error);
  }

 private:
  bool ReadMap(const YAML::Node& map, const std::string& section, std::string* error) {
    std::set<std::string> keys;
    for (const auto& entry : map) {
      const YAML::Node& key = entry.first;
      if (!key.IsScalar()) {
        return Fail(error, (section.empty() ? "configuration" : section) +
                               ": keys must be plain names" + AtLine(key));
      }
      const std::string path = section.empty() ? key.Scalar() : section + "." + key.Scalar();
      if (!keys.insert(key.Scalar()).second) {
        return Fail(error, path + ": given more than once" + AtLine(key));
      }
      seen_.insert(path);
      if (path == "version") continue;  // CheckConfigRoot
      if (!ReadEntry(path, key, entry.second, error)) return false;
    }
    return true;
  }

  bool ReadEntry(const std::string& path, const YAML::Node& key, const YAML::Node& value,
                 std::string* error) {
    if (path == "devices.camera.config")
      return ReadDriverConfig(path, value, &config_->devices.camera.config, error);
    if (path == "devices.turntable.config") {
      return ReadDriverConfig(path, value, &config_->devices.turntable.config, error);
    }
    if (const Field* field = FindField(path)) return ReadField(*field, value, error);
    if (IsSection(path)) {
      if (value.IsNull()) return true;  // "dds:" with nothing under it
      if (!value.IsMap()) return Fail(error, path + ": must be a mapping of keys" + AtLine(value));
      return ReadMap(value, path, error);
    }
    return Fail(error, path + ": unknown key" + Suggestion(path) + AtLine(key));
  }

  bool ReadField(const Field& field, const YAML::Node& value, std::string* error) {
    std::string what;
    if (field.is_list) {
      std::vector<std::string> items;
      if (!value.IsSequence()) {
        return Fail(error, field.path + ": must be a list, e.g. [/a, /b]" + AtLine(value));
      }
      for (const YAML::Node& item : value) {
        if (!item.IsScalar()) {
          return Fail(error, field.path + ": entries must be plain values" + AtLine(item));
        }
        items.push_back(item.Scalar());
      }
      if (!field.set_list(items, *config_, &what)) {
        return Fail(error, field.path + ": " + what + AtLine(value));
      }
      return true;
    }
    if (!value.IsScalar() && !value.IsNull()) {
      return Fail(error, field.path + ": must be a single value, not a " +
                             (value.IsMap() ? "mapping" : "list") + AtLine(value));
    }
    const std::string text = value.IsScalar() ? value.Scalar() : "";
    if (!field.set(text, *config_, &what)) {
      return Fail(error, field.path + ": " + what + AtLine(value));
    }
    return true;
  }

  bool ReadDriverConfig(const std::string& path, const YAML::Node& value,
                        drivers::DriverConfig* out, std::string* error) {
    out->clear();
    if (value.IsNull()) return true;
    if (!value.IsMap()) {
      return Fail(error, path + ": must be a mapping of driver settings" + AtLine(value));
    }
    for (const auto& entry : value) {
      if (!entry.first.IsScalar() || entry.first.Scalar().empty()) {
        return Fail(error, path + ": keys must be plain names" + AtLine(entry.first));
      }
      const std::string key_path = path + "." + entry.first.Scalar();
      if (!entry.second.IsScalar()) {
        return Fail(error, key_path + ": must be a single value (drivers take strings)" +
                               AtLine(entry.second));
      }
      if (!out->emplace(entry.first.Scalar(), entry.second.Scalar()).second) {
        return Fail(error, key_path + ": given more than once" + AtLine(entry.first));
      }
    }
    return true;
  }

  // A devices section replaces the simulated station: it must name both
  // devices and their drivers.
  bool CheckDevices(std::string* error) const {
    if (!seen_.count("devices")) return true;
    for (const char* device : {"devices.camera", "devices.turntable"}) {
      if (!seen_.count(device)) {
        return Fail(error, std::string(device) +
                               ": missing (give both camera and turntable, or omit devices "
                               "for the simulated station)");
      }
      if (!seen_.count(std::string(device) + ".driver")) {
        return Fail(error, std::string(device) + ".driver: missing");
      }
    }
    return true;
  }

  DaemonConfig* config_;
  std::set<std::string> seen_;  // key paths present in the file
};

bool ApplyEnvironment(const std::map<std::string, std::string>& env, DaemonConfig* config,
                      std::string* error) {
  for (const Field& field : Fields()) {
    const std::string variable = config_internal::EnvironmentVariable(field.path);
    const auto it = env.find(variable);
    if (it == env.end()) continue;
    std::string what;
    bool ok = false;
    if (field.is_list) {
      std::vector<std::string> items;
      std::istringstream in(it->second);
      for (std::string item; std::getline(in, item, ':');) {
        if (!item.empty()) items.push_back(item);
      }
      ok = field.set_list(items, *config, &what);
    } else {
      ok = field.set(it->second, *config, &what);
    }
    if (!ok) return Fail(error, variable + ": " + field.path + ": " + what);
  }
  return true;
}

// YAML emission of the config in schema order, grouping consecutive fields
// of the same section.
class Dumper {
 public:
  explicit Dumper(const DaemonConfig& config) : config_(config) {}

  std::string Dump() {
    out_ << YAML::BeginMap << YAML::Key << "version" << YAML::Value << kConfigVersion;
    std::vector<std::string> open;  // sections currently open
    for (const Field& field : Fields()) {
      std::vector<std::string> segments = Split(field.path);
      const std::string leaf = segments.back();
      segments.pop_back();
      std::size_t common = 0;
      while (common < open.size() && common < segments.size() && open[common] == segments[common]) {
        ++common;
      }
      while (open.size() > common) {
        out_ << YAML::EndMap;
        open.pop_back();
      }
      for (std::size_t i = common; i < segments.size(); ++i) {
        out_ << YAML::Key << segments[i] << YAML::Value << YAML::BeginMap;
        open.push_back(segments[i]);
      }
      EmitField(field, leaf);
      if (field.path == "devices.camera.driver") EmitDriverConfig(config_.devices.camera.config);
      if (field.path == "devices.turntable.driver") {
        EmitDriverConfig(config_.devices.turntable.config);
      }
    }
    while (!open.empty()) {
      out_ << YAML::EndMap;
      open.pop_back();
    }
    out_ << YAML::EndMap;
    return std::string(out_.c_str()) + "\n";
  }

 private:
  static std::vector<std::string> Split(const std::string& path) {
    std::vector<std::string> segments;
    std::istringstream in(path);
    for (std::string s; std::getline(in, s, '.');) segments.push_back(s);
    return segments;
  }

  void EmitField(const Field& field, const std::string& leaf) {
    out_ << YAML::Key << leaf << YAML::Value;
    if (field.is_list) {
      out_ << YAML::Flow << YAML::BeginSeq;
      for (const std::string& item : field.get_list(config_)) {
        if (field.quoted) {
          out_ << YAML::DoubleQuoted << item;
        } else {
          out_ << item;
        }
      }
      out_ << YAML::EndSeq;
    } else if (field.quoted) {
      out_ << YAML::DoubleQuoted << field.get(config_);
    } else {
      out_ << field.get(config_);
    }
  }

  void EmitDriverConfig(const drivers::DriverConfig& config) {
    out_ << YAML::Key << "config" << YAML::Value << YAML::BeginMap;
    for (const auto& [key, value] : config) {
      out_ << YAML::Key << key << YAML::Value << YAML::DoubleQuoted << value;
    }
    out_ << YAML::EndMap;
  }

  const DaemonConfig& config_;
  YAML::Emitter out_;
};

}  // namespace

bool LogLevelFromString(std::string_view text, LogLevel* level) {
  for (LogLevel l : {LogLevel::kDebug, LogLevel::kInfo, LogLevel::kWarning, LogLevel::kError}) {
    if (text == drivers::ToString(l)) {
      *level = l;
      return true;
    }
  }
  return false;
}

std::string_view ToString(ReconstructionMode mode) {
  switch (mode) {
    case ReconstructionMode::kLocal:
      return "local";
    case ReconstructionMode::kRemote:
      return "remote";
    case ReconstructionMode::kAuto:
      return "auto";
  }
  return "local";
}

bool ReconstructionModeFromString(std::string_view text, ReconstructionMode* mode) {
  for (ReconstructionMode m :
       {ReconstructionMode::kLocal, ReconstructionMode::kRemote, ReconstructionMode::kAuto}) {
    if (text == ToString(m)) {
      *mode = m;
      return true;
    }
  }
  return false;
}

std::string DefaultPluginDirectory() { return CRAFTSCAN_DEFAULT_PLUGIN_DIR; }

std::string PluginSettings::SearchPath() const { return Join(path, ":"); }

bool DaemonConfig::IsValid(std::string* why) const {
  std::string what;
  for (const Field& field : Fields()) {
    if (!field.check(*this, &what)) return Fail(why, field.path + ": " + what);
  }
  for (const auto* device : {&devices.camera, &devices.turntable}) {
    for (const auto& [key, value] : device->config) {
      if (key.empty()) {
        return Fail(why, std::string("devices.") +
                             (device == &devices.camera ? "camera" : "turntable") +
                             ".config: empty key");
      }
    }
  }
  if (!calibration.board.IsValid(&what)) {
    // BoardSpec's messages start with "board: ".
    return Fail(why, "calibration." + (what.rfind("board", 0) == 0 ? what : "board: " + what));
  }
  if (!calibration.turntable_board.IsValid(&what)) {
    return Fail(why,
                "calibration.turntable_" + (what.rfind("board", 0) == 0 ? what : "board: " + what));
  }
  if (calibration.turntable_board.type == BoardSpec::Type::kChessboard &&
      (calibration.turntable_board.cols + calibration.turntable_board.rows) % 2 == 0) {
    return Fail(why,
                "calibration.turntable_board: a chessboard needs cols + rows odd (not "
                "180-degree symmetric): the turntable axis fit needs its corner order");
  }
  if (scan.views * scan.step_deg > 360 + 1e-9) {
    return Fail(why, "scan.step_deg: " + std::to_string(scan.views) + " views × " +
                         config_internal::FormatNumber(scan.step_deg) +
                         "° = " + config_internal::FormatNumber(scan.views * scan.step_deg) +
                         "° is more than a full turn");
  }
  if (!scan.exposure_bracket.empty() && scan.exposure_us * scan.exposure_bracket.back() > 1e7) {
    return Fail(why,
                "scan.exposure_bracket: exposure_us × " +
                    config_internal::FormatNumber(scan.exposure_bracket.back()) + " = " +
                    config_internal::FormatNumber(scan.exposure_us * scan.exposure_bracket.back()) +
                    " µs is more than 10000000");
  }
  if (const double m = AutoBracketOptions{}.multiple;
      scan.auto_bracket && scan.exposure_bracket.empty() && scan.exposure_us * m > 1e7) {
    return Fail(why,
                "scan.auto_bracket: a dark view is also exposed × " +
                    config_internal::FormatNumber(m) + ", and exposure_us × " +
                    config_internal::FormatNumber(m) + " = " +
                    config_internal::FormatNumber(scan.exposure_us * m) +
                    " µs is more than 10000000: set auto_bracket: false or a shorter exposure");
  }
  if (!(pipeline.volume.max_height_mm > pipeline.volume.min_height_mm)) {
    return Fail(why, "pipeline.volume_max_height_mm: must be above volume_min_height_mm (" +
                         config_internal::FormatNumber(pipeline.volume.min_height_mm) + ")");
  }
  if (pipeline.num_disparities > 0 && !MatcherOptions(pipeline).IsValid(&what)) {
    return Fail(why, "pipeline: " + what);
  }
  if (!ReprojectionOptions(pipeline).IsValid(&what)) return Fail(why, "pipeline: " + what);
  if (!ReconstructionOptions(pipeline).IsValid(&what)) return Fail(why, "pipeline: " + what);
  return true;
}

bool ParseDaemonConfig(const std::string& yaml_text, const std::map<std::string, std::string>& env,
                       DaemonConfig* config, std::string* error) {
  DaemonConfig parsed;
  YAML::Node root;
  if (!LoadOneYamlDocument(yaml_text, &root, error)) return false;
  try {
    YamlReader reader(&parsed);
    if (!reader.ReadRoot(root, error)) return false;
  } catch (const YAML::Exception& e) {
    const std::string where =
        e.mark.is_null() ? std::string() : " at line " + std::to_string(e.mark.line + 1);
    return Fail(error, "YAML error" + where + ": " + e.msg);
  }
  if (!ApplyEnvironment(env, &parsed, error)) return false;
  if (!parsed.IsValid(error)) return false;
  *config = std::move(parsed);
  return true;
}

bool LoadDaemonConfig(const std::string& path, DaemonConfig* config, std::string* error) {
  std::string text;
  if (!ReadConfigText(path, &text, error)) return false;
  std::string why;
  if (!ParseDaemonConfig(text, CraftscanEnvironment(), config, &why)) {
    return Fail(error, path + ": " + why);
  }
  return true;
}

std::string DumpDaemonConfig(const DaemonConfig& config) { return Dumper(config).Dump(); }

std::vector<std::string> ConfigEnvironmentVariables() {
  std::vector<std::string> names;
  for (const Field& field : Fields()) {
    names.push_back(config_internal::EnvironmentVariable(field.path));
  }
  return names;
}

std::map<std::string, std::string> CraftscanEnvironment() {
  std::map<std::string, std::string> env;
  for (char** entry = environ; entry && *entry; ++entry) {
    const std::string_view text(*entry);
    const std::size_t eq = text.find('=');
    if (eq == std::string_view::npos || text.rfind("CRAFTSCAN_", 0) != 0) continue;
    env.emplace(std::string(text.substr(0, eq)), std::string(text.substr(eq + 1)));
  }
  return env;
}

ADCensusOptions MatcherOptions(const PipelineSettings& settings) {
  ADCensusOptions options;
  options.num_threads = settings.threads;
  options.aggregation_iterations = settings.aggregation_iterations;
  options.coarse_to_fine.enabled = settings.coarse_to_fine;
  if (settings.num_disparities > 0) {
    options.min_disparity = settings.min_disparity;
    options.num_disparities = settings.num_disparities;
  }
  return options;
}

ReprojectOptions ReprojectionOptions(const PipelineSettings& settings) {
  ReprojectOptions options;
  options.min_texture_std = settings.min_texture_std;
  return options;
}

ViewProcessorOptions ViewOptions(const PipelineSettings& settings) {
  ViewProcessorOptions options;
  options.num_threads = settings.threads;
  options.volume = settings.volume;
  options.platter_radius_mm = settings.platter_radius_mm;
  options.match_gamma = settings.match_gamma;
  options.min_texture_std = settings.min_texture_std;
  options.min_disparity = settings.min_disparity;
  options.num_disparities = settings.num_disparities;
  options.depth_edge_radius_px = settings.depth_edge_radius_px;
  options.depth_edge_jump_px = settings.depth_edge_jump_px;
  options.aggregation_iterations = settings.aggregation_iterations;
  options.coarse_to_fine = settings.coarse_to_fine;
  options.speckle_max_area_pct = settings.speckle_max_area_pct;
  options.speckle_range_px = settings.speckle_range_px;
  return options;
}

ScanOptions ReconstructionOptions(const PipelineSettings& settings) {
  ScanOptions options;
  options.num_threads = settings.threads;
  options.volume = settings.volume;
  options.conditioning.crop.platter_band_mm = settings.platter_band_mm;
  options.conditioning.crop.platter_normal_deg = settings.platter_normal_deg;
  options.mesh = settings.mesh;
  options.mesh_method = settings.mesh_method;
  options.free_space_check = settings.free_space_tolerance_mm > 0;
  if (options.free_space_check) options.visibility.tolerance_mm = settings.free_space_tolerance_mm;
  options.measure_box = settings.measure_box;
  return options;
}

}  // namespace craftscan::daemon
