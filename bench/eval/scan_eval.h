// Scoring a reconstruction against the simulator's exact surface: nearest
// distances (nanoflann k-d tree), quantiles, grid sampling and the connected
// components of a mesh. Used by `craftscan-bench scan` and the sim scan tests.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <nanoflann.hpp>
#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/triangle_mesh.h"

namespace craftscan::bench {

// q-quantile (0…1) by nearest rank; NaN for no values.
double Quantile(std::vector<double> values, double q);

// Nearest-neighbour distances to a point set. The set must outlive the index.
class NearestIndex {
 public:
  explicit NearestIndex(const std::vector<cv::Vec3f>& points);
  // Distance (mm) from q to the nearest point; +inf for an empty set.
  double Distance(const cv::Vec3f& q) const;

  // nanoflann's dataset adaptor interface.
  std::size_t kdtree_get_point_count() const { return points_->size(); }
  float kdtree_get_pt(std::size_t i, std::size_t dim) const { return (*points_)[i][dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }

 private:
  const std::vector<cv::Vec3f>* points_;
  nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, NearestIndex>,
                                      NearestIndex, 3, std::uint32_t>
      tree_;
};

// Distances from every query to the nearest point of `index`, on OpenCV's
// thread pool.
std::vector<double> NearestDistances(const NearestIndex& index,
                                     const std::vector<cv::Vec3f>& queries);

// One point per occupied cube of edge `cell_mm` (the first one met, in
// order): an even sampling of a surface seen at varying density.
std::vector<cv::Vec3f> GridSample(const std::vector<cv::Vec3f>& points, double cell_mm);

// Connected components of a mesh's faces (faces sharing a vertex are
// connected): the share of faces in the largest one (%), and the count.
struct MeshComponents {
  std::size_t count = 0;
  double largest_pct = 0;  // 0 for a mesh without faces
};
MeshComponents CountComponents(const TriangleMesh& mesh);

}  // namespace craftscan::bench
