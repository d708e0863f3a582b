// Pairwise registration of view clouds (method.md §7–§8): conditioning,
// FPFH + RANSAC coarse registration scored by a Huber loss, and the paper's
// weighted ICP (point-to-plane as an option).
//
//   ViewCloud source = ConditionCloud(raw_source, conditioning, &error);
//   ViewCloud target = ConditionCloud(raw_target, conditioning, &error);
//   RegistrationResult r = RegisterPair(source, target, RegistrationOptions{});
//   if (r.IsUsable()) { /* r.target_from_source maps source points into the target */ }
//
// Units: millimetres, radians; degrees only in fields named *_deg. Poses are
// rigid 4×4 transforms named target_from_source. No PCL type appears here.
#pragma once

#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/working_volume.h"

namespace craftscan {

// --- Conditioning -------------------------------------------------------------

// The crop to the working volume (common/working_volume.h): points are
// mapped into the turntable frame and kept when inside the cylinder.
struct VolumeCrop {
  bool enabled = false;
  cv::Matx44d turntable_from_cloud = cv::Matx44d::eye();  // rigid
  WorkingVolume volume;
  // Platter removal beyond the crop: points below platter_band_mm whose
  // normal (facing the camera) is within platter_normal_deg of the axis,
  // pointing up (level surface just above the platter: the platter lifted by
  // matching errors), are dropped. A surface facing down stays: the foot of
  // a jug or a figure curving in towards the platter. A band at or below
  // min_height_mm disables it, as by default here. It must stay below the
  // flattest object's top: a flat object (an embroidery, a print) is
  // exactly such a level surface (craftscan-bench scan at 640x512: with a
  // 6 mm band the embroidery kept 38 % of its surface, without it 94 %).
  // The daemon's pipeline.platter_band_mm is 1.5 mm over a 0.5 mm volume
  // bottom with platter_normal_deg 60: the walls' lowest millimetre stays
  // and the platter noise goes, level or sloped (1280x1024, no projector:
  // the box's height error 1.44 → 0.4 mm; README 11.9). The platter smeared
  // up under an overhang faces down; FusionOptions::platter_shadow_mm
  // takes it.
  double platter_band_mm = 0;
  double platter_normal_deg = 30;

  bool IsValid(std::string* why) const;
};

struct ConditioningOptions {
  VolumeCrop crop;  // disabled: no crop (clouds of an isolated object)
  // Statistical outlier removal (PCL's): a point whose mean distance to its
  // k nearest neighbours exceeds the global mean by std_ratio standard
  // deviations is dropped. k = 0 disables.
  int outlier_neighbors = 20;
  double outlier_std_ratio = 2.0;
  // Voxel sizes (mm): `fine` keeps the cloud fine ICP works on (0 = keep every
  // point), `coarse` the one features and RANSAC work on.
  double fine_voxel_mm = 1.0;
  double coarse_voxel_mm = 4.0;
  // Normals: PCA over the k nearest neighbours, oriented towards the
  // viewpoint.
  int normal_neighbors = 15;
  cv::Vec3d viewpoint_mm{0, 0, 0};  // sensor origin in the cloud's frame
  int num_threads = 1;              // ≥ 1

  bool IsValid(std::string* why) const;
};

// A conditioned view: the cleaned cloud at two resolutions, both with unit
// normals oriented towards `viewpoint_mm`, in the input cloud's frame.
struct ViewCloud {
  PointCloud fine;    // fine-voxel cloud (with colours when the input had them)
  PointCloud coarse;  // coarse-voxel cloud
  cv::Vec3d viewpoint_mm{0, 0, 0};
  std::size_t input_points = 0;    // before conditioning
  std::size_t cropped_points = 0;  // removed by the working volume
  std::size_t outlier_points = 0;  // removed by the outlier filter
  std::string error;               // non-empty when conditioning failed
  bool ok() const { return error.empty(); }
};

// Crops, removes outliers, downsamples and estimates normals. Points that are
// not finite are dropped. On invalid options or an input without points the
// result's `error` says why (an empty result is not an error in itself: a
// view whose crop leaves nothing has `error` "no points left ..."). Never
// throws. Thread-safe.
ViewCloud ConditionCloud(const PointCloud& input, const ConditioningOptions& options);

// --- Features -----------------------------------------------------------------

// FPFH descriptors (33 bins) of `cloud` (which must have normals), computed
// with PCL's FPFHEstimationOMP over a sphere of `radius_mm` on `num_threads`
// threads. Points with too few neighbours get an all-zero descriptor.
// Returns one descriptor per point; empty on a cloud without normals.
using Fpfh = std::array<float, 33>;
std::vector<Fpfh> ComputeFpfh(const PointCloud& cloud, double radius_mm, int num_threads);

// --- Registration -------------------------------------------------------------

enum class FineMethod {
  kWeightedIcp,   // method §8: normal-angle rejection, weights b·exp(−d/σ), point-to-point
  kPointToPlane,  // classic point-to-plane ICP (linearised), for comparison
};
const char* ToString(FineMethod method);  // "weighted", "point-to-plane"
bool FineMethodFromString(const std::string& text, FineMethod* method);

struct CoarseOptions {
  double feature_radius_mm = 15;  // FPFH support radius (≈ 5 coarse voxels)
  bool mutual_filter = true;      // keep a feature match only if it is mutual
  // RANSAC over 3-point samples of the correspondences.
  int max_iterations = 20000;
  double confidence = 0.999;      // early termination once the best model is this likely
  double inlier_distance_mm = 6;  // the Huber threshold w, and the inlier gate
  double edge_similarity = 0.9;   // sample pre-check: edge lengths agree to this ratio
  std::uint64_t seed = 42;        // fixed: the result is deterministic for a thread count
  // A prior (e.g. the turntable rotation by the commanded angle) is scored
  // first; RANSAC keeps it unless a hypothesis scores better.
  std::optional<cv::Matx44d> prior_target_from_source;
  // With a prior: accept it without RANSAC when at least this fraction of the
  // coarse source points lies within inlier_distance_mm of the target after
  // the prior (0 disables the shortcut: RANSAC always runs).
  double prior_accept_fitness = 0.0;

