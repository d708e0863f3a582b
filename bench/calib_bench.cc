// `craftscan-bench calib`: stereo calibration quality on a folder of board
// image pairs.
//
//   craftscan-bench calib --pairs DIR --board COLSxROWS --square MM [--json FILE]
//                         [--board-type chessboard|charuco --marker MM --dictionary N]
//                         [--model default|opencv-sample] [--detector classic|sector_based]
//                         [--save FILE]
//
// Pairs are left*.{jpg,png} / right*.{jpg,png} in DIR matched by the number
// after "left"/"right" (left01.jpg ↔ right01.jpg ↔ right1.png). A pair whose
// board is not found (or without a partner) is reported and skipped.
// Prints and writes rms_left_px, rms_right_px (monocular), rms_stereo_px,
// epipolar_px (mean |y_l − y_r| of the corners after rectification) and
// pairs_used, plus per-pair errors and the verdict against the default limits.
// The exit code is 0 whenever a calibration was computed, accepted or not.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "command.h"
#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;

struct ImagePair {
  std::string key;  // the number after left/right, without leading zeros
  fs::path left, right;
  std::string Name() const { return left.filename().string() + "/" + right.filename().string(); }
};

std::string Lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

// "left07.jpg" → ("left", "7"); nullopt for other names.
std::optional<std::pair<std::string, std::string>> SideAndKey(const fs::path& file) {
  const std::string ext = Lower(file.extension().string());
  if (ext != ".jpg" && ext != ".jpeg" && ext != ".png") return std::nullopt;
  const std::string stem = file.stem().string();
  const std::string lower = Lower(stem);
  for (const char* side : {"left", "right"}) {
    const std::string prefix(side);
    if (lower.rfind(prefix, 0) != 0) continue;
    std::string rest = stem.substr(prefix.size());
    const bool numeric = !rest.empty() && std::all_of(rest.begin(), rest.end(), [](char c) {
      return std::isdigit(static_cast<unsigned char>(c));
    });
    if (numeric) {
      rest.erase(0, std::min(rest.find_first_not_of('0'), rest.size() - 1));
    }
    return std::pair{prefix, rest};
  }
  return std::nullopt;
}

// Sorts keys numerically when both are numbers.
bool KeyLess(const std::string& a, const std::string& b) {
  const bool na = !a.empty() && std::isdigit(static_cast<unsigned char>(a[0]));
  const bool nb = !b.empty() && std::isdigit(static_cast<unsigned char>(b[0]));
  if (na && nb && a.size() != b.size()) return a.size() < b.size();
  return a < b;
}

nlohmann::ordered_json ToJson(double value) {
  return std::isfinite(value) ? nlohmann::ordered_json(value) : nlohmann::ordered_json(nullptr);
}

std::string Format(double value, int precision) {
  if (!std::isfinite(value)) return "-";
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", precision, value);
  return buffer;
}

class CalibCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "calib", "Stereo calibration RMS and epipolar error on left*/right* board image pairs");
    sub->add_option("--pairs", pairs_dir_, "Folder with left*.{jpg,png} / right*.{jpg,png}")
        ->required();
    sub->add_option("--board", board_text_,
                    "COLSxROWS: inner corners (chessboard) or squares (charuco)")
        ->required();
    sub->add_option("--square", square_mm_, "Square edge (mm)")->required();
    sub->add_option("--board-type", board_type_, "chessboard or charuco")->capture_default_str();
    sub->add_option("--marker", marker_mm_, "ChArUco marker edge (mm)");
    sub->add_option("--dictionary", dictionary_,
                    "ChArUco ArUco dictionary (cv::aruco::PREDEFINED_DICTIONARY_NAME value)")
        ->capture_default_str();
    sub->add_option("--model", model_,
                    "Lens model: default (k1 k2 p1 p2 k3) or opencv-sample (the stereo_calib "
                    "sample's flags)")
        ->capture_default_str();
    sub->add_option("--detector", detector_,
                    "Chessboard detector: classic (findChessboardCorners + adaptive "
                    "cornerSubPix) or sector_based (findChessboardCornersSB)")
        ->capture_default_str();
    sub->add_option("--json", json_path_, "Write the results as JSON to this file");
    sub->add_option("--save", save_path_, "Save the calibration (OpenCV YAML) to this file");
    return sub;
  }

  int Run() override {
    BoardSpec board;
    StereoCalibrationOptions options;
    BoardDetectionOptions detection;
    if (int code = ParseSettings(&board, &options, &detection); code != kExitOk) return code;
    for (const std::string* path : {&json_path_, &save_path_}) {  // fail before the run
      if (path->empty()) continue;
      const fs::path parent = fs::path(*path).parent_path();
      std::error_code ec;
      if (!parent.empty() && !fs::is_directory(parent, ec)) {
        return DataError("folder '" + parent.string() + "' of '" + *path + "' does not exist");
      }
    }
    std::vector<ImagePair> pairs;
    std::vector<std::string> unmatched;
    if (int code = FindPairs(&pairs, &unmatched); code != kExitOk) return code;

    std::printf("calib: %zu pair(s) in %s; %s; model %s; detector %s\n", pairs.size(),
                pairs_dir_.c_str(), Describe(board).c_str(), model_.c_str(), detector_.c_str());
    for (const std::string& u : unmatched)
      std::printf("  %-28s skipped: no partner image\n", u.c_str());
    std::fflush(stdout);

    const auto start = std::chrono::steady_clock::now();
    std::vector<StereoBoardView> views;
    cv::Size image_size;
    for (const ImagePair& pair : pairs) {
      cv::Mat left, right;
      std::string problem = ReadPair(pair, &left, &right);
      if (problem.empty() && image_size.empty()) image_size = left.size();
      if (problem.empty() && left.size() != image_size) {
        problem = "image size " + std::to_string(left.cols) + "x" + std::to_string(left.rows) +
                  " differs from the first pair's " + std::to_string(image_size.width) + "x" +
                  std::to_string(image_size.height);
      }
      StereoBoardView view;
      if (problem.empty()) {
        view = DetectStereoBoard(pair.Name(), left, right, board, detection);
      } else {
        view.name = pair.Name();
        view.left.message = view.right.message = problem;
      }
      std::string status;
      if (view.left.found && view.right.found) {
        status = "board found: " + std::to_string(view.left.image_points.size()) + "/" +
                 std::to_string(view.right.image_points.size()) + " corners";
      } else if (!problem.empty()) {
        status = "not used: " + problem;
      } else {
        status = "not used:";
        if (!view.left.found) status += " left image: " + view.left.message + ";";
        if (!view.right.found) status += " right image: " + view.right.message + ";";
        status.pop_back();
      }
      std::printf("  %-28s %s\n", view.name.c_str(), status.c_str());
      std::fflush(stdout);
      views.push_back(std::move(view));
    }
    if (image_size.empty()) return DataError("no readable image pair in '" + pairs_dir_ + "'");

    const StereoCalibrationResult result = CalibrateStereo(views, image_size, board, options);
    const double time_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    if (result.status != StereoCalibrationResult::Status::kOk) {
      return DataError("calibration failed (" + std::string(ToString(result.status)) +
                       "): " + result.message);
    }
    Print(result);
    if (!save_path_.empty()) {
      std::string error;
      if (!SaveCalibration(save_path_, result.calibration, &error)) return DataError(error);
      std::printf("saved %s\n", save_path_.c_str());
    }
    if (!json_path_.empty()) return WriteJson(result, board, time_ms, unmatched);
    return kExitOk;
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench calib: " << message << "\n";
    return kExitDataError;
  }
  static int UsageError(const std::string& message) {
    std::cerr << "craftscan-bench calib: " << message << "\nRun with --help for usage.\n";
    return kExitUsage;
  }

  int ParseSettings(BoardSpec* board, StereoCalibrationOptions* options,
                    BoardDetectionOptions* detection) const {
    if (!ChessboardDetectorFromString(detector_, &detection->chessboard_detector)) {
      return UsageError("--detector: unknown detector '" + detector_ + "' (classic, sector_based)");
    }
    if (!BoardTypeFromString(board_type_, &board->type)) {
      return UsageError("--board-type: unknown board type '" + board_type_ +
                        "' (chessboard, charuco)");
    }
    const std::string text = Lower(board_text_);
    const std::size_t x = text.find('x');
    int cols = 0, rows = 0;
    try {
      std::size_t used_cols = 0, used_rows = 0;
      if (x == std::string::npos) throw std::invalid_argument("no x");
      cols = std::stoi(text.substr(0, x), &used_cols);
      rows = std::stoi(text.substr(x + 1), &used_rows);
      if (used_cols != x || used_rows != text.size() - x - 1) throw std::invalid_argument("junk");
    } catch (const std::exception&) {
      return UsageError("--board: expected COLSxROWS (e.g. 9x6), got '" + board_text_ + "'");
    }
    board->cols = cols;
    board->rows = rows;
    board->square_mm = square_mm_;
    board->marker_mm = marker_mm_;
    board->aruco_dictionary = dictionary_;
    std::string why;
    if (!board->IsValid(&why)) return UsageError("--board/--square/--marker: " + why);
    if (model_ == "opencv-sample") {
      options->lens = LensModelOptions::OpenCvStereoSample();
    } else if (model_ != "default") {
      return UsageError("--model: unknown model '" + model_ + "' (default, opencv-sample)");
    }
    return kExitOk;
  }

  int FindPairs(std::vector<ImagePair>* pairs, std::vector<std::string>* unmatched) const {
    std::error_code ec;
    if (!fs::is_directory(pairs_dir_, ec)) {
      return DataError("pairs folder '" + pairs_dir_ + "' does not exist or is not a folder");
    }
    std::map<std::string, fs::path> left, right;
    for (fs::directory_iterator it(pairs_dir_, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code entry_ec;
      if (!it->is_regular_file(entry_ec)) continue;
      const auto side_key = SideAndKey(it->path());
      if (!side_key) continue;
      auto& side = side_key->first == "left" ? left : right;
      const auto [slot, inserted] = side.emplace(side_key->second, it->path());
      if (!inserted) {  // left01.jpg and left01.png: keep one, deterministically
        if (it->path().filename() < slot->second.filename()) slot->second = it->path();
      }
    }
    if (ec) return DataError("cannot list '" + pairs_dir_ + "': " + ec.message());
    for (const auto& [key, path] : left) {
      const auto r = right.find(key);
      if (r == right.end()) {
        unmatched->push_back(path.filename().string());
      } else {
        pairs->push_back({key, path, r->second});
      }
    }
    for (const auto& [key, path] : right) {
      if (left.count(key) == 0) unmatched->push_back(path.filename().string());
    }
    if (pairs->empty()) {
      return DataError("no left*/right* image pairs (.jpg, .png) in '" + pairs_dir_ + "'");
    }
    std::sort(pairs->begin(), pairs->end(),
              [](const ImagePair& a, const ImagePair& b) { return KeyLess(a.key, b.key); });
    return kExitOk;
  }

  static std::string ReadPair(const ImagePair& pair, cv::Mat* left, cv::Mat* right) {
    try {
      *left = cv::imread(pair.left.string(), cv::IMREAD_GRAYSCALE);
      *right = cv::imread(pair.right.string(), cv::IMREAD_GRAYSCALE);
    } catch (const cv::Exception& e) {
      return std::string("cannot read: ") + e.what();
    }
    if (left->empty()) return "cannot read '" + pair.left.filename().string() + "'";
    if (right->empty()) return "cannot read '" + pair.right.filename().string() + "'";
    if (left->size() != right->size()) return "left and right image sizes differ";
    return {};
  }

  static void Print(const StereoCalibrationResult& result) {
    const CalibrationReport& r = result.report();
    const StereoCalibration& c = result.calibration;
    std::printf("\nper pair (px):%*s %9s %9s %9s\n", 16, "", "rms_left", "rms_right", "rms_stereo");
    for (const ViewReport& v : r.views) {
      if (!v.used) continue;
      std::printf("  %-28s %9s %9s %9s\n", v.name.c_str(), Format(v.rms_left_px, 3).c_str(),
                  Format(v.rms_right_px, 3).c_str(), Format(v.rms_stereo_px, 3).c_str());
    }
    std::printf("\nrms_left_px     %s\n", Format(r.rms_left_px, 4).c_str());
    std::printf("rms_right_px    %s\n", Format(r.rms_right_px, 4).c_str());
    std::printf("rms_stereo_px   %s\n", Format(r.rms_stereo_px, 4).c_str());
    std::printf("epipolar_px     %s (max %s)\n", Format(r.epipolar_mean_px, 4).c_str(),
                Format(r.epipolar_max_px, 4).c_str());
    std::printf("pairs_used      %d of %zu\n", r.views_used, r.views.size());
    std::printf("coverage        left %s, right %s (%dx%d grid)\n",
                Format(r.coverage_left, 2).c_str(), Format(r.coverage_right, 2).c_str(),
                r.coverage_grid, r.coverage_grid);
    std::printf("focal_px        left %s/%s, right %s/%s; rectified %s\n",
                Format(c.left.camera_matrix(0, 0), 2).c_str(),
                Format(c.left.camera_matrix(1, 1), 2).c_str(),
                Format(c.right.camera_matrix(0, 0), 2).c_str(),
                Format(c.right.camera_matrix(1, 1), 2).c_str(),
                Format(c.rectified_focal_px(), 2).c_str());
    std::printf("baseline_mm     %s\n", Format(c.baseline_mm(), 3).c_str());
    std::printf("verdict         %s\n", r.verdict_reason.c_str());
    std::fflush(stdout);
  }

  int WriteJson(const StereoCalibrationResult& result, const BoardSpec& board, double time_ms,
                const std::vector<std::string>& unmatched) const {
    using Json = nlohmann::ordered_json;
    const CalibrationReport& r = result.report();
    const StereoCalibration& c = result.calibration;
    Json root;
    root["pairs_dir"] = pairs_dir_;
    root["board"] = {{"type", std::string(ToString(board.type))},
                     {"cols", board.cols},
                     {"rows", board.rows},
                     {"square_mm", board.square_mm}};
    if (board.type == BoardSpec::Type::kCharuco) {
      root["board"]["marker_mm"] = board.marker_mm;
      root["board"]["aruco_dictionary"] = board.aruco_dictionary;
    }
    root["model"] = model_;
    root["detector"] = detector_;
    root["image_width"] = c.image_size.width;
    root["image_height"] = c.image_size.height;
    root["rms_left_px"] = ToJson(r.rms_left_px);
    root["rms_right_px"] = ToJson(r.rms_right_px);
    root["rms_stereo_px"] = ToJson(r.rms_stereo_px);
    root["epipolar_px"] = ToJson(r.epipolar_mean_px);
    root["epipolar_max_px"] = ToJson(r.epipolar_max_px);
    root["pairs_used"] = r.views_used;
    root["pairs_total"] = r.views.size();
    root["coverage_left"] = ToJson(r.coverage_left);
    root["coverage_right"] = ToJson(r.coverage_right);
    root["fx_left_px"] = ToJson(c.left.camera_matrix(0, 0));
    root["fy_left_px"] = ToJson(c.left.camera_matrix(1, 1));
    root["fx_right_px"] = ToJson(c.right.camera_matrix(0, 0));
    root["fy_right_px"] = ToJson(c.right.camera_matrix(1, 1));
    root["rectified_focal_px"] = ToJson(c.rectified_focal_px());
    root["baseline_mm"] = ToJson(c.baseline_mm());
    root["verdict"] = std::string(ToString(r.verdict));
    root["verdict_reason"] = r.verdict_reason;
    root["time_ms"] = ToJson(time_ms);
    Json pairs = Json::array();
    for (const ViewReport& v : r.views) {
      Json p;
      p["name"] = v.name;
      p["used"] = v.used;
      if (!v.used) p["message"] = v.message;
      p["rms_left_px"] = ToJson(v.rms_left_px);
      p["rms_right_px"] = ToJson(v.rms_right_px);
      p["rms_stereo_px"] = ToJson(v.rms_stereo_px);
      pairs.push_back(std::move(p));
    }
    root["pairs"] = std::move(pairs);
    root["unmatched_files"] = unmatched;
    std::ofstream out(json_path_, std::ios::trunc);
    if (out) out << root.dump(2) << "\n";
    out.close();
    if (!out) return DataError("cannot write --json file '" + json_path_ + "'");
    return kExitOk;
  }

  std::string pairs_dir_;
  std::string board_text_;
  double square_mm_ = 0;
  std::string board_type_ = "chessboard";
  double marker_mm_ = 0;
  int dictionary_ = 0;
  std::string model_ = "default";
  std::string detector_ = "classic";
  std::string json_path_;
  std::string save_path_;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeCalibCommand() { return std::make_unique<CalibCommand>(); }

}  // namespace craftscan::bench
