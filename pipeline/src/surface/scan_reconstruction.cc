#include "craftscan/pipeline/surface/scan_reconstruction.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <thread>

#include <nlohmann/json.hpp>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

constexpr double kTwoPi = 2 * M_PI;

// Angle wrapped to (−π, π].
double Wrap(double a) {
  a = std::fmod(a, kTwoPi);
  if (a <= -M_PI) a += kTwoPi;
  if (a > M_PI) a -= kTwoPi;
  return a;
}

// Corners of the axis-aligned bounding box of a cloud (loop-closure samples).
std::vector<cv::Vec3d> BoxCorners(const PointCloud& cloud) {
  cv::Vec3d lo(1e300, 1e300, 1e300), hi(-1e300, -1e300, -1e300);
  for (const auto& p : cloud.points_mm)
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], static_cast<double>(p[i]));
      hi[i] = std::max(hi[i], static_cast<double>(p[i]));
    }
  std::vector<cv::Vec3d> corners;
  for (int m = 0; m < 8; ++m)
    corners.emplace_back(m & 1 ? hi[0] : lo[0], m & 2 ? hi[1] : lo[1], m & 4 ? hi[2] : lo[2]);
  return corners;
}

// A usable registration made from a turntable prior that strays from it
// beyond the options' limits becomes a refused one, saying why.
void RefuseStraying(const RegistrationOptions& pair, const PointCloud& source,
                    const ScanOptions& options, RegistrationResult* r);

// How far `registered` moves the points of `cloud` from where `prior` puts
// them: the rotation between the two (degrees) and the largest displacement
// of the cloud's bounding-box corners (mm). Refuses a registration that
// strays beyond the limits ("" when within them).
std::string PriorDeviation(const cv::Matx44d& registered, const cv::Matx44d& prior,
                           const PointCloud& cloud, const ScanOptions& options) {
  const cv::Matx44d delta = InvertRigid(prior) * registered;
  const cv::Matx33d R = delta.get_minor<3, 3>(0, 0);
  const double cos_angle = std::clamp((cv::trace(R) - 1) / 2, -1.0, 1.0);
  const double angle_deg = std::acos(cos_angle) * 180 / M_PI;
  double shift_mm = 0;
  for (const cv::Vec3d& c : BoxCorners(cloud)) {
    const cv::Vec4d a = registered * cv::Vec4d(c[0], c[1], c[2], 1);
    const cv::Vec4d b = prior * cv::Vec4d(c[0], c[1], c[2], 1);
    shift_mm = std::max(shift_mm, cv::norm(cv::Vec3d(a[0] - b[0], a[1] - b[1], a[2] - b[2])));
  }
  if (angle_deg <= options.max_prior_deviation_deg && shift_mm <= options.max_prior_deviation_mm)
    return {};
  char text[200];
  std::snprintf(text, sizeof(text),
                "it strays %.2f° and up to %.2f mm from the calibrated turntable motion (limits "
                "%.2f°, %.2f mm: a symmetric or featureless surface let it slide)",
                angle_deg, shift_mm, options.max_prior_deviation_deg,
                options.max_prior_deviation_mm);
  return text;
}

void RefuseStraying(const RegistrationOptions& pair, const PointCloud& source,
                    const ScanOptions& options, RegistrationResult* r) {
  if (!r->IsUsable() || !pair.coarse.prior_target_from_source) return;
  const std::string why =
      PriorDeviation(r->target_from_source, *pair.coarse.prior_target_from_source, source, options);
  if (why.empty()) return;
  r->status = RegistrationResult::Status::kFailed;
  r->message = why;
}

