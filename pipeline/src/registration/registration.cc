// Conditioning, FPFH + RANSAC (Huber) coarse registration and weighted ICP.
// The only PCL translation unit of the registration (its headers compile
// slowly); PCL does the voxel filter, the normals' plane fits and FPFH, nanoflann
// the neighbour searches, the rest is Eigen + TBB.
#include "craftscan/pipeline/registration/registration.h"

#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include "common/eigen_cv.h"
#include "common/point_index.h"

#include <pcl/common/centroid.h>
#include <pcl/features/normal_3d.h>
#include <pcl/features/pfh_tools.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <nanoflann.hpp>

namespace craftscan {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

Eigen::Vector3f V(const cv::Vec3f& p) { return {p[0], p[1], p[2]}; }

pcl::PointCloud<pcl::PointXYZ>::Ptr ToPclXyz(const PointCloud& cloud) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr out(new pcl::PointCloud<pcl::PointXYZ>);
  out->resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const cv::Vec3f& p = cloud.points_mm[i];
    (*out)[i] = pcl::PointXYZ(p[0], p[1], p[2]);
  }
  return out;
}

// Runs `body(begin, end)` over [0, n) in chunks on `threads` threads
// (serially for 1). OpenMP, not TBB: PCL's estimators use OpenMP, and two
// runtimes spinning on two cores slowed everything down by 2-3x.
template <typename Body>
void ParallelFor(std::size_t n, int threads, Body&& body) {
  if (threads <= 1 || n < 512) {
    body(std::size_t{0}, n);
    return;
  }
  constexpr std::size_t kChunk = 256;
  const long chunks = static_cast<long>((n + kChunk - 1) / kChunk);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
  for (long c = 0; c < chunks; ++c) {
    const std::size_t b = static_cast<std::size_t>(c) * kChunk;
    body(b, std::min(n, b + kChunk));
  }
}

// PCL's VoxelGrid (average per voxel) on a cloud of PointT.
template <typename PointT>
pcl::PointCloud<PointT> VoxelGridFilter(const typename pcl::PointCloud<PointT>::Ptr& in,
                                        double voxel_mm) {
  pcl::VoxelGrid<PointT> grid;
  grid.setInputCloud(in);
  const float leaf = static_cast<float>(voxel_mm);
  grid.setLeafSize(leaf, leaf, leaf);
  pcl::PointCloud<PointT> filtered;
  grid.filter(filtered);
  return filtered;
}

// Voxel-grid average of points (and colours).
PointCloud VoxelDownsample(const PointCloud& cloud, double voxel_mm) {
  if (voxel_mm <= 0 || cloud.empty()) return cloud;
  PointCloud out;
  if (!cloud.HasColors()) {
    for (const auto& q : VoxelGridFilter<pcl::PointXYZ>(ToPclXyz(cloud), voxel_mm))
      out.points_mm.emplace_back(q.x, q.y, q.z);
    return out;
  }
  pcl::PointCloud<pcl::PointXYZRGB>::Ptr in(new pcl::PointCloud<pcl::PointXYZRGB>);
  in->resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    auto& q = (*in)[i];
    const cv::Vec3f& p = cloud.points_mm[i];
    const cv::Vec3b& c = cloud.colors_rgb[i];
    q.x = p[0], q.y = p[1], q.z = p[2];
    q.r = c[0], q.g = c[1], q.b = c[2];
  }
  for (const auto& q : VoxelGridFilter<pcl::PointXYZRGB>(in, voxel_mm)) {
    out.points_mm.emplace_back(q.x, q.y, q.z);
    out.colors_rgb.emplace_back(q.r, q.g, q.b);
  }
  return out;
}

// Nearest-neighbour searches over the points of a cloud that survive its
// filters, on one index of the whole cloud: conditioning searches the voxel
// cloud for its outlier filter, the normals and the coarse normals, and
// building an index of the survivors after each filter cost as much as the
// filter's own searches. Indices in and out are survivors' (their order in
// the filtered cloud), except `self` below.
//
// The outlier filter's lists (each point's nearest points of the whole cloud,
// itself first, nearest first) are kept: the first k survivors of a
// survivor's list are its k nearest survivors, the same points in the same
// order as a search of the survivors alone (but for points at exactly equal
// distances, which either search may order differently). A list with fewer
// than k survivors, and any other query, searches the index for more points
// until k survivors are among them.
class SurvivorNeighbours {
 public:
  explicit SurvivorNeighbours(const PointCloud& all) : index_(all), size_(all.size()) {
    survivor_of_.resize(size_);
    original_of_.resize(size_);
    for (std::size_t i = 0; i < size_; ++i) survivor_of_[i] = original_of_[i] = static_cast<int>(i);
  }

  // Keeps each point's `count` nearest points (itself first) and their
  // squared distances, searched on `threads` threads. Before any Keep.
  void KeepLists(std::size_t count, int threads) {
    list_size_ = std::min(count, size_);
    lists_.resize(size_ * list_size_);
    list_d2_.resize(size_ * list_size_);
    const auto n = static_cast<long>(size_);
    const auto& points = *index_.points();
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static)
    for (long i = 0; i < n; ++i) {
      const std::size_t at = static_cast<std::size_t>(i) * list_size_;
      index_.KNearest(points[static_cast<std::size_t>(i)].val, list_size_, &lists_[at],
                      &list_d2_[at]);
    }
  }
  std::size_t list_size() const { return list_size_; }
  // Squared distances of point i's list (of the whole cloud: before any Keep).
  const float* ListD2(std::size_t i) const { return &list_d2_[i * list_size_]; }

  // Only these survivors (ascending survivor indices) survive from now on.
  void Keep(const std::vector<int>& kept) {
    std::vector<int> original(kept.size());
    for (const int s : original_of_) survivor_of_[static_cast<std::size_t>(s)] = -1;
    for (std::size_t t = 0; t < kept.size(); ++t) {
      original[t] = original_of_[static_cast<std::size_t>(kept[t])];
      survivor_of_[static_cast<std::size_t>(original[t])] = static_cast<int>(t);
    }
    original_of_ = std::move(original);
  }
  std::size_t survivors() const { return original_of_.size(); }

  // Per-thread search buffers.
  struct Scratch {
    std::vector<std::uint32_t> index;
    std::vector<float> d2;
  };
  // The k nearest survivors of q into out (survivor indices, nearest first);
  // returns how many (fewer only when fewer survive). `self`: the survivor
  // whose own position q is, to use its kept list; −1 for any other point.
  std::size_t Find(const float* q, int self, std::size_t k, Scratch* scratch,
                   std::uint32_t* out) const {
    k = std::min(k, survivors());
    if (k == 0) return 0;
    std::size_t m = 0;
    if (self >= 0 && list_size_ > 0) {
      const std::size_t at =
          static_cast<std::size_t>(original_of_[static_cast<std::size_t>(self)]) * list_size_;
      for (std::size_t j = 0; j < list_size_ && m < k; ++j) {
        const int s = survivor_of_[lists_[at + j]];
        if (s >= 0) out[m++] = static_cast<std::uint32_t>(s);
      }
      if (m == k) return k;
    }
    // Searched: enough more than k points that the removed ones among them
    // rarely leave fewer than k survivors, doubling until they do not.
    std::size_t want = survivors() == size_ ? k : std::max(2 * k, k + 8);
    for (;;) {
      want = std::min(want, size_);
      scratch->index.resize(want);
      scratch->d2.resize(want);
      const std::size_t found = index_.KNearest(q, want, scratch->index.data(), scratch->d2.data());
      m = 0;
      for (std::size_t j = 0; j < found && m < k; ++j) {
        const int s = survivor_of_[scratch->index[j]];
        if (s >= 0) out[m++] = static_cast<std::uint32_t>(s);
      }
      if (m == k || found < want || want == size_) return m;
      want *= 2;
    }
  }

 private:
  PointIndex index_;
  std::size_t size_;
  std::vector<int> survivor_of_;  // per point of the whole cloud: its survivor index, or −1
  std::vector<int> original_of_;  // per survivor: its index in the whole cloud
  std::size_t list_size_ = 0;
  std::vector<std::uint32_t> lists_;  // size_ × list_size_
  std::vector<float> list_d2_;
};

