// `craftscan-bench scan`: a whole turntable scan of a simulated object
// through the code the daemon runs, scored against the renderer's exact
// surface.
//
//   craftscan-bench scan [--object carved_box|egg|embroidery|mesh:FILE]
//                        [--turns 1|2] [--turn2-rotation-deg X,Y,Z] [--views N] [--seed S]
//                        [--threads N] [--image-size WxH]
//                        [--config craftscand.yaml] [--json FILE] [--out DIR]
//
// The run: the sim driver's rig and scene (sim::SimRigOptions /
// SimSceneOptions, as craftscand's sim plugin renders them) with the exact
// calibration, turntable axis included; N views at 360°/N steps; each pair
// through ViewProcessor (rectify, AD-Census over the working volume's band,
// reproject, crop) with the options daemon::ViewOptions makes of the config's
// `pipeline` section; each view's cloud then into an IncrementalScan with
// daemon::ReconstructionOptions as it comes (conditioned and registered onto
// the one before, as the daemon does while the turntable turns), Finish
// after the last, and the outputs encoded (and with --out written, report.html included) as a
// session stores them. Without --config the daemon's defaults apply: the
// working volume a new station starts with.
//
// The truth, in the object's frame (its base on the platter at z = 0):
//   seen      the surface point on the ray of every rectified left pixel that
//             shows the object, in every view (the renderer's exact depth);
//   visible   those also seen by the right camera (not occluded, inside its
//             image): what stereo can reconstruct at all.
// Figures:
//   fused_to_truth_mm  distance from each fused point to the true surface:
//                      the smaller of the distance to the nearest `seen` point
//                      and, for every view, the distance to where that view's
//                      left-camera ray through the point meets the object
//                      (both bound the true distance from above; together
//                      they are within ~0.05 mm of it); median, p95, max
//   outlier_pct        fused points farther than 1 mm from the surface
//   estimated_outlier_pct  what the scan's report estimates without the
//                      truth: fused points farther than 1 mm from the mesh
//   views_to_truth_mm  the same for every view's own cloud at its exact pose
//                      (what stereo alone leaves): median, p95, outlier_pct,
//                      completeness_pct (of all views' points together)
//   view_pose_err_deg  per turn, each view's registered pose against its true
//                      one (rotation, relative to view 0): median, max
//   completeness_pct   `visible` sampled on a 0.5 mm grid: the share with a
//                      fused point within 1 mm
//   mesh_to_truth_mm   the same distance for the mesh vertices more than 1 mm
//                      above the platter (a turn never sees the base, which
//                      Poisson closes by guess); median, p95
//   mesh_completeness_pct  `visible` on the 0.5 mm grid: the share with a
//                      mesh vertex within 1 mm (holes in the mesh)
//   mesh_largest_component_pct  faces in the largest connected component
//   fused_obb_mm, truth_obb_mm  oriented boxes (ComputeOrientedBox) of the
//                      fused cloud and of `seen` on the 0.5 mm grid (as even
//                      as fusion's voxels), extents descending;
//                      obb_error_mm their absolute differences;
//                      truth_on_fused_axes_mm the truth's extents along the
//                      fused box's axes (trimmed alike), obb_error_same_axes_mm
//                      the fused box's differences from those (two searches
//                      can settle in different orientations of nearly equal
//                      volume on an irregular figure)
//   box_edges_mm       carved_box: the 12 measured edges against the true
//                      width × depth × height: mean, std, max |error|
//   truth_box_edges_mm the same measurement (MeasureBox, the scan's options)
//                      on the true surface the cameras saw: the error the
//                      measurement itself makes of the carved faces
//   times_ms           render (all views), match_per_view_median (one view's
//                      ViewProcessor::Process), register (all views' and the
//                      closing edge's, incl. loop closure), fuse, mesh,
//                      after_last_capture (from the last pair in hand to the
//                      model encoded or written: the last view's matching,
//                      conditioning and registration, then Finish)
// --out also writes fused_error.ply: the fused cloud in the object frame
// coloured by that distance (green ≤ 0.5 mm, yellow ≤ 1 mm, red beyond),
// mesh_error.ply: the mesh's scored vertices (mesh_to_truth) coloured alike,
// missed.ply: the visible surface's grid samples no fused point covers, and
// truth_seen.ply: the `seen` truth points on the grid (what truth_obb_mm
// boxes), truth_visible.ply: the `visible` ones (what completeness counts),
// and views.ply: every view's own cloud at its exact pose (what stereo alone
// leaves, before fusion), view k of N coloured at hue 360°·k/N (view 0 red).
// --turns 2: a second turn of as many views with the object laid in another
// pose (--turn2-rotation-deg rx,ry,rz, the sim driver's object_rotation_deg;
// default 90,0,0: on its side), each turn reconstructed up to its fused
// cloud, then JoinTurnScans (turn_join.h: turn B onto turn A without a
// prior, platter contact dropped, one fusion, mesh and measurement). The
// truth is then both turns' views in the object frame, so completeness_pct
// counts the whole surface the two turns can see, the base included, and
// mesh_to_truth scores every vertex. Added: turn_join (the verdict, its
// overlap, RMSE, ambiguity, constraint), turn_rot_err_deg and
// turn_trans_err_mm (the join against the truth: the rotation's angle, and
// the displacement of turn B's fused centroid), first_turn_completeness_pct
// (turn A alone against the same truth). A refused join exits 1 with
// "status": "refused", the reason in "message" and the refused placement's
// error against the truth.
// A scan that fails (e.g. a registration refused) is reported with its
// message and exits 1; the JSON then has "status": "failed".
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <numbers>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "craftscan/daemon/config.h"
#include "craftscan/daemon/glb.h"
#include "craftscan/daemon/report.h"
#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "scan_eval.h"
#include "turn_files.h"

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr double kGridMm = 0.5;      // completeness sampling
constexpr double kGateMm = 1.0;      // completeness and outlier distance
constexpr double kBaseBandMm = 1.0;  // mesh vertices lower than this are not scored
// Upper edges of the fused-error histogram's bins (mm); the last is open.
constexpr double kHistogramMm[] = {0.25, 0.5, 1, 2, 5, 20};

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

cv::Vec3f Apply(const cv::Matx44d& T, const cv::Vec3f& p) {
  const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
  return {static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2])};
}

nlohmann::ordered_json Number(double value) {
  return std::isfinite(value) ? nlohmann::ordered_json(value) : nlohmann::ordered_json(nullptr);
}

nlohmann::ordered_json Extents(const cv::Vec3d& e) { return {e[0], e[1], e[2]}; }

// One view's pose and where its left camera is, for the ray distances.
struct ViewGeometry {
  sim::Scene* scene = nullptr;  // its turn's scene (the object's pose in that turn)
  double angle_rad = 0;
  cv::Matx44d world_from_object = cv::Matx44d::eye();
  cv::Matx44d object_from_rig = cv::Matx44d::eye();
};

