// A turntable scan from view clouds to one measured model: conditioning,
// sequential registration with the turntable prior, loop closure over a full
// turn, fusion, Poisson meshing and measurement (method.md §6–§9).
//
//   std::vector<ScanView> views = ...;  // clouds in the rig frame + commanded angles
//   ScanResult r = ReconstructScan(views, calibration.turntable, ScanOptions{});
//   if (r.IsUsable()) { r.fused; r.mesh; r.box; }
//
// Frames: every view cloud is in the rig frame (rectified left camera) at its
// own turntable angle; results are in the frame of view 0 (`view0_from_view`)
// and, when the turntable axis is known, also in the turntable frame
// (`turntable_from_view0`: origin on the axis at the platter surface, +Z up).
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/registration/loop_closure.h"
#include "craftscan/pipeline/registration/registration.h"
#include "craftscan/pipeline/registration/turn_join.h"
#include "craftscan/pipeline/surface/fusion.h"
#include "craftscan/pipeline/surface/measure.h"
#include "craftscan/pipeline/surface/mesh.h"
#include "craftscan/pipeline/surface/quality.h"
#include "craftscan/pipeline/surface/visibility.h"

namespace craftscan {

struct ScanView {
  PointCloud cloud_in_rig;         // reprojected stereo points (mm), colours optional
  double commanded_angle_rad = 0;  // turntable angle at capture
};

struct ScanOptions {
  // Conditioning; with a valid turntable axis the crop is enabled with the
  // axis and `volume`, and the viewpoint is the rig origin.
  ConditioningOptions conditioning;
  WorkingVolume volume;
  RegistrationOptions registration;
  // Loop closure runs when the views cover a full turn (the commanded angles
  // span ≥ 360° − one step, i.e. the last view overlaps the first).
  LoopClosureOptions loop;
  // With a calibrated turntable the motion between views is known to a
  // fraction of a degree (calibrate-turntable's verdict: 0.2°, 0.5 mm); a
  // registration that moves the view farther from it than this (rotation,
  // or displacement of the view's bounding-box corners) slid along a
  // symmetry (a vase, an egg) or a featureless surface and is refused: the
  // view keeps the turntable motion (ScanResult::turntable_pose).
  double max_prior_deviation_deg = 2.0;
  double max_prior_deviation_mm = 3.0;
  bool close_loop = true;
  // Free-space check before fusion (visibility.h): with the rectified left
  // camera, a view's point that other views look straight through is
  // dropped. Skipped without a camera (clouds of unknown origin) or when
  // `free_space_check` is false.
  std::optional<RectifiedCamera> camera;
  bool free_space_check = true;
  VisibilityOptions visibility;
  // Fusion; by default a voxel needs support from 2 views (floaters from
  // stereo mismatches are view-specific, see FusionOptions::min_views) near
  // its tangent plane (0.5 mm: sheets a millimetre off the surface go),
  // unless no other view saw anything within 2.5 mm or only its own camera
  // faced it within 70° or it faced no other camera at all and its own within
  // 85° (a part only one view sees stays); the support may also come from
  // 2.5 mm along the surface, on the same plane (a face one view saw squarely
  // and the others obliquely and sparsely: the base of a box laid on its
  // side kept 82 % of its surface without it). Clusters under 5 % of the object's size
  // are dropped as floaters (FusionOptions::min_cluster_fraction). README 11.9 has what each
  // bought. Within 3 mm of the platter a voxel facing down needs two views
  // with no exception (FusionOptions::platter_shadow_mm; in the turntable
  // frame, so only with a turntable axis). A view's support is its local
  // surface's (FusionOptions::local_surface_support: the median of its
  // points around the voxel within 0.5 mm of the voxel's tangent plane, not
  // any one point; README 11.9, stop 63).
  FusionOptions fusion = [] {
    FusionOptions f;
    f.min_views = 2;
    f.view_support_normal_mm = 0.5;
    f.plane_support_mm = 2.5;
    f.lone_view_radius_mm = 2.5;
    f.sole_view_incidence_deg = 70;
    f.hidden_view_incidence_deg = 85;
    f.min_cluster_fraction = 0.05;
    f.platter_shadow_mm = 3;
    f.local_surface_support = true;
    return f;
  }();
  bool mesh = true;
  // The implicit surface by default: as close to the truth as Poisson's on
  // the scans of README 11.10, a few times faster, and nothing invented
  // where no point is.
  MeshMethod mesh_method = MeshMethod::kImplicit;
  // Mesh fragments under 5 % of the largest component are removed.
  PoissonOptions poisson = [] {
    PoissonOptions p;
    p.min_component_fraction = 0.05;
    return p;
  }();
  ImplicitMeshOptions implicit;  // mesh_method kImplicit (same 5 % fragment rule)
  // Measurement: the oriented box always; the box faces when `measure_box`.
  bool measure_box = false;
  BoxMeasureOptions box;
  int num_threads = 1;

  bool IsValid(std::string* why) const;
};

struct ScanResult {
  enum class Status { kOk, kFailed };
  Status status = Status::kFailed;
  std::string message;

