#include "craftscan/pipeline/common/point_cloud.h"

#include <string>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

bool PointCloud::IsValid(std::string* why) const {
  if (!normals.empty() && normals.size() != points_mm.size()) {
    return Fail(why, std::to_string(normals.size()) + " normals for " +
                         std::to_string(points_mm.size()) + " points");
  }
  if (!colors_rgb.empty() && colors_rgb.size() != points_mm.size()) {
    return Fail(why, std::to_string(colors_rgb.size()) + " colours for " +
                         std::to_string(points_mm.size()) + " points");
  }
  return true;
}

}  // namespace craftscan
