// `craftscan-bench sim-depth`: depth accuracy of the stereo pipeline on the
// simulated station, against exact ground truth.
//
//   craftscan-bench sim-depth [--object carved_box|egg|embroidery|mesh:FILE]
//                             [--seed S] [--threads N] [--json FILE]
//                             [--aggregation-iterations N] [--projector] [--raw]
//
// One view on the default rig (1280×1024, 100 mm baseline, ~400 mm to the
// turntable axis, mild lens distortion, sensor noise σ = 1 grey level) with
// the turntable at 30° so that two sides of a box show. A mesh is scaled so
// its largest extent is 80 mm, file +Z up. The raw pair is rectified with the
// exact calibration (cv::initUndistortRectifyMap + cv::remap, bilinear),
// matched with craftscan's AD-Census (default options, with the station's
// aggregation iterations, ViewProcessorOptions) over the object's
// ground-truth disparity range ± 8 px, cleaned as the station cleans a view
// before reprojection (ViewProcessorOptions' defaults: speckles, erosion at
// depth edges, the texture filter; --raw: the matcher's output as it is),
// and reprojected with Q per pixel (Z = Q·(x, y, d, 1), as
// ReprojectToPoints). --projector lights the scene with the pattern
// projector a station mounts on its camera head (the sim driver's
// `projector: 1`). On the rectified object pixels:
//   depth_err_median_mm, depth_err_p90_mm  |Z − Z_true| over pixels with a disparity
//   valid_pct                               pixels with a disparity, % of object pixels
//   valid_nonocc_pct                        the same over the object pixels the right
//                                           camera also sees (Middlebury's "nonocc":
//                                           no matcher can match the others)
//   disp_err_median_px                      |d − d_true| over the same pixels
//   disp_bias_px, depth_bias_mm             the mean of d − d_true and of Z − Z_true
//                                           over those within 1 px of the truth (a
//                                           matcher's systematic error, outliers aside)
// and render_ms (both cameras + ground truth), match_ms (one matcher call,
// on a new matcher: its first-touch page faults count), the matcher's own
// stage times, and match_peak_rss_mb (the process's peak resident memory
// while matching, images included). --lr-tolerance and --uniqueness set
// the matcher's left-right check and uniqueness test (RefinementOptions; by
// default the matcher's own, as on the station).
//
// Threads: the renderer and the matcher get N through their options; OpenCV's
// global pool (remap) is set to N for the run and restored.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "craftscan/daemon/config.h"
#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"
#include "craftscan/pipeline/stereo/reproject.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/sim/station.h"

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;

constexpr double kTurntableAngleRad = std::numbers::pi / 6;  // 30°
constexpr int kDisparityMarginPx = 8;
constexpr double kMeshSizeMm = 80;

struct SimDepthResult {
  std::string object;
  int width = 0, height = 0;
  int min_disparity = 0, num_disparities = 0;
  double gt_disparity_min = 0, gt_disparity_max = 0;
  long object_pixels = 0, valid_pixels = 0;
  long nonocc_pixels = 0, valid_nonocc_pixels = 0;  // object ∩ seen by the right camera
  double depth_err_median_mm = NAN, depth_err_p90_mm = NAN, disp_err_median_px = NAN;
  double disp_bad2_pct = NAN;  // valid object pixels more than 2 px off the true disparity
  double disp_bias_px = NAN, depth_bias_mm = NAN;  // signed means within 1 px of the truth
  // The raw left image's share of dark pixels without texture on the
  // platter (DarkUntexturedSharePct): what the station's automatic
  // bracketing (scan.auto_bracket) decides by.
  double dark_untextured_pct = NAN;
  double valid_pct = 0, valid_nonocc_pct = 0;
  double render_ms = 0, match_ms = 0, first_match_ms = 0;
  DisparityResult::Timings match_stages;  // the matcher's own stage times
  int searched_disparities = 0;           // per pixel (coarse-to-fine: its lanes)
  double match_peak_rss_mb = NAN;         // process peak RSS while matching (VmHWM)
  // Pixels the station's clean-up removed (0 with --raw): in the whole image,
  // and of those on the object.
  std::size_t speckle_pixels = 0, edge_pixels = 0, textureless_pixels = 0;
  long speckle_object_pixels = 0, edge_object_pixels = 0, textureless_object_pixels = 0;
  long textureless_right_pixels = 0;  // of those on the object, within 1 px of the truth
};

