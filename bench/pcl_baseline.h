// The PCL registration baseline of `craftscan-bench registration`, behind a
// PCL-free interface: PCL's headers compile slowly, so only pcl_baseline.cc
// includes them.
//
// The pipeline is the one PCL's "Robust pose estimation of rigid objects"
// tutorial tunes (alignment_prerejective), in millimetres:
//   pcl::VoxelGrid (voxel_mm) → NormalEstimationOMP (radius 2 × voxel,
//   oriented towards viewpoint_mm) → FPFHEstimationOMP (radius 5 × voxel) →
//   SampleConsensusPrerejective (5000 iterations, 3 samples, correspondence
//   randomness 5, similarity 0.95, max correspondence 2.5 × voxel, inlier
//   fraction 0.25) → IterativeClosestPoint (point-to-point, 2 mm gate) on a
//   finer VoxelGrid (icp_voxel_mm) of the same raw clouds.
// It starts from the raw clouds (no outlier filter, no crop): PCL does its own
// downsampling and normals, timed apart from the registration proper.
#pragma once

#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan::bench {

struct PclBaselineOptions {
  double voxel_mm = 3.0;          // VoxelGrid leaf of the cloud features and RANSAC use
  double icp_voxel_mm = 1.0;      // VoxelGrid leaf of the cloud ICP uses (0 = every point)
  double normal_radius_mm = 6;    // 2 × voxel
  double feature_radius_mm = 15;  // 5 × voxel
  int max_iterations = 5000;
  int num_samples = 3;
  int correspondence_randomness = 5;
  double similarity_threshold = 0.95;
  double max_correspondence_mm = 7.5;  // 2.5 × voxel
  double inlier_fraction = 0.25;
  double icp_max_correspondence_mm = 2.0;
  int icp_max_iterations = 50;
  // ICP stops when an iteration moves the pose by less than this (squared
  // translation, mm²; 1e-6: 1 µm) or changes the mean squared correspondence
  // distance by less than icp_fitness_epsilon_mm2.
  double icp_transformation_epsilon_mm2 = 1e-6;
  double icp_fitness_epsilon_mm2 = 1e-6;
  cv::Vec3d viewpoint_mm{0, 0, 0};  // sensor origin in each cloud's frame (normals face it)
  int num_threads = 1;              // NormalEstimationOMP and FPFHEstimationOMP; RANSAC and
                                    // ICP are single-threaded in PCL
  unsigned seed = 42;               // std::srand before RANSAC (PCL draws its samples with rand())
};

struct PclBaselineResult {
  bool ok = false;
  std::string message;                                  // why not ok
  cv::Matx44d target_from_source = cv::Matx44d::eye();  // after ICP
  cv::Matx44d coarse_target_from_source = cv::Matx44d::eye();
  bool ransac_converged = false;
  std::size_t ransac_inliers = 0;
  bool icp_converged = false;
  int icp_iterations = 0;
  // Fraction of the ICP source points with a target point within
  // icp_max_correspondence_mm after the final pose, and the RMS distance of
  // those pairs (mm) — the same figures craftscan reports.
  double fitness = 0;
  double rmse_mm = 0;
  std::size_t source_points = 0;  // after the coarse VoxelGrid
  std::size_t target_points = 0;
  std::size_t icp_source_points = 0;  // after the ICP VoxelGrid
  std::size_t icp_target_points = 0;
  double prepare_ms = 0;  // both clouds: VoxelGrids + normals
  double coarse_ms = 0;   // FPFH of both clouds + SampleConsensusPrerejective
  double fine_ms = 0;     // ICP
  double time_ms = 0;     // coarse_ms + fine_ms
  double cpu_ms = 0;      // process CPU time (all threads) over coarse + fine
};

// PCL's FPFH (FPFHEstimationOMP, its own FLANN radius search) of a cloud with
// normals, 33 bins per point (NaN where PCL computes none): what craftscan's
// ComputeFpfh (registration.h) must equal.
std::vector<std::array<float, 33>> PclFpfh(const PointCloud& cloud_with_normals, double radius_mm,
                                           int num_threads);

// Registers `source` onto `target` (both in mm, each in its own frame).
// Never throws; a PCL failure or an empty cloud gives ok = false.
PclBaselineResult RunPclBaseline(const PointCloud& source, const PointCloud& target,
                                 const PclBaselineOptions& options);

// For every point of `query`, the distance (mm) to its nearest point of
// `reference` (a PCL kd-tree, exact search). Empty reference: all +inf.
std::vector<float> NearestDistancesMm(const PointCloud& query, const PointCloud& reference);

}  // namespace craftscan::bench
