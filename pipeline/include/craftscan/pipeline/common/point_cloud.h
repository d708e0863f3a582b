// A plain point cloud (millimetres). Reading and writing: common/ply.h.
#pragma once

#include <cstddef>
#include <opencv2/core/matx.hpp>
#include <string>
#include <vector>

// Transitional: ReadPly/WritePly used to be declared here; callers outside
// the pipeline (daemon/sessions, clients/record) still rely on this include.
#include "craftscan/pipeline/common/ply.h"

namespace craftscan {

// Points in some frame named by the owner (e.g. RangeScan::world_from_scan
// says which). `normals` and `colors_rgb` are either empty or have exactly
// one entry per point.
struct PointCloud {
  std::vector<cv::Vec3f> points_mm;   // position, mm
  std::vector<cv::Vec3f> normals;     // unit length (not enforced), unitless
  std::vector<cv::Vec3b> colors_rgb;  // 8-bit R, G, B (in that order, not BGR)

  std::size_t size() const { return points_mm.size(); }
  bool empty() const { return points_mm.empty(); }
  bool HasNormals() const { return !normals.empty(); }
  bool HasColors() const { return !colors_rgb.empty(); }
  // False with a reason (why may be null) if normals/colours are present but
  // their count differs from the point count.
  bool IsValid(std::string* why) const;
};

}  // namespace craftscan
