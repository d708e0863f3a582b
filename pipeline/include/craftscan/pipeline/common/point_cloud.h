// A plain point cloud (millimetres) and PLY reading/writing.
#pragma once

#include <cstddef>
#include <opencv2/core/matx.hpp>
#include <string>
#include <vector>

namespace craftscan {

// Points in some frame named by the owner (e.g. RangeScan::world_from_scan
// says which). `normals` and `colors_rgb` are either empty or have exactly
// one entry per point.
struct PointCloud {
  std::vector<cv::Vec3f> points_mm;   // position, mm
  std::vector<cv::Vec3f> normals;     // unit length (not enforced), unitless
  std::vector<cv::Vec3b> colors_rgb;  // 8-bit R, G, B (in that order, not BGR)

  std::size_t size() const { return points_mm.size(); }
  bool empty() const { return points_mm.empty(); }
  bool HasNormals() const { return !normals.empty(); }
  bool HasColors() const { return !colors_rgb.empty(); }
  // False with a reason (why may be null) if normals/colours are present but
  // their count differs from the point count.
  bool IsValid(std::string* why) const;
};

// Reads the "vertex" element of a PLY file (ASCII, binary_little_endian or
// binary_big_endian, version 1.0) into *cloud, replacing its contents.
//  - Vertex properties may come in any order with any scalar type (char/int8,
//    uchar/uint8, short/int16, ushort/uint16, int/int32, uint/uint32,
//    float/float32, double/float64). x, y, z are required; nx, ny, nz and
//    red, green, blue are read only when all three of a group are present.
//    Integer colours are clamped to 0..255; floating-point colours are taken
//    as 0..1 and scaled to 0..255.
//  - Other properties (scalar or list) and other elements (faces, range
//    grids, ...) before or after the vertices are skipped; comment and
//    obj_info lines are ignored. CRLF header lines are accepted.
//  - Positions are multiplied by `scale_to_mm` (1 for files in mm, 1000 for
//    files in metres; must be finite and > 0); normals are not scaled.
// Returns false and sets *error (may be null; the message names the file and
// what is wrong) for a missing/unreadable file, a file that is not PLY, an
// unsupported format, a missing vertex element or x/y/z, a list-typed x/y/z,
// an element count the data cannot possibly hold (a header claiming 10^12
// vertices fails before anything is allocated), truncated data, or a
// non-numeric / out-of-range ASCII value. *cloud is left empty on failure.
// Never throws. Thread-safe.
bool ReadPly(const std::string& path, PointCloud* cloud, std::string* error,
             double scale_to_mm = 1.0);

// Writes `cloud` as a PLY with one "vertex" element: float x y z (mm, as
// stored), float nx ny nz if present, uchar red green blue if present.
// `binary` selects binary_little_endian, otherwise ASCII (shortest
// round-trip float text, so an ASCII round trip is bit-exact for finite
// values). The write is atomic: a hidden temporary beside `path` is written,
// fsync'ed and renamed over it, then the folder is fsync'ed; on failure the
// previous file, if any, is untouched. Returns false with *error (may be
// null) for an invalid cloud (see IsValid) or an I/O failure. Never throws.
// Thread-safe for distinct paths.
bool WritePly(const std::string& path, const PointCloud& cloud, bool binary, std::string* error);

}  // namespace craftscan