// The oriented box of the fused cloud and, when asked, the box faces (on
// the platter's plane with a turntable frame). Returns the oriented box's
// error, empty on success (a failed box measurement is a note, not an error).
std::string Measure(const ScanOptions& options, bool have_axis, ScanResult* result) {
  std::string box_error;
  // In the turntable frame the box stands on the platter (z up).
  OrientedBoxOptions box_options;
  if (have_axis) box_options.up = cv::Vec3d(0, 0, 1);
  if (!ComputeOrientedBox(result->fused, box_options, &result->box, &box_error)) return box_error;
  if (options.measure_box) {
    BoxMeasureOptions box = options.box;
    if (have_axis && !box.base_plane) {
      Plane platter;  // z = 0 in the turntable frame
      platter.normal = cv::Vec3d(0, 0, 1);
      platter.offset_mm = 0;
      platter.given = true;
      box.base_plane = platter;
    }
    result->box_measurement = MeasureBox(result->fused, box);
  }
  return {};
}

// The mesh of the fused cloud (when asked) and the cloud's quality against it.
void MeshAndAssess(const ScanOptions& options, ScanResult* result) {
  if (!options.mesh) {
    result->mesh.message = "meshing not requested";
    return;
  }
  if (options.mesh_method == MeshMethod::kImplicit) {
    result->mesh = ImplicitMesh(result->fused, options.implicit);
  } else {
    PoissonOptions poisson = options.poisson;
    poisson.num_threads = options.num_threads;
    result->mesh = PoissonMesh(result->fused, poisson);
  }
  if (result->mesh.IsUsable()) {
    QualityOptions quality;
    quality.num_threads = options.num_threads;
    result->quality = AssessQuality(result->fused, result->mesh.mesh, quality);
  }
}

// What a finished scan says beside its figures: the loop closure, the views
// that kept their turntable pose, a mesh or box measurement that failed.
std::string ScanNotes(const ScanResult& result, bool closed_loop, bool meshed) {
  std::string notes;
  if (closed_loop) {
    if (!result.closing->IsUsable())
      notes = "loop not closed: " + result.closing->message;
    else if (!result.loop->IsUsable())
      notes = "loop closure failed: " + result.loop->message;
    else
      notes = std::string("loop closed (") + ToString(result.loop->model) +
              (result.loop->calibrated_axis ? ", about the calibrated axis" : "") + ")";
    const LoopClosureResult& loop = *result.loop;
    if (loop.IsUsable() && !loop.calibrated_axis && std::isfinite(loop.axis_disagreement_deg)) {
      char text[240];
      std::snprintf(text, sizeof(text),
                    "; the views turned about an axis %.2f° and %.2f mm from the calibrated one: "
                    "the turntable or the cameras may have moved since calibrate-turntable "
                    "(run it again)",
                    loop.axis_disagreement_deg, loop.axis_disagreement_mm);
      notes += text;
    }
  }
  for (std::size_t k = 1; k < result.turntable_pose.size(); ++k) {
    if (!result.turntable_pose[k]) continue;
    notes += (notes.empty() ? "" : "; ") + std::string("view ") + std::to_string(k) +
             " kept its calibrated turntable pose (registration onto view " +
             std::to_string(k - 1) + " refused: " + result.pairwise[k].message + ")";
  }
  if (meshed && !result.mesh.IsUsable())
    notes += (notes.empty() ? "" : "; ") + std::string("mesh failed: ") + result.mesh.message;
  if (result.box_measurement && !result.box_measurement->IsUsable())
    notes += (notes.empty() ? "" : "; ") + std::string("box measurement failed: ") +
             result.box_measurement->message;
  return notes;
}

// The conditioning options for every view (with a turntable frame: cropped
// to the working volume, normals towards the rectified left camera).
ConditioningOptions ViewConditioning(bool have_axis, const cv::Matx44d& turntable_from_rig,
                                     const ScanOptions& options) {
  ConditioningOptions conditioning = options.conditioning;
  conditioning.num_threads = options.num_threads;
  if (have_axis) {
    conditioning.crop.enabled = true;
    conditioning.crop.turntable_from_cloud = turntable_from_rig;
    conditioning.crop.volume = options.volume;
    conditioning.viewpoint_mm = cv::Vec3d(0, 0, 0);  // the rectified left camera
  }
  return conditioning;
}

}  // namespace