// Unit normals of `cloud` from PCA over the k nearest survivors of
// `neighbours` (`surface` holds the survivors, in order), oriented towards
// the viewpoint. Points without a usable normal get the direction towards
// the viewpoint. `surface_is_cloud`: cloud is the survivors themselves (their
// kept neighbour lists are used).
//
// PCL's NormalEstimationOMP, step for step (its covariance, plane fit and
// flip, on the same neighbours, nearest first), with the neighbours found by
// nanoflann: PCL's FLANN search made normals take ~60 ms of a 20 k-point
// scan's conditioning.
void EstimateNormals(PointCloud* cloud, const SurvivorNeighbours& neighbours, bool surface_is_cloud,
                     const pcl::PointCloud<pcl::PointXYZ>& pcl_surface, int k,
                     const cv::Vec3d& viewpoint, int threads) {
  const auto n = static_cast<long>(cloud->size());
  cloud->normals.resize(cloud->size());
  const float vx = static_cast<float>(viewpoint[0]), vy = static_cast<float>(viewpoint[1]),
              vz = static_cast<float>(viewpoint[2]);
#pragma omp parallel num_threads(std::max(1, threads))
  {
    SurvivorNeighbours::Scratch scratch;
    std::vector<std::uint32_t> found_index(static_cast<std::size_t>(k));
    pcl::Indices found_neighbours;
    Eigen::Matrix3f covariance;
    Eigen::Vector4f centroid;
#pragma omp for schedule(static)
    for (long i = 0; i < n; ++i) {
      const cv::Vec3f& p = cloud->points_mm[static_cast<std::size_t>(i)];
      const std::size_t found =
          neighbours.Find(p.val, surface_is_cloud ? static_cast<int>(i) : -1,
                          static_cast<std::size_t>(k), &scratch, found_index.data());
      found_neighbours.assign(found_index.begin(), found_index.begin() + static_cast<long>(found));
      float nx = std::numeric_limits<float>::quiet_NaN(), ny = nx, nz = nx, curvature = nx;
      if (found >= 3 && pcl::computeMeanAndCovarianceMatrix(pcl_surface, found_neighbours,
                                                            covariance, centroid) != 0) {
        pcl::solvePlaneParameters(covariance, nx, ny, nz, curvature);
        pcl::flipNormalTowardsViewpoint(pcl::PointXYZ(p[0], p[1], p[2]), vx, vy, vz, nx, ny, nz);
      }
      cv::Vec3f& out = cloud->normals[static_cast<std::size_t>(i)];
      if (std::isfinite(nx) && std::isfinite(ny) && std::isfinite(nz)) {
        out = cv::Vec3f(nx, ny, nz);
      } else {
        const cv::Vec3d to_view = viewpoint - cv::Vec3d(p);
        const double len = cv::norm(to_view);
        out = len > 0 ? cv::Vec3f(to_view / len) : cv::Vec3f(0, 0, 1);
      }
    }
  }
}

// The indices of the points PCL's StatisticalOutlierRemoval keeps, by its
// rule: a point's mean distance to its k nearest neighbours (itself
// excluded) must not exceed the mean of those over the cloud plus
// `std_ratio` standard deviations. The searches run on nanoflann and on
// `threads` threads (PCL's filter searches with FLANN on one thread and took
// ~80 ms of a 20 k-point scan's conditioning), and their lists stay in
// `neighbours` for the normals. Needs more than k points.
std::vector<int> StatisticalInliers(SurvivorNeighbours* neighbours, int k, double std_ratio,
                                    int threads) {
  neighbours->KeepLists(static_cast<std::size_t>(k) + 1, threads);
  const std::size_t n = neighbours->survivors();
  std::vector<float> distances(n);
  for (std::size_t i = 0; i < n; ++i) {
    const float* d2 = neighbours->ListD2(i);
    double sum = 0;  // entry 0 is the point itself
    for (std::size_t j = 1; j < neighbours->list_size(); ++j) sum += std::sqrt(d2[j]);
    distances[i] = static_cast<float>(sum / k);
  }
  double sum = 0, sq_sum = 0;
  for (const float d : distances) {
    sum += d;
    sq_sum += d * d;
  }
  const double count = static_cast<double>(distances.size());
  const double variance = (sq_sum - sum * sum / count) / (count - 1);
  const double threshold = sum / count + std_ratio * std::sqrt(variance);
  std::vector<int> kept;
  kept.reserve(distances.size());
  for (std::size_t i = 0; i < distances.size(); ++i)
    if (!(distances[i] > threshold)) kept.push_back(static_cast<int>(i));
  return kept;
}

// PCA flatness of a cloud: eigenvalues of the covariance, ascending.
Eigen::Vector3d CovarianceEigenvalues(const PointCloud& cloud) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : cloud.points_mm) mean += V(p).cast<double>();
  mean /= static_cast<double>(std::max<std::size_t>(1, cloud.size()));
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : cloud.points_mm) {
    const Eigen::Vector3d d = V(p).cast<double>() - mean;
    cov += d * d.transpose();
  }
  cov /= static_cast<double>(std::max<std::size_t>(1, cloud.size()));
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues();
}

// Fraction of `source` points (transformed) within `gate_mm` of `target`,
// and the RMS distance over those.
struct Overlap {
  double fitness = 0;
  double rmse = std::numeric_limits<double>::quiet_NaN();
  std::size_t inliers = 0;
};
Overlap MeasureOverlap(const PointCloud& source, const PointIndex& target,
                       const Eigen::Matrix4d& target_from_source, double gate_mm, int threads) {
  const Eigen::Matrix3f R = target_from_source.topLeftCorner<3, 3>().cast<float>();
  const Eigen::Vector3f t = target_from_source.topRightCorner<3, 1>().cast<float>();
  std::vector<float> d2(source.size(), std::numeric_limits<float>::infinity());
  const double gate2 = gate_mm * gate_mm;
  // Only distances within the gate count: the search stops beyond it.
  const float bound2 =
      std::nextafter(static_cast<float>(gate2), std::numeric_limits<float>::infinity());
  ParallelFor(source.size(), threads, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      int idx;
      float dd;
      if (target.NearestWithin(R * V(source.points_mm[i]) + t, bound2, &idx, &dd)) d2[i] = dd;
    }
  });
  Overlap o;
  double sum = 0;
  for (float dd : d2) {
    if (dd <= gate2) {
      ++o.inliers;
      sum += dd;
    }
  }
  if (!source.empty()) o.fitness = static_cast<double>(o.inliers) / source.size();
  if (o.inliers > 0) o.rmse = std::sqrt(sum / o.inliers);
  return o;
}

// Least-squares rigid transform (weighted Kabsch) mapping src onto dst.
Eigen::Matrix4d RigidFromPairs(const std::vector<Eigen::Vector3d>& src,
                               const std::vector<Eigen::Vector3d>& dst,
                               const std::vector<double>* weights) {
  Eigen::Vector3d cs = Eigen::Vector3d::Zero(), cd = Eigen::Vector3d::Zero();
  double wsum = 0;
  for (std::size_t i = 0; i < src.size(); ++i) {
    const double w = weights ? (*weights)[i] : 1.0;
    cs += w * src[i];
    cd += w * dst[i];
    wsum += w;
  }
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  if (wsum <= 0) return T;
  cs /= wsum;
  cd /= wsum;
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < src.size(); ++i) {
    const double w = weights ? (*weights)[i] : 1.0;
    H += w * (src[i] - cs) * (dst[i] - cd).transpose();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0) D(2, 2) = -1;
  const Eigen::Matrix3d R = svd.matrixV() * D * svd.matrixU().transpose();
  T.topLeftCorner<3, 3>() = R;
  T.topRightCorner<3, 1>() = cd - R * cs;
  return T;
}

// The paper's Huber loss of a residual u (mm) with threshold w.
inline double Huber(double u, double w) { return u <= w ? 0.5 * u * u : w * (u - 0.5 * w); }

}  // namespace

// --- Options ------------------------------------------------------------------

bool VolumeCrop::IsValid(std::string* why) const {
  if (!enabled) return true;
  std::string sub;
  if (!volume.IsValid(&sub)) return Fail(why, "crop.volume." + sub);
  if (!std::isfinite(platter_band_mm) || !(platter_normal_deg >= 0 && platter_normal_deg <= 90))
    return Fail(why, "crop.platter_band_mm must be finite and platter_normal_deg in [0, 90]");
  const cv::Matx33d R = turntable_from_cloud.get_minor<3, 3>(0, 0);
  const cv::Matx33d should_be_eye = R.t() * R;
  if (cv::norm(should_be_eye - cv::Matx33d::eye()) > 1e-6 ||
      std::abs(cv::determinant(R) - 1) > 1e-6)
    return Fail(why, "crop.turntable_from_cloud is not a rigid transform");
  return true;
}

bool ConditioningOptions::IsValid(std::string* why) const {
  if (!crop.IsValid(why)) return false;
  if (outlier_neighbors < 0) return Fail(why, "outlier_neighbors must be ≥ 0");
  if (outlier_neighbors > 0 && !(outlier_std_ratio > 0))
    return Fail(why, "outlier_std_ratio must be > 0");
  if (!(fine_voxel_mm >= 0) || !std::isfinite(fine_voxel_mm))
    return Fail(why, "fine_voxel_mm must be ≥ 0");
  if (!(coarse_voxel_mm > 0) || !std::isfinite(coarse_voxel_mm) || coarse_voxel_mm < fine_voxel_mm)
    return Fail(why, "coarse_voxel_mm must be > 0 and ≥ fine_voxel_mm");
  if (normal_neighbors < 3) return Fail(why, "normal_neighbors must be ≥ 3");
  if (!std::isfinite(viewpoint_mm[0]) || !std::isfinite(viewpoint_mm[1]) ||
      !std::isfinite(viewpoint_mm[2]))
    return Fail(why, "viewpoint_mm must be finite");
  if (num_threads < 1) return Fail(why, "num_threads must be ≥ 1");
  return true;
}

bool CoarseOptions::IsValid(std::string* why) const {
  if (!(feature_radius_mm > 0)) return Fail(why, "coarse.feature_radius_mm must be > 0");
  if (max_iterations < 1) return Fail(why, "coarse.max_iterations must be ≥ 1");
  if (!(confidence > 0 && confidence < 1)) return Fail(why, "coarse.confidence must be in (0, 1)");
  if (!(inlier_distance_mm > 0)) return Fail(why, "coarse.inlier_distance_mm must be > 0");
  if (!(edge_similarity > 0 && edge_similarity < 1))
    return Fail(why, "coarse.edge_similarity must be in (0, 1)");
  if (!(prior_accept_fitness >= 0 && prior_accept_fitness <= 1))
    return Fail(why, "coarse.prior_accept_fitness must be in [0, 1]");
  if (prior_target_from_source) {
    const cv::Matx33d R = prior_target_from_source->get_minor<3, 3>(0, 0);
    if (cv::norm(R.t() * R - cv::Matx33d::eye()) > 1e-6)
      return Fail(why, "coarse.prior_target_from_source is not a rigid transform");
  }
  return true;
}

