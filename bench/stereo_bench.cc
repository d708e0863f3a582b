// `craftscan-bench stereo`: disparity quality and speed of the matchers on
// Middlebury scenes.
//
//   craftscan-bench stereo --scenes DIR | --scene DIR [--scene DIR ...]
//                          [--matcher adcensus,adcensus-classic,sgbm]
//                          [--threads N] [--repeat K] [--json FILE]
//                          [--uniqueness U] [--aggregation-iterations N]
//                          [--save-disparity DIR]
//
// Threads: ADCensus gets N through its options. OpenCV's thread pool is a
// process-wide global: cv::setNumThreads(N) is set for the whole run (so SGBM
// and any OpenCV call inside ADCensus use N) and restored afterwards.
//
// time_ms is the median of K calls on one matcher object per scene (buffers
// reused across calls, for both craftscan and SGBM); with K ≥ 3 the first
// call's allocation does not count. AD-Census rows are followed by the
// matcher's own stage times (DisparityResult::time_ms, each the median over
// the K calls; JSON `stages_ms`).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "craftscan/pipeline/common/pfm.h"
#include "craftscan/pipeline/stereo/adcensus.h"
#include "stereo_scene.h"

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;

struct MatchOutput {
  bool ok = false;
  std::string message;  // why not ok
  cv::Mat disparity;    // CV_32FC1, NaN = no estimate
  // The matcher's own stage times (AD-Census), name and ms, in order.
  std::vector<std::pair<std::string, double>> stages;
};

// A matcher under test. prepare() builds it for one scene (outside the
// timing); each call of the returned function computes the left disparity.
// The repeats reuse one matcher object, as a station matching view after view
// does, so buffers are allocated once for both craftscan and SGBM.
using SceneRun = std::function<MatchOutput()>;
struct Matcher {
  std::string name;
  std::function<SceneRun(const StereoScene&, int num_threads)> prepare;
};

// What the stereo command changes in the AD-Census matchers' defaults.
struct ADCensusSettings {
  double uniqueness = 0;  // RefinementOptions::uniqueness
  int aggregation_iterations = ADCensusOptions{}.aggregation_iterations;
  double pi1 = ADCensusOptions{}.pi1, pi2 = ADCensusOptions{}.pi2;  // scanline penalties
};

SceneRun PrepareADCensus(const StereoScene& scene, int num_threads, ArmRule arm_rule,
                         const ADCensusSettings& settings) {
  ADCensusOptions options;
  options.min_disparity = 0;
  options.num_disparities = scene.ndisp;
  options.num_threads = num_threads;
  options.arm_rule = arm_rule;
  options.refinement.uniqueness = settings.uniqueness;
  options.aggregation_iterations = settings.aggregation_iterations;
  options.pi1 = settings.pi1;
  options.pi2 = settings.pi2;
  auto matcher = std::make_shared<StereoMatcher>(options);
  return [matcher, &scene] {
    DisparityResult result = matcher->Compute(scene.left, scene.right);
    MatchOutput out;
    out.ok = result.IsUsable();
    out.message = result.message;
    out.disparity = std::move(result.disparity);
    const DisparityResult::Timings& t = result.time_ms;
    out.stages = {
        {"preprocess", t.preprocess},   {"cost", t.cost},         {"arms", t.arms},
        {"aggregation", t.aggregation}, {"scanline", t.scanline}, {"refinement", t.refinement}};
    return out;
  };
}

