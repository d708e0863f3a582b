// A whole turntable scan on the simulated station (drivers/sim) against its
// exact ground truth: six views at 60° steps of the carved box and of the
// egg, each rendered by the default rig (1280×1024, 100 mm baseline, ~400 mm
// to the axis, mild lens distortion, sensor noise σ = 1 grey level),
// rectified with the exact calibration, matched by craftscan's AD-Census and
// reprojected with Q; then ReconstructScan (conditioning, registration with
// the turntable prior, loop closure, fusion, Poisson mesh, measurement) with
// the exact turntable axis.
//
// Ground truth: the surface point on the ray of every rectified left object
// pixel (the renderer's rectified_depth_mm), mapped into view 0 with the
// exact object motion and into the turntable frame with the exact axis.
// Figures:
//   fused → truth: mean and 95th percentile of the distance from each fused
//     point to its nearest ground-truth point (mm; the truth is sampled every
//     ~0.17 mm, so this is the distance to the surface within ~0.05 mm);
//   completeness: share of the truth (on a 0.5 mm grid, above the working
//     volume's floor) with a fused point within 1 mm;
//   poses: each view0_from_view[k] against the exact one (rotation deg,
//     translation mm, and the RMS displacement of the object's own points);
//   box: the 12 edge lengths against 80 × 60 × 50 mm; egg: the oriented box
//     against 60 × 45 × 45 mm (its lowest 1.5 mm is below the working volume).
// Every figure is printed and recorded as a test property; the tolerances
// (set from the measured figures, see each test) are asserted at the end.
// Both objects run (CarvedBox, Egg); a cheap test without rendering pins the
// turntable conventions the two rely on (TurntableMotionMatchesAxis).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/stereo/reproject.h"
#include "craftscan/pipeline/surface/fusion.h"
#include "craftscan/pipeline/surface/measure.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"
#include "craftscan/sim/station.h"
#include "scan_eval.h"

