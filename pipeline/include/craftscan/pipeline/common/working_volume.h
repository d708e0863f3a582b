// The working volume above the platter: a vertical cylinder about the
// turntable axis, in the turntable frame (origin on the axis at the platter
// surface, +Z along the axis). One type for the daemon's config
// (pipeline.volume_*), the per-view crop and disparity band
// (ViewProcessorOptions) and the reconstruction (ScanOptions, the
// conditioning crop).
#pragma once

#include <string>

#include <opencv2/core/matx.hpp>

namespace craftscan {

struct WorkingVolume {
  double radius_mm = 120;      // distance from the axis, finite, > 0
  double min_height_mm = 1.5;  // above the platter surface: removes the platter itself; finite
  double max_height_mm = 200;  // above the platter surface; finite, > min_height_mm

  // False with a reason naming the field ("radius_mm ...") otherwise.
  bool IsValid(std::string* why) const;
  // True when `p_in_turntable` (mm) is inside or on the cylinder.
  bool Contains(const cv::Vec3d& p_in_turntable) const {
    return p_in_turntable[0] * p_in_turntable[0] + p_in_turntable[1] * p_in_turntable[1] <=
               radius_mm * radius_mm &&
           p_in_turntable[2] >= min_height_mm && p_in_turntable[2] <= max_height_mm;
  }
};

}  // namespace craftscan
