// An indexed triangle mesh (millimetres): the one mesh type of the project,
// produced by Poisson meshing, read and written by ply.h, rendered by the
// report and loaded as a simulated object by the sim driver.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

namespace craftscan {

// `normals` and `colors_rgb` are empty or have one entry per vertex; faces
// index vertices (0-based) counter-clockwise seen from outside (right-hand
// rule gives the outward normal).
struct TriangleMesh {
  std::vector<cv::Vec3f> vertices_mm;  // position, mm (file units for a loaded file)
  std::vector<cv::Vec3f> normals;      // unit, per vertex
  std::vector<cv::Vec3b> colors_rgb;   // 8-bit R, G, B per vertex
  std::vector<cv::Vec3i> faces;

  bool empty() const { return faces.empty(); }
  // False with a reason (why may be null) for per-vertex arrays of the wrong
  // size, a face index out of range, or a non-finite vertex.
  bool IsValid(std::string* why) const;
};

}  // namespace craftscan