struct Figures {
  std::size_t fused_points = 0, truth_seen = 0, truth_visible_grid = 0, mesh_vertices = 0;
  double fused_median = NAN, fused_p95 = NAN, fused_max = NAN, outlier_pct = NAN;
  std::optional<double> estimated_outlier_pct;  // the scan report's (quality.h)
  double completeness_pct = NAN;
  double mesh_median = NAN, mesh_p95 = NAN, mesh_completeness_pct = NAN;
  // Every view's own cloud (ViewProcessor's output) at its exact pose: what
  // stereo alone leaves, before registration and fusion.
  double views_median = NAN, views_p95 = NAN, views_outlier_pct = NAN, views_completeness_pct = NAN;
  std::vector<double> fused_histogram;  // % of fused points per kHistogramMm bin
  MeshComponents components;
  cv::Vec3d fused_obb{0, 0, 0}, truth_obb{0, 0, 0};
  // The truth's trimmed extents along the fused box's own axes.
  cv::Vec3d truth_on_fused_axes{0, 0, 0};
  std::optional<cv::Vec3d> box_edges;        // mean, std, max |error|
  std::optional<cv::Vec3d> truth_box_edges;  // the same measured on the true surface
};

struct Times {
  double render = 0, match_median = NAN, reg = 0, fuse = 0, mesh = 0, after_last = 0;
};

// One turn as captured: what the scan got and the truth of its views.
struct TurnCapture {
  std::vector<ScanView> views;
  std::vector<ViewGeometry> geometry;
  std::vector<cv::Vec3f> seen, visible;  // object frame
  ScanResult result;
  cv::Matx44d object_from_result = cv::Matx44d::eye();
};

// --turns 2: the join against the truth.
struct TurnFigures {
  double rot_err_deg = NAN, trans_err_mm = NAN;
  double first_turn_completeness_pct = NAN;  // turn A alone against both turns' visible surface
};

class ScanCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "scan",
        "A whole simulated turntable scan through the daemon's per-view and reconstruction "
        "code, scored against the exact surface");
    sub->footer(
        "The truth: the renderer's exact surface point on the ray of every rectified left\n"
        "pixel that shows the object, in every view ('seen'); 'visible' keeps those the right\n"
        "camera sees too. fused_to_truth: per fused point the smaller of the distance to the\n"
        "nearest seen point and, per view, to where that view's left-camera ray through it\n"
        "meets the object. completeness: visible on a 0.5 mm grid with a fused point within\n"
        "1 mm. outlier_pct: fused points > 1 mm from the surface. mesh_to_truth: mesh vertices\n"
        "more than 1 mm above the platter (the base is never seen). Without --config the\n"
        "daemon's default pipeline settings apply (the working volume a new station has).");
    sub->add_option("--object", object_,
                    "carved_box, egg, embroidery or mesh:FILE (PLY, mm, +Z up)")
        ->capture_default_str();
    sub->add_option("--mesh-size", mesh_size_mm_,
                    "mesh:FILE only: scale so the largest extent is this (mm); 0 keeps the file's "
                    "millimetres")
        ->check(CLI::Range(0.0, 2000.0))
        ->capture_default_str();
    sub->add_option("--turns", turns_,
                    "1, or 2: a second turn with the object laid in another pose "
                    "(--turn2-rotation-deg), joined onto the first without a prior "
                    "(turn_join.h); completeness then counts both turns' visible surface, the "
                    "base included, and turn_rot_err_deg / turn_trans_err_mm score the join")
        ->check(CLI::Range(1, 2))
        ->capture_default_str();
    sub->add_option("--turn2-rotation-deg", turn2_rotation_deg_,
                    "rx,ry,rz: the second turn's pose, as the sim driver's object_rotation_deg "
                    "(about x, then y, then z, fixed axes; then seated on the platter); the "
                    "default lays the object on its side")
        ->delimiter(',')
        ->expected(3)
        ->capture_default_str();
    sub->add_option("--views", views_, "Views over one turn (360°/N apart)")
        ->check(CLI::Range(2, 72))
        ->capture_default_str();
    sub->add_option("--seed", seed_, "Texture, carving and noise seed")->capture_default_str();
    sub->add_option("--threads", threads_, "Threads for rendering, matching and reconstruction")
        ->check(CLI::Range(1, 256))
        ->capture_default_str();
    sub->add_option("--image-size", image_size_, "WxH: the default rig scaled to it")
        ->capture_default_str();
    sub->add_option("--config", config_path_,
                    "A craftscand config: its pipeline section (volume, texture threshold, band, "
                    "mesh, measure_box) is used");
    sub->add_flag("--projector", projector_,
                  "A pattern projector beside the cameras (the sim driver's `projector: 1`)");
    sub->add_option("--bracket", bracket_,
                    "Exposure bracketing: each view also captured at these multiples of the "
                    "exposure and merged, as the daemon's scan.exposure_bracket (which --config "
                    "sets when this is not given)")
        ->delimiter(',');
    sub->add_flag("--no-auto-bracket", no_auto_bracket_,
                  "Without --bracket (and a config's list): never bracket; by default a view "
                  "dark without texture on enough of the platter is also captured at 8 × the "
                  "exposure, as the daemon's scan.auto_bracket");
    sub->add_option("--json", json_path_, "Write the figures as JSON to this file");
    sub->add_option("--save-turns", save_turns_dir_,
                    "--turns 2: write both turns' fused clouds (turn_a.ply, turn_b.ply, each in "
                    "its own turntable frame) and the true join (truth_a_from_b.txt) into this "
                    "folder (created), for `craftscan-bench turn-join`");
    sub->add_option(
        "--out", out_dir_,
        "Write fused.ply, mesh.ply, mesh.obj, mesh.glb, report.json and report.html (with "
        "previews/) into this folder (created), with fused_error.ply, mesh_error.ply and "
        "missed.ply (where outliers are and what completeness misses)");
    return sub;
  }

  int Run() override {
    sim::SimDriverOptions driver;
    if (int code = ParseArguments(&driver); code != kExitOk) return code;
    daemon::DaemonConfig config;
    std::string error;
    if (!config_path_.empty() && !daemon::LoadDaemonConfig(config_path_, &config, &error))
      return DataError("--config: " + error);
    daemon::PipelineSettings settings = config.pipeline;
    if (bracket_.empty()) bracket_ = config.scan.exposure_bracket;
    config.scan.exposure_bracket = bracket_;
    auto_bracket_ = bracket_.empty() && config.scan.auto_bracket && !no_auto_bracket_;
    if (!config.IsValid(&error)) return UsageError("--bracket: " + error);
    settings.threads = threads_;

    sim::RigOptions rig = sim::SimRigOptions(driver);
    rig.num_threads = threads_;
    sim::SceneOptions scene_options = sim::SimSceneOptions(driver);
    if (!mesh_path_.empty()) {
      scene_options.object.type = sim::ObjectType::kMesh;
      scene_options.object.mesh.path = mesh_path_;
      scene_options.object.mesh.size_mm = mesh_size_mm_;
    }
    std::unique_ptr<sim::SimStation> station = sim::SimStation::Create(rig, &error);
    if (!station) return DataError(error);
    for (double k : bracket_) {
      sim::RigOptions longer = rig;
      longer.exposure *= k;
      std::unique_ptr<sim::SimStation> s = sim::SimStation::Create(longer, &error);
      if (!s) return DataError("--bracket: " + error);
      bracketed_.push_back(std::move(s));
    }
    if (auto_bracket_) {  // the exposure automatic bracketing adds
      sim::RigOptions longer = rig;
      longer.exposure *= AutoBracketOptions{}.multiple;
      auto_bracketed_ = sim::SimStation::Create(longer, &error);
      if (!auto_bracketed_) return DataError("automatic bracketing: " + error);
      auto_region_ = PlatterRegionMask(station->calibration(), settings.platter_radius_mm);
    }
    std::unique_ptr<sim::Scene> scene = sim::Scene::Create(scene_options, &error);
    if (!scene) return DataError(error);
    std::unique_ptr<sim::Scene> second;
    if (turns_ == 2) {
      if (turn2_rotation_deg_.size() != 3) return UsageError("--turn2-rotation-deg needs rx,ry,rz");
      sim::SimDriverOptions laid = driver;
      for (int i = 0; i < 3; ++i)
        laid.object_rotation_deg[i] = turn2_rotation_deg_[static_cast<std::size_t>(i)];
      if (!laid.IsValid(&error)) return UsageError("--turn2-rotation-deg: " + error);
      sim::SceneOptions second_options = scene_options;
      second_options.object.rotation_rad = sim::SimSceneOptions(laid).object.rotation_rad;
      second = sim::Scene::Create(second_options, &error);
      if (!second) return DataError("the second turn's scene: " + error);
    }

    const int previous_threads = cv::getNumThreads();
    cv::setNumThreads(threads_);
    const int code = Scan(*station, *scene, second.get(), settings);
    cv::setNumThreads(previous_threads);
    return code;
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench scan: " << message << "\n";
    return kExitDataError;
  }
  static int UsageError(const std::string& message) {
    std::cerr << "craftscan-bench scan: " << message << "\nRun with --help for usage.\n";
    return kExitUsage;
  }

  int ParseArguments(sim::SimDriverOptions* driver) {
    const std::string mesh_prefix = "mesh:";
    if (object_.rfind(mesh_prefix, 0) == 0) {
      mesh_path_ = object_.substr(mesh_prefix.size());
      if (mesh_path_.empty()) return UsageError("--object mesh:FILE needs a file");
      std::error_code ec;
      if (!fs::is_regular_file(mesh_path_, ec))
        return DataError("--object: mesh file '" + mesh_path_ + "' does not exist");
      driver->object = sim::ObjectType::kCarvedBox;  // replaced by the mesh below
    } else if (!sim::ObjectTypeFromString(object_, &driver->object) ||
               driver->object == sim::ObjectType::kNone ||
               driver->object == sim::ObjectType::kMesh) {
      return UsageError("unknown object '" + object_ +
                        "' (known: carved_box, egg, embroidery, mesh:FILE)");
    }
    int w = 0, h = 0;
    char x = 0, rest = 0;
    if (std::sscanf(image_size_.c_str(), "%d%c%d%c", &w, &x, &h, &rest) != 3 || x != 'x' ||
        w < 64 || h < 64 || w > 8192 || h > 8192)
      return UsageError("--image-size must be WxH within 64x64..8192x8192, got '" + image_size_ +
                        "'");
    driver->image_size = cv::Size(w, h);
    driver->seed = seed_;
    driver->threads = threads_;
    driver->projector = projector_;
    for (const std::string* path : {&json_path_, &out_dir_}) {  // fail before the run
      if (path->empty()) continue;
      const fs::path parent = fs::absolute(*path).parent_path();
      std::error_code ec;
      if (!fs::is_directory(parent, ec))
        return DataError("folder '" + parent.string() + "' (of '" + *path + "') does not exist");
    }
    return kExitOk;
  }

  static std::string TurnName(int turn) { return turn == 0 ? "" : "turn 2: "; }

  // One turn: every view rendered, matched and added to an IncrementalScan
  // as the daemon does, then Finish; the truth of its views into *out.
  int CaptureTurn(int turn, const sim::SimStation& station, sim::Scene& scene,
                  ViewProcessor& processor, const ScanOptions& options, Times* times,
                  std::vector<double>* process_ms, Clock::time_point* last_pair, TurnCapture* out) {
    const StereoCalibration& calibration = station.calibration();
    std::string error;
    const double f = calibration.P1(0, 0), cx = calibration.P1(0, 2), cy = calibration.P1(1, 2);
    const cv::Matx44d world_from_rig = station.world_from_rig();
    IncrementalScan scan(calibration.turntable, options);
    for (int k = 0; k < views_; ++k) {
      ViewGeometry g;
      g.scene = &scene;
      g.angle_rad = 2 * std::numbers::pi * k / views_;
      scene.SetTurntableAngle(g.angle_rad);
      const sim::StereoRender render = station.Render(scene, static_cast<std::uint64_t>(k));
      if (!render.IsUsable())
        return DataError(TurnName(turn) + "view " + std::to_string(k) +
                         ": render failed: " + render.message);
      times->render += render.render_ms;
      g.world_from_object = render.world_from_object;
      g.object_from_rig = render.world_from_object.inv() * world_from_rig;
      const cv::Matx44d& object_from_rig = g.object_from_rig;
      for (int y = 0; y < render.rectified_object_mask.rows; ++y) {
        const std::uint8_t* mask = render.rectified_object_mask.ptr<std::uint8_t>(y);
        const std::uint8_t* right = render.rectified_visible_right.ptr<std::uint8_t>(y);
        const float* z = render.rectified_depth_mm.ptr<float>(y);
        for (int x = 0; x < render.rectified_object_mask.cols; ++x) {
          if (!mask[x] || !std::isfinite(z[x])) continue;
          const cv::Vec3f p =
              Apply(object_from_rig, cv::Vec3f(static_cast<float>((x - cx) * z[x] / f),
                                               static_cast<float>((y - cy) * z[x] / f), z[x]));
          out->seen.push_back(p);
          if (right[x]) out->visible.push_back(p);
        }
      }
      cv::Mat texture;  // with a projector: the left view with it off, as the sim driver does
      if (scene.SetProjectorOn(false)) {
        const sim::StereoRender t = station.Render(scene, static_cast<std::uint64_t>(k),
                                                   sim::RenderOutputs::kLeftImageOnly);
        scene.SetProjectorOn(true);
        if (!t.IsUsable())
          return DataError(TurnName(turn) + "view " + std::to_string(k) +
                           ": texture render failed: " + t.message);
        times->render += t.render_ms;
        texture = t.left;
      }
      cv::Mat left = render.left, right = render.right;
      double pair_gamma = 1.0;  // a merge is gamma-encoded (ViewProcessor::Process)
      if (auto_bracket_) {      // as CaptureStage::CaptureView
        const AutoBracketOptions automatic;
        const double dark = DarkUntexturedSharePct(render.left, auto_region_, automatic);
        if (dark >= automatic.min_share_pct) {
          const sim::StereoRender e =
              auto_bracketed_->Render(scene, static_cast<std::uint64_t>(k + 1000));
          if (!e.IsUsable()) return DataError("bracket render failed: " + e.message);
          times->render += e.render_ms;
          ++auto_bracketed_views_;
          pair_gamma = ExposureMergeOptions{}.gamma;
          const std::vector<double> t{1.0, automatic.multiple};
          if (!MergeExposures({render.left, e.left}, t, ExposureMergeOptions{}, &left, &error) ||
              !MergeExposures({render.right, e.right}, t, ExposureMergeOptions{}, &right, &error))
            return DataError(error);
          std::printf("  %sview %d/%d: %.1f %% of the platter dark without texture: also x%g\n",
                      turn == 0 ? "" : "turn 2 ", k + 1, views_, dark, automatic.multiple);
        }
      }
      if (!bracketed_.empty()) {
        std::vector<cv::Mat> ls{render.left}, rs{render.right};
        std::vector<double> t{1.0};
        for (std::size_t b = 0; b < bracketed_.size(); ++b) {
          const sim::StereoRender e =
              bracketed_[b]->Render(scene, static_cast<std::uint64_t>(k + 1000 * (b + 1)));
          if (!e.IsUsable()) return DataError("bracket render failed: " + e.message);
          times->render += e.render_ms;
          ls.push_back(e.left);
          rs.push_back(e.right);
          t.push_back(bracket_[b]);
        }
        ExposureMergeOptions mo;
        if (!MergeExposures(ls, t, mo, &left, &error) || !MergeExposures(rs, t, mo, &right, &error))
          return DataError(error);
        pair_gamma = mo.gamma;
      }
      if (k == views_ - 1) *last_pair = Clock::now();
      const auto start = Clock::now();
      ProcessedView v = processor.Process(left, right, texture, pair_gamma);
      process_ms->push_back(MsSince(start));
      if (!v.ok) return DataError(TurnName(turn) + "view " + std::to_string(k) + ": " + v.message);
      ScanView view;
      view.cloud_in_rig = std::move(v.cloud_in_rig);
      view.commanded_angle_rad = g.angle_rad;
      out->views.push_back(view);  // kept for the figures
      scan.Add(std::move(view));
      out->geometry.push_back(g);
      std::printf(
          "  %sview %d/%d at %.0f°: %zu points (render %.0f ms, process %.0f ms: rectify %.0f, "
          "match %.0f over [%d, %d) px, reproject %.0f)\n",
          turn == 0 ? "" : "turn 2 ", k + 1, views_, g.angle_rad * 180 / std::numbers::pi,
          out->views.back().cloud_in_rig.size(), render.render_ms, process_ms->back(), v.rectify_ms,
          v.match_ms, v.min_disparity, v.min_disparity + v.num_disparities, v.reproject_ms);
      std::fflush(stdout);
    }
    out->result = scan.Finish();
    // The scan's frame (view 0's turntable frame) into the object frame.
    const cv::Matx44d view0_from_result = out->result.turntable_from_view0
                                              ? out->result.turntable_from_view0->inv()
                                              : cv::Matx44d::eye();
    out->object_from_result =
        out->geometry[0].world_from_object.inv() * world_from_rig * view0_from_result;
    // Each view's pose as registered against its true pose, both relative to
    // view 0 (whose pose defines the scan's frame).
    if (out->result.view0_from_view.size() == out->geometry.size()) {
      std::vector<double> errors;
      for (std::size_t k = 1; k < out->geometry.size(); ++k) {
        const cv::Matx44d truth =
            out->geometry[0].object_from_rig.inv() * out->geometry[k].object_from_rig;
        errors.push_back(RotationErrorDeg(truth, out->result.view0_from_view[k]));
      }
      if (!errors.empty()) {
        std::sort(errors.begin(), errors.end());
        pose_errors_.push_back({errors[errors.size() / 2], errors.back()});
        std::printf("  %sview poses against the truth: median %.3f°, max %.3f°\n",
                    turn == 0 ? "" : "turn 2 ", errors[errors.size() / 2], errors.back());
      }
    }
    return kExitOk;
  }

  int Scan(const sim::SimStation& station, sim::Scene& scene, sim::Scene* second,
           const daemon::PipelineSettings& settings) {
    const StereoCalibration& calibration = station.calibration();
    ViewProcessor processor;
    std::string error;
    if (!processor.Init(calibration, daemon::ViewOptions(settings), &error))
      return DataError("view processing: " + error);

    std::vector<double> process_ms;
    Times times;
    Clock::time_point last_pair;
    // As the daemon does: each view conditioned and registered onto the one
    // before as it comes (while a station's turntable turns), the rest after
    // the last view. With two turns each turn stops at its fused cloud and
    // the join meshes and measures once.
    ScanOptions options = daemon::ReconstructionOptions(settings);
    options.camera = RectifiedLeftCamera(calibration);
    ScanOptions turn_options = options;
    if (second) turn_options.mesh = false;
    std::vector<TurnCapture> turns(second ? 2 : 1);
    for (std::size_t t = 0; t < turns.size(); ++t) {
      if (int code = CaptureTurn(static_cast<int>(t), station, t == 0 ? scene : *second, processor,
                                 turn_options, &times, &process_ms, &last_pair, &turns[t]);
          code != kExitOk)
        return code;
    }
    times.match_median = Quantile(process_ms, 0.5);
    if (second && !save_turns_dir_.empty()) {
      const cv::Matx44d truth = turns[0].object_from_result.inv() * turns[1].object_from_result;
      if (std::string why;
          !SaveTurns(save_turns_dir_, turns[0].result.fused, turns[1].result.fused, truth, &why))
        return DataError("--save-turns: " + why);
      for (std::size_t t = 0; t < 2; ++t) {
        const std::string path =
            (fs::path(save_turns_dir_) / (t == 0 ? "turn_a.json" : "turn_b.json")).string();
        if (Status s = WriteFileAtomically(path, ScanReportJson(turns[t].result)); !s.ok())
          return DataError("--save-turns: " + s.message());
        // The turn's frame in the object frame, and the true surface its views saw
        // (object frame), to score each turn on its own.
        {
          std::ostringstream m;
          m.precision(17);
          for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
              m << turns[t].object_from_result(r, c) << (c == 3 ? '\n' : ' ');
          PointCloud seen_cloud;
          seen_cloud.points_mm = turns[t].seen;
          const std::string stem = t == 0 ? "turn_a" : "turn_b";
          if (Status s = WriteFileAtomically(
                  (fs::path(save_turns_dir_) / (stem + "_object_from_turn.txt")).string(), m.str());
              !s.ok())
            return DataError("--save-turns: " + s.message());
          if (Status s = WriteFileAtomically(
                  (fs::path(save_turns_dir_) / (stem + "_truth_seen.ply")).string(),
                  EncodePly(seen_cloud, true));
              !s.ok())
            return DataError("--save-turns: " + s.message());
        }
        // Each view's conditioned cloud (what fusion starts from), in the turn's frame.
        const ScanResult& tr = turns[t].result;
        const cv::Matx44d out_from_view0 = tr.turntable_from_view0.value_or(cv::Matx44d::eye());
        for (std::size_t k = 0; k < tr.views.size() && k < tr.view0_from_view.size(); ++k) {
          const std::string name =
              std::string(t == 0 ? "turn_a" : "turn_b") + "_view" + std::to_string(k) + ".ply";
          const PointCloud c =
              TransformCloud(out_from_view0 * tr.view0_from_view[k], tr.views[k].fine);
          if (Status s = WriteFileAtomically((fs::path(save_turns_dir_) / name).string(),
                                             EncodePly(c, true));
              !s.ok())
            return DataError("--save-turns: " + s.message());
        }
      }
    }
    ScanResult r = second
                       ? JoinTurnScans(turns[0].result, turns[1].result, options, TurnJoinOptions{})
                       : std::move(turns[0].result);
    if (r.IsUsable()) {
      if (std::string why; !StoreOutputs(r, calibration, &why)) return DataError(why);
    }
    times.after_last = MsSince(last_pair);
    times.reg = r.register_ms + r.loop_ms;
    times.fuse = r.fuse_ms;
    times.mesh = r.mesh_ms;
    // Both turns' views and truth together, in the object frame.
    std::vector<ScanView> views;
    std::vector<ViewGeometry> geometry;
    std::vector<cv::Vec3f> seen, visible;
    for (const TurnCapture& t : turns) {
      views.insert(views.end(), t.views.begin(), t.views.end());
      geometry.insert(geometry.end(), t.geometry.begin(), t.geometry.end());
      seen.insert(seen.end(), t.seen.begin(), t.seen.end());
      visible.insert(visible.end(), t.visible.begin(), t.visible.end());
    }
    std::optional<TurnFigures> turn_figures;
    if (second && r.turn_join && r.turn_join->status != TurnJoinResult::Status::kFailed) {
      // The join against the truth: turn B's frame → turn A's.
      TurnFigures tf;
      const cv::Matx44d truth = turns[0].object_from_result.inv() * turns[1].object_from_result;
      const cv::Matx44d& found = r.turn_join->a_from_b;
      tf.rot_err_deg = RotationErrorDeg(found, truth);
      // At the object: the centre of turn B's fused cloud.
      cv::Vec3d centre(0, 0, 0);
      for (const cv::Vec3f& p : turns[1].result.fused.points_mm) centre += cv::Vec3d(p);
      if (!turns[1].result.fused.empty())
        centre /= static_cast<double>(turns[1].result.fused.size());
      const cv::Vec4d c(centre[0], centre[1], centre[2], 1);
      const cv::Vec4d d = found * c - truth * c;
      tf.trans_err_mm = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      std::vector<cv::Vec3f> first;
      for (const cv::Vec3f& p : turns[0].result.fused.points_mm)
        first.push_back(Apply(turns[0].object_from_result, p));
      if (!first.empty())
        tf.first_turn_completeness_pct =
            CoveredPct(NearestDistances(NearestIndex(first), GridSample(visible, kGridMm)));
      turn_figures = tf;
    }
    if (!r.IsUsable()) {
      Print(nullptr, times, r.message);
      if (turn_figures) PrintTurns(*turn_figures, r);  // the refused placement's error too
      if (!json_path_.empty()) WriteJson(nullptr, times, r, turn_figures);
      return DataError("the scan failed: " + r.message);
    }

    // Fused cloud and mesh into the object frame (turn A's view 0 is the rig at angle 0).
    const cv::Matx44d& object_from_result = turns[0].object_from_result;
    std::vector<cv::Vec3f> fused, vertices;
    for (const cv::Vec3f& p : r.fused.points_mm) fused.push_back(Apply(object_from_result, p));
    if (r.mesh.status == MeshResult::Status::kOk)
      for (const cv::Vec3f& p : r.mesh.mesh.vertices_mm) {
        const cv::Vec3f q = Apply(object_from_result, p);
        if (second || q[2] > kBaseBandMm) vertices.push_back(q);
      }

    Figures fig;
    const NearestIndex truth(seen);
    const std::vector<double> fused_d = SurfaceDistances(truth, station, geometry, fused);
    fig.fused_points = fused.size();
    fig.truth_seen = seen.size();
    fig.fused_median = Quantile(fused_d, 0.5);
    fig.fused_p95 = Quantile(fused_d, 0.95);
    fig.fused_max = fused_d.empty() ? NAN : *std::max_element(fused_d.begin(), fused_d.end());
    fig.outlier_pct = OutlierPct(fused_d);
    if (r.quality.ok) fig.estimated_outlier_pct = r.quality.far_pct;
    fig.fused_histogram.assign(std::size(kHistogramMm) + 1, 0.0);
    for (double d : fused_d) {
      const auto bin = std::lower_bound(std::begin(kHistogramMm), std::end(kHistogramMm), d) -
                       std::begin(kHistogramMm);
      fig.fused_histogram[static_cast<std::size_t>(bin)] +=
          100.0 / static_cast<double>(fused_d.size());
    }
    std::vector<cv::Vec3f> raw;
    std::vector<cv::Vec3b> raw_view_colors;  // views.ply: view k at hue 360°·k/N
    for (std::size_t k = 0; k < views.size(); ++k) {
      cv::Mat3b hsv(1, 1, cv::Vec3b(static_cast<uchar>(180 * k / views.size()), 255, 255)), rgb;
      cv::cvtColor(hsv, rgb, cv::COLOR_HSV2RGB);
      for (const cv::Vec3f& p : views[k].cloud_in_rig.points_mm) {
        raw.push_back(Apply(geometry[k].object_from_rig, p));
        raw_view_colors.push_back(rgb(0, 0));
      }
    }
    const std::vector<double> raw_d = SurfaceDistances(truth, station, geometry, raw);
    fig.views_median = Quantile(raw_d, 0.5);
    fig.views_p95 = Quantile(raw_d, 0.95);
    fig.views_outlier_pct = OutlierPct(raw_d);
    const std::vector<cv::Vec3f> grid = GridSample(visible, kGridMm);
    fig.truth_visible_grid = grid.size();
    const NearestIndex fused_index(fused);
    const std::vector<double> covered = NearestDistances(fused_index, grid);
    fig.completeness_pct = CoveredPct(covered);
    fig.views_completeness_pct = CoveredPct(NearestDistances(NearestIndex(raw), grid));
    const std::vector<double> mesh_d = SurfaceDistances(truth, station, geometry, vertices);
    fig.mesh_vertices = vertices.size();
    fig.mesh_median = Quantile(mesh_d, 0.5);
    fig.mesh_p95 = Quantile(mesh_d, 0.95);
    fig.components = CountComponents(r.mesh.mesh);
    if (!vertices.empty())
      fig.mesh_completeness_pct = CoveredPct(NearestDistances(NearestIndex(vertices), grid));
    fig.fused_obb = r.box.extents_mm;
    // Sampled evenly, as fusion's voxels sample the fused cloud, so that the
    // box's trim (OrientedBoxOptions::trim_fraction of the points at each
    // end) cuts the same share of surface from both: `seen` itself is dense
    // where the surface faces a camera and sparse where it turns away (the
    // owl's foot: its lowest 0.1 % of seen points end 0.3 mm higher than the
    // fused cloud's, 1.1 mm on the box's tilted long axis).
    PointCloud truth_cloud;
    truth_cloud.points_mm = GridSample(seen, kGridMm);
    // Upright like the scan's when the scan has a turntable frame: its z
    // (the platter's normal) in the object's frame.
    OrientedBoxOptions truth_box_options;
    if (r.turntable_from_view0)
      truth_box_options.up = object_from_result.get_minor<3, 3>(0, 0) * cv::Vec3d(0, 0, 1);
    OrientedBox truth_box;
    if (ComputeOrientedBox(truth_cloud, truth_box_options, &truth_box, &error))
      fig.truth_obb = truth_box.extents_mm;
    // Each box is a local minimum of the volume. Where two orientations
    // enclose nearly the same volume (an irregular figure whose two shorter
    // sides are alike) the two clouds' searches can settle in different
    // ones and their extents differ by a millimetre though the clouds agree;
    // the truth along the fused box's axes tells the two apart.
    const cv::Matx33d axes_in_object = object_from_result.get_minor<3, 3>(0, 0) * r.box.axes;
    for (int k = 0; k < 3; ++k) {
      std::vector<double> along;
      along.reserve(truth_cloud.points_mm.size());
      const cv::Vec3d axis(axes_in_object(0, k), axes_in_object(1, k), axes_in_object(2, k));
      for (const cv::Vec3f& p : truth_cloud.points_mm) along.push_back(axis.dot(cv::Vec3d(p)));
      const double trim = OrientedBoxOptions{}.trim_fraction;
      fig.truth_on_fused_axes[k] = Quantile(along, 1 - trim) - Quantile(along, trim);
    }
    if (scene.options().object.type == sim::ObjectType::kCarvedBox && r.box_measurement &&
        r.box_measurement->IsUsable())
      fig.box_edges = EdgeErrors(*r.box_measurement, scene.options().object.carved_box);
    if (scene.options().object.type == sim::ObjectType::kCarvedBox && options.measure_box) {
      // The same measurement on the true surface the cameras saw: what the
      // measurement itself makes of the carved faces.
      PointCloud truth_in_result;
      const cv::Matx44d result_from_object = object_from_result.inv();
      for (const cv::Vec3f& p : truth_cloud.points_mm)
        truth_in_result.points_mm.push_back(Apply(result_from_object, p));
      BoxMeasureOptions box = options.box;
      if (r.turntable_from_view0 && !box.base_plane) {
        Plane platter;
        platter.normal = cv::Vec3d(0, 0, 1);
        platter.offset_mm = 0;
        platter.given = true;
        box.base_plane = platter;
      }
      const BoxMeasurement m = MeasureBox(truth_in_result, box);
      if (m.IsUsable()) fig.truth_box_edges = EdgeErrors(m, scene.options().object.carved_box);
    }

    if (!out_dir_.empty()) {
      if (std::string why; !WriteErrorCloud("fused_error.ply", fused, fused_d, &why) ||
                           !WriteErrorCloud("mesh_error.ply", vertices, mesh_d, &why) ||
                           !WriteMissedCloud(grid, covered, &why) ||
                           !WriteOutCloud("truth_seen.ply", truth_cloud, &why))
        return DataError(why);
      PointCloud views_cloud, visible_cloud;
      views_cloud.points_mm = raw;
      views_cloud.colors_rgb = raw_view_colors;
      visible_cloud.points_mm = grid;
      if (std::string why; !WriteOutCloud("views.ply", views_cloud, &why) ||
                           !WriteOutCloud("truth_visible.ply", visible_cloud, &why))
        return DataError(why);
    }
    Print(&fig, times, {});
    if (turn_figures) PrintTurns(*turn_figures, r);
    if (!json_path_.empty()) return WriteJson(&fig, times, r, turn_figures);
    return kExitOk;
  }

  // Per point (object frame), the smaller of the distance to the nearest
  // seen truth point and, per view, the distance to where the left camera's
  // ray through the point first meets the object.
  std::vector<double> SurfaceDistances(const NearestIndex& truth, const sim::SimStation& station,
                                       const std::vector<ViewGeometry>& geometry,
                                       const std::vector<cv::Vec3f>& points) const {
    std::vector<double> d = NearestDistances(truth, points);
    const cv::Matx44d world_from_left = station.left_from_world().inv();
    const cv::Vec3d camera(world_from_left(0, 3), world_from_left(1, 3), world_from_left(2, 3));
    for (const ViewGeometry& g : geometry) {
      sim::Scene& scene = *g.scene;
      scene.SetTurntableAngle(g.angle_rad);
      cv::parallel_for_(cv::Range(0, static_cast<int>(points.size())), [&](const cv::Range& range) {
        for (int i = range.start; i < range.end; ++i) {
          const cv::Vec3f pw = Apply(g.world_from_object, points[static_cast<std::size_t>(i)]);
          const cv::Vec3d p(pw[0], pw[1], pw[2]);
          const cv::Vec3d direction = p - camera;
          double t = 0;
          sim::SurfaceLabel label = sim::SurfaceLabel::kNothing;
          if (!scene.Intersect(camera, direction, &t, &label) ||
              label != sim::SurfaceLabel::kObject)
            continue;
          const double along = cv::norm(camera + t * direction - p);
          double& best = d[static_cast<std::size_t>(i)];
          best = std::min(best, along);
        }
      });
    }
    return d;
  }

  // fused_error.ply (mesh_error.ply): the fused cloud (the mesh's scored
  // vertices) in the object frame, coloured by the distance to the surface
  // (green ≤ 0.5 mm, yellow ≤ 1 mm, red beyond): where the outliers are.
  bool WriteErrorCloud(const std::string& name, const std::vector<cv::Vec3f>& points,
                       const std::vector<double>& d, std::string* why) const {
    PointCloud cloud;
    cloud.points_mm = points;
    cloud.colors_rgb.reserve(points.size());
    for (double e : d)
      cloud.colors_rgb.push_back(e <= 0.5       ? cv::Vec3b(40, 200, 40)
                                 : e <= kGateMm ? cv::Vec3b(230, 200, 0)
                                                : cv::Vec3b(230, 30, 30));
    return WriteOutCloud(name, cloud, why);
  }

  // missed.ply: the visible surface's grid samples with no fused point
  // within the gate (what completeness_pct misses), in the object frame.
  bool WriteMissedCloud(const std::vector<cv::Vec3f>& grid, const std::vector<double>& covered,
                        std::string* why) const {
    PointCloud cloud;
    for (std::size_t i = 0; i < grid.size(); ++i)
      if (covered[i] > kGateMm) cloud.points_mm.push_back(grid[i]);
    return WriteOutCloud("missed.ply", cloud, why);
  }

  bool WriteOutCloud(const std::string& name, const PointCloud& cloud, std::string* why) const {
    const std::string path = (fs::path(out_dir_) / name).string();
    if (Status s = WriteFileAtomically(path, EncodePly(cloud, true)); !s.ok())
      return (*why = "--out: " + s.message(), false);
    return true;
  }

  static double CoveredPct(const std::vector<double>& covered) {
    if (covered.empty()) return NAN;
    const auto n =
        std::count_if(covered.begin(), covered.end(), [](double d) { return d <= kGateMm; });
    return 100.0 * static_cast<double>(n) / static_cast<double>(covered.size());
  }

  static double OutlierPct(const std::vector<double>& d) {
    if (d.empty()) return NAN;
    const auto n = std::count_if(d.begin(), d.end(), [](double e) { return e > kGateMm; });
    return 100.0 * static_cast<double>(n) / static_cast<double>(d.size());
  }

  static cv::Vec3d EdgeErrors(const BoxMeasurement& m, const sim::CarvedBoxOptions& box) {
    std::array<double, 3> truth{box.width_mm, box.depth_mm, box.height_mm};
    std::sort(truth.begin(), truth.end(), std::greater<>());  // box axes: extent descending
    std::vector<double> errors;
    for (const BoxEdge& e : m.edges)
      errors.push_back(e.length_mm - truth[static_cast<std::size_t>(e.axis)]);
    if (errors.empty()) return {NAN, NAN, NAN};
    const double mean =
        std::accumulate(errors.begin(), errors.end(), 0.0) / static_cast<double>(errors.size());
    double var = 0, max_abs = 0;
    for (double e : errors) {
      var += (e - mean) * (e - mean);
      max_abs = std::max(max_abs, std::abs(e));
    }
    return {mean, std::sqrt(var / static_cast<double>(errors.size())), max_abs};
  }

  // The session's outputs: encoded always (the time until the model exists
  // includes it), written with --out.
  bool StoreOutputs(const ScanResult& r, const StereoCalibration& calibration,
                    std::string* why) const {
    const bool mesh = r.mesh.status == MeshResult::Status::kOk;
    std::vector<std::pair<std::string, std::string>> files;
    files.emplace_back("fused.ply", EncodePly(r.fused, true));
    if (mesh) files.emplace_back("mesh.ply", EncodeMeshPly(r.mesh.mesh, true));
    if (mesh) files.emplace_back("mesh.obj", EncodeMeshObj(r.mesh.mesh));
    const std::string report = ScanReportJson(r);
    if (mesh) {
      daemon::ModelProvenance p;
      p.object_name = object_;
      p.session_id = "bench";
      p.station = "bench";
      p.client = "craftscan-bench";
      p.calibration_id = "simulated";
      p.calibration_rms_px = calibration.report.rms_stereo_px;
      p.calibration_epipolar_mean_px = calibration.report.epipolar_mean_px;
      p.software = "craftscan-bench";
      p.scan_report_json = report;
      std::string glb, error;
      if (!daemon::EncodeGlb(r.mesh.mesh, p, &glb, &error))
        return (*why = "mesh.glb: " + error, false);
      files.emplace_back("mesh.glb", std::move(glb));
    }
    files.emplace_back("report.json", report);
    if (out_dir_.empty()) return true;
    daemon::ReportInputs inputs;
    inputs.session_id = "bench";
    inputs.object_name = object_;
    inputs.scan_report_json = report;
    inputs.calibration = &calibration;
    inputs.fused = &r.fused;
    if (mesh) inputs.mesh = &r.mesh.mesh;
    daemon::ReportFiles report_files;
    std::string error;
    if (daemon::MakeReportFiles(inputs, &report_files, &error)) {
      for (daemon::ReportFile& f : report_files.files)
        files.emplace_back(std::move(f.name), std::move(f.bytes));
    } else {
      std::cerr << "craftscan-bench scan: report.html not made: " << error << "\n";
    }
    std::error_code ec;
    fs::create_directories(fs::path(out_dir_) / "previews", ec);
    if (ec) return (*why = "--out: cannot create '" + out_dir_ + "': " + ec.message(), false);
    for (const auto& [name, bytes] : files) {
      const std::string path = (fs::path(out_dir_) / name).string();
      if (Status s = WriteFileAtomically(path, bytes); !s.ok())
        return (*why = "--out: " + s.message(), false);
    }
    return true;
  }

  void Print(const Figures* f, const Times& t, const std::string& failure) const {
    std::printf("scan: %s, %d views, seed %llu, %d thread(s), %s\n", object_.c_str(), views_,
                static_cast<unsigned long long>(seed_), threads_, image_size_.c_str());
    if (!f) {
      std::printf("  FAILED: %s\n", failure.c_str());
    } else {
      std::printf(
          "  fused_to_truth_mm median %.3f p95 %.3f max %.2f  outlier_pct %.2f  (%zu points)\n",
          f->fused_median, f->fused_p95, f->fused_max, f->outlier_pct, f->fused_points);
      if (f->estimated_outlier_pct)
        std::printf(
            "  estimated_outlier_pct %.2f (the report's, without the truth: fused points "
            "> 1 mm from the mesh)\n",
            *f->estimated_outlier_pct);
      std::printf(
          "  fused error %% per bin (mm) ≤0.25 %.1f ≤0.5 %.1f ≤1 %.1f ≤2 %.1f ≤5 %.1f ≤20 %.1f >20 "
          "%.1f\n",
          f->fused_histogram[0], f->fused_histogram[1], f->fused_histogram[2],
          f->fused_histogram[3], f->fused_histogram[4], f->fused_histogram[5],
          f->fused_histogram[6]);
      std::printf(
          "  views (stereo alone, exact poses): median %.3f p95 %.3f outlier_pct %.2f "
          "completeness_pct %.1f\n",
          f->views_median, f->views_p95, f->views_outlier_pct, f->views_completeness_pct);
      std::printf("  completeness_pct %.1f  (%zu grid samples of the visible surface)\n",
                  f->completeness_pct, f->truth_visible_grid);
      std::printf(
          "  mesh_to_truth_mm median %.3f p95 %.3f  completeness_pct %.1f  largest component "
          "%.2f %% of %zu\n",
          f->mesh_median, f->mesh_p95, f->mesh_completeness_pct, f->components.largest_pct,
          f->components.count);
      std::printf(
          "  fused_obb_mm %.1f × %.1f × %.1f  truth_obb_mm %.1f × %.1f × %.1f  truth along the "
          "fused box's axes %.1f × %.1f × %.1f\n",
          f->fused_obb[0], f->fused_obb[1], f->fused_obb[2], f->truth_obb[0], f->truth_obb[1],
          f->truth_obb[2], f->truth_on_fused_axes[0], f->truth_on_fused_axes[1],
          f->truth_on_fused_axes[2]);
      if (f->box_edges)
        std::printf("  box_edges_mm mean %+.3f std %.3f max %.3f\n", (*f->box_edges)[0],
                    (*f->box_edges)[1], (*f->box_edges)[2]);
      if (f->truth_box_edges)
        std::printf("  truth_box_edges_mm mean %+.3f std %.3f max %.3f\n", (*f->truth_box_edges)[0],
                    (*f->truth_box_edges)[1], (*f->truth_box_edges)[2]);
    }
    std::printf(
        "  times_ms render %.0f match_per_view_median %.0f register %.0f fuse %.0f mesh %.0f "
        "after_last_capture %.0f\n",
        t.render, t.match_median, t.reg, t.fuse, t.mesh, t.after_last);
    std::fflush(stdout);
  }

  // The join's verdict and figures, and its error against the truth.
  void PrintTurns(const TurnFigures& tf, const ScanResult& r) const {
    if (!r.turn_join) return;
    const TurnJoinResult& j = *r.turn_join;
    std::printf(
        "  turn join %s: overlap %.1f %% RMSE %.3f mm constraint %.4f ambiguity %.3f (alternative "
        "%.1f° / %.1f mm), %d hypotheses, %.0f ms; contact points dropped %zu (A) %zu (B)\n",
        ToString(j.status), 100 * j.overlap, j.rmse_mm, j.constraint, j.ambiguity,
        j.alternative_deg, j.alternative_mm, j.hypotheses, j.time_ms, r.contact_dropped_a,
        r.contact_dropped_b);
    std::printf(
        "  turn_rot_err_deg %.4f turn_trans_err_mm %.4f  first turn alone: completeness_pct "
        "%.1f\n",
        tf.rot_err_deg, tf.trans_err_mm, tf.first_turn_completeness_pct);
    std::fflush(stdout);
  }

  int WriteJson(const Figures* f, const Times& t, const ScanResult& r,
                const std::optional<TurnFigures>& tf) const {
    nlohmann::ordered_json root;
    root["object"] = object_;
    const bool refused = r.turn_join && !r.turn_join->IsUsable() &&
                         r.turn_join->status != TurnJoinResult::Status::kFailed;
    root["status"] = f ? "ok" : (refused ? "refused" : "failed");
    if (!f) root["message"] = r.message;
    root["turns"] = turns_;
    if (turns_ == 2)
      root["turn2_rotation_deg"] = {turn2_rotation_deg_[0], turn2_rotation_deg_[1],
                                    turn2_rotation_deg_[2]};
    root["auto_bracket"] = auto_bracket_;
    root["auto_bracketed_views"] = auto_bracketed_views_;
    if (r.turn_join) {
      const TurnJoinResult& j = *r.turn_join;
      root["turn_join"] = {{"status", ToString(j.status)},
                           {"message", j.message},
                           {"overlap_pct", Number(100 * j.overlap)},
                           {"rmse_mm", Number(j.rmse_mm)},
                           {"ambiguity", Number(j.ambiguity)},
                           {"constraint", Number(j.constraint)},
                           {"held_weakly", j.held_weakly},
                           {"alternative_deg", Number(j.alternative_deg)},
                           {"alternative_mm", Number(j.alternative_mm)},
                           {"hypotheses", j.hypotheses},
                           {"coarse_voxel_mm", Number(j.coarse_voxel_mm)},
                           {"time_ms", Number(j.time_ms)},
                           {"contact_dropped_a", r.contact_dropped_a},
                           {"contact_dropped_b", r.contact_dropped_b}};
    }
    if (tf) {
      // Of the join's placement, also when refused (was it wrong?).
      root["turn_rot_err_deg"] = Number(tf->rot_err_deg);
      root["turn_trans_err_mm"] = Number(tf->trans_err_mm);
      root["first_turn_completeness_pct"] = Number(tf->first_turn_completeness_pct);
    }
    // Per turn: each view's registered pose against its true pose (rotation,
    // relative to view 0), median and max over the views.
    nlohmann::ordered_json poses = nlohmann::ordered_json::array();
    for (const auto& [median, max] : pose_errors_)
      poses.push_back({{"median", Number(median)}, {"max", Number(max)}});
    root["view_pose_err_deg"] = poses;
    root["views"] = views_;
    root["seed"] = seed_;
    root["threads"] = threads_;
    root["image_size"] = image_size_;
    if (f) {
      root["fused_points"] = f->fused_points;
      root["fused_to_truth_mm"] = {{"median", Number(f->fused_median)},
                                   {"p95", Number(f->fused_p95)},
                                   {"max", Number(f->fused_max)}};
      root["outlier_pct"] = Number(f->outlier_pct);
      // What the scan's own report estimates without the truth (quality.h).
      root["estimated_outlier_pct"] = r.quality.ok ? Number(r.quality.far_pct) : nullptr;
      root["free_space_removed_points"] = r.visibility.removed_points;
      nlohmann::ordered_json bins = nlohmann::ordered_json::array();
      for (std::size_t b = 0; b < f->fused_histogram.size(); ++b)
        bins.push_back(
            {{"up_to_mm", b < std::size(kHistogramMm) ? Number(kHistogramMm[b]) : nullptr},
             {"pct", f->fused_histogram[b]}});
      root["fused_error_histogram"] = bins;
      root["views_to_truth_mm"] = {{"median", Number(f->views_median)},
                                   {"p95", Number(f->views_p95)},
                                   {"outlier_pct", Number(f->views_outlier_pct)},
                                   {"completeness_pct", Number(f->views_completeness_pct)}};
      root["completeness_pct"] = Number(f->completeness_pct);
      root["mesh_to_truth_mm"] = {{"median", Number(f->mesh_median)}, {"p95", Number(f->mesh_p95)}};
      root["mesh_components"] = f->components.count;
      root["mesh_completeness_pct"] = Number(f->mesh_completeness_pct);
      root["mesh_largest_component_pct"] = Number(f->components.largest_pct);
      root["fused_obb_mm"] = Extents(f->fused_obb);
      root["truth_obb_mm"] = Extents(f->truth_obb);
      const cv::Vec3d error = f->fused_obb - f->truth_obb;
      root["obb_error_mm"] = {std::abs(error[0]), std::abs(error[1]), std::abs(error[2])};
      root["truth_on_fused_axes_mm"] = Extents(f->truth_on_fused_axes);
      const cv::Vec3d same_axes = f->fused_obb - f->truth_on_fused_axes;
      root["obb_error_same_axes_mm"] = {std::abs(same_axes[0]), std::abs(same_axes[1]),
                                        std::abs(same_axes[2])};
      if (f->box_edges)
        root["box_edges_mm"] = {{"mean", Number((*f->box_edges)[0])},
                                {"std", Number((*f->box_edges)[1])},
                                {"max_abs", Number((*f->box_edges)[2])}};
      if (f->truth_box_edges)
        root["truth_box_edges_mm"] = {{"mean", Number((*f->truth_box_edges)[0])},
                                      {"std", Number((*f->truth_box_edges)[1])},
                                      {"max_abs", Number((*f->truth_box_edges)[2])}};
    }
    root["times_ms"] = {
        {"render", Number(t.render)}, {"match_per_view_median", Number(t.match_median)},
        {"register", Number(t.reg)},  {"fuse", Number(t.fuse)},
        {"mesh", Number(t.mesh)},     {"after_last_capture", Number(t.after_last)}};
    if (Status s = WriteFileAtomically(json_path_, root.dump(2) + "\n"); !s.ok())
      return DataError("--json: " + s.message());
    return f ? kExitOk : kExitDataError;
  }

  std::vector<std::unique_ptr<sim::SimStation>> bracketed_;
  int turns_ = 1;
  std::vector<double> turn2_rotation_deg_{90, 0, 0};
  std::vector<std::pair<double, double>> pose_errors_;  // per turn: median, max (deg)
  std::string object_ = "carved_box";
  std::string mesh_path_;
  double mesh_size_mm_ = 0;
  int views_ = 6;
  std::uint64_t seed_ = 1;
  int threads_ = 2;
  std::string image_size_ = "1280x1024";
  bool projector_ = false;
  bool no_auto_bracket_ = false;
  bool auto_bracket_ = false;  // no bracket given: CaptureStage's automatic bracketing
  std::unique_ptr<sim::SimStation> auto_bracketed_;
  cv::Mat auto_region_;
  int auto_bracketed_views_ = 0;
  std::vector<double> bracket_;
  std::string config_path_, json_path_, out_dir_, save_turns_dir_;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeScanCommand() { return std::make_unique<ScanCommand>(); }

}  // namespace craftscan::bench