bool FineOptions::IsValid(std::string* why) const {
  if (max_iterations < 1) return Fail(why, "fine.max_iterations must be ≥ 1");
  if (!(max_correspondence_mm > 0)) return Fail(why, "fine.max_correspondence_mm must be > 0");
  if (!(min_correspondence_mm > 0 && min_correspondence_mm <= max_correspondence_mm))
    return Fail(why, "fine.min_correspondence_mm must be in (0, max_correspondence_mm]");
  if (!(max_normal_angle_deg > 0 && max_normal_angle_deg <= 180))
    return Fail(why, "fine.max_normal_angle_deg must be in (0, 180]");
  if (!(stop_mean_distance_mm >= 0)) return Fail(why, "fine.stop_mean_distance_mm must be ≥ 0");
  if (!(min_update_mm >= 0)) return Fail(why, "fine.min_update_mm must be ≥ 0");
  if (!(outside_overlap_weight > 0 && outside_overlap_weight <= 1))
    return Fail(why, "fine.outside_overlap_weight must be in (0, 1]");
  if (max_source_points < 0) return Fail(why, "fine.max_source_points must be ≥ 0");
  return true;
}

bool RegistrationOptions::IsValid(std::string* why) const {
  if (!coarse.IsValid(why) || !fine.IsValid(why)) return false;
  if (!(min_fitness >= 0 && min_fitness <= 1)) return Fail(why, "min_fitness must be in [0, 1]");
  if (min_points < 3) return Fail(why, "min_points must be ≥ 3");
  if (!(fitness_distance_mm > 0)) return Fail(why, "fitness_distance_mm must be > 0");
  if (!(max_rmse_ratio > 0)) return Fail(why, "max_rmse_ratio must be > 0");
  if (!(prior_slide_deg >= 0)) return Fail(why, "prior_slide_deg must be ≥ 0");
  if (!(prior_slide_gain >= 0)) return Fail(why, "prior_slide_gain must be ≥ 0");
  if (!(prior_weak_constraint >= 0 && prior_weak_constraint < 1))
    return Fail(why, "prior_weak_constraint must be in [0, 1)");
  if (num_threads < 1) return Fail(why, "num_threads must be ≥ 1");
  return true;
}

const char* ToString(FineMethod method) {
  switch (method) {
    case FineMethod::kWeightedIcp:
      return "weighted";
    case FineMethod::kPointToPlane:
      return "point-to-plane";
  }
  return "unknown";
}

bool FineMethodFromString(const std::string& text, FineMethod* method) {
  if (text == "weighted")
    *method = FineMethod::kWeightedIcp;
  else if (text == "point-to-plane")
    *method = FineMethod::kPointToPlane;
  else
    return false;
  return true;
}

cv::Matx44d RotationAboutAxis(const cv::Vec3d& direction, const cv::Vec3d& point_mm,
                              double angle_rad) {
  const Eigen::Vector3d a = Eigen::Vector3d(direction[0], direction[1], direction[2]).normalized();
  const Eigen::Vector3d c(point_mm[0], point_mm[1], point_mm[2]);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle_rad, a).toRotationMatrix();
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = R;
  T.topRightCorner<3, 1>() = c - R * c;
  return ToCv(T);
}

// --- Conditioning -------------------------------------------------------------

ViewCloud ConditionCloud(const PointCloud& input, const ConditioningOptions& options) {
  ViewCloud view;
  view.viewpoint_mm = options.viewpoint_mm;
  view.input_points = input.size();
  std::string why;
  if (!options.IsValid(&why)) {
    view.error = "invalid conditioning options: " + why;
    return view;
  }
  if (!input.IsValid(&why)) {
    view.error = "invalid input cloud: " + why;
    return view;
  }
  if (input.empty()) {
    view.error = "the input cloud has no points";
    return view;
  }
  // Finite points inside the working volume.
  PointCloud kept;
  kept.points_mm.reserve(input.size());
  if (input.HasColors()) kept.colors_rgb.reserve(input.size());
  const cv::Matx44d& T = options.crop.turntable_from_cloud;
  for (std::size_t i = 0; i < input.size(); ++i) {
    const cv::Vec3f& p = input.points_mm[i];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
      continue;
    }
    if (options.crop.enabled) {
      const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
      if (!options.crop.volume.Contains(cv::Vec3d(q[0], q[1], q[2]))) {
        ++view.cropped_points;
        continue;
      }
    }
    kept.points_mm.push_back(p);
    if (input.HasColors()) kept.colors_rgb.push_back(input.colors_rgb[i]);
  }
  if (kept.empty()) {
    view.error = options.crop.enabled ? "no points left inside the working volume"
                                      : "the input cloud has no finite points";
    return view;
  }
  // Downsample first: statistical filtering of a dense stereo cloud is slow
  // and voxel averaging already halves the noise.
  const PointCloud voxels = VoxelDownsample(kept, options.fine_voxel_mm);
  SurvivorNeighbours neighbours(voxels);  // one index for every search below
  PointCloud fine = voxels;
  // The points of `fine` in `kept_indices` only (ascending), for the searches too.
  const auto keep_only = [&](const std::vector<int>& kept_indices, bool with_normals) {
    PointCloud filtered;
    filtered.points_mm.reserve(kept_indices.size());
    if (with_normals) filtered.normals.reserve(kept_indices.size());
    if (fine.HasColors()) filtered.colors_rgb.reserve(kept_indices.size());
    for (const int i : kept_indices) {
      filtered.points_mm.push_back(fine.points_mm[i]);
      if (with_normals) filtered.normals.push_back(fine.normals[i]);
      if (fine.HasColors()) filtered.colors_rgb.push_back(fine.colors_rgb[i]);
    }
    neighbours.Keep(kept_indices);
    fine = std::move(filtered);
  };
  if (options.outlier_neighbors > 0 &&
      fine.size() > static_cast<std::size_t>(options.outlier_neighbors)) {
    const std::size_t before = fine.size();
    keep_only(StatisticalInliers(&neighbours, options.outlier_neighbors, options.outlier_std_ratio,
                                 options.num_threads),
              /*with_normals=*/false);
    view.outlier_points = before - fine.size();
  }
  if (fine.size() < 3) {
    view.error = "fewer than 3 points left after filtering";
    return view;
  }
  auto surface = ToPclXyz(fine);
  const int k = std::min<int>(options.normal_neighbors, static_cast<int>(fine.size()));
  EstimateNormals(&fine, neighbours, /*surface_is_cloud=*/true, *surface, k, options.viewpoint_mm,
                  options.num_threads);
  if (options.crop.enabled && options.crop.platter_band_mm > options.crop.volume.min_height_mm) {
    // Level surface just above the platter, facing up (the normals face the
    // camera): the platter itself, lifted by matching errors (a few px of
    // disparity lift it by a millimetre or two). A surface facing down there
    // is an object's foot curving in; the platter smeared up under an
    // overhang also faces down, and fusion's platter_shadow_mm takes it.
    const double cos_level = std::cos(options.crop.platter_normal_deg * M_PI / 180.0);
    const cv::Matx33d R = T.get_minor<3, 3>(0, 0);
    std::vector<int> off_platter;
    off_platter.reserve(fine.size());
    for (std::size_t i = 0; i < fine.size(); ++i) {
      const cv::Vec3f& p = fine.points_mm[i];
      const cv::Vec4d q = T * cv::Vec4d(p[0], p[1], p[2], 1);
      const cv::Vec3d n = R * cv::Vec3d(fine.normals[i]);
      if (q[2] < options.crop.platter_band_mm && n[2] >= cos_level) {
        ++view.cropped_points;
        continue;
      }
      off_platter.push_back(static_cast<int>(i));
    }
    keep_only(off_platter, /*with_normals=*/true);
    if (fine.size() < 3) {
      view.error = "fewer than 3 points left after removing the platter";
      return view;
    }
    surface = ToPclXyz(fine);
  }
  PointCloud coarse = VoxelDownsample(PointCloud{fine.points_mm, {}, {}}, options.coarse_voxel_mm);
  EstimateNormals(&coarse, neighbours, /*surface_is_cloud=*/false, *surface,
                  std::min<int>(k, static_cast<int>(fine.size())), options.viewpoint_mm,
                  options.num_threads);
  view.fine = std::move(fine);
  view.coarse = std::move(coarse);
  return view;
}

// --- Features -----------------------------------------------------------------

