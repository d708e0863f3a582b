// Loop closure for a full turn of the turntable: the pairwise registrations
// of a closed ring of views are made consistent.
//
// First model: every view pose is a rotation about one turntable axis
// (direction, point; 4 parameters) by its own angle (one per view, the first
// fixed at 0). When that model fits the pairwise registrations poorly
// (RMS residual above `max_axis_rms_mm`, e.g. an object that moved on the
// platter), a general pose graph (6 parameters per view) is solved instead.
// Both are nonlinear least squares over point residuals: for each edge
// i → j, sample points p of view i must land where the measured
// registration puts them, ‖T_j⁻¹·T_i·p − T_ij·p‖ (mm).
//
// With the turntable's calibrated axis (calibrate-turntable: a board's
// corners over the whole turn), the axis the registrations fit is compared
// with it; where they agree within the registrations' own precision the
// views turn about the calibrated axis and only their angles are fitted.
// Six pairwise registrations of an object determine the axis's direction to
// about a tenth of a degree, and a turn fused about an axis tilted by that
// is bent by it (README 11.11). Edges whose registration slid and kept the
// turntable's motion (PoseEdge::registered_target_from_source) enter that
// comparison with the registration's own motion: the kept motion is the
// calibration's, and with a stale calibration it would agree with it. Where
// the registrations then contradict the calibration, the views turn about
// the axis their own motions fit.
#pragma once

#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

namespace craftscan {

// One measured registration: points of view `source` mapped into view
// `target` by target_from_source.
struct PoseEdge {
  int source = 0;
  int target = 0;
  cv::Matx44d target_from_source = cv::Matx44d::eye();
  double weight = 1;  // relative confidence (e.g. fitness); > 0
  // Where the registration itself put the source, when target_from_source
  // is the turntable's motion kept instead (RegistrationResult::
  // slid_target_from_source). Used only to check a calibrated axis against
  // the registrations (see CloseLoop).
  std::optional<cv::Matx44d> registered_target_from_source;
};

// A turntable axis measured by calibration, in the frame of view 0.
struct CalibratedAxis {
  cv::Vec3d direction{0, 0, 1};  // unit vector
  cv::Vec3d point_mm{0, 0, 0};   // any point on the axis
};

struct LoopClosureOptions {
  double max_axis_rms_mm = 0.5;  // above: fall back to the pose graph
  // With a calibrated axis: the axis the registrations fit may differ from
  // it by up to this in direction (deg) and in position at the sample
  // points' centroid (mm) for the calibrated axis to be used; beyond, the
  // calibration no longer matches the turntable (it moved, or the
  // calibration is stale) and the fitted axis is used. Both > 0.
  double max_axis_disagreement_deg = 0.5;
  double max_axis_disagreement_mm = 1.0;
  bool allow_pose_graph = true;
  int max_iterations = 50;  // Gauss–Newton / Levenberg–Marquardt iterations
  bool IsValid(std::string* why) const;
};

struct LoopClosureResult {
  enum class Status { kOk, kFailed };
  enum class Model { kNone, kTurntableAxis, kPoseGraph };
  Status status = Status::kFailed;
  Model model = Model::kNone;
  std::string message;

  // view0_from_view[k]: pose of view k in the frame of view 0 (identity for k = 0).
  std::vector<cv::Matx44d> view0_from_view;
  // Turntable model only: the axis in the frame of view 0 and each view's
  // angle about it (rad, view 0 = 0).
  cv::Vec3d axis_direction{0, 0, 1};
  cv::Vec3d axis_point_mm{0, 0, 0};
  std::vector<double> angles_rad;
  // With a calibrated axis given: the axis the registrations fit, against
  // it (direction in deg, position at the sample points' centroid in mm;
  // NaN when no axis could be fitted), and whether the poses turn about the
  // calibrated axis (the axis figures above are then the calibrated one's).
  double axis_disagreement_deg = std::numeric_limits<double>::quiet_NaN();
  double axis_disagreement_mm = std::numeric_limits<double>::quiet_NaN();
  bool calibrated_axis = false;

  // Closure quality. Before: the chained pairwise poses around the ring
  // compose to this error (identity expected), as rotation (deg) and the RMS
  // displacement of the sample points (mm). After: the RMS and max residual
  // of the fitted model over all edges (mm).
  double open_loop_rot_deg = 0;
  double open_loop_rms_mm = 0;
  double axis_rms_mm = 0;  // the turntable model's fit (also when rejected)
  double rms_mm = 0;
  double max_mm = 0;

  bool IsUsable() const { return status == Status::kOk; }
};

// `edges` must connect views 0..num_views−1 (e.g. the ring k → k−1 and
// 0 → num_views−1); `initial_view0_from_view` (size num_views) starts the
// solver (e.g. chained pairwise poses). `sample_points_mm` are points of a
// typical view (e.g. the object's bounding box corners) used for the point
// residuals; at least 3 not on one line. Fails with a reason on inconsistent
// input. Never throws.
// `calibrated` (optional): the turntable's calibrated axis (see above).
LoopClosureResult CloseLoop(int num_views, const std::vector<PoseEdge>& edges,
                            const std::vector<cv::Matx44d>& initial_view0_from_view,
                            const std::vector<cv::Vec3d>& sample_points_mm,
                            const LoopClosureOptions& options,
                            const std::optional<CalibratedAxis>& calibrated = std::nullopt);

const char* ToString(LoopClosureResult::Model model);  // "none", "turntable_axis", "pose_graph"

}  // namespace craftscan
