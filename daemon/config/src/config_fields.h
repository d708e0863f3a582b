// The table of craftscand's scalar config fields: one entry per YAML path
// with its text parser, range check and dump. config.cc walks the YAML and
// the environment with it; DaemonConfig::IsValid runs every check.
#pragma once

#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/daemon/config.h"

namespace craftscan::daemon::config_internal {

struct Field {
  std::string path;  // "scan.views"
  // A list of strings (YAML sequence; ':'-separated in the environment).
  bool is_list = false;
  // Values that are written quoted in the dump (strings).
  bool quoted = false;
  // Parse text into the field; *what gets the problem (without the path).
  std::function<bool(std::string_view text, DaemonConfig& config, std::string* what)> set;
  std::function<bool(const std::vector<std::string>& items, DaemonConfig& config,
                     std::string* what)>
      set_list;
  // Range check of the current value, same messages as set.
  std::function<bool(const DaemonConfig& config, std::string* what)> check;
  // The value as YAML scalar text (scalars) or items (lists).
  std::function<std::string(const DaemonConfig& config)> get;
  std::function<std::vector<std::string>(const DaemonConfig& config)> get_list;
};

// Every field, in schema order (the dump's order).
const std::vector<Field>& Fields();
// The field at `path`, or null.
const Field* FindField(std::string_view path);
// Sections (YAML mappings) of the schema, e.g. "dds", "calibration.board".
const std::vector<std::string>& Sections();
// "CRAFTSCAN_" + the path upper-cased with '.' → '_'.
std::string EnvironmentVariable(std::string_view path);
// "'text'", or "nothing" for empty text: the end of "…, got X" messages.
std::string Got(std::string_view text);
// Shortest text that reads back as the same double; integers without ".0".
std::string FormatNumber(double value);

}  // namespace craftscan::daemon::config_internal
