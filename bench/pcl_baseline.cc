// The PCL baseline (see pcl_baseline.h). The only bench file that includes PCL.
#include "pcl_baseline.h"

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <limits>
#include <string>
#include <vector>

#include <pcl/common/transforms.h>
#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/sample_consensus_prerejective.h>
#include <Eigen/Core>

namespace craftscan::bench {
namespace {

using Clock = std::chrono::steady_clock;
using PointT = pcl::PointNormal;
using CloudT = pcl::PointCloud<PointT>;
using FeatureCloud = pcl::PointCloud<pcl::FPFHSignature33>;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

pcl::PointCloud<pcl::PointXYZ>::Ptr ToPcl(const PointCloud& cloud) {
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  out->reserve(cloud.size());
  for (const cv::Vec3f& p : cloud.points_mm) {
    if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])) {
      out->push_back(pcl::PointXYZ(p[0], p[1], p[2]));
    }
  }
  return out;
}

pcl::PointCloud<pcl::PointXYZ>::Ptr Downsample(const pcl::PointCloud<pcl::PointXYZ>::Ptr& cloud,
                                               double leaf_mm) {
  if (!(leaf_mm > 0)) return cloud;
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  pcl::VoxelGrid<pcl::PointXYZ> grid;
  const float leaf = static_cast<float>(leaf_mm);
  grid.setLeafSize(leaf, leaf, leaf);
  grid.setInputCloud(cloud);
  grid.filter(*out);
  return out;
}

// Voxel cloud with normals oriented towards the viewpoint.
CloudT::Ptr WithNormals(const pcl::PointCloud<pcl::PointXYZ>::Ptr& cloud,
                        const PclBaselineOptions& options) {
  pcl::PointCloud<pcl::Normal> normals;
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> estimation;
  estimation.setNumberOfThreads(static_cast<unsigned>(options.num_threads));
  estimation.setInputCloud(cloud);
  estimation.setRadiusSearch(options.normal_radius_mm);
  estimation.setViewPoint(static_cast<float>(options.viewpoint_mm[0]),
                          static_cast<float>(options.viewpoint_mm[1]),
                          static_cast<float>(options.viewpoint_mm[2]));
  estimation.compute(normals);
  auto out = std::make_shared<CloudT>();
  out->reserve(cloud->size());
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    const pcl::Normal& n = normals[i];
    if (!std::isfinite(n.normal_x) || !std::isfinite(n.normal_y) || !std::isfinite(n.normal_z)) {
      continue;  // too few neighbours: FPFH cannot use the point
    }
    PointT p;
    p.x = (*cloud)[i].x;
    p.y = (*cloud)[i].y;
    p.z = (*cloud)[i].z;
    p.normal_x = n.normal_x;
    p.normal_y = n.normal_y;
    p.normal_z = n.normal_z;
    p.curvature = n.curvature;
    out->push_back(p);
  }
  return out;
}

FeatureCloud::Ptr Fpfh(const CloudT::Ptr& cloud, const PclBaselineOptions& options) {
  auto features = std::make_shared<FeatureCloud>();
  pcl::FPFHEstimationOMP<PointT, PointT, pcl::FPFHSignature33> estimation;
  estimation.setNumberOfThreads(static_cast<unsigned>(options.num_threads));
  estimation.setInputCloud(cloud);
  estimation.setInputNormals(cloud);
  estimation.setRadiusSearch(options.feature_radius_mm);
  estimation.compute(*features);
  return features;
}

}  // namespace

std::vector<std::array<float, 33>> PclFpfh(const PointCloud& cloud_with_normals, double radius_mm,
                                           int num_threads) {
  auto cloud = std::make_shared<CloudT>();
  cloud->resize(cloud_with_normals.size());
  for (std::size_t i = 0; i < cloud_with_normals.size(); ++i) {
    PointT& q = (*cloud)[i];
    const cv::Vec3f& p = cloud_with_normals.points_mm[i];
    const cv::Vec3f& n = cloud_with_normals.normals[i];
    q.x = p[0], q.y = p[1], q.z = p[2];
    q.normal_x = n[0], q.normal_y = n[1], q.normal_z = n[2];
  }
  // A sorted search (neighbours by distance), as craftscan's registration
  // used it; FPFHEstimation's own default search is unsorted, and the
  // weighting's float sums depend on the order.
  FeatureCloud::Ptr features = std::make_shared<FeatureCloud>();
  pcl::FPFHEstimationOMP<PointT, PointT, pcl::FPFHSignature33> estimation;
  estimation.setNumberOfThreads(static_cast<unsigned>(num_threads));
  estimation.setInputCloud(cloud);
  estimation.setInputNormals(cloud);
  estimation.setSearchMethod(std::make_shared<pcl::search::KdTree<PointT>>(/*sorted=*/true));
  estimation.setRadiusSearch(radius_mm);
  estimation.compute(*features);
  std::vector<std::array<float, 33>> out(features->size());
  for (std::size_t i = 0; i < features->size(); ++i)
    std::copy_n((*features)[i].histogram, 33, out[i].begin());
  return out;
}

namespace {

cv::Matx44d ToMatx(const Eigen::Matrix4f& m) {
  cv::Matx44d out;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) out(r, c) = m(r, c);
  }
  return out;
}

// Exposes the iteration count PCL keeps protected.
class CountingIcp : public pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> {
 public:
  int iterations() const { return nr_iterations_; }
};