struct IncrementalScan::Impl {
  Impl(const TurntableAxis& a, const ScanOptions& o) : axis(a), options(o) {
    std::string why;
    if (!options.IsValid(&why)) {
      result.message = "invalid scan options: " + why;
      return;
    }
    have_axis = axis.valid;
    if (have_axis) turntable_from_rig = TurntableFromRig(axis);
    conditioning = ViewConditioning(have_axis, turntable_from_rig, options);
    reg = options.registration;
    reg.num_threads = options.num_threads;
  }

  bool failed() const { return !result.message.empty(); }

  // The object turned by +Δθ about the axis between two views, so view k − 1
  // sees view k's points turned back by −Δθ.
  cv::Matx44d Prior(double from_angle, double to_angle) const {
    return RotationAboutAxis(axis.direction_in_rig, axis.point_in_rig_mm,
                             -Wrap(from_angle - to_angle));
  }

  bool Add(ScanView view);
  ScanResult Finish();

  TurntableAxis axis;
  ScanOptions options;
  bool have_axis = false;
  cv::Matx44d turntable_from_rig = cv::Matx44d::eye();
  ConditioningOptions conditioning;
  RegistrationOptions reg;
  std::vector<ScanView> views;  // as given: the free-space check reads what each view saw
  ScanResult result;
  bool finished = false;
};

// Conditions the view and registers it onto the previous one (view k onto
// view k − 1).
bool IncrementalScan::Impl::Add(ScanView view) {
  if (failed() || finished) return false;
  const int k = static_cast<int>(views.size());
  views.push_back(std::move(view));
  if (!std::isfinite(views.back().commanded_angle_rad)) {
    result.message = "view " + std::to_string(k) + ": the commanded angle is not finite";
    return false;
  }
  auto start = Clock::now();
  result.views.push_back(ConditionCloud(views.back().cloud_in_rig, conditioning));
  result.condition_ms += MsSince(start);
  if (!result.views.back().ok()) {
    result.message = "view " + std::to_string(k) + ": " + result.views.back().error;
    return false;
  }
  result.pairwise.emplace_back();
  result.turntable_pose.push_back(false);
  if (k == 0) {
    result.view0_from_view.push_back(cv::Matx44d::eye());
    return true;
  }
  start = Clock::now();
  RegistrationOptions pair = reg;
  if (have_axis)
    pair.coarse.prior_target_from_source =
        Prior(views[k].commanded_angle_rad, views[k - 1].commanded_angle_rad);
  RegistrationResult& registered = result.pairwise[k];
  registered = RegisterPair(result.views[k], result.views[k - 1], pair);
  RefuseStraying(pair, result.views[k].fine, options, &registered);
  cv::Matx44d previous_from_view = registered.target_from_source;
  if (!registered.IsUsable()) {
    if (!have_axis) {
      result.message = "registration of view " + std::to_string(k) + " onto view " +
                       std::to_string(k - 1) + " failed: " + registered.message;
      result.register_ms += MsSince(start);
      return false;
    }
    // The turntable is calibrated: the view keeps the motion it commanded.
    result.turntable_pose[k] = true;
    previous_from_view = *pair.coarse.prior_target_from_source;
  }
  result.view0_from_view.push_back(result.view0_from_view[k - 1] * previous_from_view);
  result.register_ms += MsSince(start);
  return true;
}