// PCL's FPFHEstimation, step for step: each point's SPFH from its pair
// features (pcl::computePairFeatures) with every other point within the radius,
// 11 bins per feature, then its FPFH as the neighbours' SPFHs weighted by
// 1 / squared distance, each third scaled to sum to 100, with PCL's float and
// double arithmetic in PCL's order (neighbours by distance, then index, as
// its sorted FLANN search returns them). FPFHEstimationOMP searched the
// radius twice per point with FLANN: ~25 ms of a 2 k-point coarse cloud's
// 30; here one nanoflann search per point serves both steps.
std::vector<Fpfh> ComputeFpfh(const PointCloud& cloud, double radius_mm, int num_threads) {
  std::vector<Fpfh> out;
  if (!cloud.HasNormals() || cloud.empty() || !(radius_mm > 0)) return out;
  constexpr int kBins = 11;
  const auto n = static_cast<long>(cloud.size());
  const PointIndex index(cloud);
  const auto radius2 = static_cast<float>(radius_mm * radius_mm);  // as KdTreeFLANN
  std::vector<std::vector<std::pair<std::uint32_t, float>>> neighbours(cloud.size());
  std::vector<Fpfh> spfh(cloud.size());  // f1, f2, f3 histograms
  const float d_pi = 1.0f / (2.0f * static_cast<float>(M_PI));
  const auto point4 = [&](std::size_t i) {
    const cv::Vec3f& p = cloud.points_mm[i];
    return Eigen::Vector4f(p[0], p[1], p[2], 1.f);
  };
  const auto normal4 = [&](std::size_t i) {
    const cv::Vec3f& m = cloud.normals[i];
    return Eigen::Vector4f(m[0], m[1], m[2], 0.f);
  };
  const auto bin = [](double at) {
    return std::clamp(static_cast<int>(std::floor(at)), 0, kBins - 1);
  };
#pragma omp parallel for num_threads(std::max(1, num_threads)) schedule(dynamic, 64)
  for (long i = 0; i < n; ++i) {
    const auto p = static_cast<std::size_t>(i);
    auto& near = neighbours[p];
    index.Within(cloud.points_mm[p].val, radius2, &near);
    Fpfh& h = spfh[p];
    h.fill(0.f);
    const float increment = 100.0f / static_cast<float>(near.size() - 1);
    const Eigen::Vector4f pp = point4(p), pn = normal4(p);
    for (const auto& [q, d2] : near) {
      if (q == p) continue;
      // PCL bins every other point's pair, a point at the same place too
      // (computePairFeatures then returns false with all four features 0).
      float f1, f2, f3, f4;
      pcl::computePairFeatures(pp, pn, point4(q), normal4(q), f1, f2, f3, f4);
      h[static_cast<std::size_t>(bin(kBins * ((f1 + M_PI) * d_pi)))] += increment;
      h[static_cast<std::size_t>(kBins + bin(kBins * ((f2 + 1.0) * 0.5)))] += increment;
      h[static_cast<std::size_t>(2 * kBins + bin(kBins * ((f3 + 1.0) * 0.5)))] += increment;
    }
  }
  out.resize(cloud.size());
#pragma omp parallel for num_threads(std::max(1, num_threads)) schedule(static)
  for (long i = 0; i < n; ++i) {
    Fpfh& f = out[static_cast<std::size_t>(i)];
    f.fill(0.f);
    std::array<double, 3> sum{0, 0, 0};
    for (const auto& [q, d2] : neighbours[static_cast<std::size_t>(i)]) {
      if (d2 == 0) continue;  // the point itself
      const float weight = 1.0f / d2;
      for (int b = 0; b < 3 * kBins; ++b) {
        const float value = spfh[q][static_cast<std::size_t>(b)] * weight;
        sum[static_cast<std::size_t>(b / kBins)] += value;
        f[static_cast<std::size_t>(b)] += value;
      }
    }
    for (int b = 0; b < 3 * kBins; ++b) {
      double& s = sum[static_cast<std::size_t>(b / kBins)];
      const double scale = s != 0 ? 100.0 / s : 0.0;
      f[static_cast<std::size_t>(b)] = static_cast<float>(f[static_cast<std::size_t>(b)] * scale);
    }
  }
  return out;
}

namespace {

// Nearest feature (squared L2) of each row of `a` among the rows of `b`
// and of each row of `b` among the rows of `a`, from one blocked matrix
// product (exact and deterministic: ties go to the lowest index; FPFH is
// 33-D, where k-d trees degrade to brute force anyway).
struct NearestBothWays {
  std::vector<int> a_to_b, b_to_a;
};
NearestBothWays FindNearestBothWays(const Eigen::MatrixXf& a, const Eigen::MatrixXf& b,
                                    int threads) {
  NearestBothWays out;
  out.a_to_b.assign(a.rows(), -1);
  out.b_to_a.assign(b.rows(), -1);
  if (a.rows() == 0 || b.rows() == 0) return out;
  const Eigen::VectorXf an = a.rowwise().squaredNorm();
  const Eigen::VectorXf bn = b.rowwise().squaredNorm();
  constexpr Eigen::Index kBlock = 256;
  const long blocks = static_cast<long>((a.rows() + kBlock - 1) / kBlock);
  // Per block: the best row of the block for every column of b.
  std::vector<Eigen::VectorXf> col_best(blocks);
  std::vector<std::vector<int>> col_arg(blocks);
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(dynamic, 1)
  for (long blk = 0; blk < blocks; ++blk) {
    const Eigen::Index r0 = blk * kBlock;
    const Eigen::Index rows = std::min<Eigen::Index>(kBlock, a.rows() - r0);
    Eigen::MatrixXf d = -2.f * a.middleRows(r0, rows) * b.transpose();
    d.rowwise() += bn.transpose();
    d.colwise() += an.segment(r0, rows);
    for (Eigen::Index r = 0; r < rows; ++r) {
      Eigen::Index best;
      d.row(r).minCoeff(&best);
      out.a_to_b[r0 + r] = static_cast<int>(best);
    }
    col_best[blk].resize(b.rows());
    col_arg[blk].resize(b.rows());
    for (Eigen::Index c = 0; c < b.rows(); ++c) {
      Eigen::Index best;
      col_best[blk][c] = d.col(c).minCoeff(&best);
      col_arg[blk][c] = static_cast<int>(r0 + best);
    }
  }
  for (Eigen::Index c = 0; c < b.rows(); ++c) {
    float best = std::numeric_limits<float>::infinity();
    for (long blk = 0; blk < blocks; ++blk) {
      if (col_best[blk][c] < best) {
        best = col_best[blk][c];
        out.b_to_a[c] = col_arg[blk][c];
      }
    }
  }
  return out;
}

Eigen::MatrixXf FeatureMatrix(const std::vector<Fpfh>& f) {
  Eigen::MatrixXf m(static_cast<Eigen::Index>(f.size()), 33);
  for (std::size_t i = 0; i < f.size(); ++i)
    for (int b = 0; b < 33; ++b) m(static_cast<Eigen::Index>(i), b) = f[i][b];
  return m;
}

struct Hypothesis {
  double score = std::numeric_limits<double>::infinity();
  std::size_t inliers = 0;
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  long index = std::numeric_limits<long>::max();  // tie-break: lowest index wins
};

bool Better(const Hypothesis& a, const Hypothesis& b) {
  if (a.score != b.score) return a.score < b.score;
  return a.index < b.index;
}

// Scores T over the correspondences with the paper's Huber loss. Residuals
// beyond `cap` cost as much as `cap` (an outlier correspondence then costs a
// constant, as in MSAC, instead of growing with its distance, which would let
// the far outliers decide between hypotheses).
Hypothesis Score(const Eigen::Matrix4d& T, const std::vector<Eigen::Vector3d>& src,
                 const std::vector<Eigen::Vector3d>& dst, double w, double cap) {
  Hypothesis h;
  h.T = T;
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = T.topRightCorner<3, 1>();
  const double cap_loss = Huber(cap, w);
  double score = 0;
  std::size_t inliers = 0;
  for (std::size_t i = 0; i < src.size(); ++i) {
    const double u = (R * src[i] + t - dst[i]).norm();
    if (u <= w) ++inliers;
    score += u >= cap ? cap_loss : Huber(u, w);
  }
  h.score = score;
  h.inliers = inliers;
  return h;
}

std::uint64_t SplitMix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

}  // namespace