  bool IsValid(std::string* why) const;
};

struct FineOptions {
  FineMethod method = FineMethod::kWeightedIcp;
  int max_iterations = 60;
  double max_correspondence_mm = 4;    // gate on correspondence distance (first iteration)
  double min_correspondence_mm = 1.0;  // the gate shrinks to 3× the RMS but not below this
  double max_normal_angle_deg = 45;    // t_r: pairs whose normals differ more are rejected
  // Stop when the mean correspondence distance falls below this (r of §8) or
  // the update moves points by less than `min_update_mm`.
  double stop_mean_distance_mm = 0.05;
  double min_update_mm = 2e-3;
  // Overlap factor b of §8: 1 for a pair the target view can see (the source
  // point's normal faces the target's viewpoint), `outside_overlap_weight`
  // otherwise.
  double outside_overlap_weight = 0.5;
  // Weighted ICP: pair each source point with the foot of its perpendicular
  // on the tangent plane of its nearest target point (false: the target point
  // itself, the literal reading; measured slower to converge and biased by
  // the sample spacing).
  bool tangent_projection = true;
  // The source points used: at most this many, an even stride through the
  // fine cloud (the target keeps every fine point). 0 = all.
  int max_source_points = 8000;
  bool IsValid(std::string* why) const;
};

struct RegistrationOptions {
  CoarseOptions coarse;
  FineOptions fine;
  // Fails the result as "no overlap" when the final fitness (see
  // RegistrationResult: the fraction of fine source points within
  // fitness_distance_mm of the target) is below this.
  double min_fitness = 0.1;
  double fitness_distance_mm = 2.0;
  // Also "no overlap" when the inlier RMSE exceeds this fraction of
  // fitness_distance_mm: two unrelated surfaces pushed together cross each
  // other everywhere, so their distances spread evenly over the gate (RMSE ≈
  // 0.58 of it), while a true overlap leaves residuals at the noise level.
  double max_rmse_ratio = 0.5;
  // With a prior: when fine registration from it turns the pose by more than
  // prior_slide_deg but gains less than prior_slide_gain in fitness, it slid
  // along a direction the geometry does not fix (an egg turning about its own
  // axis, which is the turntable's): the prior pose itself is kept (0 = off).
  // On the simulated egg ICP slid 1.1–1.5° per pair at +0.00–0.005 fitness.
  double prior_slide_deg = 0.3;
  double prior_slide_gain = 0.02;
  // With a prior, fine registration moves the view away from it only along
  // the motions the source's surface holds (degeneracy-aware registration,
  // "solution remapping": Zhang, Kaess & Singh, ICRA 2016). Along a motion
  // whose point-to-plane information is below this fraction of the
  // strongest's (KeepPriorAlongWeakMotions) the prior's pose is kept: the
  // surface cannot place the view there better than the turntable does, and
  // ICP follows the stereo's small biases instead. A body of revolution on
  // the turntable (the owl, the jug) is held about its axis by 0.004–0.04 of
  // the strongest; a box, a statue 0.1 and more. 0 = off; [0, 1).
  double prior_weak_constraint = 0.05;
  int min_points = 30;  // fewer (coarse) points than this on either side: fails
  int num_threads = 1;  // ≥ 1; results are deterministic for a given count

