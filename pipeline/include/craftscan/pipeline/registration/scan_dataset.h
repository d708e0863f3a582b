// Range scans with ground-truth poses (Stanford scanalyze .conf data sets).
// Pose helpers and error metrics: common/pose.h.
#pragma once

#include <opencv2/core/matx.hpp>
#include <string>
#include <vector>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

// One range scan: points in the scan's own frame, and the rigid pose that
// maps them into the common (world) frame: p_world = world_from_scan · p_scan
// (homogeneous, translation in mm, last row 0 0 0 1).
struct RangeScan {
  std::string name;  // file name as listed, e.g. "bun045.ply"
  PointCloud cloud;  // in the scan frame, mm
  cv::Matx44d world_from_scan = cv::Matx44d::eye();
};

// Loads every scan listed in `dir`/bun.conf, in file order.
//
// bun.conf lines (blank lines and lines starting with '#' are ignored):
//   camera tx ty tz qx qy qz qw        viewing pose; checked for syntax, unused
//   bmesh <file> tx ty tz qx qy qz qw  one scan; <file> relative to `dir`
// Translations and the PLY coordinates are in metres and are converted to mm.
// Pose convention (scanalyze; stated in the data set's README.txt and verified
// by test_point_cloud against overlapping scans): the quaternion is stored as
// (qx qy qz qw) and the scan-to-world map uses its CONJUGATE,
//   p_world = R(q)ᵀ · p_scan + t,
// so world_from_scan = [R(q)ᵀ | 1000·t]. The quaternion must be unit length
// within 1e-3 (it is renormalised).
//
// Returns false with *error (may be null; names the file, line number and what
// is wrong) if bun.conf is missing, a line is malformed (unknown keyword,
// wrong number of fields, non-numeric or non-finite values, non-unit
// quaternion), there is no bmesh line, or a listed PLY cannot be read.
// *scans is cleared first and left empty on failure. Never throws.
// Thread-safe.
bool LoadStanfordScans(const std::string& dir, std::vector<RangeScan>* scans, std::string* error);

}  // namespace craftscan