namespace {

// How many distinct hypotheses RegisterCoarseImpl keeps besides the best.
struct CandidateKeep {
  int max_candidates = 0;
  double min_separation_rad = 0;
  double min_separation_mm = 0;
};

bool SameHypothesis(const Hypothesis& a, const Hypothesis& b, const CandidateKeep& keep) {
  const Eigen::Matrix3d dR = a.T.topLeftCorner<3, 3>().transpose() * b.T.topLeftCorner<3, 3>();
  const double angle = Eigen::AngleAxisd(dR).angle();
  const double shift = (a.T.topRightCorner<3, 1>() - b.T.topRightCorner<3, 1>()).norm();
  return angle < keep.min_separation_rad && shift < keep.min_separation_mm;
}

// The best hypotheses, at most keep.max_candidates, no two the same: a
// hypothesis close to a kept one replaces it when it scores better.
void OfferCandidate(const Hypothesis& h, const CandidateKeep& keep, std::vector<Hypothesis>* top) {
  for (Hypothesis& kept : *top) {
    if (SameHypothesis(kept, h, keep)) {
      if (Better(h, kept)) kept = h;
      std::sort(top->begin(), top->end(), Better);
      return;
    }
  }
  top->push_back(h);
  std::sort(top->begin(), top->end(), Better);
  if (top->size() > static_cast<std::size_t>(keep.max_candidates)) top->pop_back();
}

RegistrationResult RegisterCoarseImpl(const ViewCloud& source, const ViewCloud& target,
                                      const CoarseOptions& options, int num_threads,
                                      const CandidateKeep& keep,
                                      std::vector<RegistrationResult>* candidates) {
  return NoThrow<RegistrationResult>(
      "RegisterCoarse", RegistrationResult::Status::kFailed, [&]() -> RegistrationResult {
        const auto start = Clock::now();
        RegistrationResult result;
        std::string why;
        if (!options.IsValid(&why)) {
          result.message = "invalid options: " + why;
          return result;
        }
        const PointCloud& s = source.coarse;
        const PointCloud& t = target.coarse;
        if (s.size() < 3 || t.size() < 3 || !s.HasNormals() || !t.HasNormals()) {
          result.message = "coarse clouds need at least 3 points with normals";
          return result;
        }
        const int threads = std::max(1, num_threads);
        const std::vector<Fpfh> fs = ComputeFpfh(s, options.feature_radius_mm, threads);
        const std::vector<Fpfh> ft = ComputeFpfh(t, options.feature_radius_mm, threads);
        const Eigen::MatrixXf ms = FeatureMatrix(fs), mt = FeatureMatrix(ft);
        const NearestBothWays nearest = FindNearestBothWays(ms, mt, threads);
        const std::vector<int>& s_to_t = nearest.a_to_b;
        std::vector<std::pair<int, int>> pairs;
        if (options.mutual_filter) {
          const std::vector<int>& t_to_s = nearest.b_to_a;
          for (std::size_t i = 0; i < s_to_t.size(); ++i)
            if (s_to_t[i] >= 0 && t_to_s[s_to_t[i]] == static_cast<int>(i))
              pairs.emplace_back(static_cast<int>(i), s_to_t[i]);
        }
        // Too few mutual matches (tiny or repetitive clouds): use the one-way ones.
        if (pairs.size() < 10) {
          pairs.clear();
          for (std::size_t i = 0; i < s_to_t.size(); ++i)
            if (s_to_t[i] >= 0) pairs.emplace_back(static_cast<int>(i), s_to_t[i]);
        }
        result.correspondences = pairs.size();
        std::vector<Eigen::Vector3d> src(pairs.size()), dst(pairs.size());
        std::vector<Eigen::Vector3d> src_n(pairs.size()), dst_n(pairs.size());
        for (std::size_t i = 0; i < pairs.size(); ++i) {
          src[i] = V(s.points_mm[pairs[i].first]).cast<double>();
          dst[i] = V(t.points_mm[pairs[i].second]).cast<double>();
          src_n[i] = V(s.normals[pairs[i].first]).cast<double>();
          dst_n[i] = V(t.normals[pairs[i].second]).cast<double>();
        }
        const double w = options.inlier_distance_mm;
        const double cap = 2 * w;
        PointIndex target_index(t);

        Hypothesis best;
        std::vector<Hypothesis> top;  // with candidates: the best distinct ones
        if (options.prior_target_from_source) {
          best = Score(ToEigen(*options.prior_target_from_source), src, dst, w, cap);
          best.index = -1;
          if (candidates) OfferCandidate(best, keep, &top);
          if (options.prior_accept_fitness > 0) {
            const Overlap o = MeasureOverlap(s, target_index, best.T, w, threads);
            if (o.fitness >= options.prior_accept_fitness) {
              result.status = RegistrationResult::Status::kOk;
              result.target_from_source = ToCv(best.T);
              result.fitness = o.fitness;
              result.rmse_mm = o.rmse;
              result.inliers = o.inliers;
              result.prior_kept = true;
              result.converged = true;
              result.message = "prior accepted without RANSAC";
              result.time_ms = MsSince(start);
              return result;
            }
          }
        }

        const std::size_t n = pairs.size();
        const double min_ratio = options.edge_similarity;
        const double cos_normal = std::cos(60.0 * M_PI / 180.0);
        long needed = options.max_iterations;
        long done = 0;
        constexpr long kBatch = 512;
        while (n >= 3 && done < needed) {
          const long batch = std::min<long>(kBatch, needed - done);
          std::vector<Hypothesis> hyps(static_cast<std::size_t>(batch));
          ParallelFor(static_cast<std::size_t>(batch), threads, [&](std::size_t b, std::size_t e) {
            for (std::size_t k = b; k < e; ++k) {
              const long index = done + static_cast<long>(k);
              std::mt19937_64 rng(
                  SplitMix(options.seed ^ SplitMix(static_cast<std::uint64_t>(index))));
              std::uniform_int_distribution<std::size_t> pick(0, n - 1);
              std::array<std::size_t, 3> id{pick(rng), pick(rng), pick(rng)};
              if (id[0] == id[1] || id[0] == id[2] || id[1] == id[2]) continue;
              bool ok = true;
              for (int a = 0; a < 3 && ok; ++a) {
                const int b2 = (a + 1) % 3;
                const double ls = (src[id[a]] - src[id[b2]]).norm();
                const double lt = (dst[id[a]] - dst[id[b2]]).norm();
                if (ls < 2 * w || lt < 2 * w)
                  ok = false;  // too close: an ill-posed rotation
                else if (std::min(ls, lt) < min_ratio * std::max(ls, lt))
                  ok = false;
              }
              if (!ok) continue;
              std::vector<Eigen::Vector3d> a3{src[id[0]], src[id[1]], src[id[2]]};
              std::vector<Eigen::Vector3d> b3{dst[id[0]], dst[id[1]], dst[id[2]]};
              const Eigen::Matrix4d T = RigidFromPairs(a3, b3, nullptr);
              const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
              for (int a = 0; a < 3 && ok; ++a)
                if ((R * src_n[id[a]]).dot(dst_n[id[a]]) < cos_normal) ok = false;
              if (!ok) continue;
              Hypothesis h = Score(T, src, dst, w, cap);
              h.index = index;
              hyps[k] = h;
            }
          });
          for (const Hypothesis& h : hyps) {
            if (std::isfinite(h.score) && Better(h, best)) best = h;
            if (candidates && std::isfinite(h.score)) OfferCandidate(h, keep, &top);
          }
          done += batch;
          // Early termination: enough samples for an all-inlier one with the
          // confidence asked, at the best inlier ratio so far.
          const double ratio = static_cast<double>(best.inliers) / static_cast<double>(n);
          if (ratio > 0) {
            const double p_good = ratio * ratio * ratio;
            const double k =
                p_good >= 1 ? 1 : std::log(1 - options.confidence) / std::log(1 - p_good);
            // Samples rejected by the pre-checks count too, so this is conservative.
            needed = std::min<long>(options.max_iterations,
                                    std::max<long>(kBatch, static_cast<long>(std::ceil(k))));
          }
        }
        result.iterations = static_cast<int>(done);
        result.converged = done < options.max_iterations;
        if (!std::isfinite(best.score)) {
          result.message = "RANSAC found no consistent hypothesis among " + std::to_string(n) +
                           " feature matches";
          result.time_ms = MsSince(start);
          return result;
        }
        result.prior_kept = best.index == -1;
        // Refit on the inliers (twice: the set may grow).
        auto refit = [&](const Eigen::Matrix4d& initial) {
          Eigen::Matrix4d T = initial;
          for (int round = 0; round < 2; ++round) {
            std::vector<Eigen::Vector3d> a, b;
            const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
            const Eigen::Vector3d tt = T.topRightCorner<3, 1>();
            for (std::size_t i = 0; i < n; ++i) {
              if ((R * src[i] + tt - dst[i]).norm() <= w) {
                a.push_back(src[i]);
                b.push_back(dst[i]);
              }
            }
            if (a.size() < 3) break;
            T = RigidFromPairs(a, b, nullptr);
          }
          return T;
        };
        const Eigen::Matrix4d T = refit(best.T);
        const Overlap o = MeasureOverlap(s, target_index, T, w, threads);
        result.status = RegistrationResult::Status::kOk;
        result.target_from_source = ToCv(T);
        result.fitness = o.fitness;
        result.rmse_mm = o.rmse;
        result.inliers = o.inliers;
        result.time_ms = MsSince(start);
        if (candidates) {
          for (const Hypothesis& h : top) {
            RegistrationResult c = result;
            c.prior_kept = h.index == -1;
            const Eigen::Matrix4d Tc = refit(h.T);
            const Overlap oc = MeasureOverlap(s, target_index, Tc, w, threads);
            c.target_from_source = ToCv(Tc);
            c.fitness = oc.fitness;
            c.rmse_mm = oc.rmse;
            c.inliers = oc.inliers;
            candidates->push_back(c);
          }
        }
        return result;
      });
}

}  // namespace

RegistrationResult RegisterCoarse(const ViewCloud& source, const ViewCloud& target,
                                  const CoarseOptions& options, int num_threads) {
  return RegisterCoarseImpl(source, target, options, num_threads, CandidateKeep{}, nullptr);
}

std::vector<RegistrationResult> RegisterCoarseCandidates(const ViewCloud& source,
                                                         const ViewCloud& target,
                                                         const CoarseOptions& options,
                                                         const CoarseCandidates& wanted,
                                                         int num_threads) {
  std::vector<RegistrationResult> candidates;
  CandidateKeep keep;
  keep.max_candidates = std::max(1, wanted.max_candidates);
  keep.min_separation_rad = wanted.min_separation_deg * M_PI / 180.0;
  keep.min_separation_mm = wanted.min_separation_mm;
  const RegistrationResult best =
      RegisterCoarseImpl(source, target, options, num_threads, keep, &candidates);
  if (!best.IsUsable()) return {best};
  if (candidates.empty()) candidates.push_back(best);
  return candidates;
}

// --- Fine ---------------------------------------------------------------------

