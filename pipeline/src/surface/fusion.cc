#include "craftscan/pipeline/surface/fusion.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <utility>

namespace craftscan {
namespace {

// Voxel indices are packed into 21 bits per axis (offset by 2^20), so a key
// is one uint64 and sorting by it groups a voxel's points together.
constexpr std::int64_t kHalfRange = std::int64_t{1} << 20;

bool Fail(const std::string& message, std::string* error) {
  if (error) *error = message;
  return false;
}

bool Finite(const cv::Vec3f& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

bool FusionOptions::IsValid(std::string* why) const {
  if (!(voxel_mm > 0) || !std::isfinite(voxel_mm))
    return Fail("FusionOptions.voxel_mm must be finite and > 0", why);
  if (min_points_per_voxel < 1) return Fail("FusionOptions.min_points_per_voxel must be >= 1", why);
  if (min_views < 1) return Fail("FusionOptions.min_views must be >= 1", why);
  if (!(view_support_mm > 0) || !std::isfinite(view_support_mm))
    return Fail("FusionOptions.view_support_mm must be > 0", why);
  if (!(min_normal_agreement >= 0 && min_normal_agreement <= 1))
    return Fail("FusionOptions.min_normal_agreement must be within 0..1", why);
  return true;
}

PointCloud FuseClouds(const std::vector<PointCloud>& clouds, const FusionOptions& options,
                      std::string* error, FusionStats* stats) {
  FusionStats local_stats;
  FusionStats& s = stats ? *stats : local_stats;
  s = FusionStats{};
  if (error) error->clear();
  std::string why;
  if (!options.IsValid(&why)) {
    Fail("fusion: " + why, error);
    return {};
  }
  bool all_normals = true, all_colors = true, any_points = false;
  std::size_t total = 0;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    if (!clouds[c].IsValid(&why)) {
      Fail("fusion: cloud " + std::to_string(c) + " is invalid: " + why, error);
      return {};
    }
    if (clouds[c].empty()) continue;
    any_points = true;
    all_normals = all_normals && clouds[c].HasNormals();
    all_colors = all_colors && clouds[c].HasColors();
    total += clouds[c].size();
  }
  s.input_points = total;
  if (!any_points) {
    Fail("fusion: no input points (" + std::to_string(clouds.size()) + " clouds, all empty)",
         error);
    return {};
  }
  if (total >= std::numeric_limits<std::uint32_t>::max()) {
    Fail("fusion: too many input points (" + std::to_string(total) + ")", error);
    return {};
  }

  // (voxel key, global point index), sorted: deterministic grouping.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> where;  // global index → (cloud, point)
  keyed.reserve(total);
  where.reserve(total);
  const double inv_voxel = 1.0 / options.voxel_mm;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    const auto& points = clouds[c].points_mm;
    for (std::size_t i = 0; i < points.size(); ++i) {
      const cv::Vec3f& p = points[i];
      if (!Finite(p)) {
        ++s.nonfinite_points;
        continue;
      }
      std::uint64_t key = 0;
      bool in_range = true;
      for (int a = 0; a < 3; ++a) {
        const double cell = std::floor(p[a] * inv_voxel);
        if (!(cell >= -kHalfRange && cell < kHalfRange)) {
          in_range = false;
          break;
        }
        key =
            (key << 21) | static_cast<std::uint64_t>(static_cast<std::int64_t>(cell) + kHalfRange);
      }
      if (!in_range) {
        ++s.out_of_range_points;
        continue;
      }
      keyed.emplace_back(key, static_cast<std::uint32_t>(where.size()));
      where.emplace_back(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(i));
    }
  }
  if (keyed.empty()) {
    Fail("fusion: no finite input point within range (" + std::to_string(s.nonfinite_points) +
             " non-finite, " + std::to_string(s.out_of_range_points) + " out of range)",
         error);
    return {};
  }
  // x is packed first (highest bits), so this orders by x, then y, then z.
  std::sort(keyed.begin(), keyed.end());