  std::vector<ViewCloud> views;               // conditioned, in each view's rig frame
  std::vector<RegistrationResult> pairwise;   // [k]: view k → view k−1 (k ≥ 1); [0] unused
  std::optional<RegistrationResult> closing;  // view 0 → last view, for a full turn
  std::optional<LoopClosureResult> loop;
  std::vector<cv::Matx44d> view0_from_view;  // final poses
  // [k]: view k's registration onto view k − 1 was refused and, the
  // turntable being calibrated, the view kept the commanded turntable motion
  // (said in `message` and the report; the loop closure uses that motion).
  std::vector<bool> turntable_pose;
  std::optional<cv::Matx44d> turntable_from_view0;
  // The free-space check (zero when no camera was given).
  VisibilityStats visibility;
  // The last fusion's figures (after the free-space check): what multi-view
  // support dropped and kept, and the clusters dropped as floaters.
  FusionStats fusion;

  PointCloud fused;  // in the turntable frame when known, else view 0's
  MeshResult mesh;   // same frame; status kFailed with a message if not made
  // The cloud against its mesh, without ground truth (quality.h); not ok
  // without a mesh.
  CloudQuality quality;
  OrientedBox box;  // oriented bounding box of the fused cloud
  std::optional<BoxMeasurement> box_measurement;

  // Two turns (JoinTurnScans): how turn B was joined onto this turn (A),
  // and the platter-contact points each turn lost to the other.
  std::optional<TurnJoinResult> turn_join;
  std::size_t contact_dropped_a = 0, contact_dropped_b = 0;

  // Stage wall-clock times (ms).
  double condition_ms = 0, register_ms = 0, loop_ms = 0, fuse_ms = 0, mesh_ms = 0, measure_ms = 0;

  bool IsUsable() const { return status == Status::kOk; }
};

// Reconstructs one scan. `axis` may be invalid (no turntable calibration):
// then there is no working-volume crop (the clouds must be cropped already),
// no prior and no turntable frame. Fails with a reason when fewer than 2
// views, a view conditions to nothing, or a registration fails (the result
// keeps everything done up to there); with a valid axis a refused
// registration is not a failure: the view keeps its turntable pose. Never
// throws.
ScanResult ReconstructScan(const std::vector<ScanView>& views, const TurntableAxis& axis,
                           const ScanOptions& options);

// The same reconstruction, fed view by view as the views arrive, so that
// the work of each view is done while the turntable turns to the next:
// conditioning and the registration onto the previous view happen in Add;
// Finish does what only the last view allows (the closing edge of a full
// turn, loop closure, fusion, mesh, measurement). Add(v0)…Add(vn−1) then
// Finish() gives exactly ReconstructScan's result on those views.
//
//   IncrementalScan scan(calibration.turntable, options);
//   for (each view as it is matched, in order) scan.Add(std::move(view));
//   ScanResult r = scan.Finish();
//
// Add returns false once the scan can no longer succeed (invalid options, a
// view that conditions to nothing or whose commanded angle is not finite,
// a registration failure without a turntable axis); later views are then
// ignored and Finish returns the failure, with everything done up to there.
// Finish may be called once; a second call fails. Never throws. Not
// thread-safe: one thread feeds it.
class IncrementalScan {
 public:
  IncrementalScan(const TurntableAxis& axis, const ScanOptions& options);
  ~IncrementalScan();
  IncrementalScan(IncrementalScan&&) noexcept;
  IncrementalScan& operator=(IncrementalScan&&) noexcept;

  bool Add(ScanView view);
  int views() const;  // views added so far (also after a failure)
  ScanResult Finish();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Two turns of one object (turn_join.h): `turn_a` and `turn_b` each a
// finished scan (ReconstructScan or IncrementalScan; their meshes are not
// needed: ScanOptions::mesh false saves the time) in its own turntable
// frame. Joins B onto A without a prior (JoinTurns), drops each turn's
// platter-contact points the other turn sees (MergeTurns), then one fusion
// (voxels of options.fusion.voxel_mm; each turn's cloud already carries its
// views' support), one mesh, one quality assessment and one measurement as
// ReconstructScan does, in turn A's frame. The result is turn A's (views,
// registrations, loop closure, turntable_from_view0) with `turn_join` set
// and the joined fused cloud, mesh and measurement; register_ms includes the
// join. Fails (status kFailed, `turn_join` set, the refusal's reason in
// `message`) when either turn is unusable or the join is refused: nothing is
// merged wrongly. Never throws.
ScanResult JoinTurnScans(const ScanResult& turn_a, const ScanResult& turn_b,
                         const ScanOptions& options, const TurnJoinOptions& join);

// A JSON report (pretty-printed) of the scan: per-view conditioning and
// registration quality (fitness, RMSE, iterations, converged, prior kept),
// the loop closure (model, axis, open-loop and closed residuals), stage
// times, the fused cloud and mesh sizes, and the measurement (the
// MeasurementReportJson object under "measurement"). Never throws.
std::string ScanReportJson(const ScanResult& result);

// Writes the scan's products into the existing folder `dir`: fused.ply
// (binary), mesh.ply (binary) and mesh.obj when a mesh was made, and
// report.json; each atomically. Returns false with *error naming the file
// on the first failure. Never throws.
bool WriteScanOutputs(const std::string& dir, const ScanResult& result, std::string* error);

// turntable_from_rig for a valid axis: origin at axis.point_in_rig_mm, +Z
// along the axis, +X the rig's x axis made orthogonal to it.
cv::Matx44d TurntableFromRig(const TurntableAxis& axis);

}  // namespace craftscan
