#include "scan_eval.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_set>

#include <opencv2/core/utility.hpp>

namespace craftscan::bench {

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return NAN;
  const std::size_t k = std::min(
      values.size() - 1, static_cast<std::size_t>(std::floor(q * (values.size() - 1) + 0.5)));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

NearestIndex::NearestIndex(const std::vector<cv::Vec3f>& points)
    : points_(&points), tree_(3, *this, nanoflann::KDTreeSingleIndexAdaptorParams(10)) {
  tree_.buildIndex();
}

double NearestIndex::Distance(const cv::Vec3f& q) const {
  if (points_->empty()) return INFINITY;
  std::uint32_t index = 0;
  float d2 = 0;
  if (tree_.knnSearch(q.val, 1, &index, &d2) != 1) return INFINITY;
  return std::sqrt(static_cast<double>(d2));
}

std::vector<double> NearestDistances(const NearestIndex& index,
                                     const std::vector<cv::Vec3f>& queries) {
  std::vector<double> d(queries.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(queries.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i)
      d[static_cast<std::size_t>(i)] = index.Distance(queries[static_cast<std::size_t>(i)]);
  });
  return d;
}

std::vector<cv::Vec3f> GridSample(const std::vector<cv::Vec3f>& points, double cell_mm) {
  // Cells keyed by 21 bits per axis (±1 km at 0.5 mm).
  const auto key = [cell_mm](const cv::Vec3f& p) {
    std::uint64_t k = 0;
    for (int a = 0; a < 3; ++a) {
      const auto c = static_cast<std::int64_t>(std::floor(p[a] / cell_mm)) + (1 << 20);
      k = (k << 21) | (static_cast<std::uint64_t>(c) & ((1u << 21) - 1));
    }
    return k;
  };
  std::unordered_set<std::uint64_t> seen;
  std::vector<cv::Vec3f> out;
  for (const cv::Vec3f& p : points) {
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
    if (seen.insert(key(p)).second) out.push_back(p);
  }
  return out;
}

MeshComponents CountComponents(const TriangleMesh& mesh) {
  MeshComponents out;
  if (mesh.faces.empty()) return out;
  std::vector<int> parent(mesh.vertices_mm.size());
  std::iota(parent.begin(), parent.end(), 0);
  const auto find = [&](int v) {
    while (parent[static_cast<std::size_t>(v)] != v) {
      parent[static_cast<std::size_t>(v)] =
          parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(v)])];
      v = parent[static_cast<std::size_t>(v)];
    }
    return v;
  };
  for (const cv::Vec3i& f : mesh.faces) {
    const int a = find(f[0]);
    parent[static_cast<std::size_t>(find(f[1]))] = a;
    parent[static_cast<std::size_t>(find(f[2]))] = a;
  }
  std::vector<std::size_t> faces_of(mesh.vertices_mm.size(), 0);
  for (const cv::Vec3i& f : mesh.faces) ++faces_of[static_cast<std::size_t>(find(f[0]))];
  std::size_t largest = 0;
  for (std::size_t n : faces_of) {
    if (n == 0) continue;
    ++out.count;
    largest = std::max(largest, n);
  }
  out.largest_pct = 100.0 * static_cast<double>(largest) / static_cast<double>(mesh.faces.size());
  return out;
}

}  // namespace craftscan::bench
