// PLY files (version 1.0; ascii, binary_little_endian, binary_big_endian):
// the one reader and writer of point clouds and triangle meshes, shared by
// the pipeline, the session store, the recorder, the sim driver's mesh
// objects, the benchmarks and the tests; fuzzed by tests/fuzz/fuzz_ply.cc.
//
// Common reading rules (ReadPly and ReadMeshPly):
//  - Vertex properties may come in any order with any scalar type (char/int8,
//    uchar/uint8, short/int16, ushort/uint16, int/int32, uint/uint32,
//    float/float32, double/float64). x, y, z are required; nx, ny, nz and
//    red, green, blue (or diffuse_red, ...) are read only when all three of a
//    group are present. Integer colours are clamped to 0..255; floating-point
//    colours are taken as 0..1 and scaled to 0..255.
//  - Other properties (scalar or list) and other elements (range grids,
//    edges, ...) before or after the vertices are skipped; comment and
//    obj_info lines are ignored. CRLF header lines are accepted.
//  - Positions are multiplied by `scale_to_mm` (1 for files in mm, 1000 for
//    files in metres; must be finite and > 0); normals are not scaled.
//  - Every element count is checked against the bytes the file holds before
//    anything is allocated (a header claiming 10^12 vertices fails at once).
// Errors: false with *error (may be null; the message names the file and
// what is wrong) for a missing/unreadable file, a file that is not PLY, an
// unsupported format, a missing vertex element or x/y/z, a list-typed x/y/z,
// an impossible element count, truncated data, or a non-numeric /
// out-of-range ASCII value. The output is left empty on failure. None of
// these functions throws (except the encoders' std::bad_alloc); all are thread-safe (the writers
// for distinct paths).
#pragma once

#include <string>

namespace craftscan {

struct PointCloud;    // common/point_cloud.h
struct TriangleMesh;  // common/triangle_mesh.h

// Reads the "vertex" element into *cloud, replacing its contents; faces and
// other elements are skipped.
bool ReadPly(const std::string& path, PointCloud* cloud, std::string* error,
             double scale_to_mm = 1.0);

// Reads the "vertex" element (positions, and normals/colours when present)
// and the "face" element's vertex_indices (or vertex_index) list into *mesh;
// polygons with more than three vertices become triangle fans (0, j, j+1).
// Besides the common errors it fails for a file without faces (a point cloud
// is not a mesh), a face element without that list, a face with fewer than 3
// vertices or an index that is not an integer in [0, vertex count), and a
// non-finite vertex position.
bool ReadMeshPly(const std::string& path, TriangleMesh* mesh, std::string* error,
                 double scale_to_mm = 1.0);

// The bytes WritePly writes for `cloud` (header and data), for a caller that
// writes them itself (the session store, with the Status-returning
// WriteFileAtomically). `cloud` must be valid (PointCloud::IsValid; an
// invalid one gives an empty string, never an out-of-range read). Throws
// only std::bad_alloc.
std::string EncodePly(const PointCloud& cloud, bool binary);

// The same for WriteMeshPly: the bytes for a valid `mesh` (empty for an
// invalid one). Throws only std::bad_alloc.
std::string EncodeMeshPly(const TriangleMesh& mesh, bool binary);

// Writes `cloud` as a PLY with one "vertex" element: float x y z (mm, as
// stored), float nx ny nz if present, uchar red green blue if present.
// `binary` selects binary_little_endian, otherwise ASCII (shortest
// round-trip float text, so an ASCII round trip is bit-exact for finite
// values). The write is atomic (WriteFileAtomically: a hidden temporary
// beside `path`, fsync'ed and renamed over it; on failure the previous file,
// if any, is untouched). Fails for an invalid cloud (PointCloud::IsValid) or
// an I/O failure.
bool WritePly(const std::string& path, const PointCloud& cloud, bool binary, std::string* error);

// Writes `mesh` as PLY: element vertex as WritePly, then element face (list
// uchar int vertex_indices). Binary/ASCII and atomicity as WritePly. Fails
// for an invalid mesh (TriangleMesh::IsValid) or an I/O failure.
bool WriteMeshPly(const std::string& path, const TriangleMesh& mesh, bool binary,
                  std::string* error);

}  // namespace craftscan