// OpenCV's SGBM with the usual Middlebury settings (P1, P2 for 3 channels and
// 5×5 blocks, as in OpenCV's stereo_match sample).
SceneRun PrepareSgbm(const StereoScene& scene, int num_threads) {
  constexpr int kMinDisparity = 0;
  constexpr int kBlockSize = 5;
  const int num_disparities = (scene.ndisp + 15) / 16 * 16;
  cv::setNumThreads(num_threads);  // process-wide; see the file comment
  cv::Ptr<cv::StereoSGBM> sgbm = cv::StereoSGBM::create(
      kMinDisparity, num_disparities, kBlockSize, /*P1=*/8 * 3 * kBlockSize * kBlockSize,
      /*P2=*/32 * 3 * kBlockSize * kBlockSize, /*disp12MaxDiff=*/1, /*preFilterCap=*/0,
      /*uniquenessRatio=*/10, /*speckleWindowSize=*/100, /*speckleRange=*/2,
      cv::StereoSGBM::MODE_SGBM);
  return [sgbm, &scene] {
    cv::Mat fixed;  // CV_16S, disparity × 16; (minDisparity − 1) × 16 = invalid
    sgbm->compute(scene.left, scene.right, fixed);
    MatchOutput out;
    out.disparity.create(fixed.size(), CV_32FC1);
    for (int y = 0; y < fixed.rows; ++y) {
      const short* src = fixed.ptr<short>(y);
      float* dst = out.disparity.ptr<float>(y);
      for (int x = 0; x < fixed.cols; ++x) {
        dst[x] =
            src[x] < kMinDisparity * 16 ? kInvalidDisparity : static_cast<float>(src[x]) / 16.f;
      }
    }
    out.ok = true;
    return out;
  };
}

// `settings` apply to both AD-Census matchers.
std::vector<Matcher> AllMatchers(const ADCensusSettings& settings) {
  return {
      {"adcensus",
       [settings](const StereoScene& s, int n) {
         return PrepareADCensus(s, n, ArmRule::kImproved, settings);
       }},
      {"adcensus-classic",
       [settings](const StereoScene& s, int n) {
         return PrepareADCensus(s, n, ArmRule::kClassic, settings);
       }},
      {"sgbm", PrepareSgbm},
  };
}

struct MatcherResult {
  std::string matcher;
  DisparityMetrics nonocc, all, disc;
  bool has_all_disc = false;
  // 2001/2003 scenes: bad-1 nonocc as Middlebury's v2 evaluation scored it
  // (the disparities rounded to 1 / gt_scale, as its PNG uploads were; the
  // figures published for those scenes, e.g. Mei et al.'s, are these).
  double bad1_v2 = std::numeric_limits<double>::quiet_NaN();
  double time_ms = 0;  // median over the repeats
  // Per stage, the median over the repeats (AD-Census only).
  std::vector<std::pair<std::string, double>> stages_ms;
};

struct SceneResult {
  std::string name;
  int width = 0, height = 0, ndisp = 0;
  std::vector<MatcherResult> results;  // in --matcher order

  const MatcherResult* Find(const std::string& matcher) const {
    for (const MatcherResult& r : results) {
      if (r.matcher == matcher) return &r;
    }
    return nullptr;
  }
};

double Median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

// Keeps file names portable whatever scene.json calls the scene.
std::string FileSafe(const std::string& text) {
  std::string out = text;
  for (char& c : out) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '-' || c == '_' || c == '.';
    if (!ok) c = '_';
  }
  return out;
}

bool SaveDisparity(const fs::path& dir, const StereoScene& scene, const std::string& matcher,
                   const cv::Mat& disparity, std::string* error) {
  const std::string stem = FileSafe(scene.name) + "-" + matcher;
  if (!WritePfm((dir / (stem + ".pfm")).string(), disparity, error)) return false;
  // Colour map over 0 … ndisp − 1; pixels without an estimate black.
  const double scale = 255.0 / std::max(1, scene.ndisp - 1);
  cv::Mat valid = disparity == disparity;
  cv::Mat grey;
  disparity.convertTo(grey, CV_8U, scale);  // saturates; NaN → 0
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_JET);
  colour.setTo(cv::Scalar::all(0), ~valid);
  const std::string png = (dir / (stem + ".png")).string();
  bool written = false;
  try {
    written = cv::imwrite(png, colour);
  } catch (const cv::Exception& e) {
    *error = "'" + png + "': " + e.what();
    return false;
  }
  if (!written) *error = "'" + png + "': cannot write";
  return written;
}

std::string Format(double value, int precision) {
  if (!std::isfinite(value)) return "-";
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", precision, value);
  return buffer;
}

nlohmann::ordered_json ToJson(double value) {
  return std::isfinite(value) ? nlohmann::ordered_json(value) : nlohmann::ordered_json(nullptr);
}

class StereoCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "stereo", "Disparity quality (bad-1/2, avg error, density) and time per matcher");
    CLI::Option* scenes =
        sub->add_option("--scenes", scenes_dir_,
                        "Folder whose subfolders with a scene.json are the scenes (by name)");
    CLI::Option* scene = sub->add_option("--scene", scene_dirs_, "One scene folder (repeatable)");
    scenes->excludes(scene);
    sub->add_option("--matcher", matcher_names_,
                    "Comma-separated matchers: adcensus, adcensus-classic, sgbm")
        ->delimiter(',')
        ->capture_default_str();
    sub->add_option("--threads", threads_, "Threads per matcher call (also OpenCV's global pool)")
        ->check(CLI::Range(1, 256))
        ->capture_default_str();
    sub->add_option("--uniqueness", settings_.uniqueness,
                    "AD-Census uniqueness test (RefinementOptions::uniqueness, [0, 1); 0 = off)")
        ->check(CLI::Range(0.0, 0.99))
        ->capture_default_str();
    sub->add_option("--aggregation-iterations", settings_.aggregation_iterations,
                    "AD-Census cross-based aggregation iterations (ADCensusOptions' 2, one of "
                    "each order; the paper's 4; the station runs pipeline.aggregation_iterations, "
                    "default 0)")
        ->check(CLI::Range(0, 16))
        ->capture_default_str();
    sub->add_option("--pi1", settings_.pi1,
                    "AD-Census scanline penalty Π1 (ADCensusOptions::pi1; the station's is 0.5)")
        ->check(CLI::Range(0.0, 100.0))
        ->capture_default_str();
    sub->add_option("--pi2", settings_.pi2,
                    "AD-Census scanline penalty Π2, at least Π1 (ADCensusOptions::pi2; the "
                    "station's is 6)")
        ->check(CLI::Range(0.0, 100.0))
        ->capture_default_str();
    sub->add_option("--repeat", repeat_, "Runs per scene and matcher; time = median")
        ->check(CLI::Range(1, 1000))
        ->capture_default_str();
    sub->add_option("--json", json_path_, "Write the results as JSON to this file");
    sub->add_option("--save-disparity", save_dir_,
                    "Write <scene>-<matcher>.pfm and a colour-mapped .png per result here");
    return sub;
  }

  int Run() override {
    if (settings_.pi1 > settings_.pi2)
      return UsageError("--pi1 (" + std::to_string(settings_.pi1) + ") must not exceed --pi2 (" +
                        std::to_string(settings_.pi2) + ")");
    std::vector<Matcher> matchers;
    if (int code = SelectMatchers(&matchers); code != kExitOk) return code;
    std::vector<std::string> dirs;
    if (int code = FindSceneDirs(&dirs); code != kExitOk) return code;
    if (!json_path_.empty()) {  // fail before the run, not after it
      const fs::path parent = fs::path(json_path_).parent_path();
      std::error_code ec;
      if (!parent.empty() && !fs::is_directory(parent, ec)) {
        return DataError("--json: folder '" + parent.string() + "' does not exist");
      }
    }
    if (!save_dir_.empty()) {
      std::error_code ec;
      fs::create_directories(save_dir_, ec);
      if (ec || !fs::is_directory(save_dir_)) {
        return DataError("cannot create --save-disparity folder '" + save_dir_ + "'");
      }
    }

    // Load (and so validate) every scene before spending time on matching.
    std::vector<StereoScene> scenes(dirs.size());
    for (std::size_t i = 0; i < dirs.size(); ++i) {
      std::string error;
      if (!LoadStereoScene(dirs[i], &scenes[i], &error)) return DataError(error);
    }

    const int previous_threads = cv::getNumThreads();
    cv::setNumThreads(threads_);
    std::vector<SceneResult> results;
    const int code = RunAll(scenes, matchers, &results);
    cv::setNumThreads(previous_threads);
    if (code != kExitOk) return code;

    PrintSummary(results, matchers);
    if (!json_path_.empty()) return WriteJson(results);
    return kExitOk;
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench stereo: " << message << "\n";
    return kExitDataError;
  }
  static int UsageError(const std::string& message) {
    std::cerr << "craftscan-bench stereo: " << message << "\nRun with --help for usage.\n";
    return kExitUsage;
  }

  int SelectMatchers(std::vector<Matcher>* selected) const {
    const std::vector<Matcher> all = AllMatchers(settings_);
    for (const std::string& name : matcher_names_) {
      auto it =
          std::find_if(all.begin(), all.end(), [&](const Matcher& m) { return m.name == name; });
      if (it == all.end()) {
        return UsageError("unknown matcher '" + name +
                          "' (known: adcensus, adcensus-classic, sgbm)");
      }
      const bool duplicate = std::any_of(selected->begin(), selected->end(),
                                         [&](const Matcher& m) { return m.name == name; });
      if (!duplicate) selected->push_back(*it);
    }
    if (selected->empty()) return UsageError("--matcher lists no matcher");
    return kExitOk;
  }

  int FindSceneDirs(std::vector<std::string>* dirs) const {
    if (scenes_dir_.empty() && scene_dirs_.empty()) {
      return UsageError("give --scenes DIR or at least one --scene DIR");
    }
    if (!scene_dirs_.empty()) {
      *dirs = scene_dirs_;
      return kExitOk;
    }
    std::error_code ec;
    if (!fs::is_directory(scenes_dir_, ec)) {
      return DataError("scenes folder '" + scenes_dir_ + "' does not exist or is not a folder");
    }
    std::vector<fs::path> found;
    for (fs::directory_iterator it(scenes_dir_, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code entry_ec;
      if (it->is_directory(entry_ec) && fs::is_regular_file(it->path() / "scene.json", entry_ec)) {
        found.push_back(it->path());
      }
    }
    if (ec) return DataError("cannot list scenes folder '" + scenes_dir_ + "': " + ec.message());
    if (found.empty()) {
      return DataError("no scenes (subfolders with a scene.json) in '" + scenes_dir_ + "'");
    }
    std::sort(found.begin(), found.end(),
              [](const fs::path& a, const fs::path& b) { return a.filename() < b.filename(); });
    for (const fs::path& p : found) dirs->push_back(p.string());
    return kExitOk;
  }

  int RunAll(const std::vector<StereoScene>& scenes, const std::vector<Matcher>& matchers,
             std::vector<SceneResult>* results) const {
    std::size_t name_width = 5;
    for (const StereoScene& s : scenes) name_width = std::max(name_width, s.name.size());
    std::printf("stereo: %zu scene(s), %d thread(s), %d repeat(s)\n\n", scenes.size(), threads_,
                repeat_);
    std::printf("%-*s  %-16s %12s %12s %14s %8s %10s %9s %10s %8s\n", static_cast<int>(name_width),
                "scene", "matcher", "bad1_nonocc", "bad2_nonocc", "avgerr_nonocc", "density",
                "time_ms", "bad1_all", "bad1_disc", "bad1_v2");
    std::fflush(stdout);

    for (const StereoScene& scene : scenes) {
      SceneResult scene_result;
      scene_result.name = scene.name;
      scene_result.width = scene.left.cols;
      scene_result.height = scene.left.rows;
      scene_result.ndisp = scene.ndisp;
      for (const Matcher& matcher : matchers) {
        MatchOutput output;
        std::vector<double> times_ms;
        std::vector<std::vector<double>> stage_ms;  // [stage][repeat]
        SceneRun run;
        try {
          run = matcher.prepare(scene, threads_);
        } catch (const std::exception& e) {
          return DataError(matcher.name + " cannot be set up for scene '" + scene.name +
                           "': " + e.what());
        }
        for (int k = 0; k < repeat_; ++k) {
          const auto start = std::chrono::steady_clock::now();
          try {
            output = run();
          } catch (const std::exception& e) {  // e.g. cv::Exception from SGBM
            output = MatchOutput{false, e.what(), {}};
          }
          const auto stop = std::chrono::steady_clock::now();
          if (!output.ok || output.disparity.type() != CV_32FC1 ||
              output.disparity.size() != scene.gt.size()) {
            return DataError(matcher.name + " failed on scene '" + scene.name +
                             "': " + (output.ok ? "wrong output size or type" : output.message));
          }
          times_ms.push_back(std::chrono::duration<double, std::milli>(stop - start).count());
          stage_ms.resize(output.stages.size());
          for (std::size_t i = 0; i < output.stages.size(); ++i)
            stage_ms[i].push_back(output.stages[i].second);
        }

        MatcherResult r;
        r.matcher = matcher.name;
        r.time_ms = Median(times_ms);
        for (std::size_t i = 0; i < output.stages.size() && i < stage_ms.size(); ++i)
          r.stages_ms.emplace_back(output.stages[i].first, Median(stage_ms[i]));
        r.nonocc = EvaluateDisparity(output.disparity, scene.gt, scene.mask_nonocc);
        r.has_all_disc = scene.HasAllAndDiscMasks();
        if (r.has_all_disc) {
          r.all = EvaluateDisparity(output.disparity, scene.gt, scene.mask_all);
          r.disc = EvaluateDisparity(output.disparity, scene.gt, scene.mask_disc);
          if (scene.gt_scale > 0) {
            cv::Mat rounded = output.disparity.clone();
            const float k = static_cast<float>(scene.gt_scale);
            rounded.forEach<float>([k](float& d, const int*) {
              if (std::isfinite(d)) d = std::round(d * k) / k;
            });
            r.bad1_v2 = EvaluateDisparity(rounded, scene.gt, scene.mask_nonocc).bad1;
          }
        }
        std::printf("%-*s  %-16s %12s %12s %14s %8s %10s %9s %10s %8s\n",
                    static_cast<int>(name_width), scene.name.c_str(), matcher.name.c_str(),
                    Format(r.nonocc.bad1, 2).c_str(), Format(r.nonocc.bad2, 2).c_str(),
                    Format(r.nonocc.avgerr, 3).c_str(), Format(r.nonocc.density, 1).c_str(),
                    Format(r.time_ms, 1).c_str(),
                    r.has_all_disc ? Format(r.all.bad1, 2).c_str() : "-",
                    r.has_all_disc ? Format(r.disc.bad1, 2).c_str() : "-",
                    std::isfinite(r.bad1_v2) ? Format(r.bad1_v2, 2).c_str() : "-");
        if (!r.stages_ms.empty()) {
          std::printf("%-*s    stages (ms, median):", static_cast<int>(name_width), "");
          for (const auto& [stage, ms] : r.stages_ms)
            std::printf(" %s %s", stage.c_str(), Format(ms, 1).c_str());
          std::printf("\n");
        }
        std::fflush(stdout);

        if (!save_dir_.empty()) {
          std::string error;
          if (!SaveDisparity(save_dir_, scene, matcher.name, output.disparity, &error)) {
            return DataError(error);
          }
        }
        scene_result.results.push_back(std::move(r));
      }
      results->push_back(std::move(scene_result));
    }
    return kExitOk;
  }

  static void PrintSummary(const std::vector<SceneResult>& results,
                           const std::vector<Matcher>& matchers) {
    std::printf("\nsummary (mean over scenes):\n");
    const bool have_sgbm = std::any_of(matchers.begin(), matchers.end(),
                                       [](const Matcher& m) { return m.name == "sgbm"; });
    for (const Matcher& matcher : matchers) {
      double sum[5] = {0, 0, 0, 0, 0};
      int n[5] = {0, 0, 0, 0, 0};
      double all_sum = 0, disc_sum = 0, v2_sum = 0;
      int all_n = 0, v2_n = 0;
      auto add = [](double v, double* s, int* count) {
        if (std::isfinite(v)) {
          *s += v;
          ++*count;
        }
      };
      for (const SceneResult& scene : results) {
        const MatcherResult* r = scene.Find(matcher.name);
        if (r == nullptr) continue;
        add(r->nonocc.bad1, &sum[0], &n[0]);
        add(r->nonocc.bad2, &sum[1], &n[1]);
        add(r->nonocc.avgerr, &sum[2], &n[2]);
        add(r->nonocc.density, &sum[3], &n[3]);
        add(r->time_ms, &sum[4], &n[4]);
        if (r->has_all_disc && std::isfinite(r->all.bad1) && std::isfinite(r->disc.bad1)) {
          all_sum += r->all.bad1;
          disc_sum += r->disc.bad1;
          ++all_n;
        }
        if (std::isfinite(r->bad1_v2)) {
          v2_sum += r->bad1_v2;
          ++v2_n;
        }
      }
      auto mean = [](double s, int count) {
        return count > 0 ? s / count : std::numeric_limits<double>::quiet_NaN();
      };
      std::printf(
          "  %-16s bad1_nonocc %s  bad2_nonocc %s  avgerr_nonocc %s  density %s  time_ms %s",
          matcher.name.c_str(), Format(mean(sum[0], n[0]), 2).c_str(),
          Format(mean(sum[1], n[1]), 2).c_str(), Format(mean(sum[2], n[2]), 3).c_str(),
          Format(mean(sum[3], n[3]), 1).c_str(), Format(mean(sum[4], n[4]), 1).c_str());
      if (all_n > 0) {
        std::printf("  bad1_all %s  bad1_disc %s (%d scene(s))", Format(all_sum / all_n, 2).c_str(),
                    Format(disc_sum / all_n, 2).c_str(), all_n);
      }
      if (v2_n > 0)
        std::printf("  bad1_v2 %s (%d scene(s))", Format(v2_sum / v2_n, 2).c_str(), v2_n);
      std::printf("\n");

      if (have_sgbm && matcher.name.rfind("adcensus", 0) == 0) {
        std::string line;
        double max_ratio = 0;
        for (const SceneResult& scene : results) {
          const MatcherResult* a = scene.Find(matcher.name);
          const MatcherResult* s = scene.Find("sgbm");
          if (a == nullptr || s == nullptr || !(s->time_ms > 0)) continue;
          const double ratio = a->time_ms / s->time_ms;
          max_ratio = std::max(max_ratio, ratio);
          const std::string item = " " + scene.name + " " + Format(ratio, 2);
          const std::size_t last_break = line.rfind('\n');
          const std::size_t width =
              line.size() - (last_break == std::string::npos ? 0 : last_break);
          if (width + item.size() > 80) line += "\n" + std::string(21, ' ');
          line += item;
        }
        std::printf("  %-16s time %s/sgbm:%s; max %s\n", "", matcher.name.c_str(), line.c_str(),
                    Format(max_ratio, 2).c_str());
      }
    }
    std::fflush(stdout);
  }

  int WriteJson(const std::vector<SceneResult>& results) const {
    using Json = nlohmann::ordered_json;
    Json root;
    root["threads"] = threads_;
    root["uniqueness"] = settings_.uniqueness;
    root["aggregation_iterations"] = settings_.aggregation_iterations;
    root["pi1"] = settings_.pi1;
    root["pi2"] = settings_.pi2;
    root["scenes"] = Json::array();
    for (const SceneResult& scene : results) {
      Json s;
      s["name"] = scene.name;
      s["width"] = scene.width;
      s["height"] = scene.height;
      s["ndisp"] = scene.ndisp;
      Json per_matcher = Json::object();
      for (const MatcherResult& r : scene.results) {
        Json m;
        m["bad1_nonocc"] = ToJson(r.nonocc.bad1);
        m["bad2_nonocc"] = ToJson(r.nonocc.bad2);
        m["avgerr_nonocc"] = ToJson(r.nonocc.avgerr);
        m["density"] = ToJson(r.nonocc.density);
        m["time_ms"] = ToJson(r.time_ms);
        if (!r.stages_ms.empty()) {
          Json stages = Json::object();
          for (const auto& [stage, ms] : r.stages_ms) stages[stage] = ToJson(ms);
          m["stages_ms"] = std::move(stages);
        }
        if (r.has_all_disc) {
          m["bad1_all"] = ToJson(r.all.bad1);
          m["bad1_disc"] = ToJson(r.disc.bad1);
          if (std::isfinite(r.bad1_v2)) m["bad1_nonocc_v2"] = ToJson(r.bad1_v2);
        }
        per_matcher[r.matcher] = std::move(m);
      }
      s["results"] = std::move(per_matcher);
      root["scenes"].push_back(std::move(s));
    }
    std::ofstream out(json_path_, std::ios::trunc);
    if (out) out << root.dump(2) << "\n";
    out.close();
    if (!out) return DataError("cannot write --json file '" + json_path_ + "'");
    return kExitOk;
  }

  std::string scenes_dir_;
  std::vector<std::string> scene_dirs_;
  std::vector<std::string> matcher_names_{"adcensus", "adcensus-classic", "sgbm"};
  int threads_ = 2;
  ADCensusSettings settings_;
  int repeat_ = 3;
  std::string json_path_;
  std::string save_dir_;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeStereoCommand() { return std::make_unique<StereoCommand>(); }

}  // namespace craftscan::bench
