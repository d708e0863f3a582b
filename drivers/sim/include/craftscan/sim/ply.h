// Triangle meshes from PLY files (ASCII and binary little-endian).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace craftscan::sim {

struct TriangleMesh {
  std::vector<cv::Vec3d> vertices;   // file units
  std::vector<cv::Vec3i> triangles;  // indices into vertices, counter-clockwise seen from outside
};

// Reads the `vertex` element's x, y, z (any numeric type; other properties
// skipped) and the `face` element's vertex_indices (or vertex_index) list;
// polygons with more than three vertices become triangle fans. Other
// elements are skipped. Formats: ascii 1.0 and binary_little_endian 1.0.
// Returns false with *error naming the file and the problem (cannot open,
// not a PLY file, unsupported format, malformed header, truncated data, a
// face index out of range, a face with fewer than 3 vertices, no faces).
// Thread-safe.
bool LoadPly(const std::string& path, TriangleMesh* mesh, std::string* error);

// Writes vertices and triangles as PLY (binary little-endian or ASCII).
// Atomic (WriteFileAtomically). Returns false with *error if the file cannot
// be written.
bool SavePly(const std::string& path, const TriangleMesh& mesh, bool binary, std::string* error);

}  // namespace craftscan::sim