ScanResult IncrementalScan::Impl::Finish() {
  if (finished) {
    ScanResult again;
    again.message = "the scan was already finished";
    return again;
  }
  finished = true;
  std::string why;
  const int n = static_cast<int>(views.size());
  if (failed()) return std::move(result);
  if (n < 2) {
    result.message = "a scan needs at least 2 views, got " + std::to_string(n);
    return std::move(result);
  }

  // --- Closing edge: a full turn, the first view overlaps the last -----------
  auto start = Clock::now();
  double span = 0;
  for (int k = 1; k < n; ++k)
    span += std::abs(Wrap(views[k].commanded_angle_rad - views[k - 1].commanded_angle_rad));
  const double step = n > 1 ? span / (n - 1) : 0;
  const bool full_turn = n >= 3 && span + step >= kTwoPi - 1e-3;
  if (full_turn && options.close_loop) {
    RegistrationOptions pair = reg;
    if (have_axis)
      pair.coarse.prior_target_from_source =
          Prior(views[0].commanded_angle_rad, views[n - 1].commanded_angle_rad);
    result.closing = RegisterPair(result.views[0], result.views[n - 1], pair);
    RefuseStraying(pair, result.views[0].fine, options, &*result.closing);
  }
  result.register_ms += MsSince(start);

  // --- Loop closure ----------------------------------------------------------
  start = Clock::now();
  if (result.closing && result.closing->IsUsable()) {
    std::vector<PoseEdge> edges;
    for (int k = 1; k < n; ++k) {
      if (result.turntable_pose[k])
        edges.push_back({k, k - 1,
                         Prior(views[k].commanded_angle_rad, views[k - 1].commanded_angle_rad), 1.0,
                         std::nullopt});
      else
        edges.push_back({k, k - 1, result.pairwise[k].target_from_source, 1.0,
                         result.pairwise[k].slid_target_from_source});
    }
    edges.push_back({0, n - 1, result.closing->target_from_source, 1.0,
                     result.closing->slid_target_from_source});
    // With a calibrated turntable, its axis (in the rig frame, which is
    // view 0's frame) where the registrations agree with it.
    std::optional<CalibratedAxis> calibrated;
    if (have_axis) calibrated = CalibratedAxis{axis.direction_in_rig, axis.point_in_rig_mm};
    result.loop = CloseLoop(n, edges, result.view0_from_view, BoxCorners(result.views[0].fine),
                            options.loop, calibrated);
    if (result.loop->IsUsable()) result.view0_from_view = result.loop->view0_from_view;
  }
  result.loop_ms = MsSince(start);

  // --- Fusion ------------------------------------------------------------------
  start = Clock::now();
  // Everything into the turntable frame at view 0 (or view 0's rig frame).
  const cv::Matx44d out_from_view0 = have_axis ? turntable_from_rig : cv::Matx44d::eye();
  if (have_axis) result.turntable_from_view0 = turntable_from_rig;
  std::vector<cv::Matx44d> out_from_view(n);
  for (int k = 0; k < n; ++k) out_from_view[k] = out_from_view0 * result.view0_from_view[k];
  // Each view's camera: the rig frame's origin is the rectified left camera.
  std::vector<cv::Vec3d> centers(n);
  for (int k = 0; k < n; ++k)
    centers[k] = cv::Vec3d(out_from_view[k](0, 3), out_from_view[k](1, 3), out_from_view[k](2, 3));
  // In the turntable frame the platter is z = 0.
  FusionOptions fusion = options.fusion;
  fusion.num_threads = options.num_threads;
  if (have_axis) fusion.platter = {0, 0, 1, 0};
  auto fuse = [&](const std::vector<PointCloud>& in_rig) {
    std::vector<PointCloud> clouds;
    clouds.reserve(n);
    for (int k = 0; k < n; ++k) clouds.push_back(TransformCloud(out_from_view[k], in_rig[k]));
    return FuseClouds(clouds, fusion, &why, &result.fusion, &centers);
  };
  std::vector<PointCloud> fine;
  fine.reserve(n);
  for (int k = 0; k < n; ++k) fine.push_back(result.views[k].fine);
  result.fused = fuse(fine);
  if (options.camera && options.free_space_check && !result.fused.empty()) {
    // Fused once, the surface is confirmed by several views; what each view
    // saw on it shows where space is free. Points there go, then fuse again.
    std::vector<PointCloud> seen;
    seen.reserve(n);
    for (int k = 0; k < n; ++k) seen.push_back(views[k].cloud_in_rig);
    VisibilityOptions visibility = options.visibility;
    visibility.num_threads = options.num_threads;
    why.clear();
    fine = RemoveFreeSpaceViolations(fine, seen, out_from_view, *options.camera, visibility,
                                     &result.visibility, &why, &result.fused);
    if (!why.empty()) {
      result.message = "free-space check: " + why;
      return std::move(result);
    }
    result.fused = fuse(fine);
  }
  result.fuse_ms = MsSince(start);
  if (result.fused.empty()) {
    result.message = "fusion failed: " + why;
    return std::move(result);
  }

  // --- Mesh and measurement -------------------------------------------------------
  // Both read only the fused cloud and write their own parts of the result,
  // so with more than one thread the measurement runs on a thread of its own
  // while the mesh is made (PCL's Poisson keeps about one core busy).
  std::string measure_error;
  const auto measure = [&] {
    const auto measure_start = Clock::now();
    try {
      measure_error = Measure(options, have_axis, &result);
    } catch (const std::exception& e) {
      measure_error = std::string("failed: ") + e.what();
    }
    result.measure_ms = MsSince(measure_start);
  };
  std::thread alongside;
  if (options.num_threads > 1) alongside = std::thread(measure);
  start = Clock::now();
  try {
    MeshAndAssess(options, &result);
  } catch (...) {
    if (alongside.joinable()) alongside.join();
    throw;
  }
  result.mesh_ms = MsSince(start);
  if (alongside.joinable())
    alongside.join();
  else
    measure();
  if (!measure_error.empty()) {
    result.message = "oriented box: " + measure_error;
    return std::move(result);
  }
  result.status = ScanResult::Status::kOk;
  result.message = ScanNotes(result, full_turn && options.close_loop, options.mesh);
  return std::move(result);
}

