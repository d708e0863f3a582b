// Dimension measurement (method.md §9): the oriented bounding box of any
// object, and for box-like objects the face planes, the 8 vertices, the 12
// edges and their lengths, with the paper's point-circle vertex refinement.
//
//   OrientedBox obb;
//   ComputeOrientedBox(fused, &obb, &error);
//   BoxMeasureOptions options;
//   options.base_plane = Plane{{0, 0, -1}, 0};   // the platter (world frame), base unseen
//   BoxMeasurement box = MeasureBox(fused, options);
//   std::string json = MeasurementReportJson(obb, box.IsUsable() ? &box : nullptr);
//
// Units: millimetres; degrees only in fields named *_deg. Every position is in
// the frame of the input cloud. No PCL or Eigen type appears here.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

// ----------------------------------------------------------- oriented box ----

struct OrientedBoxOptions {
  // Fraction of the points ignored at each end of each axis when taking the
  // extents (robustness to a few outliers), 0 ≤ x < 0.2.
  double trim_fraction = 0.001;
  // The axis search runs on at most this many points (a seeded random
  // subset); the final extents use every finite point. ≥ 100.
  int max_search_points = 20000;
  std::uint64_t seed = 1;
  // An upright box (non-zero, finite; need not be unit): one axis along
  // `up`, the other two about it where the footprint's trimmed area is
  // least, as catalogue dimensions are taken (height as the object stands,
  // width and depth of its footprint). A scan has the turntable's axis:
  // there the smallest box over all orientations is ill-conditioned for
  // irregular figures (boxes of nearly equal volume in several tilts, a
  // millimetre apart in their extents), the upright one is not. Unset: the
  // smallest box over all orientations.
  std::optional<cv::Vec3d> up;

  bool IsValid(std::string* why) const;  // names the offending field
};

// A box around the object: p = center_mm + axes · (s0, s1, s2) with
// |s_k| ≤ extents_mm[k] / 2 covers the (trimmed) points.
struct OrientedBox {
  cv::Vec3d center_mm{0, 0, 0};
  cv::Matx33d axes = cv::Matx33d::eye();  // columns: unit axes, sorted by extent desc; det = +1
  cv::Vec3d extents_mm{0, 0, 0};          // full side lengths along the columns of axes, desc
  std::size_t points = 0;                 // finite points used
  int up_axis = -1;  // upright box (OrientedBoxOptions::up): the column along up; else −1
};

// Computes a tight oriented box: axes from PCA, then refined by a local
// search over rotations that minimises the volume of the trimmed extents (so
// a box-shaped object gets axes along its faces even when PCA is ambiguous,
// e.g. a cube), started from 27 turns of the PCA axes (0°, 30°, 60° about
// each) so that it settles in the smallest of several local minima. Non-finite points are ignored.
// Returns false with *error (may be null) for invalid options or fewer than 4 finite points; *box
// is then left unchanged. Never throws. Thread-safe.
bool ComputeOrientedBox(const PointCloud& cloud, const OrientedBoxOptions& options,
                        OrientedBox* box, std::string* error);
// Same with default options.
bool ComputeOrientedBox(const PointCloud& cloud, OrientedBox* box, std::string* error);

// ------------------------------------------------------------------ boxes ----

// The plane n·p + offset_mm = 0 with unit normal n. A box face's normal points
// outwards (away from the box's inside).
struct Plane {
  cv::Vec3d normal{0, 0, 1};  // unit
  double offset_mm = 0;
  // Quality of a fitted plane (0 for a given one).
  std::size_t inliers = 0;  // points supporting the plane
  double rms_mm = 0;        // RMS distance of the inliers
  bool given = false;       // true: taken from BoxMeasureOptions::base_plane, not fitted

  double SignedDistanceMm(const cv::Vec3d& p) const { return normal.dot(p) + offset_mm; }
};

// How the reported vertices (and edge lengths, dims) are obtained.
enum class VertexMethod {
  // Intersection of the three face planes, each fitted to all of its face's
  // points (robust RANSAC + least squares, faces made mutually orthogonal).
  kPlaneIntersection,
  // method §9 "point circle fitting": each of the three edge lines at the
  // vertex is fitted independently from points near that edge only (a local
  // least-squares plane on each side within a band along the edge, then their
  // intersection line); the pairwise closest-point midpoints of the three
  // lines are fitted with a circle whose centre is the vertex.
  kPointCircle,
};
const char* ToString(VertexMethod method);  // "plane_intersection", "point_circle"
bool VertexMethodFromString(const std::string& text, VertexMethod* method);