  bool IsValid(std::string* why) const;
};

// Outcome and quality of one registration stage or a whole registration.
struct RegistrationResult {
  enum class Status { kOk, kFailed };
  Status status = Status::kFailed;
  std::string message;  // why it failed, or notes on success

  cv::Matx44d target_from_source = cv::Matx44d::eye();
  // Fitness: fraction of source points with a target point within the
  // inlier gate after the transform; inlier RMSE over those pairs (mm).
  double fitness = 0;
  double rmse_mm = std::numeric_limits<double>::quiet_NaN();
  std::size_t inliers = 0;
  int iterations = 0;               // RANSAC hypotheses tried / ICP iterations
  bool converged = false;           // ICP met its stop criterion (coarse: early-terminated)
  bool prior_kept = false;          // coarse: the prior was the winning hypothesis
  std::size_t correspondences = 0;  // coarse: feature matches used by RANSAC
  double time_ms = 0;               // whole call
  double coarse_ms = 0;             // RegisterPair: its coarse stage (features, matching, RANSAC)
  double fine_ms = 0;               // RegisterPair: its fine stage
  // RegisterPair with a prior, when the prior pose was kept because fine
  // registration slid away from it without fitting better
  // (RegistrationOptions::prior_slide_deg): where fine registration put the
  // source. The kept pose is the turntable's motion; loop closure checks the
  // calibrated axis against the registrations' own motions, which a stale
  // calibration's kept motion would otherwise hide.
  // Also set when motions the surface barely holds were kept from the prior
  // (RegistrationOptions::prior_weak_constraint): then weak_motions_kept
  // (1–5) says how many.
  std::optional<cv::Matx44d> slid_target_from_source;
  int weak_motions_kept = 0;

  bool IsUsable() const { return status == Status::kOk; }
};

// `registered` (target_from_source) with its motion away from `prior` kept
// only along the motions the surface of `source` (with normals) holds: the
// eigenvectors of its point-to-plane information matrix about its centroid
// (rotations scaled by its radius) whose eigenvalue is at least
// min_constraint times the largest; along the others the prior's pose
// stays. *weak_motions (optional) gets how many were reverted. Returns
// `registered` unchanged when min_constraint is 0 or the cloud has fewer than
// 6 points or no normals.
cv::Matx44d KeepPriorAlongWeakMotions(const PointCloud& source, const cv::Matx44d& prior,
                                      const cv::Matx44d& registered, double min_constraint,
                                      int* weak_motions = nullptr);

// Coarse stage only (method §7) on the coarse clouds.
RegistrationResult RegisterCoarse(const ViewCloud& source, const ViewCloud& target,
                                  const CoarseOptions& options, int num_threads);

// The coarse stage's best distinct hypotheses, best (lowest Huber score)
// first, each refit on its inliers like RegisterCoarse's winner, with its
// fitness and RMSE on the coarse clouds. Two hypotheses are the same when
// they differ by less than min_separation_deg in rotation and less than
// min_separation_mm in translation (a better one replaces a kept one close
// to it). For the ambiguity of a registration without a prior: a second
// distinct hypothesis that fits about as well as the first (a symmetric
// object) means the first may be wrong.
struct CoarseCandidates {
  int max_candidates = 5;          // ≥ 1
  double min_separation_deg = 10;  // ≥ 0
  double min_separation_mm = 10;   // ≥ 0
};
// The first entry is RegisterCoarse's result (the same transform); on a
// failure the one entry says why. Never throws. Thread-safe.
std::vector<RegistrationResult> RegisterCoarseCandidates(const ViewCloud& source,
                                                         const ViewCloud& target,
                                                         const CoarseOptions& options,
                                                         const CoarseCandidates& wanted,
                                                         int num_threads);

// Fine stage only (method §8) on the fine clouds, from `initial_target_from_source`.
RegistrationResult RegisterFine(const ViewCloud& source, const ViewCloud& target,
                                const cv::Matx44d& initial_target_from_source,
                                const FineOptions& options, int num_threads);

// Coarse then fine. Fails with a reason (never a wrong "success") on invalid
// options, too few points, a degenerate (flat or linear) cloud, no overlap
// (fitness below min_fitness) or a fine stage that diverges. Never throws.
// Thread-safe (each call is independent).
RegistrationResult RegisterPair(const ViewCloud& source, const ViewCloud& target,
                                const RegistrationOptions& options);

// Rotation by `angle_rad` about the axis through `point_mm` with unit
// `direction` (right hand): the pose a turntable step gives.
cv::Matx44d RotationAboutAxis(const cv::Vec3d& direction, const cv::Vec3d& point_mm,
                              double angle_rad);

}  // namespace craftscan
