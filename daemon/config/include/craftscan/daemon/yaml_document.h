// Reading a configuration file as one YAML document, shared by craftscand's
// config (config.h) and craftscan-worker's: the yaml-cpp 0.7 workaround for
// malformed input, syntax errors with their line and column, and " (line N)"
// for messages about a node, the scalar parsers.
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>
#include <string_view>

namespace craftscan::daemon {

// Parses `text` as at most one YAML document into *root (an undefined node
// for empty text). False with *error (may be null): "YAML syntax error at
// line L, column C: …" or "the configuration must be one YAML document,
// found N". Never hangs on malformed input (yaml-cpp 0.7's LoadAll can).
bool LoadOneYamlDocument(const std::string& text, YAML::Node* root, std::string* error);

// The top of a config file: a mapping with `version: <version>`. False with
// *error: "empty configuration; …", "the configuration must be a mapping of
// keys …", "version: missing; …", "version: 2 is not supported; this
// <program> reads config version 1 (line 1)", "version: must be an integer …".
bool CheckConfigRoot(const YAML::Node& root, int version, std::string_view program,
                     std::string* error);

// " (line N)" for a node that came from a document, else "".
std::string AtYamlLine(const YAML::Node& node);

// The contents of the file at `path`; false with *error "<path>: cannot
// open: …" (or "is a directory", "read error").
bool ReadConfigText(const std::string& path, std::string* text, std::string* error);

// Scalar text of a config value: a whole decimal integer; a boolean (true,
// yes, on, 1 / false, no, off, 0). False for anything else.
bool ParseConfigInteger(std::string_view text, long long* value);
bool ParseConfigBool(std::string_view text, bool* value);

}  // namespace craftscan::daemon