namespace craftscan {
namespace {

constexpr int kNumThreads = 2;
constexpr int kNumViews = 6;
constexpr double kStepRad = CV_PI / 3;  // 60°
// Margin around the true disparities of the object and the platter. A
// station derives its band from the working volume (the cylinder above the
// platter); the platter's and the object's true disparities ± 8 px cover
// what such a band would, without rendering-specific knowledge of the rig.
constexpr int kDisparityMarginPx = 8;
constexpr double kCompletenessGridMm = 0.5;
constexpr double kCompletenessGateMm = 1.0;
constexpr double kInlierMm = 2.0;  // fused points farther than this are outliers

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

cv::Vec3d Apply(const cv::Matx44d& T, const cv::Vec3d& p) {
  const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
  return {q[0], q[1], q[2]};
}

double Mean(const std::vector<double>& values) {
  if (values.empty()) return NAN;
  return std::accumulate(values.begin(), values.end(), 0.0) / static_cast<double>(values.size());
}

// Population standard deviation; NaN for no values.
double StdDev(const std::vector<double>& values) {
  if (values.empty()) return NAN;
  const double m = Mean(values);
  double s = 0;
  for (double v : values) s += (v - m) * (v - m);
  return std::sqrt(s / static_cast<double>(values.size()));
}

using bench::NearestDistances;  // nearest-neighbour distances (nanoflann), scan_eval.h
using bench::NearestIndex;
using bench::Quantile;

// ------------------------------------------------------------- the scan -----

struct SimView {
  double angle_rad = 0;
  cv::Matx44d view0_from_view = cv::Matx44d::eye();  // exact
  int min_disparity = 0, num_disparities = 0;
  double gt_disparity_min = 0, gt_disparity_max = 0;
  std::size_t object_pixels = 0, object_valid = 0;
  // Matched pixels whose points land in the working volume, by true label.
  std::size_t background_in_volume = 0, platter_in_volume = 0, object_in_volume = 0;
  double depth_err_median_mm = NAN, depth_err_p90_mm = NAN;
  double render_ms = 0, match_ms = 0;
};

struct SimScan {
  std::vector<ScanView> views;
  std::vector<SimView> info;
  PointCloud truth_in_view0;  // object surface seen by the left camera, all views
  StereoCalibration calibration;
  cv::Matx44d world_from_rig = cv::Matx44d::eye();
  double total_render_ms = 0, total_match_ms = 0;
};

// Renders, rectifies, matches and reprojects `num_views` views of `scene`
// at turntable angles 0, step, 2·step, …; collects the ground truth and
// counts the matched points in `volume` (radius and heights only) by label.
// Returns false with *error on a failure.
bool RunSimScan(const sim::SceneOptions& scene_options, int num_views, double step_rad,
                const WorkingVolume& volume, SimScan* scan, std::string* error) {
  sim::RigOptions rig;
  rig.num_threads = kNumThreads;
  std::unique_ptr<sim::SimStation> station = sim::SimStation::Create(rig, error);
  if (!station) return false;
  std::unique_ptr<sim::Scene> scene = sim::Scene::Create(scene_options, error);
  if (!scene) return false;

  const StereoCalibration& c = station->calibration();
  scan->calibration = c;
  scan->world_from_rig = station->world_from_rig();
  cv::Mat map_lx, map_ly, map_rx, map_ry;
  cv::initUndistortRectifyMap(c.left.camera_matrix, c.left.distortion, c.R1, c.P1, c.image_size,
                              CV_32FC1, map_lx, map_ly);
  cv::initUndistortRectifyMap(c.right.camera_matrix, c.right.distortion, c.R2, c.P2, c.image_size,
                              CV_32FC1, map_rx, map_ry);
  const double f = c.P1(0, 0), cx = c.P1(0, 2), cy = c.P1(1, 2);

  cv::Matx44d world_from_object0 = cv::Matx44d::eye();
  std::unique_ptr<StereoMatcher> matcher;
  for (int k = 0; k < num_views; ++k) {
    SimView info;
    info.angle_rad = k * step_rad;
    scene->SetTurntableAngle(info.angle_rad);
    const sim::StereoRender render = station->Render(*scene, static_cast<std::uint64_t>(k));
    if (!render.IsUsable()) {
      *error = "view " + std::to_string(k) + ": render failed: " + render.message;
      return false;
    }
    info.render_ms = render.render_ms;
    if (k == 0) world_from_object0 = render.world_from_object;
    info.view0_from_view = render.rig_from_world * world_from_object0 *
                           InvertRigid(render.world_from_object) *
                           InvertRigid(render.rig_from_world);

    cv::Mat left, right;
    cv::remap(render.left, left, map_lx, map_ly, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::remap(render.right, right, map_rx, map_ry, cv::INTER_LINEAR, cv::BORDER_CONSTANT);

    // Band: true disparities of the object and the platter, ± the margin.
    const cv::Mat band_mask =
        (render.rectified_labels == static_cast<int>(sim::SurfaceLabel::kObject)) |
        (render.rectified_labels == static_cast<int>(sim::SurfaceLabel::kPlatter));
    cv::Mat finite_disparity;
    cv::compare(render.rectified_disparity, render.rectified_disparity, finite_disparity,
                cv::CMP_EQ);  // false for NaN
    cv::minMaxLoc(render.rectified_disparity, &info.gt_disparity_min, &info.gt_disparity_max,
                  nullptr, nullptr, band_mask & finite_disparity);
    info.min_disparity = static_cast<int>(std::floor(info.gt_disparity_min)) - kDisparityMarginPx;
    info.num_disparities = static_cast<int>(std::ceil(info.gt_disparity_max)) + kDisparityMarginPx -
                           info.min_disparity + 1;

    ADCensusOptions options;
    options.min_disparity = info.min_disparity;
    options.num_disparities = info.num_disparities;
    options.num_threads = kNumThreads;
    // A point cloud wants no invented surface (as the station runs it).
    options.refinement.interpolate = false;
    if (!matcher || matcher->options().min_disparity != options.min_disparity ||
        matcher->options().num_disparities != options.num_disparities) {
      matcher = std::make_unique<StereoMatcher>(options);
    }
    const auto match_start = std::chrono::steady_clock::now();
    const DisparityResult match = matcher->Compute(left, right);
    info.match_ms = MsSince(match_start);
    if (!match.IsUsable()) {
      *error = "view " + std::to_string(k) + ": matcher failed: " + match.message;
      return false;
    }

    ScanView view;
    view.commanded_angle_rad = info.angle_rad;
    // The texture filter drops the dark backdrop, whose true disparity lies
    // outside the band: the matcher's guesses there are consistent in both
    // views and would land inside the working volume.
    ReprojectOptions reproject;
    reproject.min_texture_std = 2.5;
    const ReprojectResult reprojected =
        ReprojectToPoints(match.disparity, cv::Mat(c.Q), left, reproject);
    if (!reprojected.IsUsable()) {
      *error = "view " + std::to_string(k) + ": " + reprojected.message;
      return false;
    }
    const std::vector<ColoredPoint>& points = reprojected.points;
    view.cloud_in_rig.points_mm.reserve(points.size());
    view.cloud_in_rig.colors_rgb.reserve(points.size());
    for (const ColoredPoint& p : points) {
      view.cloud_in_rig.points_mm.emplace_back(p.x, p.y, p.z);
      view.cloud_in_rig.colors_rgb.emplace_back(p.r, p.g, p.b);
    }

    // Ground truth on the object pixels; depth error of the matched ones.
    std::vector<double> depth_errors;
    const cv::Mat& mask = render.rectified_object_mask;
    for (int v = 0; v < mask.rows; ++v) {
      const std::uint8_t* m = mask.ptr<std::uint8_t>(v);
      const float* z_true = render.rectified_depth_mm.ptr<float>(v);
      const float* d = match.disparity.ptr<float>(v);
      for (int u = 0; u < mask.cols; ++u) {
        if (!m[u] || !std::isfinite(z_true[u])) continue;
        ++info.object_pixels;
        const double z = z_true[u];
        const cv::Vec3d p_in_rig((u - cx) * z / f, (v - cy) * z / f, z);
        const cv::Vec3d p_in_view0 = Apply(info.view0_from_view, p_in_rig);
        scan->truth_in_view0.points_mm.emplace_back(static_cast<float>(p_in_view0[0]),
                                                    static_cast<float>(p_in_view0[1]),
                                                    static_cast<float>(p_in_view0[2]));
        if (!IsValidDisparity(d[u])) continue;
        const cv::Vec4d q = c.Q * cv::Vec4d(u, v, d[u], 1);
        if (!(std::abs(q[3]) > 1e-12)) continue;
        ++info.object_valid;
        depth_errors.push_back(std::abs(q[2] / q[3] - z));
      }
    }
    // Matched pixels that land in the working volume but are not the
    // object: the background (its true disparity lies outside the band, so
    // any match there is false) and the platter.
    const cv::Matx44d turntable_from_rig = TurntableFromRig(c.turntable);
    const cv::Mat textured = TextureMask(left, reproject.texture_window, reproject.min_texture_std);
    for (int v = 0; v < mask.rows; ++v) {
      const float* d = match.disparity.ptr<float>(v);
      const std::uint8_t* label = render.rectified_labels.ptr<std::uint8_t>(v);
      const std::uint8_t* tex = textured.ptr<std::uint8_t>(v);
      for (int u = 0; u < mask.cols; ++u) {
        if (!IsValidDisparity(d[u]) || !tex[u]) continue;
        const cv::Vec4d q = c.Q * cv::Vec4d(u, v, d[u], 1);
        if (!(std::abs(q[3]) > 1e-12)) continue;
        const cv::Vec3d p =
            Apply(turntable_from_rig, cv::Vec3d(q[0] / q[3], q[1] / q[3], q[2] / q[3]));
        if (std::hypot(p[0], p[1]) > volume.radius_mm || p[2] < volume.min_height_mm ||
            p[2] > volume.max_height_mm)
          continue;
        if (label[u] == static_cast<std::uint8_t>(sim::SurfaceLabel::kBackground))
          ++info.background_in_volume;
        if (label[u] == static_cast<std::uint8_t>(sim::SurfaceLabel::kPlatter))
          ++info.platter_in_volume;
        if (label[u] == static_cast<std::uint8_t>(sim::SurfaceLabel::kObject))
          ++info.object_in_volume;
      }
    }
    info.depth_err_median_mm = Quantile(depth_errors, 0.5);
    info.depth_err_p90_mm = Quantile(depth_errors, 0.9);
    scan->total_render_ms += info.render_ms;
    scan->total_match_ms += info.match_ms;
    std::printf(
        "  view %d (%3.0f deg): render %.0f ms, band [%d, %d) (true %.1f … %.1f px), match %.0f "
        "ms, %zu points; object %zu px, %.1f %% matched, depth error median %.3f mm p90 %.3f "
        "mm\n"
        "    matched points in the working volume: object %zu, platter %zu, background %zu\n",
        k, info.angle_rad * 180 / CV_PI, info.render_ms, info.min_disparity,
        info.min_disparity + info.num_disparities, info.gt_disparity_min, info.gt_disparity_max,
        info.match_ms, view.cloud_in_rig.size(), info.object_pixels,
        100.0 * static_cast<double>(info.object_valid) /
            static_cast<double>(std::max<std::size_t>(1, info.object_pixels)),
        info.depth_err_median_mm, info.depth_err_p90_mm, info.object_in_volume,
        info.platter_in_volume, info.background_in_volume);
    std::fflush(stdout);
    scan->views.push_back(std::move(view));
    scan->info.push_back(info);
  }
  return true;
}

// ---------------------------------------------------------- evaluation -----

struct ScanFigures {
  double fused_mean_mm = NAN, fused_p95_mm = NAN, fused_median_mm = NAN;
  double completeness_pct = NAN;
  // Fused points within kInlierMm of the truth: share (%), mean and p95.
  double inlier_pct = NAN, inlier_mean_mm = NAN, inlier_p95_mm = NAN;
  std::size_t fused_points = 0, truth_points = 0, truth_grid_points = 0;
  std::vector<double> rot_err_deg, trans_err_mm, point_err_mm;  // per view
  double max_rot_err_deg = 0, max_trans_err_mm = 0, max_point_err_mm = 0;
};

// Each conditioned view cloud at its exact pose against the truth: the
// stereo and conditioning error without registration.
void PrintViewErrors(const SimScan& scan, const ScanResult& result) {
  const cv::Matx44d turntable_from_view0 = TurntableFromRig(scan.calibration.turntable);
  const PointCloud truth = TransformCloud(turntable_from_view0, scan.truth_in_view0);
  const NearestIndex truth_index(truth.points_mm);
  // Each conditioned view at its exact pose: the stereo and conditioning
  // error without registration.
  for (std::size_t k = 0; k < result.views.size() && k < scan.info.size(); ++k) {
    const PointCloud at_truth =
        TransformCloud(turntable_from_view0 * scan.info[k].view0_from_view, result.views[k].fine);
    const std::vector<double> dk = NearestDistances(truth_index, at_truth.points_mm);
    std::printf(
        "  view %zu fine cloud at the exact pose vs truth: mean %.3f mm, median %.3f mm, "
        "p95 %.3f mm, %.1f %% beyond 2 mm\n",
        k, Mean(dk), Quantile(dk, 0.5), Quantile(dk, 0.95),
        100.0 *
            static_cast<double>(
                std::count_if(dk.begin(), dk.end(), [](double v) { return v > 2; })) /
            static_cast<double>(std::max<std::size_t>(1, dk.size())));
  }
}

// Compares the result with the truth and prints the figures.
ScanFigures Evaluate(const SimScan& scan, const ScanResult& result, double min_height_mm) {
  ScanFigures fig;
  const cv::Matx44d turntable_from_view0 = TurntableFromRig(scan.calibration.turntable);

  // Poses; the point error is the RMS displacement of view k's own truth
  // points (the object) between the estimated and the exact pose.
  for (std::size_t k = 0; k < scan.info.size(); ++k) {
    const cv::Matx44d& truth = scan.info[k].view0_from_view;
    const cv::Matx44d& estimate = result.view0_from_view[k];
    fig.rot_err_deg.push_back(RotationErrorDeg(estimate, truth));
    fig.trans_err_mm.push_back(TranslationErrorMm(estimate, truth));
    const cv::Matx44d delta = estimate * InvertRigid(truth);  // view0 → view0
    double sum = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < scan.truth_in_view0.size(); i += 97, ++n) {
      const cv::Vec3d p(scan.truth_in_view0.points_mm[i]);
      sum += cv::norm(Apply(delta, p) - p, cv::NORM_L2SQR);
    }
    fig.point_err_mm.push_back(std::sqrt(sum / static_cast<double>(std::max<std::size_t>(1, n))));
    fig.max_rot_err_deg = std::max(fig.max_rot_err_deg, fig.rot_err_deg.back());
    fig.max_trans_err_mm = std::max(fig.max_trans_err_mm, fig.trans_err_mm.back());
    fig.max_point_err_mm = std::max(fig.max_point_err_mm, fig.point_err_mm.back());
    std::printf(
        "  pose %zu: rotation error %.4f deg, translation error %.3f mm, object RMS %.3f mm\n", k,
        fig.rot_err_deg.back(), fig.trans_err_mm.back(), fig.point_err_mm.back());
  }

  // The truth in the fused cloud's frame.
  PointCloud truth = TransformCloud(turntable_from_view0, scan.truth_in_view0);
  fig.truth_points = truth.size();
  const NearestIndex truth_index(truth.points_mm);
  const std::vector<double> d = NearestDistances(truth_index, result.fused.points_mm);
  fig.fused_points = d.size();
  fig.fused_mean_mm = Mean(d);
  fig.fused_p95_mm = Quantile(d, 0.95);
  fig.fused_median_mm = Quantile(d, 0.5);
  std::vector<double> inliers;
  for (double v : d)
    if (v <= kInlierMm) inliers.push_back(v);
  fig.inlier_pct = 100.0 * static_cast<double>(inliers.size()) /
                   static_cast<double>(std::max<std::size_t>(1, d.size()));
  fig.inlier_mean_mm = Mean(inliers);
  fig.inlier_p95_mm = Quantile(inliers, 0.95);

  // Completeness over the truth above the working volume's floor, on a grid.
  PointCloud above;
  for (const cv::Vec3f& p : truth.points_mm)
    if (p[2] >= min_height_mm) above.points_mm.push_back(p);
  FusionOptions grid;
  grid.voxel_mm = kCompletenessGridMm;
  grid.refine_along_normal = false;
  std::string error;
  const PointCloud truth_grid = FuseClouds({above}, grid, &error);
  fig.truth_grid_points = truth_grid.size();
  const NearestIndex fused_index(result.fused.points_mm);
  const std::vector<double> back = NearestDistances(fused_index, truth_grid.points_mm);
  const auto covered =
      std::count_if(back.begin(), back.end(), [](double v) { return v <= kCompletenessGateMm; });
  fig.completeness_pct = 100.0 * static_cast<double>(covered) /
                         static_cast<double>(std::max<std::size_t>(1, truth_grid.size()));
  std::printf(
      "  fused %zu points vs truth %zu points: distance mean %.3f mm, median %.3f mm, p95 %.3f "
      "mm; completeness %.1f %% of %zu truth grid points (%.1f mm grid, z ≥ %.1f mm) within "
      "%.1f mm\n",
      fig.fused_points, fig.truth_points, fig.fused_mean_mm, fig.fused_median_mm, fig.fused_p95_mm,
      fig.completeness_pct, fig.truth_grid_points, kCompletenessGridMm, min_height_mm,
      kCompletenessGateMm);
  std::printf(
      "  fused points within %.0f mm of the truth: %.1f %%, their distance mean %.3f mm, p95 %.3f "
      "mm\n",
      kInlierMm, fig.inlier_pct, fig.inlier_mean_mm, fig.inlier_p95_mm);
  std::fflush(stdout);
  return fig;
}

void PrintStages(const SimScan& scan, const ScanResult& r, double reconstruct_ms) {
  std::printf(
      "  times: render %.0f ms, match %.0f ms (all views); reconstruct %.0f ms = condition %.0f + "
      "register %.0f + loop %.0f + fuse %.0f + mesh %.0f + measure %.0f ms\n",
      scan.total_render_ms, scan.total_match_ms, reconstruct_ms, r.condition_ms, r.register_ms,
      r.loop_ms, r.fuse_ms, r.mesh_ms, r.measure_ms);
  for (std::size_t k = 0; k < r.views.size(); ++k) {
    const ViewCloud& v = r.views[k];
    std::printf(
        "  view %zu conditioned: %zu input, %zu cropped, %zu outliers, %zu fine, %zu coarse\n", k,
        v.input_points, v.cropped_points, v.outlier_points, v.fine.size(), v.coarse.size());
  }
  for (std::size_t k = 1; k < r.pairwise.size(); ++k) {
    const RegistrationResult& p = r.pairwise[k];
    std::printf(
        "  pair %zu→%zu: fitness %.3f, rmse %.3f mm, %d iterations, prior kept %d, %.0f ms\n", k,
        k - 1, p.fitness, p.rmse_mm, p.iterations, p.prior_kept ? 1 : 0, p.time_ms);
  }
  if (r.closing) {
    std::printf("  closing 0→%zu: %s fitness %.3f, rmse %.3f mm\n", r.pairwise.size() - 1,
                r.closing->IsUsable() ? "ok" : r.closing->message.c_str(), r.closing->fitness,
                r.closing->rmse_mm);
  }
  if (r.loop) {
    std::printf(
        "  loop: %s, model %s, open loop %.4f deg / %.3f mm, axis rms %.3f mm, rms %.3f mm, max "
        "%.3f mm\n",
        r.loop->IsUsable() ? "ok" : r.loop->message.c_str(), ToString(r.loop->model),
        r.loop->open_loop_rot_deg, r.loop->open_loop_rms_mm, r.loop->axis_rms_mm, r.loop->rms_mm,
        r.loop->max_mm);
  }
  std::printf("  mesh: %s, %zu input points; message: '%s'\n",
              r.mesh.IsUsable() ? "ok" : r.mesh.message.c_str(), r.mesh.input_points,
              r.message.c_str());
  std::fflush(stdout);
}

// Runs the whole scan of one object; the test asserts on the figures.
struct ObjectRun {
  SimScan scan;
  ScanResult result;
  ScanFigures figures;
  double reconstruct_ms = 0;
};

void RunObject(const sim::SceneOptions& scene, const ScanOptions& options, ObjectRun* run) {
  const int previous_threads = cv::getNumThreads();
  cv::setNumThreads(kNumThreads);
  std::string error;
  const WorkingVolume volume = options.volume;
  const bool ok = RunSimScan(scene, kNumViews, kStepRad, volume, &run->scan, &error);
  if (ok) {
    const auto start = std::chrono::steady_clock::now();
    run->result = ReconstructScan(run->scan.views, run->scan.calibration.turntable, options);
    run->reconstruct_ms = MsSince(start);
  }
  cv::setNumThreads(previous_threads);
  ASSERT_TRUE(ok) << error;
  PrintStages(run->scan, run->result, run->reconstruct_ms);
  PrintViewErrors(run->scan, run->result);
  ASSERT_TRUE(run->result.IsUsable()) << run->result.message;
  ASSERT_EQ(run->result.view0_from_view.size(), static_cast<std::size_t>(kNumViews));
  ASSERT_TRUE(run->result.turntable_from_view0.has_value());
  run->figures = Evaluate(run->scan, run->result, options.volume.min_height_mm);

  const ScanFigures& f = run->figures;
  ::testing::Test::RecordProperty("fused_mean_mm", std::to_string(f.fused_mean_mm));
  ::testing::Test::RecordProperty("fused_p95_mm", std::to_string(f.fused_p95_mm));
  ::testing::Test::RecordProperty("fused_median_mm", std::to_string(f.fused_median_mm));
  ::testing::Test::RecordProperty("completeness_pct", std::to_string(f.completeness_pct));
  ::testing::Test::RecordProperty("inlier_pct", std::to_string(f.inlier_pct));
  ::testing::Test::RecordProperty("inlier_mean_mm", std::to_string(f.inlier_mean_mm));
  ::testing::Test::RecordProperty("max_rot_err_deg", std::to_string(f.max_rot_err_deg));
  ::testing::Test::RecordProperty("max_trans_err_mm", std::to_string(f.max_trans_err_mm));
  ::testing::Test::RecordProperty("max_point_err_mm", std::to_string(f.max_point_err_mm));
  ::testing::Test::RecordProperty("render_ms", std::to_string(run->scan.total_render_ms));
  ::testing::Test::RecordProperty("match_ms", std::to_string(run->scan.total_match_ms));
  ::testing::Test::RecordProperty("reconstruct_ms", std::to_string(run->reconstruct_ms));
}

// The scan options of both objects: the defaults (working volume 120 mm ×
// 200 mm about the axis, the turntable prior verified by RANSAC) on 2 threads.
ScanOptions DefaultScanOptions() {
  ScanOptions options;
  options.num_threads = kNumThreads;
  return options;
}

// ---------------------------------------------------------------- tests ----

// The exact object motion between views is the rotation about the
// calibrated turntable axis by minus the angle step (view k's points seen
// from view k − 1), and the turntable frame from the axis is the world frame.
// Cheap (no rendering); pins the conventions the scan test relies on.
TEST(ScanSim, TurntableMotionMatchesAxis) {
  std::string error;
  sim::RigOptions rig;
  std::unique_ptr<sim::SimStation> station = sim::SimStation::Create(rig, &error);
  ASSERT_TRUE(station) << error;
  std::unique_ptr<sim::Scene> scene = sim::Scene::Create(sim::SceneOptions{}, &error);
  ASSERT_TRUE(scene) << error;
  const TurntableAxis& axis = station->calibration().turntable;
  ASSERT_TRUE(axis.valid);
  const cv::Matx44d rig_from_world = station->rig_from_world();
  scene->SetTurntableAngle(0);
  const cv::Matx44d world_from_object0 = scene->world_from_object();
  for (int k = 1; k < kNumViews; ++k) {
    scene->SetTurntableAngle(k * kStepRad);
    const cv::Matx44d view0_from_view = rig_from_world * world_from_object0 *
                                        InvertRigid(scene->world_from_object()) *
                                        InvertRigid(rig_from_world);
    const cv::Matx44d prior =
        RotationAboutAxis(axis.direction_in_rig, axis.point_in_rig_mm, -k * kStepRad);
    EXPECT_LT(RotationErrorDeg(prior, view0_from_view), 1e-6) << "view " << k;
    EXPECT_LT(TranslationErrorMm(prior, view0_from_view), 1e-6) << "view " << k;
  }
  const cv::Matx44d turntable_from_rig = TurntableFromRig(axis);
  const cv::Matx44d world_from_rig = station->world_from_rig();
  EXPECT_LT(RotationErrorDeg(turntable_from_rig, world_from_rig), 1e-6);
  EXPECT_LT(TranslationErrorMm(turntable_from_rig, world_from_rig), 1e-6);
}

TEST(ScanSim, CarvedBox) {
  sim::SceneOptions scene;
  scene.object.type = sim::ObjectType::kCarvedBox;
  ScanOptions options = DefaultScanOptions();
  options.measure_box = true;
  ObjectRun run;
  RunObject(scene, options, &run);
  if (HasFatalFailure()) return;
  const ScanResult& r = run.result;

  ASSERT_TRUE(r.box_measurement.has_value());
  const BoxMeasurement& box = *r.box_measurement;
  ASSERT_TRUE(box.IsUsable()) << box.message;
  ASSERT_EQ(box.edges.size(), 12u);
  // Truth along the box axes (sorted by extent, descending).
  std::array<double, 3> truth{scene.object.carved_box.width_mm, scene.object.carved_box.depth_mm,
                              scene.object.carved_box.height_mm};
  std::sort(truth.begin(), truth.end(), std::greater<>());
  std::vector<double> errors, circle_errors;
  for (const BoxEdge& e : box.edges) {
    errors.push_back(e.length_mm - truth[e.axis]);
    circle_errors.push_back(e.circle_length_mm - truth[e.axis]);
    std::printf(
        "  edge %d-%d (axis %d, truth %.0f mm): %.3f mm, error %+.3f mm (point circle %+.3f mm)\n",
        e.a, e.b, e.axis, truth[e.axis], e.length_mm, errors.back(), circle_errors.back());
  }
  double max_abs = 0;
  for (double e : errors) max_abs = std::max(max_abs, std::abs(e));
  const double mean = Mean(errors), stddev = StdDev(errors);
  std::printf(
      "  box dims %.3f × %.3f × %.3f mm (truth %.0f × %.0f × %.0f); edge error mean %+.3f mm, std "
      "%.3f mm, max |e| %.3f mm; point circle: mean %+.3f std %.3f mm; face rms %.3f mm, "
      "orthogonality %.3f deg\n",
      box.dims_mm[0], box.dims_mm[1], box.dims_mm[2], truth[0], truth[1], truth[2], mean, stddev,
      max_abs, Mean(circle_errors), StdDev(circle_errors), box.face_rms_mm,
      box.max_orthogonality_error_deg);
  std::printf("  oriented box %.3f × %.3f × %.3f mm\n", r.box.extents_mm[0], r.box.extents_mm[1],
              r.box.extents_mm[2]);
  std::fflush(stdout);
  RecordProperty("edge_error_mean_mm", std::to_string(mean));
  RecordProperty("edge_error_std_mm", std::to_string(stddev));
  RecordProperty("edge_error_max_mm", std::to_string(max_abs));

  // Measured (seed 1, Release, 2 threads, Nov 2026): poses within 0.097°,
  // 0.63 mm (rig origin) and 0.24 mm RMS on the object; loop closed by the
  // axis model (rms 0.085 mm); completeness 98.6 %; edges +0.040 ± 0.054 mm
  // (std; max |e| 0.110 mm); the fused cloud's figures are noted at their
  // assertions. Tolerances leave 30–50 % headroom. Dec 2026 (stop 50, the
  // loop about the calibrated axis): poses within 0.026° and 0.16 mm,
  // completeness 98.0 %, edges -0.103 ± 0.059 mm (max |e| 0.171 mm); since
  // stop 51 (faces fitted to their outer layer) -0.030 ± 0.027 mm (max 0.061).
  const ScanFigures& f = run.figures;
  ASSERT_TRUE(r.loop.has_value());
  EXPECT_EQ(r.loop->model, LoopClosureResult::Model::kTurntableAxis);
  EXPECT_LE(f.max_rot_err_deg, 0.15);
  EXPECT_LE(f.max_trans_err_mm, 1.0);
  EXPECT_LE(f.max_point_err_mm, 0.35);
  EXPECT_LE(f.fused_median_mm, 0.25);
  EXPECT_LE(f.fused_mean_mm, 0.45);  // measured 0.274 (seed 1, Nov 2026)
  EXPECT_LE(f.fused_p95_mm, 1.2);    // measured 0.751
  EXPECT_GE(f.inlier_pct, 95.0);     // measured 99.0
  EXPECT_LE(f.inlier_mean_mm, 0.35);
  EXPECT_GE(f.completeness_pct, 95.0);
  // The goal (edge error std ≤ 0.2 mm) is met with room; held at 0.1 mm.
  // The mean: with the loop about the calibrated axis (stop 50) the edges
  // came out -0.103 mm short. The faces' flat parts were right (within
  // 0.01 mm at 1280×1024); the chip-cut pockets, which stereo smooths into
  // shallow dishes within the face's gates, pulled the fitted faces in.
  // MeasureBox now fits each face to its outer layer
  // (BoxMeasureOptions::outer_layer_sigmas). Held at 0.1 mm.
  EXPECT_LE(stddev, 0.1);
  EXPECT_LE(std::abs(mean), 0.1);
  EXPECT_LE(max_abs, 0.15);
}

// The egg: a surface of revolution about the turntable axis, so geometry
// cannot fix the rotation about it and only the prior can.
TEST(ScanSim, Egg) {
  sim::SceneOptions scene;
  scene.object.type = sim::ObjectType::kEgg;
  ScanOptions options = DefaultScanOptions();
  ObjectRun run;
  RunObject(scene, options, &run);
  if (HasFatalFailure()) return;
  const ScanResult& r = run.result;
  // Truth: the ellipsoid's extents; the working volume drops its lowest
  // volume_min_height_mm.
  const double height = scene.object.egg.height_mm - options.volume.min_height_mm;
  const double diameter = scene.object.egg.diameter_mm;
  std::printf("  oriented box %.3f × %.3f × %.3f mm (truth %.1f × %.1f × %.1f)\n",
              r.box.extents_mm[0], r.box.extents_mm[1], r.box.extents_mm[2], height, diameter,
              diameter);
  std::fflush(stdout);
  RecordProperty("obb_extents_mm", std::to_string(r.box.extents_mm[0]) + " " +
                                       std::to_string(r.box.extents_mm[1]) + " " +
                                       std::to_string(r.box.extents_mm[2]));
  // Measured (seed 1, Nov 2026): poses ≤ 0.065° (fine ICP slides about the
  // egg's own axis without fitting better, so the prior pose is kept:
  // RegistrationOptions::prior_slide_deg; before that rule poses drifted up
  // to 1.66°); fused cloud mean 0.676, median 0.200, p95 1.95 mm, 95.2 %
  // of points within 2 mm, completeness 76.7 % (the egg's stereo is weaker
  // than the box's: depth error median 0.6–0.7 mm, and floaters from
  // mismatched platter pixels remain).
  const ScanFigures& f = run.figures;
  ASSERT_TRUE(r.loop.has_value());
  EXPECT_EQ(r.loop->model, LoopClosureResult::Model::kTurntableAxis);
  EXPECT_LE(f.max_rot_err_deg, 0.15);
  EXPECT_LE(f.fused_median_mm, 0.3);
  EXPECT_LE(f.fused_mean_mm, 1.0);
  EXPECT_GE(f.inlier_pct, 92.0);
  EXPECT_GE(f.completeness_pct, 70.0);
}

}  // namespace
}  // namespace craftscan
