// Nearest-neighbour queries over a point cloud's points, shared by the
// registration stages (implementation header, not part of the public API).
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <nanoflann.hpp>
#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

// Nearest-neighbour index over a cloud's points (nanoflann k-d tree; queries
// are const, allocation-free and run from many threads).
class PointIndex {
 public:
  explicit PointIndex(const PointCloud& cloud)
      : points_(&cloud.points_mm), tree_(3, *this, nanoflann::KDTreeSingleIndexAdaptorParams(10)) {
    if (!points_->empty()) tree_.buildIndex();
  }
  // Index of the nearest point and its squared distance; false when empty.
  bool Nearest(const Eigen::Vector3f& q, int* index, float* dist2) const {
    if (points_->empty()) return false;
    std::uint32_t i = 0;
    float d2 = 0;
    if (tree_.knnSearch(q.data(), 1, &i, &d2) != 1) return false;
    *index = static_cast<int>(i);
    *dist2 = d2;
    return true;
  }
  // The nearest point strictly nearer than sqrt(max_dist2), if any: the
  // same point Nearest finds whenever that one is within the bound (the
  // tree is walked in the same order; branches beyond the bound are not),
  // so a gated query costs less where nothing is near.
  bool NearestWithin(const Eigen::Vector3f& q, float max_dist2, int* index, float* dist2) const {
    if (points_->empty()) return false;
    std::uint32_t i = 0;
    float d2 = 0;
    nanoflann::KNNResultSet<float, std::uint32_t> result(1);
    result.init(&i, &d2);
    d2 = max_dist2;  // the worst distance kept: the bound
    tree_.findNeighbors(result, q.data(), nanoflann::SearchParams());
    if (result.size() != 1) return false;
    *index = static_cast<int>(i);
    *dist2 = d2;
    return true;
  }
  // The k nearest points of q (fewer when the cloud has fewer), nearest
  // first: their indices and squared distances; returns how many.
  std::size_t KNearest(const float* q, std::size_t k, std::uint32_t* index, float* dist2) const {
    if (points_->empty() || k == 0) return 0;
    return tree_.knnSearch(q, k, index, dist2);
  }
  // The points strictly within sqrt(radius2) of q: indices and squared
  // distances, by distance and then index (FLANN's order, as PCL's sorted
  // radius searches return them).
  void Within(const float* q, float radius2,
              std::vector<std::pair<std::uint32_t, float>>* found) const {
    found->clear();
    if (points_->empty()) return;
    tree_.radiusSearch(q, radius2, *found, nanoflann::SearchParams(32, 0.f, /*sorted=*/false));
    std::sort(found->begin(), found->end(), [](const auto& a, const auto& b) {
      return a.second < b.second || (a.second == b.second && a.first < b.first);
    });
  }
  const std::vector<cv::Vec3f>* points() const { return points_; }
  // nanoflann's dataset adaptor interface.
  std::size_t kdtree_get_point_count() const { return points_->size(); }
  float kdtree_get_pt(std::size_t i, std::size_t dim) const { return (*points_)[i][dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }

 private:
  const std::vector<cv::Vec3f>* points_;
  nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, PointIndex>, PointIndex,
                                      3>
      tree_;
};

}  // namespace craftscan