struct BoxMeasureOptions {
  // --- face planes: sequential RANSAC, then least squares on the inliers ---
  double plane_distance_mm = 0.6;  // inlier gate (≈ 3σ of the surface noise), > 0
  // An inlier's normal must lie within this angle of the plane's (either
  // sign). Normals are estimated (PCA within normal_radius_mm) when the cloud
  // has none. 0 < x ≤ 90.
  double normal_angle_deg = 25;
  double normal_radius_mm = 2.0;  // > 0; used only when the cloud has no normals
  // The final least-squares face fits use a tighter normal gate: the larger of
  // this and 2.5 × the median normal deviation of the face's inliers (noisy
  // normals), at most normal_angle_deg. It keeps the walls of shallow cuts,
  // which lie within the distance gate, from pulling a face inwards, deg (> 0).
  double fit_normal_angle_deg = 10;
  // Each face is then fitted to its outer layer: the cameras smooth relief
  // below a face (a chip-cut groove comes out as a shallow dish with the
  // face's normal, within both gates) and it pulled the face inwards (the
  // simulated carved box: its edges 0.07–0.09 mm short on average at
  // 1280×1024, +0.003 mm with the outer layer). The noise σ is taken from
  // the residuals on the outer side only, the face refitted to the points
  // within this many σ on either side, until they no longer change (at most
  // 10 rounds; from 2 the gate settles near 1.5 σ, symmetric, so the noise
  // does not bias the face). 0 = off, else within [1, 10].
  double outer_layer_sigmas = 2;
  int ransac_iterations = 1000;     // per plane, ≥ 1
  int ransac_sample_points = 4000;  // hypotheses are scored on this many random points, ≥ 100
  int max_planes = 10;              // planes detected before picking the faces, ≥ 1
  // A plane needs this many inliers, and this fraction of the cloud, to count.
  int min_face_points = 50;
  double min_face_fraction = 0.01;  // 0..1
  // Faces must be pairwise parallel or orthogonal within this angle, deg (> 0).
  double orthogonality_tolerance_deg = 5;
  // Make the six faces exactly pairwise orthogonal/parallel: one rotation is
  // fitted to all face normals (weighted by inliers), then each face's offset
  // is refitted with its normal fixed.
  bool enforce_orthogonality = true;
  // Face points within this distance of another face's plane (the edge zone,
  // where estimated normals blur) are left out of the least-squares refits, mm.
  double edge_margin_mm = 1.0;

  // The plane the box stands on, e.g. the platter, when the base is unseen.
  // Either normal sign is accepted (it is turned outwards). Points within
  // base_exclusion_mm above it, and every point below it, are ignored (the
  // platter and the side faces' bottom rim). Without it the base must be
  // found among the points like any other face.
  std::optional<Plane> base_plane;
  double base_exclusion_mm = 1.0;  // ≥ 0

  // --- point-circle refinement (method §9) ---
  // An edge line is fitted from the points of its two faces that lie between
  // edge_band_min_mm and edge_band_max_mm from the edge (measured inside each
  // face) and within edge_local_length_mm of the vertex along the edge (at most
  // 45 % of the edge). Carved relief keeps ≥ 4 mm from the edges, so the band
  // sees the flat rim. 0 ≤ min < max.
  double edge_band_min_mm = 0.5;
  double edge_band_max_mm = 3.5;
  double edge_local_length_mm = 20;  // > edge_band_min_mm
  int min_edge_points = 12;          // per side; fewer: the global face plane is used, ≥ 3
  // A circle larger than this, or larger than the midpoints' largest distance
  // (nearly collinear midpoints: an obtuse triangle of noise), is not trusted:
  // the midpoints' centroid is used instead, mm (> 0).
  double max_circle_radius_mm = 2.0;