namespace {

// The source points fine registration uses: an even stride through the fine
// cloud down to `max_points` (0 = all). Returns `fine` itself when no
// stride is needed, else fills and returns *strided.
const PointCloud& StridedSource(const PointCloud& fine, int max_points, PointCloud* strided) {
  const std::size_t cap = max_points > 0 ? static_cast<std::size_t>(max_points) : fine.size();
  if (fine.size() <= cap) return fine;
  const double stride = static_cast<double>(fine.size()) / static_cast<double>(cap);
  for (std::size_t k = 0; k < cap; ++k) {
    const std::size_t i = static_cast<std::size_t>(k * stride);
    strided->points_mm.push_back(fine.points_mm[i]);
    strided->normals.push_back(fine.normals[i]);
  }
  return *strided;
}

// The ICP iterations of the fine stage: source points `s` (with normals)
// against `target` (indexed by `target_index`) from `initial_target_from_source`.
// Sets the pose, iterations and converged flag (status kOk), or a failure;
// leaves fitness and timing to the caller.
// One fine-registration correspondence of a source point.
struct FinePair {
  float d2 = -1;  // squared distance (mm²); < 0: rejected
  int target = -1;
  float b = 1;       // overlap weight
  int nearest = -1;  // the last search's nearest target point, accepted or not
};

// The nearest target point of every source point under the pose (R, t),
// within the gate and with agreeing normals; weighted by whether the source
// point faces the target's sensor.
void FindCorrespondences(const PointCloud& s, const ViewCloud& target,
                         const PointIndex& target_index, const Eigen::Matrix4d& T, double gate,
                         const FineOptions& options, int threads, std::vector<FinePair>* pairs) {
  const PointCloud& t = target.fine;
  const Eigen::Vector3d view_t(target.viewpoint_mm[0], target.viewpoint_mm[1],
                               target.viewpoint_mm[2]);
  const double cos_max = std::cos(options.max_normal_angle_deg * M_PI / 180.0);
  // Overlap test: the source point's normal faces the target's sensor.
  constexpr double kFacingCos = 0.2;  // within ~78° of the line of sight
  const Eigen::Matrix3f R = T.topLeftCorner<3, 3>().cast<float>();
  const Eigen::Vector3f tt = T.topRightCorner<3, 1>().cast<float>();
  const float gate2 = static_cast<float>(gate * gate);
  const float bound_gate2 = std::nextafter(gate2, std::numeric_limits<float>::infinity());
  ParallelFor(s.size(), threads, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      FinePair& pr = (*pairs)[i];
      pr.d2 = -1;
      const Eigen::Vector3f p = R * V(s.points_mm[i]) + tt;
      // The search is bounded just above the gate (a pair at exactly the
      // gate is kept; anything found beyond it is refused below), and above
      // the distance to the last iteration's nearest point, which the small
      // step since rarely changes: the same nearest point is found (the
      // tree is walked in the same order), with fewer branches opened.
      float bound2 = bound_gate2;
      if (pr.nearest >= 0) {
        const Eigen::Vector3f d = p - V(t.points_mm[static_cast<std::size_t>(pr.nearest)]);
        bound2 = std::min(bound2, d.squaredNorm() * (1 + 1e-5f) + 1e-12f);
      }
      int idx;
      float d2;
      if (!target_index.NearestWithin(p, bound2, &idx, &d2)) continue;
      pr.nearest = idx;
      if (d2 > gate2) continue;
      const Eigen::Vector3f n = R * V(s.normals[i]);
      if (n.dot(V(t.normals[idx])) < cos_max) continue;
      const Eigen::Vector3f to_view = view_t.cast<float>() - p;
      const float facing = n.dot(to_view) / std::max(1e-6f, to_view.norm());
      pr.d2 = d2;
      pr.target = idx;
      pr.b = facing >= kFacingCos ? 1.f : static_cast<float>(options.outside_overlap_weight);
    }
  });
}

// The accepted correspondences as point pairs for the solver: source points
// moved by T, their target points (projected onto the target's tangent
// plane when options.tangent_projection), the target normals and weights.
struct WeightedPairs {
  std::vector<Eigen::Vector3d> a, b, b_normals;
  std::vector<double> weights;
};

WeightedPairs BuildWeightedPairs(const PointCloud& s, const PointCloud& t,
                                 const std::vector<FinePair>& pairs, const Eigen::Matrix4d& T,
                                 double sigma, std::size_t z, const FineOptions& options) {
  WeightedPairs out;
  out.a.reserve(z);
  out.b.reserve(z);
  out.weights.reserve(z);
  const Eigen::Matrix3d Rd = T.topLeftCorner<3, 3>();
  const Eigen::Vector3d td = T.topRightCorner<3, 1>();
  for (std::size_t i = 0; i < pairs.size(); ++i) {
    const FinePair& pr = pairs[i];
    if (pr.d2 < 0) continue;
    out.a.push_back(Rd * V(s.points_mm[i]).cast<double>() + td);
    const Eigen::Vector3d q = V(t.points_mm[pr.target]).cast<double>();
    const Eigen::Vector3d nq = V(t.normals[pr.target]).cast<double>();
    out.b_normals.push_back(nq);
    // The target point on the target's tangent plane nearest the source
    // point: tangential offsets between samples then cost nothing, so
    // point-to-point least squares slides along the surface as fast as
    // point-to-plane (the nearest sample alone converges slowly and
    // sticks at sample spacing).
    out.b.push_back(options.tangent_projection
                        ? Eigen::Vector3d(out.a.back() - (out.a.back() - q).dot(nq) * nq)
                        : q);
    out.weights.push_back(pr.b * (sigma > 0 ? std::exp(-pr.d2 / sigma) : 1.0));
  }
  return out;
}

// The pose increment that best aligns the pairs (weighted point-to-point, or
// point-to-plane linearised about the current pose). False when the
// point-to-plane system is singular.
bool SolveIncrement(WeightedPairs* pairs, FineMethod method, Eigen::Matrix4d* delta) {
  *delta = Eigen::Matrix4d::Identity();
  if (method == FineMethod::kWeightedIcp) {
    *delta = RigidFromPairs(pairs->a, pairs->b, &pairs->weights);
    return true;
  }
  // Point-to-plane, linearised about the current pose (small angles).
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
  for (std::size_t i = 0; i < pairs->a.size(); ++i) {
    Eigen::Matrix<double, 6, 1> J;
    J.head<3>() = pairs->a[i].cross(pairs->b_normals[i]);
    J.tail<3>() = pairs->b_normals[i];
    const double r = (pairs->a[i] - pairs->b[i]).dot(pairs->b_normals[i]);
    H += pairs->weights[i] * J * J.transpose();
    g += pairs->weights[i] * J * r;
  }
  const Eigen::Matrix<double, 6, 1> x = H.ldlt().solve(-g);
  if (!x.allFinite()) return false;
  const Eigen::Vector3d w(x[0], x[1], x[2]);
  const double angle = w.norm();
  if (angle > 0)
    delta->topLeftCorner<3, 3>() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
  delta->topRightCorner<3, 1>() = x.tail<3>();
  return true;
}

// Anderson acceleration (type II, as in AA-ICP / Fast and Robust ICP) of
// the fixed-point map T → ICP step(T), on x = (radius·rotation vector,
// translation). Weighted point-to-point ICP creeps along weakly
// constrained directions (hundreds of iterations on smooth surfaces);
// accelerated, it needs tens.
class AndersonAccelerator {
 public:
  explicit AndersonAccelerator(double radius) : rscale_(std::max(1.0, radius)) {}

  // Records the step T → G and returns the extrapolated pose (G itself
  // until there is history, or when the extrapolation is not finite);
  // *accelerated says which.
  Eigen::Matrix4d Step(const Eigen::Matrix4d& T, const Eigen::Matrix4d& G, bool* accelerated) {
    const Vec6 x = Log(T), g = Log(G);
    hist_g_.push_back(g);
    hist_f_.push_back(g - x);
    if (hist_g_.size() > kHistory + 1) {
      hist_g_.erase(hist_g_.begin());
      hist_f_.erase(hist_f_.begin());
    }
    *accelerated = false;
    const std::size_t m = hist_g_.size() - 1;
    if (m < 1) return G;
    Eigen::MatrixXd dF(6, m), dG(6, m);
    for (std::size_t j = 0; j < m; ++j) {
      dF.col(j) = hist_f_[j + 1] - hist_f_[j];
      dG.col(j) = hist_g_[j + 1] - hist_g_[j];
    }
    const Eigen::VectorXd gamma = dF.colPivHouseholderQr().solve(hist_f_.back());
    const Vec6 next = hist_g_.back() - dG * gamma;
    if (!gamma.allFinite() || !next.allFinite()) return G;
    *accelerated = true;
    return Exp(next);
  }

  // Forgets the history (after an extrapolation that made things worse).
  void Reset() {
    hist_g_.clear();
    hist_f_.clear();
  }

 private:
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  static constexpr std::size_t kHistory = 5;

  Vec6 Log(const Eigen::Matrix4d& M) const {
    const Eigen::AngleAxisd aa(Eigen::Matrix3d(M.topLeftCorner<3, 3>()));
    Vec6 x;
    x.head<3>() = aa.axis() * aa.angle() * rscale_;
    x.tail<3>() = M.topRightCorner<3, 1>();
    return x;
  }
  Eigen::Matrix4d Exp(const Vec6& x) const {
    Eigen::Matrix4d M = Eigen::Matrix4d::Identity();
    const Eigen::Vector3d w = x.head<3>() / rscale_;
    const double angle = w.norm();
    if (angle > 0) M.topLeftCorner<3, 3>() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
    M.topRightCorner<3, 1>() = x.tail<3>();
    return M;
  }

  double rscale_;
  std::vector<Vec6> hist_g_, hist_f_;  // G(x_i) and f_i = G(x_i) − x_i, newest last
};

