// Fusion of registered view clouds into one cloud by voxel averaging.
//
//   std::vector<PointCloud> in_world = ...;  // every view mapped into one frame
//   std::string error;
//   PointCloud fused = FuseClouds(in_world, FusionOptions{}, &error);
//   if (!error.empty()) { /* nothing fused; error says why */ }
//
// Units: millimetres. No PCL type appears here.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

struct FusionOptions {
  // Edge of the cubic voxels, mm (> 0). Voxels are aligned to the frame's
  // origin: voxel (i, j, k) holds the points with floor(p / voxel_mm) = (i, j, k).
  double voxel_mm = 0.5;
  // A voxel with fewer input points than this is dropped (≥ 1; 1 keeps every
  // occupied voxel). Raising it removes isolated outliers at the cost of thin,
  // sparsely seen parts.
  int min_points_per_voxel = 1;
  // Normals of one voxel are summed after flipping each to agree with the
  // running sum (views may orient them differently); a sum shorter than this
  // fraction of the number of normals (they disagree: a thin wall seen from
  // both sides, or noise) falls back to the first normal of the voxel. 0..1.
  double min_normal_agreement = 0.1;
  // Averaging within a voxel alone barely reduces noise along the surface
  // normal once the noise is a fair part of the voxel: a voxel that the
  // surface crosses near its wall collects one tail of the noise. With
  // normals, each fused point is therefore moved along its normal onto the
  // plane through the mean of the input points in its 3×3×3 voxel block
  // (mean of the block ⟂ the normal; a first-order moving-least-squares step).
  bool refine_along_normal = true;
  // Multi-view consistency: a voxel is kept only when points of at least
  // `min_views` different input clouds lie within `view_support_mm` of it
  // (1 = off). Stereo leaves view-specific floaters (mismatches at
  // silhouettes and occlusions, each at its own place in each view) while
  // the surface is seen from several views. Clouds beyond the 64th count as
  // the 64th. ≥ 1; view_support_mm > 0.
  int min_views = 1;
  double view_support_mm = 1.0;
  // Support along the surface (mm, ≥ 0; 0 = off): with normals, a
  // neighbouring voxel of another cloud supports only when one of the two
  // lies within this distance of the other's tangent plane. Stereo also
  // leaves sheets a millimetre or so off the surface (a dark or grazing patch
  // matched at a slightly wrong disparity): they lie inside the cube of
  // view_support_mm around the surface, but not on its plane.
  double view_support_normal_mm = 0;
  // Local-surface support (needs view_support_normal_mm and normals): a
  // cloud supports a voxel when the median offset, along the voxel's
  // normal, of that cloud's points within view_support_mm (in voxels whose
  // normal is within local_support_normal_deg of the voxel's: the far wall
  // of a groove is another surface) is within view_support_normal_mm. The
  // voxel's own clouds are tested alike. A cloud with fewer than
  // min_local_points such points, or whose camera faced the voxel at more
  // than local_support_incidence_deg (a grazing view measures badly; needs
  // FuseClouds' camera centres, 0 = no such exception), supports it as
  // without this option. Two views that each matched a patch a millimetre
  // or two off (a periodic stitch along both views' epipolar lines, each
  // view's points a noisy sheet of its own) have points near each other's
  // planes by chance, but their surfaces do not agree (README 11.9, stop 63).
  bool local_surface_support = false;
  int min_local_points = 3;                 // ≥ 1
  double local_support_normal_deg = 45;     // (0, 180]
  double local_support_incidence_deg = 70;  // [0, 90)
  int num_threads = 1;  // ≥ 1, for the local-surface support; the result does not depend on it
  // Support from farther along the surface (mm, ≥ 0; 0 = off; needs
  // view_support_normal_mm): a voxel without support within
  // view_support_mm is also supported by another cloud's voxel within this
  // distance when each lies within view_support_normal_mm of the other's
  // tangent plane and their normals differ by less than 25°, and such
  // voxels lie around it (their mean direction along the plane under half
  // their number), not only to one side. A face one view saw squarely and
  // the others only obliquely is sampled densely by the one and sparsely by
  // the others: their points are millimetres apart but on one plane; a
  // floater or a sheet off the surface is on no other view's plane, and a
  // surface fattened past its silhouette has the others' points on one
  // side only.
  double plane_support_mm = 0;
  // A voxel without support is still kept when no other cloud has a point
  // near it (mm, ≥ 0; 0 = off: unsupported voxels always go): a part of the
  // surface only one view saw (a recess, the inside of a handle) is no
  // floater. Floaters lie where other views saw the surface and did not
  // confirm them. "Near" is the 3×3×3 block of cells of this edge around the
  // voxel's cell: at least this distance, at most twice it.
  double lone_view_radius_mm = 0;
  // Parts only their own view could see (degrees, [0, 90); 0 = off; needs
  // normals and FuseClouds' `camera_centers_mm`): a voxel without support is
  // also kept when its own cloud's camera looked at it within this angle of
  // its normal and no other cloud's camera did (every other view saw it at a
  // grazing angle or from behind, so none could have confirmed it). The
  // underside of a jug's belly, seen obliquely from above by the one view
  // facing it, is such a part; a mismatched patch usually lies where another
  // view had a clear look, or faces no camera squarely. Occlusion is not
  // considered: a voxel facing a camera that another part hides it from
  // still needs support.
  double sole_view_incidence_deg = 0;
  // Parts no other camera could see (degrees, [0, 90); 0 = off; needs
  // normals and the camera centres): a voxel without support is also kept
  // when its own camera looked at it within this angle of its normal and
  // every other cloud's camera lies behind its tangent plane, so that no
  // other view could have confirmed it however good its matching. The band
  // of an egg curving in towards the platter, seen from above at 75–85° by
  // the one view in front of it and from behind by all the others, is such a
  // part; sole_view_incidence_deg's tighter angle drops it. A patch that any
  // other camera faces, however obliquely, still needs support.
  double hidden_view_incidence_deg = 0;
  // Under an overhang, next to the platter (mm, ≥ 0; 0 = off; needs normals
  // and `platter`): a voxel lower than this above the platter whose normal
  // is within platter_shadow_normal_deg of straight down gets none of the
  // exceptions above (lone, sole, hidden view): it needs the support of
  // min_views clouds. There the matcher smears the object's disparity onto
  // the shadowed platter, a skirt under an egg that one view makes and no
  // other confirms; the real foot of a jug or a figure curving in towards
  // the platter is seen by the neighbouring views as well (1280x1024, the
  // egg at seed 23: 54 of its 55 points below 3 mm had one view's points
  // only; the jug's foot: 132 of its 278 had two views'). The angle is in
  // [0, 90).
  double platter_shadow_mm = 0;
  double platter_shadow_normal_deg = 60;
  // The platter in the clouds' frame, (a, b, c, d) with height above it
  // a·x + b·y + c·z + d and (a, b, c) a unit vector pointing up; all zero:
  // unknown (platter_shadow_mm is then not applied).
  cv::Vec4d platter = {0, 0, 0, 0};
  // Floaters: the kept voxels fall into clusters (cells of cluster_gap_mm
  // that touch, 26-neighbourhood, are one cluster: parts farther apart than
  // about one to two cells are separate). A cluster with fewer voxels than
  // min_cluster_fraction × the largest one's is dropped: a turntable holds
  // one object, while stereo leaves detached specks and sheets around it.
  // 0 = off; 0..1; cluster_gap_mm > 0.
  double min_cluster_fraction = 0;
  double cluster_gap_mm = 2.0;

