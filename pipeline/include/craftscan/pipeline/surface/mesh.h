// Surface meshing of a fused cloud: Poisson reconstruction (PCL), trimmed
// where the input gives it no support, and an OBJ writer (PLY: common/ply.h).
//
//   MeshResult r = PoissonMesh(fused_with_normals, PoissonOptions{});
//   if (r.IsUsable()) WriteMeshPly(dir + "/mesh.ply", r.mesh, /*binary=*/true, &error);
//
// Units: millimetres. No PCL type appears here (only mesh.cc includes PCL).
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/ply.h"  // WriteMeshPly, for the callers of PoissonMesh
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/triangle_mesh.h"

namespace craftscan {

struct PoissonOptions {
  // Octree depth (resolution 2^depth over `scale` × the cloud's bounding
  // cube): 8 gives ≈ 0.3 mm cells on a 70 mm object. 4..12.
  int depth = 8;
  double samples_per_node = 1.5;  // ≥ 1; more smooths noisy input
  double point_weight = 4.0;      // screening weight (≥ 0; 0 = unscreened)
  double scale = 1.1;             // reconstruction cube / bounding cube, ≥ 1
  // Density trimming. Each vertex's support is the number of input points
  // within support_radius_mm (0: 2.5 × the median nearest-neighbour spacing
  // of the input). Vertices with no support are always removed (the
  // surface Poisson invents over holes and unseen parts, e.g. a box's base);
  // so are vertices whose support is below this quantile of all supports
  // (0 disables the quantile; e.g. 0.02 also removes thinly supported fringes).
  double trim_density_quantile = 0.0;  // 0 ≤ q < 1
  double support_radius_mm = 0;        // ≥ 0
  // After trimming, connected components (faces sharing a vertex) with fewer
  // faces than this fraction of the largest component's are removed: the
  // fragments trimming leaves of invented surface and of floaters. 0 keeps
  // every component; 0..1.
  double min_component_fraction = 0;
  // Vertex colours from the nearest input point when the input has colours.
  bool colors = true;
  int num_threads = 1;  // ≥ 1, Poisson's solver threads

  bool IsValid(std::string* why) const;  // names the offending field
};

struct MeshResult {
  enum class Status { kOk, kFailed };
  Status status = Status::kFailed;
  std::string message;  // why it failed
  TriangleMesh mesh;    // trimmed, with per-vertex normals (and colours)

  std::size_t input_points = 0;  // finite points with finite normals used
  std::size_t raw_vertices = 0;  // Poisson output, before trimming
  std::size_t raw_faces = 0;
  std::size_t trimmed_vertices = 0;    // removed by density trimming
  std::size_t removed_components = 0;  // small components removed (min_component_fraction)
  std::size_t components = 0;          // connected components of the final mesh
  double support_radius_mm = 0;        // the radius used
  double support_threshold = 0;        // vertices with support below this were removed
  double seconds = 0;                  // wall time
  // Lines PCL's Poisson printed to stdout, kept off it (see PoissonMesh).
  std::size_t library_stdout_lines = 0;

