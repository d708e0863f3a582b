// Fuzz target: ReadPly and ReadMeshPly (pipeline/common/ply.h) on arbitrary
// file contents. Properties: a success is a valid cloud (mesh) that survives
// a binary WritePly/ReadPly (WriteMeshPly/ReadMeshPly) round trip unchanged,
// and a mesh's vertices are the cloud the same file gives; a failure names
// the problem and leaves the output empty.
#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "fuzz_target.h"

namespace {

using craftscan::fuzz::Outcome;
using craftscan::fuzz::WriteTempFile;

bool SameFloat(float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); }

bool SameVertices(const std::vector<cv::Vec3f>& points_a, const std::vector<cv::Vec3f>& normals_a,
                  const std::vector<cv::Vec3b>& colors_a, const std::vector<cv::Vec3f>& points_b,
                  const std::vector<cv::Vec3f>& normals_b, const std::vector<cv::Vec3b>& colors_b) {
  if (points_a.size() != points_b.size() || normals_a.size() != normals_b.size() ||
      colors_a != colors_b) {
    return false;
  }
  for (std::size_t i = 0; i < points_a.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      if (!SameFloat(points_a[i][k], points_b[i][k])) return false;
      if (!normals_a.empty() && !SameFloat(normals_a[i][k], normals_b[i][k])) return false;
    }
  }
  return true;
}

bool SameClouds(const craftscan::PointCloud& a, const craftscan::PointCloud& b) {
  return SameVertices(a.points_mm, a.normals, a.colors_rgb, b.points_mm, b.normals, b.colors_rgb);
}

bool SameMeshVertices(const craftscan::TriangleMesh& a, const craftscan::PointCloud& b) {
  return SameVertices(a.vertices_mm, a.normals, a.colors_rgb, b.points_mm, b.normals, b.colors_rgb);
}

// ReadMeshPly on the same file: a mesh is a cloud plus faces, so it reads
// only files ReadPly reads, with the same vertices.
void CheckMesh(const std::string& path, bool cloud_ok, const craftscan::PointCloud& cloud) {
  using namespace craftscan;
  TriangleMesh mesh;
  std::string error;
  if (!Outcome(ReadMeshPly(path, &mesh, &error), error)) {
    CRAFTSCAN_FUZZ_CHECK(mesh.vertices_mm.empty() && mesh.faces.empty() && mesh.normals.empty() &&
                         mesh.colors_rgb.empty());
    return;
  }
  CRAFTSCAN_FUZZ_CHECK(cloud_ok && SameMeshVertices(mesh, cloud));
  std::string why;
  CRAFTSCAN_FUZZ_CHECK(mesh.IsValid(&why) && !mesh.faces.empty());
  if (mesh.vertices_mm.size() + mesh.faces.size() <= 4096) {
    const std::string copy_path = WriteTempFile("copy_mesh.ply", "");
    CRAFTSCAN_FUZZ_CHECK(WriteMeshPly(copy_path, mesh, /*binary=*/true, &error));
    TriangleMesh again;
    CRAFTSCAN_FUZZ_CHECK(ReadMeshPly(copy_path, &again, &error));
    CRAFTSCAN_FUZZ_CHECK(again.faces == mesh.faces);
    PointCloud again_vertices;
    again_vertices.points_mm = again.vertices_mm;
    again_vertices.normals = again.normals;
    again_vertices.colors_rgb = again.colors_rgb;
    CRAFTSCAN_FUZZ_CHECK(SameMeshVertices(mesh, again_vertices));
  }
}

}  // namespace

CRAFTSCAN_FUZZ_TARGET(ply) {
  const std::string path =
      WriteTempFile("input.ply", std::string_view(reinterpret_cast<const char*>(data), size));
  PointCloud cloud;
  std::string error;
  const bool cloud_ok = ReadPly(path, &cloud, &error);
  CheckMesh(path, cloud_ok, cloud);
  if (!Outcome(cloud_ok, error)) {
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