  // False with a reason naming the field (why may be null).
  bool IsValid(std::string* why) const;
};

// Figures of one fusion (optional output of FuseClouds).
struct FusionStats {
  std::size_t input_points = 0;            // over all clouds
  std::size_t nonfinite_points = 0;        // dropped: NaN/inf coordinates
  std::size_t out_of_range_points = 0;     // dropped: beyond ±2^20 voxels from the origin
  std::size_t sparse_voxel_points = 0;     // dropped: in voxels below min_points_per_voxel
  std::size_t single_view_voxels = 0;      // dropped: supported by fewer than min_views clouds
  std::size_t plane_supported_voxels = 0;  // supported only from farther along their plane
  std::size_t lone_view_voxels = 0;        // kept unsupported: no other cloud near them
  std::size_t sole_view_voxels = 0;        // kept unsupported: only their own camera faced them
  std::size_t hidden_view_voxels = 0;      // kept unsupported: every other camera behind them
  std::size_t platter_shadow_voxels = 0;   // unsupported under an overhang by the platter: dropped
  std::size_t small_cluster_voxels = 0;    // dropped: in clusters below min_cluster_fraction
  std::size_t clusters = 0;                // clusters before that (0: not computed)
  std::size_t output_points = 0;           // = occupied voxels kept
  double mean_points_per_voxel = 0;        // over the kept voxels
};

// Merges clouds that are already in one common frame. Each occupied voxel
// becomes one output point: the mean of its input points (moved along the
// normal when refine_along_normal is set and normals exist). The output has
// normals only when every non-empty input has normals (the voxel's normals,
// each flipped to agree with the running sum, summed and renormalised to unit
// length) and colours only when every non-empty input has colours (the
// rounded mean per channel). Non-finite input points are skipped; a
// non-finite normal is skipped within its voxel (the first finite normal, or
// +Z if none, stands in). Output points are ordered by voxel index (x, then y,
// then z), so the result does not depend on the order of the inputs' points
// beyond floating-point summation order.
//
// Returns an empty cloud and sets *error (may be null) for invalid options,
// an input that fails PointCloud::IsValid, no finite input point, or no voxel
// left after min_points_per_voxel; *error is cleared on success. *stats (may
// be null) is filled in either way. Never throws. Thread-safe (reentrant).
//
// `camera_centers_mm` (may be null or empty: sole_view_incidence_deg is then
// not applied): the optical centre of the camera that saw each cloud, in the
// common frame, one per cloud; another count is an error.
PointCloud FuseClouds(const std::vector<PointCloud>& clouds, const FusionOptions& options,
                      std::string* error, FusionStats* stats = nullptr,
                      const std::vector<cv::Vec3d>* camera_centers_mm = nullptr);

}  // namespace craftscan