namespace {

using Json = nlohmann::ordered_json;

Json Num(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

Json PoseJson(const cv::Matx44d& T) {
  Json rows = Json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({T(r, 0), T(r, 1), T(r, 2), T(r, 3)});
  return rows;
}

Json RegistrationJson(const RegistrationResult& r) {
  Json j;
  j["ok"] = r.IsUsable();
  j["message"] = r.message;
  j["fitness"] = Num(r.fitness);
  j["rmse_mm"] = Num(r.rmse_mm);
  j["inliers"] = r.inliers;
  j["iterations"] = r.iterations;
  j["converged"] = r.converged;
  j["prior_kept"] = r.prior_kept;
  j["weak_motions_kept"] = r.weak_motions_kept;
  j["correspondences"] = r.correspondences;
  j["coarse_ms"] = Num(r.coarse_ms);
  j["fine_ms"] = Num(r.fine_ms);
  j["target_from_source"] = PoseJson(r.target_from_source);
  return j;
}

// The axis-aligned bounds of `points` (not empty) in the report's frame, mm:
// what a reader of fused.ply or mesh.ply finds.
Json BoundsJson(const std::vector<cv::Vec3f>& points) {
  cv::Vec3f lo = points.front(), hi = points.front();
  for (const cv::Vec3f& p : points) {
    for (int c = 0; c < 3; ++c) {
      lo[c] = std::min(lo[c], p[c]);
      hi[c] = std::max(hi[c], p[c]);
    }
  }
  return {{"min", {lo[0], lo[1], lo[2]}}, {"max", {hi[0], hi[1], hi[2]}}};
}

}  // namespace

std::string ScanReportJson(const ScanResult& result) {
  try {
    Json j;
    j["ok"] = result.IsUsable();
    j["message"] = result.message;
    j["views"] = Json::array();
    for (std::size_t k = 0; k < result.views.size(); ++k) {
      const ViewCloud& v = result.views[k];
      Json view;
      view["index"] = k;
      view["input_points"] = v.input_points;
      view["cropped_points"] = v.cropped_points;
      view["outlier_points"] = v.outlier_points;
      view["fine_points"] = v.fine.size();
      if (k < result.visibility.removed_per_view.size())
        view["free_space_removed"] = result.visibility.removed_per_view[k];
      view["coarse_points"] = v.coarse.size();
      if (!v.ok()) view["error"] = v.error;
      if (k >= 1 && k < result.pairwise.size())
        view["registration_to_previous"] = RegistrationJson(result.pairwise[k]);
      if (k < result.turntable_pose.size())
        view["pose"] =
            result.turntable_pose[k] ? "turntable" : (k == 0 ? "reference" : "registered");
      if (k < result.view0_from_view.size())
        view["view0_from_view"] = PoseJson(result.view0_from_view[k]);
      j["views"].push_back(view);
    }
    if (result.closing) j["closing_registration"] = RegistrationJson(*result.closing);
    if (result.loop) {
      const LoopClosureResult& l = *result.loop;
      Json loop;
      loop["ok"] = l.IsUsable();
      loop["model"] = ToString(l.model);
      loop["message"] = l.message;
      loop["open_loop_rot_deg"] = Num(l.open_loop_rot_deg);
      loop["open_loop_rms_mm"] = Num(l.open_loop_rms_mm);
      loop["axis_rms_mm"] = Num(l.axis_rms_mm);
      loop["rms_mm"] = Num(l.rms_mm);
      loop["max_mm"] = Num(l.max_mm);
      if (std::isfinite(l.axis_disagreement_deg)) {
        loop["axis"] = l.calibrated_axis ? "calibrated" : "fitted";
        loop["axis_disagreement_deg"] = Num(l.axis_disagreement_deg);
        loop["axis_disagreement_mm"] = Num(l.axis_disagreement_mm);
      }
      if (l.model == LoopClosureResult::Model::kTurntableAxis) {
        loop["axis_direction"] = {l.axis_direction[0], l.axis_direction[1], l.axis_direction[2]};
        loop["axis_point_mm"] = {l.axis_point_mm[0], l.axis_point_mm[1], l.axis_point_mm[2]};
        Json angles = Json::array();
        for (double a : l.angles_rad) angles.push_back(a * 180 / M_PI);
        loop["angles_deg"] = angles;
      }
      j["loop_closure"] = loop;
    }
    j["frame"] = result.turntable_from_view0 ? "turntable" : "view0";
    if (result.turntable_from_view0)
      j["turntable_from_view0"] = PoseJson(*result.turntable_from_view0);
    if (!result.visibility.removed_per_view.empty()) {
      Json vis;
      vis["checked_points"] = result.visibility.checked_points;
      vis["removed_points"] = result.visibility.removed_points;
      vis["removed_per_view"] = result.visibility.removed_per_view;
      vis["unsupported_points"] = result.visibility.unsupported_points;
      j["free_space_check"] = vis;
    }
    if (const FusionStats& f = result.fusion; f.output_points > 0)
      j["fusion"] = {{"input_points", f.input_points},
                     {"unsupported_voxels_dropped", f.single_view_voxels},
                     {"plane_supported_voxels", f.plane_supported_voxels},
                     {"lone_view_voxels_kept", f.lone_view_voxels},
                     {"sole_view_voxels_kept", f.sole_view_voxels},
                     {"hidden_view_voxels_kept", f.hidden_view_voxels},
                     {"platter_shadow_voxels_dropped", f.platter_shadow_voxels},
                     {"small_cluster_voxels_dropped", f.small_cluster_voxels},
                     {"output_points", f.output_points}};
    if (result.quality.ok) {
      const CloudQuality& q = result.quality;
      Json quality;
      quality["far_from_mesh_pct"] = q.far_pct;
      quality["far_from_mesh_points"] = q.far_points;
      quality["gate_mm"] = q.gate_mm;
      quality["median_to_mesh_mm"] = q.median_to_mesh_mm;
      quality["p95_to_mesh_mm"] = q.p95_to_mesh_mm;
      quality["holes"] = q.holes;
      quality["largest_hole_mm"] = q.largest_hole_mm;
      quality["base_opening_mm"] = q.base_opening_mm;
      j["quality"] = quality;
    }
    j["fused_points"] = result.fused.size();
    if (!result.fused.empty()) j["fused_bounds_mm"] = BoundsJson(result.fused.points_mm);
    Json mesh;
    mesh["ok"] = result.mesh.IsUsable();
    mesh["message"] = result.mesh.message;
    mesh["vertices"] = result.mesh.mesh.vertices_mm.size();
    mesh["faces"] = result.mesh.mesh.faces.size();
    // Diagnostics PCL's Poisson printed, kept off stdout (PoissonMesh).
    mesh["library_stdout_lines"] = result.mesh.library_stdout_lines;
    if (!result.mesh.mesh.vertices_mm.empty())
      mesh["bounds_mm"] = BoundsJson(result.mesh.mesh.vertices_mm);
    j["mesh"] = mesh;
    Json times;
    times["condition_ms"] = result.condition_ms;
    times["register_ms"] = result.register_ms;
    times["loop_ms"] = result.loop_ms;
    times["fuse_ms"] = result.fuse_ms;
    times["mesh_ms"] = result.mesh_ms;
    times["measure_ms"] = result.measure_ms;
    j["times"] = times;
    if (!result.fused.empty()) {
      const BoxMeasurement* box = result.box_measurement && result.box_measurement->IsUsable()
                                      ? &*result.box_measurement
                                      : nullptr;
      j["measurement"] = Json::parse(MeasurementReportJson(result.box, box), nullptr, false);
      if (result.box_measurement && !result.box_measurement->IsUsable())
        j["box_measurement_error"] = result.box_measurement->message;
    }
    // Messages may quote bytes that are not UTF-8 (a file name): replace
    // them rather than losing the whole report to nlohmann's type_error.
    return j.dump(2, ' ', false, Json::error_handler_t::replace);
  } catch (const std::exception& e) {
    return std::string("{\"ok\": false, \"message\": \"report failed\"}");
  }
}

bool WriteScanOutputs(const std::string& dir, const ScanResult& result, std::string* error) {
  const std::string base = dir.empty() || dir.back() == '/' ? dir : dir + "/";
  if (!result.fused.empty() && !WritePly(base + "fused.ply", result.fused, true, error))
    return false;
  if (result.mesh.IsUsable()) {
    if (!WriteMeshPly(base + "mesh.ply", result.mesh.mesh, true, error)) return false;
    if (!WriteMeshObj(base + "mesh.obj", result.mesh.mesh, error)) return false;
  }
  return WriteFileAtomically(base + "report.json", ScanReportJson(result), error);
}

bool ScanOptions::IsValid(std::string* why) const {
  std::string sub;
  if (!volume.IsValid(&sub)) return Fail(why, "volume." + sub);
  if (num_threads < 1) return Fail(why, "num_threads must be ≥ 1");
  if (!(max_prior_deviation_deg > 0) || !(max_prior_deviation_mm > 0))
    return Fail(why, "max_prior_deviation_deg and max_prior_deviation_mm must be > 0");
  if (!conditioning.IsValid(&sub)) return Fail(why, "conditioning: " + sub);
  if (!registration.IsValid(&sub)) return Fail(why, "registration: " + sub);
  if (!loop.IsValid(&sub)) return Fail(why, "loop: " + sub);
  if (!fusion.IsValid(&sub)) return Fail(why, "fusion: " + sub);
  if (mesh && mesh_method == MeshMethod::kPoisson && !poisson.IsValid(&sub))
    return Fail(why, "poisson: " + sub);
  if (mesh && mesh_method == MeshMethod::kImplicit && !implicit.IsValid(&sub))
    return Fail(why, "implicit: " + sub);
  if (measure_box && !box.IsValid(&sub)) return Fail(why, "box: " + sub);
  if (camera && !camera->IsValid(&sub)) return Fail(why, "camera: " + sub);
  if (camera && !visibility.IsValid(&sub)) return Fail(why, "visibility: " + sub);
  return true;
}

cv::Matx44d TurntableFromRig(const TurntableAxis& axis) {
  cv::Vec3d z = axis.direction_in_rig;
  z /= cv::norm(z);
  cv::Vec3d x(1, 0, 0);
  x -= z * z.dot(x);
  if (cv::norm(x) < 1e-6) {  // the axis along the rig's x: use its y
    x = cv::Vec3d(0, 1, 0) - z * z[1];
  }
  x /= cv::norm(x);
  const cv::Vec3d y = z.cross(x);
  // rig_from_turntable = [x y z | p]; invert.
  cv::Matx44d rig_from_turntable = cv::Matx44d::eye();
  for (int r = 0; r < 3; ++r) {
    rig_from_turntable(r, 0) = x[r];
    rig_from_turntable(r, 1) = y[r];
    rig_from_turntable(r, 2) = z[r];
    rig_from_turntable(r, 3) = axis.point_in_rig_mm[r];
  }
  return InvertRigid(rig_from_turntable);
}

IncrementalScan::IncrementalScan(const TurntableAxis& axis, const ScanOptions& options)
    : impl_(std::make_unique<Impl>(axis, options)) {}
IncrementalScan::~IncrementalScan() = default;
IncrementalScan::IncrementalScan(IncrementalScan&&) noexcept = default;
IncrementalScan& IncrementalScan::operator=(IncrementalScan&&) noexcept = default;

int IncrementalScan::views() const { return static_cast<int>(impl_->views.size()); }

bool IncrementalScan::Add(ScanView view) {
  try {
    return impl_->Add(std::move(view));
  } catch (const std::exception& e) {  // e.g. std::bad_alloc from a huge cloud
    impl_->result.message = std::string("reconstruction failed: ") + e.what();
    return false;
  }
}

ScanResult IncrementalScan::Finish() {
  try {
    return impl_->Finish();
  } catch (const std::exception& e) {
    ScanResult result;
    result.message = std::string("reconstruction failed: ") + e.what();
    return result;
  }
}

ScanResult JoinTurnScans(const ScanResult& turn_a, const ScanResult& turn_b,
                         const ScanOptions& options, const TurnJoinOptions& join) {
  return NoThrow<ScanResult>("JoinTurnScans", ScanResult::Status::kFailed, [&]() -> ScanResult {
    ScanResult result = turn_a;
    result.status = ScanResult::Status::kFailed;
    result.mesh = MeshResult{};
    result.quality = CloudQuality{};
    result.box_measurement.reset();
    std::string why;
    if (!options.IsValid(&why)) {
      result.message = "invalid options: " + why;
      return result;
    }
    if (!turn_a.IsUsable() || !turn_b.IsUsable()) {
      result.message = std::string("the ") + (turn_a.IsUsable() ? "second" : "first") +
                       " turn failed: " + (turn_a.IsUsable() ? turn_b : turn_a).message;
      return result;
    }
    auto start = Clock::now();
    TurnJoinOptions j = join;
    j.num_threads = options.num_threads;
    result.turn_join = JoinTurns(turn_a.fused, turn_b.fused, j);
    result.register_ms += MsSince(start);
    if (!result.turn_join->IsUsable()) {
      result.message = "joining the turns: " + result.turn_join->message;
      return result;
    }
    start = Clock::now();
    const PointCloud merged = MergeTurns(turn_a.fused, turn_b.fused, result.turn_join->a_from_b, j,
                                         &result.contact_dropped_a, &result.contact_dropped_b);
    FusionOptions fusion;
    fusion.voxel_mm = options.fusion.voxel_mm;
    fusion.refine_along_normal = options.fusion.refine_along_normal;
    result.fused = FuseClouds({merged}, fusion, &why, &result.fusion);
    result.fuse_ms = MsSince(start);
    if (result.fused.empty()) {
      result.message = "fusion of the turns failed: " + why;
      return result;
    }
    start = Clock::now();
    MeshAndAssess(options, &result);
    result.mesh_ms = MsSince(start);
    start = Clock::now();
    const bool have_axis = turn_a.turntable_from_view0.has_value();
    if (std::string error = Measure(options, have_axis, &result); !error.empty()) {
      result.message = "oriented box: " + error;
      result.measure_ms = MsSince(start);
      return result;
    }
    result.measure_ms = MsSince(start);
    result.status = ScanResult::Status::kOk;
    result.message = "two turns " + result.turn_join->message;
    return result;
  });
}

ScanResult ReconstructScan(const std::vector<ScanView>& views, const TurntableAxis& axis,
                           const ScanOptions& options) {
  try {
    IncrementalScan scan(axis, options);
    for (const ScanView& view : views)
      if (!scan.Add(view)) break;
    return scan.Finish();
  } catch (const std::exception& e) {  // e.g. std::bad_alloc copying a huge cloud
    ScanResult result;
    result.message = std::string("reconstruction failed: ") + e.what();
    return result;
  }
}

}  // namespace craftscan
