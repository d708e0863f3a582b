// Fuzz target: ReadPly (pipeline/point_cloud.h) on arbitrary file contents.
// Properties: a success is a valid cloud that survives a binary
// WritePly/ReadPly round trip unchanged; a failure names the problem and
// leaves the cloud empty.
#include <cmath>
#include <string>
#include <string_view>

#include "craftscan/pipeline/common/point_cloud.h"
#include "fuzz_target.h"

namespace {

bool SameFloat(float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); }

bool SameClouds(const craftscan::PointCloud& a, const craftscan::PointCloud& b) {
  if (a.size() != b.size() || a.normals.size() != b.normals.size() ||
      a.colors_rgb != b.colors_rgb) {
    return false;
  }
  for (std::size_t i = 0; i < a.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      if (!SameFloat(a.points_mm[i][k], b.points_mm[i][k])) return false;
      if (a.HasNormals() && !SameFloat(a.normals[i][k], b.normals[i][k])) return false;
    }
  }
  return true;
}

}  // namespace

CRAFTSCAN_FUZZ_TARGET(ply) {
  const std::string path =
      WriteTempFile("input.ply", std::string_view(reinterpret_cast<const char*>(data), size));
  PointCloud cloud;
  std::string error;
  if (!Outcome(ReadPly(path, &cloud, &error), error)) {
    CRAFTSCAN_FUZZ_CHECK(cloud.empty() && !cloud.HasNormals() && !cloud.HasColors());
    return 0;
  }
  std::string why;
  CRAFTSCAN_FUZZ_CHECK(cloud.IsValid(&why));
  // Round trip through the writer (small clouds only: it costs file I/O).
  if (cloud.size() <= 4096) {
    const std::string copy_path = WriteTempFile("copy.ply", "");
    CRAFTSCAN_FUZZ_CHECK(WritePly(copy_path, cloud, /*binary=*/true, &error));
    PointCloud again;
    CRAFTSCAN_FUZZ_CHECK(ReadPly(copy_path, &again, &error));
    CRAFTSCAN_FUZZ_CHECK(SameClouds(cloud, again));
  }
  return 0;
}