RegistrationResult IterateFine(const PointCloud& s, const ViewCloud& target,
                               const PointIndex& target_index,
                               const Eigen::Matrix4d& initial_target_from_source,
                               const FineOptions& options, int threads) {
  RegistrationResult result;
  // The scale of rotations for the update test: the source's extent.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : s.points_mm) centroid += V(p).cast<double>();
  centroid /= static_cast<double>(s.size());
  double radius = 0;
  for (const auto& p : s.points_mm)
    radius = std::max(radius, (V(p).cast<double>() - centroid).norm());

  Eigen::Matrix4d T = initial_target_from_source;
  double gate = options.max_correspondence_mm;
  std::vector<FinePair> pairs(s.size());
  int iteration = 0;
  bool converged = false;
  // A step that raises the mean distance is undone and the history cleared.
  AndersonAccelerator anderson(radius);
  bool accelerated = false;
  Eigen::Matrix4d plain_step = T;
  double accepted_mean = std::numeric_limits<double>::infinity();
  for (; iteration < options.max_iterations; ++iteration) {
    FindCorrespondences(s, target, target_index, T, gate, options, threads, &pairs);
    double sum_d2 = 0, sum_d = 0;
    for (const FinePair& pr : pairs) {
      if (pr.d2 < 0) continue;
      sum_d2 += pr.d2;
      sum_d += std::sqrt(pr.d2);
    }
    const std::size_t z = static_cast<std::size_t>(
        std::count_if(pairs.begin(), pairs.end(), [](const FinePair& p) { return p.d2 >= 0; }));
    if (z < 6) {
      result.message = "fine registration lost its correspondences (" + std::to_string(z) +
                       " pairs within " + std::to_string(gate) + " mm)";
      result.iterations = iteration;
      return result;
    }
    const double mean = sum_d / static_cast<double>(z);
    if (accelerated && mean > accepted_mean) {
      T = plain_step;  // the accelerated step made things worse: undo it
      anderson.Reset();
      accelerated = false;
      continue;
    }
    accepted_mean = mean;
    if (mean < options.stop_mean_distance_mm) {
      converged = true;
      break;
    }
    // (reading of §8) σ = (2/z)·Σd with d the squared distance; the weight
    // exp(−d/σ) is a Gaussian kernel whose variance follows the residuals
    // (the literal exp(−d/σ²) is not dimensionless and collapses to zero
    // weight for all but the closest pairs once residuals are below 1 mm).
    const double sigma = 2.0 * sum_d2 / static_cast<double>(z);
    WeightedPairs weighted = BuildWeightedPairs(s, target.fine, pairs, T, sigma, z, options);
    Eigen::Matrix4d delta;
    if (!SolveIncrement(&weighted, options.method, &delta)) {
      result.message = "point-to-plane system is singular";
      result.iterations = iteration;
      return result;
    }
    const Eigen::Matrix4d G = delta * T;
    plain_step = G;
    T = anderson.Step(T, G, &accelerated);
    // How far the plain update moved the source: rotation at the cloud's
    // radius plus the translation of its centroid.
    const Eigen::Matrix3d dR = delta.topLeftCorner<3, 3>();
    const double angle = Eigen::AngleAxisd(dR).angle();
    const Eigen::Vector3d c = G.topLeftCorner<3, 3>() * centroid + G.topRightCorner<3, 1>();
    const double moved = angle * radius + (dR * c + delta.topRightCorner<3, 1>() - c).norm();
    // Shrink the gate towards the residual level (robust to the start).
    const double rms = std::sqrt(sum_d2 / static_cast<double>(z));
    gate = std::clamp(3.0 * rms, options.min_correspondence_mm, gate);
    if (moved < options.min_update_mm) {
      T = G;  // converged: the plain step, not an extrapolation
      converged = true;
      ++iteration;
      break;
    }
  }
  result.status = RegistrationResult::Status::kOk;
  result.target_from_source = ToCv(T);
  result.iterations = iteration;
  result.converged = converged;
  if (!converged) result.message = "stopped at max_iterations";
  return result;
}

}  // namespace

RegistrationResult RegisterFine(const ViewCloud& source, const ViewCloud& target,
                                const cv::Matx44d& initial_target_from_source,
                                const FineOptions& options, int num_threads) {
  return NoThrow<RegistrationResult>(
      "RegisterFine", RegistrationResult::Status::kFailed, [&]() -> RegistrationResult {
        const auto start = Clock::now();
        RegistrationResult result;
        std::string why;
        if (!options.IsValid(&why)) {
          result.message = "invalid options: " + why;
          return result;
        }
        const PointCloud& t = target.fine;
        if (source.fine.size() < 3 || t.size() < 3 || !source.fine.HasNormals() ||
            !t.HasNormals()) {
          result.message = "fine clouds need at least 3 points with normals";
          return result;
        }
        PointCloud strided;
        const PointCloud& s = StridedSource(source.fine, options.max_source_points, &strided);
        const int threads = std::max(1, num_threads);
        const PointIndex target_index(t);
        result = IterateFine(s, target, target_index, ToEigen(initial_target_from_source), options,
                             threads);
        if (result.IsUsable()) {
          const Overlap o = MeasureOverlap(s, target_index, ToEigen(result.target_from_source),
                                           options.max_correspondence_mm, threads);
          result.fitness = o.fitness;
          result.rmse_mm = o.rmse;
          result.inliers = o.inliers;
        }
        result.time_ms = MsSince(start);
        return result;
      });
}

// --- Both ---------------------------------------------------------------------

namespace {

// The point-to-plane information matrix of `cloud` against itself, for
// motions x = (radius · rotation vector, translation) about the centroid
// (rotations scaled by the cloud's radius, so that both halves are in mm).
// False when the cloud has fewer than 6 points, no normals or no extent.
bool SelfInformation(const PointCloud& cloud, Eigen::Matrix<double, 6, 6>* H,
                     Eigen::Vector3d* centroid, double* radius) {
  if (cloud.size() < 6 || !cloud.HasNormals()) return false;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : cloud.points_mm) c += V(p).cast<double>();
  c /= static_cast<double>(cloud.size());
  double r = 0;
  for (const auto& p : cloud.points_mm) r = std::max(r, (V(p).cast<double>() - c).norm());
  if (!(r > 0)) return false;
  H->setZero();
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d q = (V(cloud.points_mm[i]).cast<double>() - c) / r;
    const Eigen::Vector3d n = V(cloud.normals[i]).cast<double>();
    Eigen::Matrix<double, 6, 1> J;
    J.head<3>() = q.cross(n);
    J.tail<3>() = n;
    *H += J * J.transpose();
  }
  *centroid = c;
  *radius = r;
  return true;
}

// Smallest over largest eigenvalue of SelfInformation: near 0 when some
// motion leaves the surface on itself (a plane, a sphere, a cylinder about
// its axis).
double Constrainedness(const PointCloud& cloud) {
  Eigen::Matrix<double, 6, 6> H;
  Eigen::Vector3d c;
  double radius = 0;
  if (!SelfInformation(cloud, &H, &c, &radius)) return 0;
  const auto ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>>(H).eigenvalues();
  return ev[5] > 0 ? ev[0] / ev[5] : 0;
}

}  // namespace

cv::Matx44d KeepPriorAlongWeakMotions(const PointCloud& source, const cv::Matx44d& prior,
                                      const cv::Matx44d& registered, double min_constraint,
                                      int* weak_motions) {
  if (weak_motions) *weak_motions = 0;
  Eigen::Matrix<double, 6, 6> H;
  Eigen::Vector3d c;
  double radius = 0;
  if (!(min_constraint > 0) || !SelfInformation(source, &H, &c, &radius)) return registered;
  // The registration's motion away from the prior, on the source's points
  // (registered = prior · delta), as x = (radius · rotation vector,
  // displacement of the centroid).
  const Eigen::Matrix4d delta = ToEigen(InvertRigid(prior) * registered);
  const Eigen::Matrix3d R = delta.topLeftCorner<3, 3>();
  const Eigen::AngleAxisd turn(R);
  Eigen::Matrix<double, 6, 1> x;
  x.head<3>() = radius * turn.angle() * turn.axis();
  x.tail<3>() = R * c + delta.topRightCorner<3, 1>() - c;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eigen(H);
  const double strongest = eigen.eigenvalues()[5];
  if (!(strongest > 0)) return registered;
  Eigen::Matrix<double, 6, 1> kept = Eigen::Matrix<double, 6, 1>::Zero();
  int weak = 0;
  for (int i = 0; i < 6; ++i) {
    const Eigen::Matrix<double, 6, 1> v = eigen.eigenvectors().col(i);
    if (eigen.eigenvalues()[i] >= min_constraint * strongest)
      kept += v * v.dot(x);
    else
      ++weak;
  }
  if (weak_motions) *weak_motions = weak;
  if (weak == 0) return registered;
  const Eigen::Vector3d w = kept.head<3>() / radius;
  Eigen::Matrix4d moved = Eigen::Matrix4d::Identity();
  if (w.norm() > 0)
    moved.topLeftCorner<3, 3>() = Eigen::AngleAxisd(w.norm(), w / w.norm()).toRotationMatrix();
  moved.topRightCorner<3, 1>() = kept.tail<3>() + c - moved.topLeftCorner<3, 3>() * c;
  return prior * ToCv(moved);
}