  PointCloud out;
  std::vector<std::uint64_t> out_keys;                 // voxel of each output point (sorted)
  std::vector<std::pair<cv::Vec3d, double>> out_sums;  // Σ points, count per output voxel
  std::vector<std::uint64_t> out_views;                // bit c: cloud c has points here
  std::size_t kept_points = 0;
  for (std::size_t begin = 0; begin < keyed.size();) {
    std::size_t end = begin + 1;
    while (end < keyed.size() && keyed[end].first == keyed[begin].first) ++end;
    const std::size_t count = end - begin;
    if (count < static_cast<std::size_t>(options.min_points_per_voxel)) {
      s.sparse_voxel_points += count;
      begin = end;
      continue;
    }
    cv::Vec3d sum_p(0, 0, 0), sum_n(0, 0, 0), sum_c(0, 0, 0);
    cv::Vec3d first_n(0, 0, 0);
    bool have_first_n = false;
    std::size_t normals = 0;
    std::uint64_t views = 0;
    for (std::size_t k = begin; k < end; ++k) {
      const auto [c, i] = where[keyed[k].second];
      views |= std::uint64_t{1} << std::min<std::uint32_t>(c, 63);
      const PointCloud& cloud = clouds[c];
      sum_p += cv::Vec3d(cloud.points_mm[i]);
      if (all_normals) {
        const cv::Vec3f& nf = cloud.normals[i];
        if (Finite(nf)) {
          cv::Vec3d n(nf);
          if (!have_first_n) {
            first_n = n;
            have_first_n = true;
          }
          if ((normals > 0 ? sum_n : first_n).dot(n) < 0) n = -n;
          sum_n += n;
          ++normals;
        }
      }
      if (all_colors) sum_c += cv::Vec3d(cloud.colors_rgb[i]);
    }
    const double inv = 1.0 / static_cast<double>(count);
    const cv::Vec3d mean = sum_p * inv;
    out.points_mm.emplace_back(static_cast<float>(mean[0]), static_cast<float>(mean[1]),
                               static_cast<float>(mean[2]));
    out_keys.push_back(keyed[begin].first);
    out_sums.emplace_back(sum_p, static_cast<double>(count));
    out_views.push_back(views);
    if (all_normals) {
      cv::Vec3d n = have_first_n ? first_n : cv::Vec3d(0, 0, 1);
      const double length = cv::norm(sum_n);
      if (normals > 0 && length > options.min_normal_agreement * static_cast<double>(normals) &&
          length > 0)
        n = sum_n / length;
      else if (cv::norm(n) > 0)
        n /= cv::norm(n);
      else
        n = cv::Vec3d(0, 0, 1);
      out.normals.emplace_back(static_cast<float>(n[0]), static_cast<float>(n[1]),
                               static_cast<float>(n[2]));
    }
    if (all_colors) {
      cv::Vec3b rgb;
      for (int a = 0; a < 3; ++a)
        rgb[a] = static_cast<std::uint8_t>(std::clamp(std::lround(sum_c[a] * inv), 0L, 255L));
      out.colors_rgb.push_back(rgb);
    }
    kept_points += count;
    begin = end;
  }
  s.output_points = out.size();
  if (out.empty()) {
    Fail("fusion: no voxel holds min_points_per_voxel = " +
             std::to_string(options.min_points_per_voxel) + " points (" +
             std::to_string(keyed.size()) + " finite points)",
         error);
    return {};
  }
  s.mean_points_per_voxel = static_cast<double>(kept_points) / static_cast<double>(out.size());
  constexpr std::uint64_t kMask = (std::uint64_t{1} << 21) - 1;
  if (options.min_views > 1) {
    std::unordered_map<std::uint64_t, std::size_t> index;
    index.reserve(out_keys.size() * 2);
    for (std::size_t v = 0; v < out_keys.size(); ++v) index.emplace(out_keys[v], v);
    const std::int64_t r = std::max<std::int64_t>(
        1, std::llround(std::ceil(options.view_support_mm / options.voxel_mm)));
    std::vector<char> keep(out_keys.size(), 0);
    for (std::size_t v = 0; v < out_keys.size(); ++v) {
      const std::int64_t cx = static_cast<std::int64_t>((out_keys[v] >> 42) & kMask);
      const std::int64_t cy = static_cast<std::int64_t>((out_keys[v] >> 21) & kMask);
      const std::int64_t cz = static_cast<std::int64_t>(out_keys[v] & kMask);
      std::uint64_t views = out_views[v];
      for (std::int64_t dx = -r; dx <= r && std::popcount(views) < options.min_views; ++dx)
        for (std::int64_t dy = -r; dy <= r; ++dy)
          for (std::int64_t dz = -r; dz <= r; ++dz) {
            const std::int64_t x = cx + dx, y = cy + dy, z = cz + dz;
            if (x < 0 || y < 0 || z < 0 || x > static_cast<std::int64_t>(kMask) ||
                y > static_cast<std::int64_t>(kMask) || z > static_cast<std::int64_t>(kMask))
              continue;
            const auto it =
                index.find((static_cast<std::uint64_t>(x) << 42) |
                           (static_cast<std::uint64_t>(y) << 21) | static_cast<std::uint64_t>(z));
            if (it != index.end()) views |= out_views[it->second];
          }
      keep[v] = std::popcount(views) >= options.min_views;
    }
    PointCloud kept;
    std::vector<std::uint64_t> kept_keys;
    std::vector<std::pair<cv::Vec3d, double>> kept_sums;
    for (std::size_t v = 0; v < out_keys.size(); ++v) {
      if (!keep[v]) {
        ++s.single_view_voxels;
        continue;
      }
      kept.points_mm.push_back(out.points_mm[v]);
      if (out.HasNormals()) kept.normals.push_back(out.normals[v]);
      if (out.HasColors()) kept.colors_rgb.push_back(out.colors_rgb[v]);
      kept_keys.push_back(out_keys[v]);
      kept_sums.push_back(out_sums[v]);
    }
    out = std::move(kept);
    out_keys = std::move(kept_keys);
    out_sums = std::move(kept_sums);
    s.output_points = out.size();
    if (out.empty()) {
      Fail("fusion: no voxel is supported by min_views = " + std::to_string(options.min_views) +
               " clouds",
           error);
      return {};
    }
  }
  if (options.refine_along_normal && out.HasNormals()) {
    std::vector<cv::Vec3f> refined(out.size());
    for (std::size_t v = 0; v < out.size(); ++v) {
      const std::uint64_t key = out_keys[v];
      const std::int64_t cx = static_cast<std::int64_t>((key >> 42) & kMask);
      const std::int64_t cy = static_cast<std::int64_t>((key >> 21) & kMask);
      const std::int64_t cz = static_cast<std::int64_t>(key & kMask);
      cv::Vec3d sum(0, 0, 0);
      double count = 0;
      for (std::int64_t dx = -1; dx <= 1; ++dx)
        for (std::int64_t dy = -1; dy <= 1; ++dy)
          for (std::int64_t dz = -1; dz <= 1; ++dz) {
            const std::int64_t x = cx + dx, y = cy + dy, z = cz + dz;
            if (x < 0 || y < 0 || z < 0 || x > static_cast<std::int64_t>(kMask) ||
                y > static_cast<std::int64_t>(kMask) || z > static_cast<std::int64_t>(kMask))
              continue;
            const std::uint64_t k = (static_cast<std::uint64_t>(x) << 42) |
                                    (static_cast<std::uint64_t>(y) << 21) |
                                    static_cast<std::uint64_t>(z);
            const auto it = std::lower_bound(out_keys.begin(), out_keys.end(), k);
            if (it == out_keys.end() || *it != k) continue;
            const auto& [block_sum, block_count] =
                out_sums[static_cast<std::size_t>(it - out_keys.begin())];
            sum += block_sum;
            count += block_count;
          }
      const cv::Vec3d p(out.points_mm[v]);
      const cv::Vec3d n(out.normals[v]);
      const cv::Vec3d moved = p + n * n.dot(sum / count - p);
      refined[v] = cv::Vec3f(static_cast<float>(moved[0]), static_cast<float>(moved[1]),
                             static_cast<float>(moved[2]));
    }
    out.points_mm.swap(refined);
  }
  return out;
}

}  // namespace craftscan
