#include "stereo_scene.h"

#include <cctype>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <utility>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/common/pfm.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Thrown inside the loader only, turned into the error string at its boundary.
struct SceneError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class SceneReader {
 public:
  SceneReader(fs::path dir, json doc) : dir_(std::move(dir)), doc_(std::move(doc)) {
    json_path_ = (dir_ / "scene.json").string();
  }

  bool Has(const char* key) const { return doc_.contains(key) && !doc_[key].is_null(); }

  std::string String(const char* key) const {
    if (!Has(key)) Fail("missing key \"" + std::string(key) + "\"");
    if (!doc_[key].is_string() || doc_[key].get<std::string>().empty()) {
      Fail("key \"" + std::string(key) + "\" must be a non-empty string");
    }
    return doc_[key].get<std::string>();
  }

  double Number(const char* key) const {
    if (!Has(key)) Fail("missing key \"" + std::string(key) + "\"");
    if (!doc_[key].is_number()) Fail("key \"" + std::string(key) + "\" must be a number");
    return doc_[key].get<double>();
  }

  long long Integer(const char* key) const {
    if (!Has(key)) Fail("missing key \"" + std::string(key) + "\"");
    const json& v = doc_[key];
    if (v.is_number_integer()) return v.get<long long>();
    if (v.is_number_float()) {
      const double d = v.get<double>();
      if (std::isfinite(d) && d == std::floor(d) && std::abs(d) < 1e9) {
        return static_cast<long long>(d);
      }
    }
    Fail("key \"" + std::string(key) + "\" must be an integer");
  }

  // Path of the file named by `key`, which must exist.
  fs::path File(const char* key) const {
    const fs::path path = dir_ / String(key);
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) {
      Fail("key \"" + std::string(key) + "\": file '" + path.string() + "' not found");
    }
    return path;
  }

  [[noreturn]] void Fail(const std::string& what) const {
    throw SceneError(json_path_ + ": " + what);
  }

 private:
  fs::path dir_;
  json doc_;
  std::string json_path_;
};

cv::Mat ReadImageUnchanged(const fs::path& path, const char* key) {
  cv::Mat image = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  if (image.empty()) {
    throw SceneError("'" + path.string() + "' (key \"" + key + "\"): unreadable image");
  }
  return image;
}

// To 8-bit with 1 or 3 channels: 16-bit scaled by 255/65535, alpha dropped.
cv::Mat To8Bit(cv::Mat image, const fs::path& path, const char* key) {
  if (image.depth() == CV_16U) {
    image.convertTo(image, CV_MAKETYPE(CV_8U, image.channels()), 255.0 / 65535.0);
  } else if (image.depth() != CV_8U) {
    throw SceneError("'" + path.string() + "' (key \"" + key +
                     "\"): unsupported pixel depth (need 8- or 16-bit)");
  }
  switch (image.channels()) {
    case 1:
    case 3:
      return image;
    case 4:
      cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
      return image;
    case 2: {  // grey + alpha
      cv::Mat grey;
      cv::extractChannel(image, grey, 0);
      return grey;
    }
    default:
      throw SceneError("'" + path.string() + "' (key \"" + key + "\"): unsupported channel count " +
                       std::to_string(image.channels()));
  }
}

cv::Mat LoadMask(const SceneReader& reader, const char* key) {
  const fs::path path = reader.File(key);
  cv::Mat mask = To8Bit(ReadImageUnchanged(path, key), path, key);
  // Palette PNGs (2001/2003 masks) arrive as BGR; white stays 255.
  if (mask.channels() == 3) cv::cvtColor(mask, mask, cv::COLOR_BGR2GRAY);
  return mask;
}

cv::Mat LoadGroundTruth(const SceneReader& reader) {
  const fs::path path = reader.File("gt");
  std::string ext = path.extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const bool is_pfm = ext == ".pfm";
  const double scale = is_pfm && !reader.Has("gt_scale") ? 1.0 : reader.Number("gt_scale");
  if (!(scale > 0) || !std::isfinite(scale)) reader.Fail("key \"gt_scale\" must be > 0");

  cv::Mat raw;
  if (is_pfm) {
    std::string error;
    if (!ReadPfm(path.string(), &raw, &error)) throw SceneError(error + " (key \"gt\")");
  } else {
    raw = ReadImageUnchanged(path, "gt");
    if (raw.depth() != CV_8U && raw.depth() != CV_16U && raw.depth() != CV_32F) {
      throw SceneError("'" + path.string() + "' (key \"gt\"): unsupported pixel depth");
    }
  }
  if (raw.channels() != 1) {
    throw SceneError("'" + path.string() + "' (key \"gt\"): ground truth must have one channel");
  }
  cv::Mat gt;
  raw.convertTo(gt, CV_32F, 1.0 / scale);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < gt.rows; ++y) {
    float* row = gt.ptr<float>(y);
    for (int x = 0; x < gt.cols; ++x) {
      if (!std::isfinite(row[x]) || row[x] == 0) row[x] = nan;
    }
  }
  return gt;
}

void CheckSize(const cv::Mat& image, const cv::Size& expected, const std::string& dir,
               const char* key) {
  if (image.size() != expected) {
    throw SceneError(dir + "/scene.json: \"" + key + "\" is " + std::to_string(image.cols) + "x" +
                     std::to_string(image.rows) + " but \"left\" is " +
                     std::to_string(expected.width) + "x" + std::to_string(expected.height));
  }
}

