// Helpers shared by the craftscan-record tests: the index.jsonl of a session
// folder. (Temporary folders: file_util.h; bit-exact images: mat_util.h.)
#pragma once

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace craftscan::testing {

// The lines of <folder>/index.jsonl that parse as JSON (none if absent).
inline std::vector<nlohmann::json> ReadIndex(const std::filesystem::path& folder) {
  std::vector<nlohmann::json> lines;
  std::ifstream in(folder / "index.jsonl");
  std::string line;
  while (std::getline(in, line)) {
    nlohmann::json parsed = nlohmann::json::parse(line, nullptr, false);
    if (!parsed.is_discarded()) lines.push_back(std::move(parsed));
  }
  return lines;
}

}  // namespace craftscan::testing
