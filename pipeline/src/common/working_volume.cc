#include "craftscan/pipeline/common/working_volume.h"

#include <cmath>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

bool WorkingVolume::IsValid(std::string* why) const {
  if (!(radius_mm > 0) || !std::isfinite(radius_mm)) {
    return Fail(why, "radius_mm must be finite and > 0");
  }
  if (!std::isfinite(min_height_mm) || !std::isfinite(max_height_mm) ||
      !(max_height_mm > min_height_mm)) {
    return Fail(why, "max_height_mm must be finite and > min_height_mm");
  }
  return true;
}

}  // namespace craftscan
