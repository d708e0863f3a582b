// report.html's 3D view (report.h, ReportOptions::viewer): the fused cloud
// thinned and the mesh simplified to the page's budget, in the arrays
// CraftscanViewer.setData takes (clients/web/API.md "The 3D viewer"), and
// the page's parts that carry them (base64 in <script> elements, the viewer
// bundle, the script that starts it).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/triangle_mesh.h"

namespace craftscan::daemon::internal {

struct ViewerModel {
  std::vector<float> cloud_positions_mm;   // x, y, z per point
  std::vector<std::uint8_t> cloud_colors;  // r, g, b per point (sRGB), or empty
  std::size_t cloud_source_points = 0;     // points of the fused cloud given

  std::vector<float> mesh_positions_mm;     // x, y, z per vertex
  std::vector<std::uint8_t> mesh_colors;    // r, g, b per vertex, or empty
  std::vector<std::uint32_t> mesh_indices;  // three per triangle (counter-clockwise)
  std::size_t mesh_source_triangles = 0;    // triangles of the mesh given
  std::string mesh_left_out;                // why the mesh is not shown ("" when it is)

  std::size_t points() const { return cloud_positions_mm.size() / 3; }
  std::size_t triangles() const { return mesh_indices.size() / 3; }
  bool empty() const { return cloud_positions_mm.empty() && mesh_indices.empty(); }
};

// The model for the page: the cloud's finite points, an even subsample of
// them (every (n / max_points)-th) when there are more than max_points; the
// mesh as it is when it has at most max_triangles, else SimplifyMesh'd. An
// invalid mesh (TriangleMesh::IsValid) is left out with mesh_left_out set.
// Null or empty inputs give empty parts. max_* ≥ 1.
ViewerModel MakeViewerModel(const PointCloud* cloud, const TriangleMesh* mesh,
                            std::size_t max_points, std::size_t max_triangles);

// Vertex clustering: vertices are merged per cell of a regular grid
// (position and colour averaged), triangles that collapse or repeat are
// dropped; the cell grows until at most max_triangles remain. Keeps the
// shape to about one cell (reported in *cell_mm, may be null); normals are
// not carried. A valid mesh with at most max_triangles is returned as it is.
TriangleMesh SimplifyMesh(const TriangleMesh& mesh, std::size_t max_triangles,
                          double* cell_mm = nullptr);

// RFC 4648 base64 (with padding).
std::string Base64(std::string_view bytes);

// The section that holds the view (placed above the previews) and what ends
// the page body: the data elements, the bundle and the start-up script.
// `frame` is report.json's ("turntable": +Z up; "view0": the rig's −Y up).
std::string ViewerSectionHtml(const ViewerModel& model);
std::string ViewerScriptsHtml(const ViewerModel& model, std::string_view bundle,
                              const std::string& frame);

}  // namespace craftscan::daemon::internal
