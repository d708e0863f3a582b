#include "craftscan/pipeline/registration/scan_dataset.h"

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>
#include <utility>

namespace craftscan {
namespace {

constexpr double kMetresToMm = 1000.0;
constexpr double kQuaternionNormTolerance = 1e-3;

bool ParseFinite(const std::string& text, double* value) {
  std::string_view digits = text;
  if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
  const char* end = digits.data() + digits.size();
  const auto r = std::from_chars(digits.data(), end, *value);
  return r.ec == std::errc() && r.ptr == end && std::isfinite(*value);
}

// Parses 7 pose numbers (tx ty tz qx qy qz qw) into world_from_scan.
bool ParsePose(const std::vector<std::string>& words, std::size_t first, const std::string& at,
               cv::Matx44d* world_from_scan, std::string* error) {
  std::array<double, 7> v{};
  for (std::size_t i = 0; i < 7; ++i) {
    if (!ParseFinite(words[first + i], &v[i])) {
      return Fail(error, at + "value '" + words[first + i] + "' is not a finite number");
    }
  }
  const double norm = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
  if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
    return Fail(error,
                at + "quaternion (qx qy qz qw) has norm " + std::to_string(norm) + ", expected 1");
  }
  // Scanalyze stores the conjugate: p_world = R(q)ᵀ · p_scan + t.
  const cv::Matx33d r = RotationFromQuaternion(v[6], v[3], v[4], v[5]).t();
  *world_from_scan = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*world_from_scan)(i, j) = r(i, j);
    (*world_from_scan)(i, 3) = v[static_cast<std::size_t>(i)] * kMetresToMm;
  }
  return true;
}

bool LoadStanfordScansImpl(const std::string& dir, std::vector<RangeScan>* scans,
                           std::string* error) {
  namespace fs = std::filesystem;
  if (scans == nullptr) return Fail(error, "LoadStanfordScans: null output");
  scans->clear();
  const fs::path conf = fs::path(dir) / "bun.conf";
  std::string where = "'";  // appended, not operator+: dodges a GCC 12 -Wrestrict false positive
  where += conf.string();
  where += "': ";
  std::error_code ec;
  if (!fs::is_regular_file(conf, ec)) return Fail(error, where + "no such file");
  std::ifstream in(conf);
  if (!in) return Fail(error, where + "cannot open");

  std::vector<RangeScan> out;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words_in(line);
    std::vector<std::string> words;
    for (std::string w; words_in >> w;) words.push_back(w);
    if (words.empty() || words[0][0] == '#') continue;
    const std::string at = where + "line " + std::to_string(line_number) + ": ";
    if (words[0] == "camera") {
      if (words.size() != 8) return Fail(error, at + "expected 'camera tx ty tz qx qy qz qw'");
      cv::Matx44d unused;
      if (!ParsePose(words, 1, at, &unused, error)) return false;
    } else if (words[0] == "bmesh") {
      if (words.size() != 9) {
        return Fail(error, at + "expected 'bmesh <file> tx ty tz qx qy qz qw', got " +
                               std::to_string(words.size()) + " fields");
      }
      RangeScan scan;
      scan.name = words[1];
      if (!ParsePose(words, 2, at, &scan.world_from_scan, error)) return false;
      const std::string ply = (fs::path(dir) / scan.name).string();
      std::string why;
      if (!ReadPly(ply, &scan.cloud, &why, kMetresToMm)) {
        return Fail(error, at + "scan '" + scan.name + "': " + why);
      }
      out.push_back(std::move(scan));
    } else {
      return Fail(error, at + "unknown keyword '" + words[0] + "' (expected camera or bmesh)");
    }
  }
  if (in.bad()) return Fail(error, where + "read error");
  if (out.empty()) return Fail(error, where + "no 'bmesh' lines");
  *scans = std::move(out);
  return true;
}

}  // namespace

bool LoadStanfordScans(const std::string& dir, std::vector<RangeScan>* scans, std::string* error) {
  try {
    return LoadStanfordScansImpl(dir, scans, error);
  } catch (const std::exception& e) {
    if (scans != nullptr) scans->clear();
    return Fail(error, "LoadStanfordScans '" + dir + "': " + e.what());
  }
}

}  // namespace craftscan