RegistrationResult RegisterPair(const ViewCloud& source, const ViewCloud& target,
                                const RegistrationOptions& options) {
  return NoThrow<RegistrationResult>(
      "RegisterPair", RegistrationResult::Status::kFailed, [&]() -> RegistrationResult {
        const auto start = Clock::now();
        RegistrationResult result;
        std::string why;
        if (!options.IsValid(&why)) {
          result.message = "invalid options: " + why;
          return result;
        }
        if (!source.ok() || !target.ok()) {
          result.message = "conditioning failed: " + (source.ok() ? target.error : source.error);
          return result;
        }
        const std::size_t need = static_cast<std::size_t>(options.min_points);
        if (source.coarse.size() < need || target.coarse.size() < need) {
          result.message = "too few points: " + std::to_string(source.coarse.size()) +
                           " (source) and " + std::to_string(target.coarse.size()) +
                           " (target) coarse points, need " + std::to_string(need);
          return result;
        }
        for (const PointCloud* c : {&source.fine, &target.fine}) {
          const Eigen::Vector3d ev = CovarianceEigenvalues(*c);
          if (ev[2] <= 0 || ev[1] / ev[2] < 1e-4) {
            result.message = std::string("degenerate ") +
                             (c == &source.fine ? "source" : "target") +
                             " cloud: its points lie on a line";
            return result;
          }
          if (ev[0] / ev[2] < 1e-4) {
            result.message = std::string("degenerate ") +
                             (c == &source.fine ? "source" : "target") +
                             " cloud: its points lie on a plane, which does not fix the pose";
            return result;
          }
        }
        const bool has_prior = options.coarse.prior_target_from_source.has_value();
        const double constrained =
            std::min(Constrainedness(source.fine), Constrainedness(target.fine));
        constexpr double kMinConstrainedness = 1e-3;
        if (constrained < kMinConstrainedness && !has_prior) {
          result.message =
              "degenerate geometry: a motion leaves the surface on itself (plane, sphere or "
              "surface of "
              "revolution) and there is no prior pose";
          return result;
        }
        // One target index and one strided source for every fine run below.
        const int threads = options.num_threads;
        const PointIndex target_index(target.fine);
        PointCloud strided;
        const PointCloud& fine_source =
            StridedSource(source.fine, options.fine.max_source_points, &strided);
        auto refine = [&](const cv::Matx44d& initial) {
          const auto fine_start = Clock::now();
          RegistrationResult r = IterateFine(fine_source, target, target_index, ToEigen(initial),
                                             options.fine, threads);
          r.time_ms = MsSince(fine_start);
          return r;
        };
        // Fitness and RMSE of a fine pose at the (tighter) fitness gate.
        auto evaluate = [&](RegistrationResult* r) {
          const Overlap o =
              MeasureOverlap(source.fine, target_index, ToEigen(r->target_from_source),
                             options.fitness_distance_mm, options.num_threads);
          r->fitness = o.fitness;
          r->rmse_mm = o.rmse;
          r->inliers = o.inliers;
        };
        // With a prior (the turntable), fine registration from the prior is one
        // candidate; RANSAC's pose replaces it only when it fits clearly better.
        // On symmetric objects (a box turned by 180°, an egg) RANSAC's best
        // hypothesis can score as well as the truth; the turntable settles it.
        // RANSAC must beat the prior's fitness by both margins: a symmetric object
        // (a box turned by 180°) lets a wrong pose fit nearly as well as the truth,
        // while a wrong commanded angle or a moved object leaves the prior's
        // fitness far below the true pose's.
        constexpr double kReplaceGain = 0.1;   // absolute fitness gain
        constexpr double kReplaceRatio = 1.5;  // relative fitness gain
        std::optional<RegistrationResult> from_prior;
        if (has_prior) {
          from_prior = refine(*options.coarse.prior_target_from_source);
          if (from_prior->IsUsable()) evaluate(&*from_prior);
        }
        const RegistrationResult coarse =
            RegisterCoarse(source, target, options.coarse, options.num_threads);
        std::optional<RegistrationResult> from_coarse;
        if (coarse.IsUsable() && !(coarse.prior_kept && from_prior)) {
          from_coarse = refine(coarse.target_from_source);
          if (from_coarse->IsUsable()) evaluate(&*from_coarse);
        }
        const bool prior_ok = from_prior && from_prior->IsUsable();
        const bool coarse_ok = from_coarse && from_coarse->IsUsable();
        if (!prior_ok && !coarse_ok) {
          result = coarse.IsUsable() ? (from_coarse ? *from_coarse : *from_prior) : coarse;
          result.status = RegistrationResult::Status::kFailed;
          result.message = !coarse.IsUsable() ? "coarse registration failed: " + coarse.message
                                              : "fine registration failed: " + result.message;
          result.time_ms = MsSince(start);
          return result;
        }
        const bool use_prior =
            prior_ok && (!coarse_ok || from_coarse->fitness < from_prior->fitness + kReplaceGain ||
                         from_coarse->fitness < from_prior->fitness * kReplaceRatio);
        RegistrationResult fine = use_prior ? *from_prior : *from_coarse;
        fine.prior_kept = use_prior || coarse.prior_kept;
        bool prior_pose_kept = false;
        if (use_prior && options.prior_slide_deg > 0) {
          // ICP that moves far from the prior without fitting better slid along
          // a direction the geometry does not fix (a surface of revolution about
          // the turntable axis): keep the turntable's own pose.
          RegistrationResult at_prior = *from_prior;
          at_prior.target_from_source = *options.coarse.prior_target_from_source;
          evaluate(&at_prior);
          const double moved_deg =
              RotationErrorDeg(from_prior->target_from_source, at_prior.target_from_source);
          if (moved_deg > options.prior_slide_deg &&
              from_prior->fitness < at_prior.fitness + options.prior_slide_gain) {
            fine.slid_target_from_source = from_prior->target_from_source;
            fine.target_from_source = at_prior.target_from_source;
            fine.fitness = at_prior.fitness;
            fine.rmse_mm = at_prior.rmse_mm;
            fine.inliers = at_prior.inliers;
            prior_pose_kept = true;
          }
        }
        int weak_motions = 0;
        if (use_prior && !prior_pose_kept && options.prior_weak_constraint > 0) {
          const cv::Matx44d registered = fine.target_from_source;
          fine.target_from_source =
              KeepPriorAlongWeakMotions(source.fine, *options.coarse.prior_target_from_source,
                                        registered, options.prior_weak_constraint, &weak_motions);
          if (weak_motions > 0) {
            fine.slid_target_from_source = registered;
            fine.weak_motions_kept = weak_motions;
            evaluate(&fine);
          }
        }

        fine.coarse_ms = coarse.time_ms;
        fine.fine_ms =
            (from_prior ? from_prior->time_ms : 0) + (from_coarse ? from_coarse->time_ms : 0);
        fine.correspondences = coarse.correspondences;
        std::string notes = fine.message;
        if (prior_ok && coarse_ok && !use_prior)
          notes += std::string(notes.empty() ? "" : "; ") + "the prior was replaced (fitness " +
                   std::to_string(from_prior->fitness) + " → " +
                   std::to_string(from_coarse->fitness) + ")";
        if (prior_pose_kept)
          notes += std::string(notes.empty() ? "" : "; ") +
                   "fine registration slid away from the prior without fitting better: the prior "
                   "pose is kept";
        if (weak_motions > 0)
          notes += std::string(notes.empty() ? "" : "; ") + std::to_string(weak_motions) +
                   (weak_motions == 1 ? " motion" : " motions") +
                   " the surface barely holds (a body of revolution turning about its axis) "
                   "kept from the prior";
        if (constrained < kMinConstrainedness && !prior_pose_kept && weak_motions == 0)
          notes +=
              std::string(notes.empty() ? "" : "; ") +
              "surface of revolution or similar: the unconstrained motion is kept from the prior";
        // Does the result agree with the prior (then the turntable vouches for it)?
        bool near_prior = false;
        if (has_prior) {
          Eigen::Vector3d c = Eigen::Vector3d::Zero();
          for (const auto& p : source.fine.points_mm) c += V(p).cast<double>();
          c /= static_cast<double>(source.fine.size());
          const Eigen::Matrix4d A = ToEigen(fine.target_from_source);
          const Eigen::Matrix4d B = ToEigen(*options.coarse.prior_target_from_source);
          const double moved = ((A.topLeftCorner<3, 3>() - B.topLeftCorner<3, 3>()) * c +
                                A.topRightCorner<3, 1>() - B.topRightCorner<3, 1>())
                                   .norm();
          near_prior = RotationErrorDeg(fine.target_from_source,
                                        *options.coarse.prior_target_from_source) < 3.0 &&
                       moved < 5.0;
        }
        if (!near_prior && fine.fitness >= options.min_fitness &&
            fine.rmse_mm > options.max_rmse_ratio * options.fitness_distance_mm) {
          fine.status = RegistrationResult::Status::kFailed;
          fine.message = "no overlap: the residuals (RMSE " + std::to_string(fine.rmse_mm) +
                         " mm within " + std::to_string(options.fitness_distance_mm) +
                         " mm) are spread like those of unrelated surfaces";
        } else if (fine.fitness < options.min_fitness) {
          fine.status = RegistrationResult::Status::kFailed;
          fine.message = "no overlap: only " +
                         std::to_string(static_cast<int>(fine.fitness * 100 + 0.5)) +
                         " % of the source lies on the target after registration (need " +
                         std::to_string(static_cast<int>(options.min_fitness * 100 + 0.5)) + " %)";
        } else {
          fine.message = notes;
        }
        fine.time_ms = MsSince(start);
        return fine;
      });
}

}  // namespace craftscan