  // Which vertex set the edge lengths and dims_mm are taken from (both sets
  // are always reported). Plane intersection is the default: on synthetic
  // 80×60×50 mm boxes (σ = 0.2 mm noise, 2 mm deep cuts, base given; 5 poses,
  // 60 edges; MeasureBox.VertexMethodsCompared) its edge-length RMS error
  // is 0.005 mm against 0.085 mm for point-circle fitting: each face plane is
  // fitted to thousands of points, while an edge line sees only a thin band
  // near its vertex and the circle through three nearly coincident midpoints
  // amplifies their noise.
  VertexMethod vertex_method = VertexMethod::kPlaneIntersection;

  std::uint64_t seed = 1;  // RANSAC; results are deterministic for a seed

  bool IsValid(std::string* why) const;  // names the offending field
};

// One edge of the box: vertices a < b (indices into the vertex arrays).
struct BoxEdge {
  int a = 0, b = 0;
  int axis = 0;                       // box axis (0..2) the edge runs along
  double length_mm = 0;               // from the vertex set chosen by vertex_method
  double intersection_length_mm = 0;  // from vertices_mm
  double circle_length_mm = 0;        // from refined_vertices_mm
};

struct BoxMeasurement {
  enum class Status { kOk, kFailed };
  Status status = Status::kFailed;
  std::string message;  // why it failed; notes (e.g. "base plane given") on success

  // Box frame: columns are unit axes sorted by box extent, descending; det +1.
  cv::Matx33d axes = cv::Matx33d::eye();
  // The six faces, outward normals, in the order −axis0, +axis0, −axis1,
  // +axis1, −axis2, +axis2 (face 2k + s, s = 1 on the + side).
  std::vector<Plane> planes;
  // Vertex i lies on the + side of axis k when bit k of i is set.
  std::vector<cv::Vec3d> vertices_mm;          // 8, intersections of the face planes
  std::vector<cv::Vec3d> refined_vertices_mm;  // 8, point-circle fitting
  std::vector<double> circle_radius_mm;        // 8, radius of each vertex's circle
  std::vector<bool> circle_fallback;           // 8, true: circle rejected, centroid used
  std::vector<BoxEdge> edges;                  // 12: 4 along axis 0, then axis 1, axis 2
  VertexMethod vertex_method = VertexMethod::kPlaneIntersection;  // the set used below
  cv::Vec3d dims_mm{0, 0, 0};  // mean length of the 4 edges along each axis, desc

  // Quality.
  std::vector<Plane> detected_planes;      // every RANSAC plane (also on failure), by inliers desc
  double max_orthogonality_error_deg = 0;  // of the fitted face normals before enforcing
  double face_rms_mm = 0;                  // RMS of fitted face inliers about their planes
  std::size_t input_points = 0;            // finite points considered
  std::size_t face_points = 0;             // inliers of the six faces

  bool IsUsable() const { return status == Status::kOk; }
};

// Measures a box-like object (a rectangular block, possibly with relief cut
// into its faces) in `cloud` (e.g. the fused cloud; normals optional, their
// sign is ignored). Faces are found by sequential RANSAC (a plane's inliers
// must also agree in normal), refitted by least squares, and must be pairwise
// parallel or orthogonal; relief below a face is rejected by the inlier gate.
// A missing base can be supplied by options.base_plane. Vertices come from
// plane triples; refined vertices from point-circle fitting (see
// VertexMethod).
//
// Fails (status kFailed, message says why; detected_planes still filled in)
// for invalid options or cloud, fewer than 100 finite points, fewer than
// three mutually orthogonal faces, a missing face (the message names it and
// suggests base_plane), a base plane that is neither parallel nor orthogonal
// to the faces, or degenerate plane intersections. Never throws.
// Thread-safe.
BoxMeasurement MeasureBox(const PointCloud& cloud, const BoxMeasureOptions& options);

// A JSON report (UTF-8, pretty-printed) of the object's oriented box and, when
// `measurement` is not null, its box measurement (faces, both vertex sets,
// edges, dims, quality, status and message). Never throws.
std::string MeasurementReportJson(const OrientedBox& box, const BoxMeasurement* measurement);

// Writes MeasurementReportJson atomically to `path` (WriteFileAtomically).
// Returns false with *error (may be null) on an I/O failure. Never throws.
bool WriteMeasurementReport(const std::string& path, const OrientedBox& box,
                            const BoxMeasurement* measurement, std::string* error);

}  // namespace craftscan
