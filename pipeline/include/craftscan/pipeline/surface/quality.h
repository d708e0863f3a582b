// What a scan's report can say of its model without ground truth: how far
// the fused points lie from the mesh fitted through them (points far from
// it are floaters the fit did not follow), and where the mesh is open.
//
//   CloudQuality q = AssessQuality(result.fused, result.mesh.mesh, {});
//   q.far_pct;  // estimated outlier share; q.holes, q.largest_hole_mm
//
// The Poisson surface is smooth and fitted through the whole cloud, so a
// point more than `gate_mm` from it is most likely a stereo floater; on the
// simulated objects this estimate follows the share measured against the
// true surface (craftscan-bench scan prints both). The mesh's open
// boundaries are its holes, except the longest one, the base the platter
// hid: a turntable scan never sees it and the trimmed mesh is open there.
#pragma once

#include <cstddef>
#include <string>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/triangle_mesh.h"

namespace craftscan {

struct QualityOptions {
  double gate_mm = 1.0;  // a point farther than this from the mesh counts as far, > 0
  int num_threads = 1;
  bool IsValid(std::string* why) const;
};

struct CloudQuality {
  bool ok = false;
  std::string message;  // why not ok (no mesh, invalid input)
  std::size_t points = 0;
  double gate_mm = 0;          // the options' gate
  std::size_t far_points = 0;  // farther than gate_mm from the mesh
  double far_pct = 0;
  double median_to_mesh_mm = 0, p95_to_mesh_mm = 0;
  // Open boundary loops of the mesh: every one but the longest (the base).
  std::size_t holes = 0;
  double largest_hole_mm = 0;  // perimeter of the longest hole, 0 with none
  double base_opening_mm = 0;  // perimeter of the longest loop, 0 for a closed mesh
};

// Never throws; without mesh faces returns ok = false saying so.
CloudQuality AssessQuality(const PointCloud& fused, const TriangleMesh& mesh,
                           const QualityOptions& options);

}  // namespace craftscan
