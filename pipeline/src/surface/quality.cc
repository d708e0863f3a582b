#include "craftscan/pipeline/surface/quality.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <map>
#include <numeric>
#include <utility>
#include <vector>

#include <nanoflann.hpp>

#include "common/parallel.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

struct VertexAdaptor {
  const std::vector<cv::Vec3f>* v;
  std::size_t kdtree_get_point_count() const { return v->size(); }
  float kdtree_get_pt(std::size_t i, std::size_t d) const { return (*v)[i][static_cast<int>(d)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};
using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, VertexAdaptor>,
                                                 VertexAdaptor, 3, std::uint32_t>;

// Squared distance from p to triangle abc (Ericson, Real-Time Collision
// Detection, 5.1.5: the closest point by Voronoi region).
double TriangleDistance2(const cv::Vec3d& p, const cv::Vec3d& a, const cv::Vec3d& b,
                         const cv::Vec3d& c) {
  const cv::Vec3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  auto d2to = [&](const cv::Vec3d& q) { return (p - q).dot(p - q); };
  if (d1 <= 0 && d2 <= 0) return d2to(a);
  const cv::Vec3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return d2to(b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return d2to(a + ab * (d1 / (d1 - d3)));
  const cv::Vec3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return d2to(c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return d2to(a + ac * (d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return d2to(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
  const double denom = va + vb + vc;
  if (!(std::abs(denom) > 0)) return std::min({d2to(a), d2to(b), d2to(c)});  // degenerate
  return d2to(a + ab * (vb / denom) + ac * (vc / denom));
}

cv::Vec3d D(const cv::Vec3f& v) { return cv::Vec3d(v[0], v[1], v[2]); }

// Distance of every point to the mesh: exact to the triangles around its
// few nearest vertices (the mesh is much denser than the gate).
std::vector<double> DistancesToMesh(const PointCloud& cloud, const TriangleMesh& mesh,
                                    int num_threads) {
  const std::size_t nv = mesh.vertices_mm.size();
  std::vector<std::uint32_t> start(nv + 1, 0), faces_of;
  for (const cv::Vec3i& f : mesh.faces)
    for (int k = 0; k < 3; ++k) ++start[static_cast<std::size_t>(f[k]) + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  faces_of.resize(start.back());
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  for (std::size_t i = 0; i < mesh.faces.size(); ++i)
    for (int k = 0; k < 3; ++k)
      faces_of[fill[static_cast<std::size_t>(mesh.faces[i][k])]++] = static_cast<std::uint32_t>(i);

  const VertexAdaptor adaptor{&mesh.vertices_mm};
  Tree tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  std::vector<double> d(cloud.size(), 0);
  Parallel(num_threads)
      .For(
          0, static_cast<int>(cloud.size()),
          [&](int b, int e) {
            constexpr std::size_t kNearest = 4;
            std::uint32_t index[kNearest];
            float dist2[kNearest];
            for (int i = b; i < e; ++i) {
              const cv::Vec3f& p = cloud.points_mm[static_cast<std::size_t>(i)];
              const std::size_t found = tree.knnSearch(&p[0], kNearest, index, dist2);
              double best = found ? dist2[0] : INFINITY;  // the nearest vertex bounds it
              for (std::size_t k = 0; k < found; ++k)
                for (std::uint32_t f = start[index[k]]; f < start[index[k] + 1]; ++f) {
                  const cv::Vec3i& t = mesh.faces[faces_of[f]];
                  best = std::min(best, TriangleDistance2(D(p), D(mesh.vertices_mm[t[0]]),
                                                          D(mesh.vertices_mm[t[1]]),
                                                          D(mesh.vertices_mm[t[2]])));
                }
              d[static_cast<std::size_t>(i)] = std::sqrt(best);
            }
          },
          1024);
  return d;
}

// Perimeters of the mesh's open boundaries: the edges one face uses,
// grouped by the vertices they share (union-find), longest first.
std::vector<double> BoundaryLoops(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> uses;
  for (const cv::Vec3i& f : mesh.faces)
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  std::vector<int> parent(mesh.vertices_mm.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int v) {
    while (parent[static_cast<std::size_t>(v)] != v)
      v = parent[static_cast<std::size_t>(v)] =
          parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(v)])];
    return v;
  };
  std::vector<std::pair<int, int>> boundary;
  for (const auto& [edge, count] : uses) {
    if (count != 1) continue;
    boundary.push_back(edge);
    parent[static_cast<std::size_t>(find(edge.first))] = find(edge.second);
  }
  std::map<int, double> length;
  for (const auto& [a, b] : boundary)
    length[find(a)] += cv::norm(D(mesh.vertices_mm[static_cast<std::size_t>(a)]) -
                                D(mesh.vertices_mm[static_cast<std::size_t>(b)]));
  std::vector<double> loops;
  for (const auto& [root, mm] : length) loops.push_back(mm);
  std::sort(loops.begin(), loops.end(), std::greater<>());
  return loops;
}

}  // namespace

bool QualityOptions::IsValid(std::string* why) const {
  if (!(std::isfinite(gate_mm) && gate_mm > 0)) return Fail(why, "gate_mm must be finite and > 0");
  if (num_threads < 1) return Fail(why, "num_threads must be >= 1");
  return true;
}

CloudQuality AssessQuality(const PointCloud& fused, const TriangleMesh& mesh,
                           const QualityOptions& options) {
  CloudQuality q;
  std::string why;
  if (!options.IsValid(&why)) return (q.message = "quality: " + why, q);
  if (mesh.faces.empty()) return (q.message = "quality: no mesh to compare the cloud with", q);
  if (!mesh.IsValid(&why)) return (q.message = "quality: the mesh is invalid: " + why, q);
  if (fused.empty()) return (q.message = "quality: no fused points", q);
  try {
    std::vector<double> d = DistancesToMesh(fused, mesh, options.num_threads);
    q.points = d.size();
    q.gate_mm = options.gate_mm;
    q.far_points = static_cast<std::size_t>(
        std::count_if(d.begin(), d.end(), [&](double e) { return e > options.gate_mm; }));
    q.far_pct = 100.0 * static_cast<double>(q.far_points) / static_cast<double>(q.points);
    auto quantile = [&](double t) {
      const auto k = static_cast<std::ptrdiff_t>(t * static_cast<double>(d.size() - 1));
      std::nth_element(d.begin(), d.begin() + k, d.end());
      return d[static_cast<std::size_t>(k)];
    };
    q.median_to_mesh_mm = quantile(0.5);
    q.p95_to_mesh_mm = quantile(0.95);
    const std::vector<double> loops = BoundaryLoops(mesh);
    if (!loops.empty()) {
      q.base_opening_mm = loops[0];
      q.holes = loops.size() - 1;
      q.largest_hole_mm = loops.size() > 1 ? loops[1] : 0;
    }
    q.ok = true;
  } catch (const std::exception& e) {
    q.message = std::string("quality: ") + e.what();
  }
  return q;
}

}  // namespace craftscan