StereoScene LoadOrThrow(const std::string& dir_text) {
  const fs::path dir(dir_text);
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) {
    throw SceneError("scene folder '" + dir_text + "' does not exist or is not a folder");
  }
  const fs::path json_path = dir / "scene.json";
  if (!fs::is_regular_file(json_path, ec)) {
    throw SceneError("'" + json_path.string() + "' not found");
  }
  std::ifstream in(json_path);
  if (!in) throw SceneError("'" + json_path.string() + "' cannot be opened");
  json doc;
  try {
    doc = json::parse(in);
  } catch (const json::exception& e) {
    throw SceneError("'" + json_path.string() + "' is malformed JSON: " + e.what());
  }
  if (!doc.is_object()) throw SceneError("'" + json_path.string() + "' is not a JSON object");
  SceneReader reader(dir, std::move(doc));

  StereoScene scene;
  scene.directory = dir_text;
  if (reader.Has("name")) {
    scene.name = reader.String("name");
  } else {
    const fs::path normal = dir.lexically_normal();
    scene.name =
        (normal.has_filename() ? normal.filename() : normal.parent_path().filename()).string();
  }

  const long long ndisp = reader.Integer("ndisp");
  if (ndisp <= 0 || ndisp > 100000) {
    reader.Fail("key \"ndisp\" must be in 1..100000 (is " + std::to_string(ndisp) + ")");
  }
  scene.ndisp = static_cast<int>(ndisp);

  const fs::path left_path = reader.File("left");
  const fs::path right_path = reader.File("right");
  scene.left = To8Bit(ReadImageUnchanged(left_path, "left"), left_path, "left");
  scene.right = To8Bit(ReadImageUnchanged(right_path, "right"), right_path, "right");
  const cv::Size size = scene.left.size();
  CheckSize(scene.right, size, dir_text, "right");
  if (scene.left.channels() != scene.right.channels()) {
    cv::Mat& grey = scene.left.channels() == 1 ? scene.left : scene.right;
    cv::cvtColor(grey, grey, cv::COLOR_GRAY2BGR);
  }

  scene.gt = LoadGroundTruth(reader);
  {
    std::string ext = reader.File("gt").extension().string();
    for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    scene.gt_scale = ext == ".pfm" ? 0.0 : reader.Number("gt_scale");
  }
  CheckSize(scene.gt, size, dir_text, "gt");

  if (reader.Has("mask_nonocc")) {
    scene.mask_nonocc = LoadMask(reader, "mask_nonocc");
    CheckSize(scene.mask_nonocc, size, dir_text, "mask_nonocc");
  } else {
    cv::Mat valid = scene.gt == scene.gt;  // NaN ≠ NaN
    scene.mask_nonocc = valid;
  }
  if (reader.Has("mask_all")) {
    scene.mask_all = LoadMask(reader, "mask_all");
    CheckSize(scene.mask_all, size, dir_text, "mask_all");
  }
  if (reader.Has("mask_disc")) {
    scene.mask_disc = LoadMask(reader, "mask_disc");
    CheckSize(scene.mask_disc, size, dir_text, "mask_disc");
  }
  return scene;
}

}  // namespace

bool LoadStereoScene(const std::string& dir, StereoScene* scene, std::string* error) {
  std::string message;
  try {
    if (scene == nullptr) throw SceneError("LoadStereoScene: scene is null");
    *scene = LoadOrThrow(dir);
    return true;
  } catch (const SceneError& e) {
    message = e.what();
  } catch (const cv::Exception& e) {
    message = "scene '" + dir + "': OpenCV error: " + e.what();
  } catch (const std::exception& e) {
    message = "scene '" + dir + "': " + e.what();
  }
  if (error != nullptr) *error = std::move(message);
  return false;
}

DisparityMetrics EvaluateDisparity(const cv::Mat& disp, const cv::Mat& gt, const cv::Mat& mask) {
  if (disp.type() != CV_32FC1 || gt.type() != CV_32FC1) {
    throw std::invalid_argument("EvaluateDisparity: disp and gt must be CV_32FC1");
  }
  if (disp.size() != gt.size()) {
    throw std::invalid_argument("EvaluateDisparity: disp and gt differ in size");
  }
  if (!mask.empty() && (mask.type() != CV_8UC1 || mask.size() != gt.size())) {
    throw std::invalid_argument("EvaluateDisparity: mask must be empty or CV_8UC1 of gt's size");
  }
  std::int64_t count = 0, estimated = 0, bad1 = 0, bad2 = 0;
  double abs_error_sum = 0;
  for (int y = 0; y < gt.rows; ++y) {
    const float* d_row = disp.ptr<float>(y);
    const float* g_row = gt.ptr<float>(y);
    const std::uint8_t* m_row = mask.empty() ? nullptr : mask.ptr<std::uint8_t>(y);
    for (int x = 0; x < gt.cols; ++x) {
      if (m_row != nullptr && m_row[x] != 255) continue;
      const float g = g_row[x];
      if (!std::isfinite(g) || g == 0) continue;
      ++count;
      const float d = d_row[x];
      if (!std::isfinite(d)) {
        ++bad1;
        ++bad2;
        continue;
      }
      ++estimated;
      const double error = std::abs(static_cast<double>(d) - g);
      abs_error_sum += error;
      if (error > 1.0) ++bad1;
      if (error > 2.0) ++bad2;
    }
  }
  DisparityMetrics m;
  m.count = count;
  if (count == 0) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    m.bad1 = m.bad2 = m.avgerr = m.density = nan;
    return m;
  }
  const double n = static_cast<double>(count);
  m.bad1 = 100.0 * static_cast<double>(bad1) / n;
  m.bad2 = 100.0 * static_cast<double>(bad2) / n;
  m.density = 100.0 * static_cast<double>(estimated) / n;
  m.avgerr = estimated > 0 ? abs_error_sum / static_cast<double>(estimated)
                           : std::numeric_limits<double>::quiet_NaN();
  return m;
}

}  // namespace craftscan