PclBaselineResult Run(const PointCloud& source, const PointCloud& target,
                      const PclBaselineOptions& options) {
  PclBaselineResult result;
  const auto raw_source = ToPcl(source);
  const auto raw_target = ToPcl(target);
  if (raw_source->empty() || raw_target->empty()) {
    result.message = "empty cloud";
    return result;
  }

  auto start = Clock::now();
  const auto coarse_source = WithNormals(Downsample(raw_source, options.voxel_mm), options);
  const auto coarse_target = WithNormals(Downsample(raw_target, options.voxel_mm), options);
  const auto fine_source = Downsample(raw_source, options.icp_voxel_mm);
  const auto fine_target = Downsample(raw_target, options.icp_voxel_mm);
  result.prepare_ms = MsSince(start);
  result.source_points = coarse_source->size();
  result.target_points = coarse_target->size();
  result.icp_source_points = fine_source->size();
  result.icp_target_points = fine_target->size();
  if (coarse_source->size() < 3 || coarse_target->size() < 3) {
    result.message = "fewer than 3 points with normals after the voxel grid";
    return result;
  }

  start = Clock::now();
  const std::clock_t cpu_start = std::clock();
  const auto source_features = Fpfh(coarse_source, options);
  const auto target_features = Fpfh(coarse_target, options);
  pcl::SampleConsensusPrerejective<PointT, PointT, pcl::FPFHSignature33> ransac;
  ransac.setInputSource(coarse_source);
  ransac.setSourceFeatures(source_features);
  ransac.setInputTarget(coarse_target);
  ransac.setTargetFeatures(target_features);
  ransac.setMaximumIterations(options.max_iterations);
  ransac.setNumberOfSamples(options.num_samples);
  ransac.setCorrespondenceRandomness(options.correspondence_randomness);
  ransac.setSimilarityThreshold(static_cast<float>(options.similarity_threshold));
  ransac.setMaxCorrespondenceDistance(options.max_correspondence_mm);
  ransac.setInlierFraction(static_cast<float>(options.inlier_fraction));
  std::srand(options.seed);
  CloudT aligned;
  ransac.align(aligned);
  result.ransac_converged = ransac.hasConverged();
  result.ransac_inliers = ransac.getInliers().size();
  const Eigen::Matrix4f coarse = ransac.getFinalTransformation();
  result.coarse_target_from_source = ToMatx(coarse);
  result.coarse_ms = MsSince(start);

  start = Clock::now();
  CountingIcp icp;
  icp.setInputSource(fine_source);
  icp.setInputTarget(fine_target);
  icp.setMaxCorrespondenceDistance(options.icp_max_correspondence_mm);
  icp.setMaximumIterations(options.icp_max_iterations);
  icp.setTransformationEpsilon(options.icp_transformation_epsilon_mm2);
  icp.setEuclideanFitnessEpsilon(options.icp_fitness_epsilon_mm2);
  pcl::PointCloud<pcl::PointXYZ> refined;
  icp.align(refined, coarse);
  result.icp_converged = icp.hasConverged();
  result.icp_iterations = icp.iterations();
  const Eigen::Matrix4f fine = icp.getFinalTransformation();
  result.fine_ms = MsSince(start);
  result.time_ms = result.coarse_ms + result.fine_ms;
  result.cpu_ms = 1000.0 * static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  result.target_from_source = ToMatx(fine);

  // Fitness and inlier RMSE over the ICP clouds, outside the timing.
  pcl::PointCloud<pcl::PointXYZ> moved;
  pcl::transformPointCloud(*fine_source, moved, fine);
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(fine_target);
  pcl::Indices index(1);
  std::vector<float> squared(1);
  const double gate_sq = options.icp_max_correspondence_mm * options.icp_max_correspondence_mm;
  std::size_t inliers = 0;
  double sum_sq = 0;
  for (const pcl::PointXYZ& p : moved) {
    if (tree.nearestKSearch(p, 1, index, squared) == 1 && squared[0] <= gate_sq) {
      ++inliers;
      sum_sq += squared[0];
    }
  }
  result.fitness = moved.empty() ? 0.0 : static_cast<double>(inliers) / moved.size();
  result.rmse_mm = inliers > 0 ? std::sqrt(sum_sq / inliers) : std::nan("");

  result.ok = result.ransac_converged;
  if (!result.ransac_converged) {
    result.message = "SampleConsensusPrerejective did not converge (ICP ran from its best pose)";
  } else if (!result.icp_converged) {
    result.message = "ICP did not converge";
  }
  return result;
}

}  // namespace

PclBaselineResult RunPclBaseline(const PointCloud& source, const PointCloud& target,
                                 const PclBaselineOptions& options) {
  try {
    return Run(source, target, options);
  } catch (const std::exception& e) {
    PclBaselineResult result;
    result.message = std::string("PCL threw: ") + e.what();
    return result;
  }
}

std::vector<float> NearestDistancesMm(const PointCloud& query, const PointCloud& reference) {
  std::vector<float> distances(query.size(), std::numeric_limits<float>::infinity());
  const auto ref = ToPcl(reference);
  if (ref->empty()) return distances;
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(ref);
  pcl::Indices index(1);
  std::vector<float> squared(1);
  for (std::size_t i = 0; i < query.size(); ++i) {
    const cv::Vec3f& p = query.points_mm[i];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
    if (tree.nearestKSearch(pcl::PointXYZ(p[0], p[1], p[2]), 1, index, squared) == 1) {
      distances[i] = std::sqrt(squared[0]);
    }
  }
  return distances;
}

}  // namespace craftscan::bench