  bool IsUsable() const { return status == Status::kOk; }
};

// Poisson surface reconstruction (PCL, Kazhdan et al.) of an oriented point
// cloud (normals required, pointing outwards; their length is ignored), then
// density trimming (see PoissonOptions), then per-vertex normals (area-weighted
// face normals) and colours. Faces are oriented outwards consistently with the
// input normals. Points or normals that are not finite, and zero normals, are
// skipped.
//
// Fails (status kFailed, message says why) for invalid options or cloud, a
// cloud without normals, fewer than 100 usable points, a reconstruction that
// produces no triangle, or one that trimming removes entirely. Never throws.
// Thread-safe, but PCL's Poisson step runs one at a time per process (it
// keeps static state): calls from several threads wait for each other there.
// PCL prints diagnostics to stdout there ("Vertex pair not in list", by the
// thousand); for that step fd 1 goes to a memory file instead, and the lines
// are counted in library_stdout_lines. Whatever another thread of the process
// writes to stdout during that step is counted with them, not shown.
MeshResult PoissonMesh(const PointCloud& cloud_with_normals, const PoissonOptions& options);

// Which surface a scan's mesh is: Poisson's (closed, then trimmed where the
// points give it no support) or the implicit one (only where the points are).
enum class MeshMethod { kPoisson, kImplicit };
std::string_view ToString(MeshMethod method);  // "poisson", "implicit"
bool MeshMethodFromString(std::string_view text, MeshMethod* method);

// Implicit surface meshing: the signed distance of Kolluri's implicit moving
// least squares (IMLS: at x, the Gaussian-weighted mean of n_i·(x − p_i)
// over the input points within a radius) on a grid around the points, and
// marching cubes (PCL's tables) over the cells where it is defined. It is
// defined only near points and not past the edge of the data, so there is
// nothing to trim; holes up to about the fill radius close from the surface
// around them (where the points surround a grid vertex). Cost is linear in
// the points: a scatter of each point onto the grid, a search tree only
// for the fill. Poisson (PCL's single-threaded port) took 4.5–5 s on the
// carved box's fused cloud; this takes about a second with the fill and a
// tenth of one without (README, mesh methods).
struct ImplicitMeshOptions {
  // Sizes in units of the input's median nearest-neighbour spacing s (the
  // fused cloud's voxel, about 0.4–0.7 mm): the grid spacing and the IMLS
  // radius. voxel_mm > 0 sets the grid spacing in mm instead.
  double voxel_spacings = 1.5;   // (0, 10]
  double voxel_mm = 0;           // ≥ 0
  double radius_spacings = 4.0;  // [1, 20]
  // Where the surface is undefined at the radius (a hole in the points),
  // it is taken at this × the radius: holes up to about that wide close
  // from the surface around them. 0 (off) or (1, 10].
  double fill_radii = 2.0;
  // A vertex's value: the distance to the algebraic sphere fitted to the
  // points and normals within the radius (APSS, Guennebaud and Gross 2007),
  // with the same weights, which follows the surface's curvature and carries
  // it across a hole; false: Kolluri's value, which blends the tangent
  // planes (over a hole in a convex cap they meet above it). The support and
  // edge tests are Kolluri's either way.
  bool sphere_fit = true;
  int min_support = 4;  // ≥ 1 points within the radius
  // A grid vertex whose neighbours' weighted centroid lies farther than this
  // × the radius from it along the surface is past the edge of the data:
  // undefined. At a straight edge the centroid lies 0.28 radii inside. The
  // fill asks instead that the points surround the vertex (no empty sector
  // of 135°). (0, 1].
  double max_tangent_radii = 0.3;
  double min_component_fraction = 0.05;  // as PoissonOptions, [0, 1]
  bool colors = true;                    // vertex colours, IMLS-weighted like the surface

  bool IsValid(std::string* why) const;  // names the offending field
};

// Fails (status kFailed, message says why) for invalid options or cloud, a
// cloud without normals, fewer than 100 usable points, or no surface.
// support_radius_mm is the IMLS radius; trimmed_vertices and
// support_threshold stay 0. Never throws. Thread-safe (reentrant).
MeshResult ImplicitMesh(const PointCloud& cloud_with_normals, const ImplicitMeshOptions& options);

// Writes `mesh` as Wavefront OBJ: "v x y z" (with " r g b" in 0..1 when the
// mesh has colours, the common vertex-colour extension), "vn" when it has
// normals, and 1-based "f a b c" (or "f a//a b//b c//c" with normals).
// Atomic write (WriteFileAtomically). Returns false with *error (may be
// null) for an invalid mesh or an I/O failure. Never throws. Thread-safe for
// distinct paths.
bool WriteMeshObj(const std::string& path, const TriangleMesh& mesh, std::string* error);

// The bytes WriteMeshObj writes for a valid `mesh` (empty for an invalid
// one), for a caller that writes them with the Status-returning
// WriteFileAtomically. Throws only std::bad_alloc. Thread-safe.
std::string EncodeMeshObj(const TriangleMesh& mesh);

}  // namespace craftscan
