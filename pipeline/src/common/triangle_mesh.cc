#include "craftscan/pipeline/common/triangle_mesh.h"

#include <cmath>
#include <string>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

bool TriangleMesh::IsValid(std::string* why) const {
  if (!normals.empty() && normals.size() != vertices_mm.size()) {
    return Fail(why, "mesh has " + std::to_string(normals.size()) + " normals for " +
                         std::to_string(vertices_mm.size()) + " vertices");
  }
  if (!colors_rgb.empty() && colors_rgb.size() != vertices_mm.size()) {
    return Fail(why, "mesh has " + std::to_string(colors_rgb.size()) + " colours for " +
                         std::to_string(vertices_mm.size()) + " vertices");
  }
  for (std::size_t i = 0; i < vertices_mm.size(); ++i) {
    const cv::Vec3f& v = vertices_mm[i];
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) {
      return Fail(why, "mesh vertex " + std::to_string(i) + " is not finite");
    }
  }
  const auto n = static_cast<long long>(vertices_mm.size());
  for (std::size_t f = 0; f < faces.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (faces[f][k] < 0 || faces[f][k] >= n) {
        return Fail(why, "mesh face " + std::to_string(f) + " references vertex " +
                             std::to_string(faces[f][k]) + " of " + std::to_string(n));
      }
    }
  }
  return true;
}

}  // namespace craftscan
