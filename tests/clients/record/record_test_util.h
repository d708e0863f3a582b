// Helpers shared by the craftscan-record tests: a temporary folder, the
// index.jsonl of a session folder, and a bit-exact image comparison.
#pragma once

#include <stdlib.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core/mat.hpp>

namespace craftscan::testing {

// A fresh folder under /tmp (mkdtemp), removed with everything in it.
class TempDir {
 public:
  TempDir() {
    char pattern[] = "/tmp/craftscan-record-test-XXXXXX";
    path_ = ::mkdtemp(pattern);
  }
  ~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

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

// Same size, type and bytes (NaN payloads included). Continuous Mats only.
inline bool SameBytes(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && a.isContinuous() && b.isContinuous() &&
         std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

}  // namespace craftscan::testing