// Resets the process's peak resident set size (Linux: "5" to
// /proc/self/clear_refs), so that PeakRssMb() afterwards tells the peak of
// what follows. False where that is not possible.
bool ResetPeakRss() {
  std::ofstream clear("/proc/self/clear_refs");
  clear << "5";
  clear.close();
  return static_cast<bool>(clear);
}

// VmHWM from /proc/self/status in MB (NaN if unreadable).
double PeakRssMb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  return NAN;
}

// q-quantile (0…1) by nearest rank.
double Quantile(std::vector<double>* values, double q) {
  if (values->empty()) return NAN;
  const std::size_t k = std::min(
      values->size() - 1, static_cast<std::size_t>(std::floor(q * (values->size() - 1) + 0.5)));
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(k),
                   values->end());
  return (*values)[k];
}

nlohmann::ordered_json ToJson(double value) {
  return std::isfinite(value) ? nlohmann::ordered_json(value) : nlohmann::ordered_json(nullptr);
}

class SimDepthCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "sim-depth", "Depth error of rectify + AD-Census + Q on the simulated station");
    sub->add_option("--object", object_, "carved_box, egg, embroidery or mesh:FILE (PLY)")
        ->capture_default_str();
    sub->add_option("--seed", seed_, "Texture and noise seed")->capture_default_str();
    sub->add_option("--threads", threads_, "Threads for rendering and matching")
        ->check(CLI::Range(1, 256))
        ->capture_default_str();
    sub->add_option("--json", json_path_, "Write the results as JSON to this file");
    sub->add_flag("--fill", fill_,
                  "Fill refinement outliers by interpolation (a dense map, as on Middlebury); "
                  "by default they stay invalid, as the reconstruction uses them");
    sub->add_option("--aggregation-iterations", aggregation_iterations_,
                    "AD-Census cross-based aggregation iterations; by default the station's "
                    "(pipeline.aggregation_iterations; the paper's is 4)")
        ->check(CLI::Range(0, 16))
        ->capture_default_str();
    sub->add_option("--lr-tolerance", lr_tolerance_px_,
                    "The matcher's left-right check: |dL - dR| above this (px) is an outlier")
        ->check(CLI::Range(0.0, 64.0))
        ->capture_default_str();
    sub->add_option("--uniqueness", uniqueness_,
                    "The matcher's uniqueness test, [0, 1); 0 = off; the station's is 0.1 "
                    "(view_processing.cc)")
        ->check(CLI::Range(0.0, 0.99))
        ->capture_default_str();
    sub->add_flag("--projector", projector_,
                  "Light the scene with the pattern projector on the camera head (the sim "
                  "driver's `projector: 1`)");
    sub->add_option("--band-margin", band_margin_px_,
                    "Disparities searched beyond the object's true ones on either side (px); "
                    "a station's working-volume band is hundreds wide")
        ->check(CLI::Range(0, 1000))
        ->capture_default_str();
    sub->add_flag("--coarse-to-fine", coarse_to_fine_,
                  "Per-pixel disparity ranges from a coarse pass (CoarseToFineOptions; used for "
                  "bands over 192 disparities)");
    sub->add_option("--lanes", lanes_,
                    "With --coarse-to-fine: disparities searched per pixel "
                    "(CoarseToFineOptions::lanes, a multiple of 16)")
        ->check(CLI::Range(16, 256))
        ->capture_default_str();
    sub->add_option("--repeat", repeat_,
                    "Matcher calls on the same matcher; match_ms is then the median of all but "
                    "the first (which allocates the volumes)")
        ->check(CLI::Range(1, 20))
        ->capture_default_str();
    sub->add_flag("--raw", raw_,
                  "Score the matcher's disparities as they are, without the station's clean-up "
                  "(speckles, depth edges, texture filter)");
    sub->add_option("--match-gamma", match_gamma_,
                    "The matcher sees the pair gamma-encoded with this (the station's "
                    "pipeline.match_gamma; 1 = the linear render)")
        ->check(CLI::Range(1.0, 4.0))
        ->capture_default_str();
    sub->add_option("--min-texture-std", min_texture_std_,
                    "The clean-up's texture filter: drop pixels whose 7x7 grey-level standard "
                    "deviation is below this, outside the platter disc's image as on the station "
                    "(pipeline.min_texture_std; 0 = off)")
        ->check(CLI::Range(0.0, 255.0))
        ->capture_default_str();
    sub->add_option("--bracket", bracket_,
                    "Also render the pair at this multiple of the exposure and match the merge "
                    "(MergeExposures, gamma-encoded; as the station's scan.exposure_bracket or "
                    "automatic bracketing's x8); 1 = one exposure")
        ->check(CLI::Range(1.0, 64.0))
        ->capture_default_str();
    sub->add_option("--save-images", save_images_dir_,
                    "Write the rectified pair and a map of the object's pixels to this folder "
                    "(left.png, right.png, pixels.png: green within 1 px of the truth, red "
                    "further, blue dropped by the matcher, yellow by the clean-up, grey occluded)");
    return sub;
  }

  int Run() override {
    sim::SceneOptions scene_options;
    if (int code = ParseObject(&scene_options); code != kExitOk) return code;
    if (!json_path_.empty()) {  // fail before the run, not after it
      const fs::path parent = fs::path(json_path_).parent_path();
      std::error_code ec;
      if (!parent.empty() && !fs::is_directory(parent, ec)) {
        return DataError("--json: folder '" + parent.string() + "' does not exist");
      }
    }
    scene_options.seed = seed_;
    scene_options.turntable_angle_rad = kTurntableAngleRad;
    sim::RigOptions rig;
    rig.num_threads = threads_;
    rig.seed = seed_;
    if (projector_) scene_options.lighting.projector = sim::ProjectorOnCameraHead(rig);

    std::string error;
    std::unique_ptr<sim::SimStation> station = sim::SimStation::Create(rig, &error);
    if (!station) return DataError(error);
    std::unique_ptr<sim::SimStation> bracketed;
    if (bracket_ != 1) {
      sim::RigOptions longer = rig;
      longer.exposure *= bracket_;
      bracketed = sim::SimStation::Create(longer, &error);
      if (!bracketed) return DataError("--bracket: " + error);
    }
    std::unique_ptr<sim::Scene> scene = sim::Scene::Create(scene_options, &error);
    if (!scene) return DataError(error);

    const int previous_threads = cv::getNumThreads();
    cv::setNumThreads(threads_);
    SimDepthResult result;
    const int code = Measure(*station, bracketed.get(), *scene, &result);
    cv::setNumThreads(previous_threads);
    if (code != kExitOk) return code;

    Print(result);
    if (!json_path_.empty()) return WriteJson(result);
    return kExitOk;
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench sim-depth: " << message << "\n";
    return kExitDataError;
  }
  static int UsageError(const std::string& message) {
    std::cerr << "craftscan-bench sim-depth: " << message << "\nRun with --help for usage.\n";
    return kExitUsage;
  }

  int ParseObject(sim::SceneOptions* options) const {
    const std::string mesh_prefix = "mesh:";
    if (object_.rfind(mesh_prefix, 0) == 0) {
      options->object.type = sim::ObjectType::kMesh;
      options->object.mesh.path = object_.substr(mesh_prefix.size());
      options->object.mesh.size_mm = kMeshSizeMm;
      if (options->object.mesh.path.empty()) return UsageError("--object mesh:FILE needs a file");
      return kExitOk;
    }
    sim::ObjectType type;
    if (!sim::ObjectTypeFromString(object_, &type) || type == sim::ObjectType::kNone ||
        type == sim::ObjectType::kMesh) {
      return UsageError("unknown object '" + object_ +
                        "' (known: carved_box, egg, embroidery, mesh:FILE)");
    }
    options->object.type = type;
    return kExitOk;
  }

  int Measure(const sim::SimStation& station, const sim::SimStation* bracketed,
              const sim::Scene& scene, SimDepthResult* result) const {
    result->object = object_;
    const sim::StereoRender render = station.Render(scene);
    if (!render.IsUsable()) return DataError("render failed: " + render.message);
    result->render_ms = render.render_ms;
    // --bracket: the pair as the station merges it (CaptureStage), gamma-encoded.
    cv::Mat raw_left = render.left, raw_right = render.right;
    if (bracketed) {
      const sim::StereoRender longer = bracketed->Render(scene, 1000);
      if (!longer.IsUsable()) return DataError("bracket render failed: " + longer.message);
      result->render_ms += longer.render_ms;
      std::string error;
      const std::vector<double> t{1.0, bracket_};
      if (!MergeExposures({render.left, longer.left}, t, ExposureMergeOptions{}, &raw_left,
                          &error) ||
          !MergeExposures({render.right, longer.right}, t, ExposureMergeOptions{}, &raw_right,
                          &error))
        return DataError("--bracket: " + error);
    }
    result->dark_untextured_pct = DarkUntexturedSharePct(
        render.left,
        PlatterRegionMask(render.calibration, daemon::PipelineSettings{}.platter_radius_mm),
        AutoBracketOptions{});
    const StereoCalibration& c = render.calibration;
    result->width = c.image_size.width;
    result->height = c.image_size.height;

    // Rectify with the exact calibration.
    cv::Mat map_lx, map_ly, map_rx, map_ry, left, right;
    cv::initUndistortRectifyMap(c.left.camera_matrix, c.left.distortion, c.R1, c.P1, c.image_size,
                                CV_32FC1, map_lx, map_ly);
    cv::initUndistortRectifyMap(c.right.camera_matrix, c.right.distortion, c.R2, c.P2, c.image_size,
                                CV_32FC1, map_rx, map_ry);
    cv::remap(raw_left, left, map_lx, map_ly, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::remap(raw_right, right, map_rx, map_ry, cv::INTER_LINEAR, cv::BORDER_CONSTANT);

    // The matcher's copy gamma-encoded as the station's (ViewProcessorOptions::
    // match_gamma); the texture filter judges the pair as rendered.
    cv::Mat match_left = left, match_right = right;
    if (match_gamma_ != 1 && !bracketed) {  // a merge is encoded already
      cv::Mat table(1, 256, CV_8U);
      for (int i = 0; i < 256; ++i)
        table.at<std::uint8_t>(i) =
            cv::saturate_cast<std::uint8_t>(255 * std::pow(i / 255.0, 1 / match_gamma_));
      match_left = cv::Mat();  // not into left's buffer: the texture filter reads it
      match_right = cv::Mat();
      cv::LUT(left, table, match_left);
      cv::LUT(right, table, match_right);
    }

    // Search range: the object's true disparities plus a margin.
    const cv::Mat& mask = render.rectified_object_mask;
    result->object_pixels = cv::countNonZero(mask);
    if (result->object_pixels == 0) return DataError("the object is not in view");
    cv::minMaxLoc(render.rectified_disparity, &result->gt_disparity_min, &result->gt_disparity_max,
                  nullptr, nullptr, mask);
    result->min_disparity =
        static_cast<int>(std::floor(result->gt_disparity_min)) - band_margin_px_;
    const int max_disparity =
        static_cast<int>(std::ceil(result->gt_disparity_max)) + band_margin_px_;
    result->num_disparities = max_disparity - result->min_disparity + 1;

    ADCensusOptions options;
    options.min_disparity = result->min_disparity;
    options.num_disparities = result->num_disparities;
    options.num_threads = threads_;
    options.aggregation_iterations = aggregation_iterations_;
    options.refinement.lr_tolerance_px = lr_tolerance_px_;
    options.refinement.uniqueness = uniqueness_;
    options.coarse_to_fine.enabled = coarse_to_fine_;
    options.coarse_to_fine.lanes = lanes_;
    // A point cloud wants no invented surface: occluded and mismatched pixels
    // stay invalid unless --fill asks for the dense map.
    options.refinement.interpolate = fill_;
    // The station's scanline penalties (ViewProcessor::Init, view_processing.cc);
    // its uniqueness is --uniqueness's default.
    options.pi1 = 0.5;
    options.pi2 = 6.0;
    const bool peak_reset = ResetPeakRss();
    StereoMatcher matcher(options);
    // The first call allocates the volumes; a station's matcher is reused
    // view after view, so --repeat reports the later calls' median.
    DisparityResult match;
    std::vector<double> times;
    for (int i = 0; i < repeat_; ++i) {
      const auto start = std::chrono::steady_clock::now();
      match = matcher.Compute(match_left, match_right);
      times.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count());
      if (!match.IsUsable()) return DataError("matcher failed: " + match.message);
    }
    result->first_match_ms = times.front();
    if (times.size() > 1) times.erase(times.begin());
    std::sort(times.begin(), times.end());
    result->match_ms = times[times.size() / 2];
    result->match_stages = match.time_ms;
    result->searched_disparities = match.searched_disparities;
    if (peak_reset) result->match_peak_rss_mb = PeakRssMb();
    cv::Mat& disparity = match.disparity;
    const cv::Mat matched = disparity.clone();  // before the clean-up, for --save-images
    if (!raw_) {                                // as ViewProcessor::Process and ReprojectToPoints
      const ViewProcessorOptions station;
      const auto valid_on_object = [&] {
        long n = 0;
        for (int y = 0; y < mask.rows; ++y) {
          const std::uint8_t* m = mask.ptr<std::uint8_t>(y);
          const float* d = disparity.ptr<float>(y);
          for (int x = 0; x < mask.cols; ++x) n += m[x] && IsValidDisparity(d[x]);
        }
        return n;
      };
      long before = valid_on_object();
      result->speckle_pixels = RemoveDisparitySpeckles(
          static_cast<int>(std::lround(station.speckle_max_area_pct / 100 *
                                       static_cast<double>(disparity.total()))),
          station.speckle_range_px, &disparity);
      long after = valid_on_object();
      result->speckle_object_pixels = before - after;
      before = after;
      result->edge_pixels =
          EraseNearDepthEdges(station.depth_edge_radius_px, station.depth_edge_jump_px, &disparity);
      after = valid_on_object();
      result->edge_object_pixels = before - after;
      before = after;
      const cv::Mat textured =
          TextureMask(left, ReprojectOptions{}.texture_window, min_texture_std_);
      // Over the platter the station does not filter (ViewProcessor).
      const cv::Mat over_platter =
          RectifiedPlatterRegion(c, daemon::PipelineSettings{}.platter_radius_mm);
      for (int y = 0; y < disparity.rows; ++y) {
        float* d = disparity.ptr<float>(y);
        const std::uint8_t* t = textured.ptr<std::uint8_t>(y);
        const std::uint8_t* m = mask.ptr<std::uint8_t>(y);
        const float* d_true = render.rectified_disparity.ptr<float>(y);
        for (int x = 0; x < disparity.cols; ++x) {
          if (t[x] || !IsValidDisparity(d[x]) ||
              (!over_platter.empty() && over_platter.at<std::uint8_t>(y, x)))
            continue;
          if (m[x] && std::abs(d[x] - d_true[x]) <= 1.0f) ++result->textureless_right_pixels;
          d[x] = std::numeric_limits<float>::quiet_NaN();
          ++result->textureless_pixels;
        }
      }
      result->textureless_object_pixels = before - valid_on_object();
    }

    // Depth through Q on the object pixels.
    const cv::Matx44d& Q = c.Q;
    std::vector<double> depth_errors, disparity_errors;
    double disparity_bias = 0, depth_bias = 0;
    long bias_pixels = 0;
    for (int y = 0; y < mask.rows; ++y) {
      const std::uint8_t* m = mask.ptr<std::uint8_t>(y);
      const std::uint8_t* seen_right = render.rectified_visible_right.ptr<std::uint8_t>(y);
      const float* d = disparity.ptr<float>(y);
      const float* d_true = render.rectified_disparity.ptr<float>(y);
      const float* z_true = render.rectified_depth_mm.ptr<float>(y);
      for (int x = 0; x < mask.cols; ++x) {
        if (m[x] && seen_right[x]) ++result->nonocc_pixels;
        if (!m[x] || !IsValidDisparity(d[x])) continue;
        const cv::Vec4d p = Q * cv::Vec4d(x, y, d[x], 1);
        if (!(std::abs(p[3]) > 1e-12)) continue;  // at infinity: no depth
        if (seen_right[x]) ++result->valid_nonocc_pixels;
        depth_errors.push_back(std::abs(p[2] / p[3] - z_true[x]));
        disparity_errors.push_back(std::abs(d[x] - d_true[x]));
        if (std::abs(d[x] - d_true[x]) <= 1.0f) {
          disparity_bias += d[x] - d_true[x];
          depth_bias += p[2] / p[3] - z_true[x];
          ++bias_pixels;
        }
      }
    }
    if (bias_pixels > 0) {
      result->disp_bias_px = disparity_bias / static_cast<double>(bias_pixels);
      result->depth_bias_mm = depth_bias / static_cast<double>(bias_pixels);
    }
    result->valid_pixels = static_cast<long>(depth_errors.size());
    result->valid_pct = 100.0 * result->valid_pixels / result->object_pixels;
    result->valid_nonocc_pct = result->nonocc_pixels > 0
                                   ? 100.0 * result->valid_nonocc_pixels / result->nonocc_pixels
                                   : 0.0;
    result->depth_err_median_mm = Quantile(&depth_errors, 0.5);
    result->depth_err_p90_mm = Quantile(&depth_errors, 0.9);
    result->disp_err_median_px = Quantile(&disparity_errors, 0.5);
    const long bad = std::count_if(disparity_errors.begin(), disparity_errors.end(),
                                   [](double e) { return e > 2.0; });
    result->disp_bad2_pct =
        disparity_errors.empty() ? NAN : 100.0 * bad / static_cast<double>(disparity_errors.size());
    if (!save_images_dir_.empty()) return SaveImages(left, right, render, matched, disparity);
    return kExitOk;
  }

  // --save-images: the rectified pair and what became of each object pixel.
  int SaveImages(const cv::Mat& left, const cv::Mat& right, const sim::StereoRender& render,
                 const cv::Mat& matched, const cv::Mat& cleaned) const {
    cv::Mat map;
    if (left.channels() == 1)
      cv::cvtColor(left, map, cv::COLOR_GRAY2BGR);
    else
      left.copyTo(map);
    map.convertTo(map, CV_8UC3, 0.35);  // the scene dimmed under the object's colours
    for (int y = 0; y < map.rows; ++y) {
      const std::uint8_t* m = render.rectified_object_mask.ptr<std::uint8_t>(y);
      const std::uint8_t* seen = render.rectified_visible_right.ptr<std::uint8_t>(y);
      const float* d0 = matched.ptr<float>(y);
      const float* d = cleaned.ptr<float>(y);
      const float* t = render.rectified_disparity.ptr<float>(y);
      cv::Vec3b* out = map.ptr<cv::Vec3b>(y);
      for (int x = 0; x < map.cols; ++x) {
        if (!m[x]) continue;
        if (!seen[x])
          out[x] = {128, 128, 128};
        else if (!IsValidDisparity(d0[x]))
          out[x] = {255, 0, 0};
        else if (!IsValidDisparity(d[x]))
          out[x] = {0, 255, 255};
        else if (std::abs(d[x] - t[x]) <= 1.0f)
          out[x] = {0, 200, 0};
        else
          out[x] = {0, 0, 255};
      }
    }
    std::error_code ec;
    fs::create_directories(save_images_dir_, ec);
    for (const auto& [name, image] : {std::pair<const char*, const cv::Mat&>{"left.png", left},
                                      {"right.png", right},
                                      {"pixels.png", map}}) {
      const std::string path = (fs::path(save_images_dir_) / name).string();
      if (!cv::imwrite(path, image)) return DataError("--save-images: cannot write " + path);
    }
    return kExitOk;
  }

  void Print(const SimDepthResult& r) const {
    char bracket[32] = "";
    if (bracket_ != 1) std::snprintf(bracket, sizeof bracket, ", bracket x%g", bracket_);
    std::printf(
        "sim-depth: %s, seed %llu, %d thread(s), %dx%d, turntable %.0f deg, %s, %s, match gamma "
        "%g%s%s\n",
        r.object.c_str(), static_cast<unsigned long long>(seed_), threads_, r.width, r.height,
        kTurntableAngleRad * 180 / std::numbers::pi, fill_ ? "outliers filled" : "outliers invalid",
        raw_ ? "raw matcher output" : "the station's clean-up", match_gamma_,
        projector_ ? ", projector" : "", bracket);
    std::printf("  object pixels %ld, true disparity %.1f … %.1f px, searched [%d, %d)\n",
                r.object_pixels, r.gt_disparity_min, r.gt_disparity_max, r.min_disparity,
                r.min_disparity + r.num_disparities);
    std::printf(
        "  depth_err_median_mm %.3f  depth_err_p90_mm %.3f  valid_pct %.1f  "
        "valid_nonocc_pct %.1f (of %ld pixels the right camera also sees)  "
        "disp_err_median_px %.3f  disp_bad2_pct %.2f  disp_bias_px %+.4f  depth_bias_mm %+.4f\n",
        r.depth_err_median_mm, r.depth_err_p90_mm, r.valid_pct, r.valid_nonocc_pct, r.nonocc_pixels,
        r.disp_err_median_px, r.disp_bad2_pct, r.disp_bias_px, r.depth_bias_mm);
    if (!raw_)
      std::printf(
          "  removed: speckles %zu  depth edges %zu  textureless %zu pixels "
          "(on the object: %ld, %ld, %ld, of the last %ld within 1 px of the truth)\n",
          r.speckle_pixels, r.edge_pixels, r.textureless_pixels, r.speckle_object_pixels,
          r.edge_object_pixels, r.textureless_object_pixels, r.textureless_right_pixels);
    std::printf(
        "  dark_untextured_pct %.2f (of the platter's pixels in the raw left image; the "
        "station brackets automatically from %.1f)\n",
        r.dark_untextured_pct, AutoBracketOptions{}.min_share_pct);
    std::printf("  render_ms %.0f  match_ms %.0f (first call %.0f)  match_peak_rss_mb %.0f\n",
                r.render_ms, r.match_ms, r.first_match_ms, r.match_peak_rss_mb);
    const DisparityResult::Timings& t = r.match_stages;
    std::printf(
        "  match stages (ms): coarse %.0f  preprocess %.0f  cost %.0f  arms %.0f  aggregation %.0f "
        " "
        "scanline+wta %.0f  refinement %.0f; %d disparities searched per pixel\n",
        t.coarse, t.preprocess, t.cost, t.arms, t.aggregation, t.scanline, t.refinement,
        r.searched_disparities);
    std::fflush(stdout);
  }

  int WriteJson(const SimDepthResult& r) const {
    nlohmann::ordered_json root;
    root["object"] = r.object;
    root["seed"] = seed_;
    root["fill"] = fill_;
    root["aggregation_iterations"] = aggregation_iterations_;
    root["projector"] = projector_;
    root["raw"] = raw_;
    root["match_gamma"] = match_gamma_;
    root["bracket"] = bracket_;
    root["min_texture_std"] = min_texture_std_;
    root["dark_untextured_pct"] = r.dark_untextured_pct;
    root["speckle_pixels"] = r.speckle_pixels;
    root["edge_pixels"] = r.edge_pixels;
    root["textureless_pixels"] = r.textureless_pixels;
    root["speckle_object_pixels"] = r.speckle_object_pixels;
    root["edge_object_pixels"] = r.edge_object_pixels;
    root["textureless_object_pixels"] = r.textureless_object_pixels;
    root["textureless_right_pixels"] = r.textureless_right_pixels;
    root["threads"] = threads_;
    root["width"] = r.width;
    root["height"] = r.height;
    root["turntable_angle_deg"] = kTurntableAngleRad * 180 / std::numbers::pi;
    root["object_pixels"] = r.object_pixels;
    root["gt_disparity_min"] = ToJson(r.gt_disparity_min);
    root["gt_disparity_max"] = ToJson(r.gt_disparity_max);
    root["min_disparity"] = r.min_disparity;
    root["num_disparities"] = r.num_disparities;
    root["depth_err_median_mm"] = ToJson(r.depth_err_median_mm);
    root["depth_err_p90_mm"] = ToJson(r.depth_err_p90_mm);
    root["valid_pct"] = ToJson(r.valid_pct);
    root["valid_nonocc_pct"] = ToJson(r.valid_nonocc_pct);
    root["nonocc_pixels"] = r.nonocc_pixels;
    root["disp_err_median_px"] = ToJson(r.disp_err_median_px);
    root["disp_bias_px"] = ToJson(r.disp_bias_px);
    root["depth_bias_mm"] = ToJson(r.depth_bias_mm);
    root["disp_bad2_pct"] = ToJson(r.disp_bad2_pct);
    root["render_ms"] = ToJson(r.render_ms);
    root["match_ms"] = ToJson(r.match_ms);
    root["first_match_ms"] = ToJson(r.first_match_ms);
    root["match_peak_rss_mb"] = ToJson(r.match_peak_rss_mb);
    const DisparityResult::Timings& t = r.match_stages;
    root["searched_disparities"] = r.searched_disparities;
    root["match_stages_ms"] = {{"coarse", t.coarse},
                               {"preprocess", t.preprocess},
                               {"cost", t.cost},
                               {"arms", t.arms},
                               {"aggregation", t.aggregation},
                               {"scanline", t.scanline},
                               {"refinement", t.refinement}};
    std::ofstream out(json_path_, std::ios::trunc);
    if (out) out << root.dump(2) << "\n";
    out.close();
    if (!out) return DataError("cannot write --json file '" + json_path_ + "'");
    return kExitOk;
  }

  std::string object_ = "carved_box";
  std::uint64_t seed_ = 1;
  int threads_ = 2;
  int repeat_ = 1;
  bool fill_ = false;
  int aggregation_iterations_ = ViewProcessorOptions{}.aggregation_iterations;
  double lr_tolerance_px_ = RefinementOptions{}.lr_tolerance_px;
  double uniqueness_ = 0.1;  // the station's (ViewProcessor::Init, view_processing.cc)
  bool projector_ = false;
  bool raw_ = false;
  int band_margin_px_ = kDisparityMarginPx;
  bool coarse_to_fine_ = false;
  int lanes_ = CoarseToFineOptions{}.lanes;
  std::string json_path_;
  std::string save_images_dir_;
  double match_gamma_ = ViewProcessorOptions{}.match_gamma;
  double bracket_ = 1;
  double min_texture_std_ = ViewProcessorOptions{}.min_texture_std;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeSimDepthCommand() { return std::make_unique<SimDepthCommand>(); }

}  // namespace craftscan::bench
