#include "craftscan/pipeline/surface/fusion.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <numbers>
#include <unordered_map>
#include <utility>

#include "common/parallel.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

// Voxel indices are packed into 21 bits per axis (offset by 2^20), so a key
// is one uint64 and sorting by it groups a voxel's points together.
constexpr std::int64_t kHalfRange = std::int64_t{1} << 20;

bool Finite(const cv::Vec3f& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

constexpr std::uint64_t kMask = (std::uint64_t{1} << 21) - 1;

// The key of the voxel (dx, dy, dz) cells from `key`; false outside the grid.
bool NeighbourKey(std::uint64_t key, std::int64_t dx, std::int64_t dy, std::int64_t dz,
                  std::uint64_t* neighbour) {
  const std::int64_t x = static_cast<std::int64_t>((key >> 42) & kMask) + dx;
  const std::int64_t y = static_cast<std::int64_t>((key >> 21) & kMask) + dy;
  const std::int64_t z = static_cast<std::int64_t>(key & kMask) + dz;
  if (x < 0 || y < 0 || z < 0 || x > static_cast<std::int64_t>(kMask) ||
      y > static_cast<std::int64_t>(kMask) || z > static_cast<std::int64_t>(kMask))
    return false;
  *neighbour = (static_cast<std::uint64_t>(x) << 42) | (static_cast<std::uint64_t>(y) << 21) |
               static_cast<std::uint64_t>(z);
  return true;
}

// What the inputs hold: the per-point attributes every non-empty cloud has.
struct InputSummary {
  bool all_normals = true;
  bool all_colors = true;
};

// Validates options and clouds and counts the input points.
bool CheckInputs(const std::vector<PointCloud>& clouds, const FusionOptions& options,
                 InputSummary* summary, FusionStats* s, std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) return Fail(error, "fusion: " + why);
  bool any_points = false;
  std::size_t total = 0;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    if (!clouds[c].IsValid(&why)) {
      return Fail(error, "fusion: cloud " + std::to_string(c) + " is invalid: " + why);
    }
    if (clouds[c].empty()) continue;
    any_points = true;
    summary->all_normals = summary->all_normals && clouds[c].HasNormals();
    summary->all_colors = summary->all_colors && clouds[c].HasColors();
    total += clouds[c].size();
  }
  s->input_points = total;
  if (!any_points) {
    return Fail(
        error, "fusion: no input points (" + std::to_string(clouds.size()) + " clouds, all empty)");
  }
  if (total >= std::numeric_limits<std::uint32_t>::max()) {
    return Fail(error, "fusion: too many input points (" + std::to_string(total) + ")");
  }
  return true;
}

// Every finite, in-range input point with its voxel key, sorted by key (then
// by global index): deterministic grouping.
struct KeyedPoints {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;  // (voxel key, global index)
  std::vector<std::pair<std::uint32_t, std::uint32_t>> where;  // global index → (cloud, point)
};

KeyedPoints KeyPoints(const std::vector<PointCloud>& clouds, const FusionOptions& options,
                      FusionStats* s) {
  KeyedPoints out;
  out.keyed.reserve(s->input_points);
  out.where.reserve(s->input_points);
  const double inv_voxel = 1.0 / options.voxel_mm;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    const auto& points = clouds[c].points_mm;
    for (std::size_t i = 0; i < points.size(); ++i) {
      const cv::Vec3f& p = points[i];
      if (!Finite(p)) {
        ++s->nonfinite_points;
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
        ++s->out_of_range_points;
        continue;
      }
      out.keyed.emplace_back(key, static_cast<std::uint32_t>(out.where.size()));
      out.where.emplace_back(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(i));
    }
  }
  // x is packed first (highest bits), so this orders by x, then y, then z.
  std::sort(out.keyed.begin(), out.keyed.end());
  return out;
}

// The fused cloud, one point per kept voxel, with each voxel's key (sorted),
// point sum and count, and the clouds that have points in it (bit c).
struct Voxels {
  PointCloud cloud;
  std::vector<std::uint64_t> keys;
  std::vector<std::pair<cv::Vec3d, double>> sums;
  std::vector<std::uint64_t> views;
  // With FusionOptions::local_surface_support: each voxel's points per
  // cloud (mean), voxel v's at view_points[view_start[v] … view_start[v + 1]).
  std::vector<std::uint32_t> view_start;
  std::vector<std::pair<std::uint32_t, cv::Vec3f>> view_points;
};

// Averages the points (normals, colours) of every voxel holding at least
// min_points_per_voxel points.
Voxels AverageVoxels(const std::vector<PointCloud>& clouds, const KeyedPoints& points,
                     const FusionOptions& options, const InputSummary& summary, FusionStats* s) {
  const auto& keyed = points.keyed;
  Voxels out;
  std::size_t kept_points = 0;
  const bool per_view = options.local_surface_support && options.min_views > 1;
  int view_count = 0;
  for (std::size_t begin = 0; begin < keyed.size();) {
    std::size_t end = begin + 1;
    while (end < keyed.size() && keyed[end].first == keyed[begin].first) ++end;
    const std::size_t count = end - begin;
    if (count < static_cast<std::size_t>(options.min_points_per_voxel)) {
      s->sparse_voxel_points += count;
      begin = end;
      continue;
    }
    cv::Vec3d sum_p(0, 0, 0), sum_n(0, 0, 0), sum_c(0, 0, 0);
    cv::Vec3d first_n(0, 0, 0);
    bool have_first_n = false;
    std::size_t normals = 0;
    std::uint64_t views = 0;
    if (per_view) out.view_start.push_back(static_cast<std::uint32_t>(out.view_points.size()));
    const std::size_t first_view_point = out.view_points.size();
    for (std::size_t k = begin; k < end; ++k) {
      const auto [c, i] = points.where[keyed[k].second];
      views |= std::uint64_t{1} << std::min<std::uint32_t>(c, 63);
      const PointCloud& cloud = clouds[c];
      sum_p += cv::Vec3d(cloud.points_mm[i]);
      if (per_view) {  // a voxel's points are sorted by cloud: one run each
        if (out.view_points.size() == first_view_point || out.view_points.back().first != c) {
          if (out.view_points.size() > first_view_point) {
            auto& [last, mean] = out.view_points.back();
            mean /= static_cast<float>(view_count);
          }
          out.view_points.emplace_back(c, cv::Vec3f(0, 0, 0));
          view_count = 0;
        }
        out.view_points.back().second += cloud.points_mm[i];
        ++view_count;
      }
      if (summary.all_normals) {
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
      if (summary.all_colors) sum_c += cv::Vec3d(cloud.colors_rgb[i]);
    }
    if (per_view && view_count > 0) out.view_points.back().second /= static_cast<float>(view_count);
    const double inv = 1.0 / static_cast<double>(count);
    const cv::Vec3d mean = sum_p * inv;
    out.cloud.points_mm.emplace_back(static_cast<float>(mean[0]), static_cast<float>(mean[1]),
                                     static_cast<float>(mean[2]));
    out.keys.push_back(keyed[begin].first);
    out.sums.emplace_back(sum_p, static_cast<double>(count));
    out.views.push_back(views);
    if (summary.all_normals) {
      cv::Vec3d n = have_first_n ? first_n : cv::Vec3d(0, 0, 1);
      const double length = cv::norm(sum_n);
      if (normals > 0 && length > options.min_normal_agreement * static_cast<double>(normals) &&
          length > 0)
        n = sum_n / length;
      else if (cv::norm(n) > 0)
        n /= cv::norm(n);
      else
        n = cv::Vec3d(0, 0, 1);
      out.cloud.normals.emplace_back(static_cast<float>(n[0]), static_cast<float>(n[1]),
                                     static_cast<float>(n[2]));
    }
    if (summary.all_colors) {
      cv::Vec3b rgb;
      for (int a = 0; a < 3; ++a)
        rgb[a] = static_cast<std::uint8_t>(std::clamp(std::lround(sum_c[a] * inv), 0L, 255L));
      out.cloud.colors_rgb.push_back(rgb);
    }
    kept_points += count;
    begin = end;
  }
  if (per_view) out.view_start.push_back(static_cast<std::uint32_t>(out.view_points.size()));
  s->output_points = out.cloud.size();
  if (!out.cloud.empty()) {
    s->mean_points_per_voxel =
        static_cast<double>(kept_points) / static_cast<double>(out.cloud.size());
  }
  return out;
}

// Keeps the voxels v with keep[v]; returns how many were dropped.
std::size_t FilterVoxels(const std::vector<char>& keep, Voxels* voxels) {
  const PointCloud& out = voxels->cloud;
  Voxels kept;
  std::size_t dropped = 0;
  for (std::size_t v = 0; v < voxels->keys.size(); ++v) {
    if (!keep[v]) {
      ++dropped;
      continue;
    }
    kept.cloud.points_mm.push_back(out.points_mm[v]);
    if (out.HasNormals()) kept.cloud.normals.push_back(out.normals[v]);
    if (out.HasColors()) kept.cloud.colors_rgb.push_back(out.colors_rgb[v]);
    kept.keys.push_back(voxels->keys[v]);
    kept.sums.push_back(voxels->sums[v]);
    kept.views.push_back(voxels->views[v]);
  }
  *voxels = std::move(kept);  // the per-view points go: only multi-view support reads them
  return dropped;
}

// The key of the cell of edge `cell_mm` holding voxel `key`.
std::uint64_t CellKey(std::uint64_t key, double voxel_mm, double cell_mm) {
  const double ratio = voxel_mm / cell_mm;
  std::uint64_t cell = 0;
  for (int shift : {42, 21, 0}) {
    const auto i = static_cast<std::int64_t>((key >> shift) & kMask) - kHalfRange;
    const auto c = static_cast<std::int64_t>(std::floor(static_cast<double>(i) * ratio));
    cell = (cell << 21) | static_cast<std::uint64_t>(c + kHalfRange);
  }
  return cell;
}

// The clouds with points in the 3×3×3 cells around `cell` (cells: cell key →
// clouds, bit c).
std::uint64_t ViewsAroundCell(const std::unordered_map<std::uint64_t, std::uint64_t>& cells,
                              std::uint64_t cell) {
  std::uint64_t views = 0;
  for (std::int64_t dx = -1; dx <= 1; ++dx)
    for (std::int64_t dy = -1; dy <= 1; ++dy)
      for (std::int64_t dz = -1; dz <= 1; ++dz) {
        std::uint64_t neighbour = 0;
        if (!NeighbourKey(cell, dx, dy, dz, &neighbour)) continue;
        const auto it = cells.find(neighbour);
        if (it != cells.end()) views |= it->second;
      }
  return views;
}

// The clouds (bit c) whose camera looked at the surface at p, normal n,
// within max_incidence_deg of the normal.
std::uint64_t FacingCameras(const cv::Vec3f& p, const cv::Vec3f& n,
                            const std::vector<cv::Vec3d>& centers, double max_incidence_deg) {
  const double cos_max = std::cos(max_incidence_deg * std::numbers::pi / 180);
  const cv::Vec3d normal(n);
  std::uint64_t facing = 0;
  for (std::size_t c = 0; c < centers.size(); ++c) {
    const cv::Vec3d ray = centers[c] - cv::Vec3d(p);
    const double length = cv::norm(ray);
    if (length > 0 && normal.dot(ray) > cos_max * length)
      facing |= std::uint64_t{1} << std::min<std::size_t>(c, 63);
  }
  return facing;
}

// Drops voxels seen by fewer than min_views clouds within view_support_mm
// (and, with view_support_normal_mm, near the tangent plane), unless no
// other cloud is within lone_view_radius_mm, only their own camera faced
// them (sole_view_incidence_deg) or every other camera is behind them
// (hidden_view_incidence_deg).
void KeepMultiViewVoxels(const FusionOptions& options, const std::vector<cv::Vec3d>* centers,
                         Voxels* voxels, FusionStats* s) {
  const std::vector<std::uint64_t>& keys = voxels->keys;
  const PointCloud& cloud = voxels->cloud;
  std::unordered_map<std::uint64_t, std::size_t> index;
  index.reserve(keys.size() * 2);
  for (std::size_t v = 0; v < keys.size(); ++v) index.emplace(keys[v], v);
  const std::int64_t r = std::max<std::int64_t>(
      1, std::llround(std::ceil(options.view_support_mm / options.voxel_mm)));
  const bool along_normal = options.view_support_normal_mm > 0 && cloud.HasNormals();
  const std::int64_t r_plane = std::llround(std::ceil(options.plane_support_mm / options.voxel_mm));
  const float kPlaneCos = static_cast<float>(std::cos(25.0 * M_PI / 180));
  const auto tol = static_cast<float>(options.view_support_normal_mm);
  // Supports v: w lies near v's tangent plane or v near w's.
  const auto on_plane = [&](std::size_t v, std::size_t w) {
    const cv::Vec3f d = cloud.points_mm[w] - cloud.points_mm[v];
    return std::abs(d.dot(cloud.normals[v])) <= tol || std::abs(d.dot(cloud.normals[w])) <= tol;
  };
  // Calls fn(w) for every voxel w in the cube of `radius` voxels around v
  // (v included) while fn returns true.
  const auto for_block = [&](std::size_t v, std::int64_t radius, auto&& fn) {
    for (std::int64_t dx = -radius; dx <= radius; ++dx)
      for (std::int64_t dy = -radius; dy <= radius; ++dy)
        for (std::int64_t dz = -radius; dz <= radius; ++dz) {
          std::uint64_t neighbour = 0;
          if (!NeighbourKey(keys[v], dx, dy, dz, &neighbour)) continue;
          const auto it = index.find(neighbour);
          if (it != index.end() && !fn(it->second)) return;
        }
  };
  const double lone = options.lone_view_radius_mm;
  std::unordered_map<std::uint64_t, std::uint64_t> cells;  // cell → clouds
  if (lone > 0)
    for (std::size_t v = 0; v < keys.size(); ++v)
      cells[CellKey(keys[v], options.voxel_mm, lone)] |= voxels->views[v];

  const bool with_cameras = centers && !centers->empty() && cloud.HasNormals();
  const bool sole = options.sole_view_incidence_deg > 0 && with_cameras;
  const bool hidden = options.hidden_view_incidence_deg > 0 && with_cameras;
  // Just under 90°: a camera in the tangent plane itself sees nothing.
  constexpr double kInFrontDeg = 89.99;
  const cv::Vec3f up(static_cast<float>(options.platter[0]), static_cast<float>(options.platter[1]),
                     static_cast<float>(options.platter[2]));
  const bool shadow = options.platter_shadow_mm > 0 && cloud.HasNormals() && cv::norm(up) > 0.5;
  const auto cos_down =
      static_cast<float>(std::cos(options.platter_shadow_normal_deg * std::numbers::pi / 180));
  // Faces the platter from just above it: no exception for lack of support.
  const auto in_shadow = [&](std::size_t v) {
    const cv::Vec3f& p = cloud.points_mm[v];
    return p.dot(up) + options.platter[3] < options.platter_shadow_mm &&
           cloud.normals[v].dot(up) <= -cos_down;
  };
  // Local-surface support (FusionOptions::local_surface_support): each
  // cloud's points in the block around v, on v's side of any edge, their
  // offsets along v's normal; the cloud supports v when their median is
  // within tolerance. Clouds with fewer points there, or whose camera saw
  // v's surface at a grazing angle, support v as below (any point near
  // either tangent plane, or being v's own).
  const bool local =
      options.local_surface_support && along_normal && voxels->view_start.size() == keys.size() + 1;
  std::vector<std::uint64_t> local_views;
  if (local) {
    const auto same_side =
        static_cast<float>(std::cos(options.local_support_normal_deg * std::numbers::pi / 180));
    const bool grazing = options.local_support_incidence_deg > 0 && with_cameras;
    local_views.resize(keys.size());
    Parallel(options.num_threads).For(0, static_cast<int>(keys.size()), [&](int v0, int v1) {
      std::array<std::vector<float>, 64> per_cloud;
      for (std::size_t v = static_cast<std::size_t>(v0); v < static_cast<std::size_t>(v1); ++v) {
        std::uint64_t seen = 0, near_plane = voxels->views[v];
        const cv::Vec3f& pv = cloud.points_mm[v];
        const cv::Vec3f& nv = cloud.normals[v];
        for_block(v, r, [&](std::size_t w) {
          if (w != v && on_plane(v, w)) near_plane |= voxels->views[w];
          // Another face (the far wall of a groove, the other side of an
          // edge) is not the surface v is on.
          if (nv.dot(cloud.normals[w]) < same_side) return true;
          for (std::uint32_t k = voxels->view_start[w]; k < voxels->view_start[w + 1]; ++k) {
            const auto& [c, p] = voxels->view_points[k];
            const std::uint32_t slot = std::min<std::uint32_t>(c, 63);
            if (!(seen >> slot & 1)) per_cloud[slot].clear();
            seen |= std::uint64_t{1} << slot;
            per_cloud[slot].push_back((p - pv).dot(nv));
          }
          return true;
        });
        const std::uint64_t facing =
            grazing ? FacingCameras(pv, nv, *centers, options.local_support_incidence_deg)
                    : ~std::uint64_t{0};
        std::uint64_t supported = 0;
        for (std::uint64_t rest = seen; rest != 0; rest &= rest - 1) {
          const int slot = std::countr_zero(rest);
          const std::uint64_t bit = std::uint64_t{1} << slot;
          std::vector<float>& o = per_cloud[static_cast<std::size_t>(slot)];
          if ((facing & bit) && o.size() >= static_cast<std::size_t>(options.min_local_points)) {
            const auto middle = o.begin() + static_cast<std::ptrdiff_t>(o.size() / 2);
            std::nth_element(o.begin(), middle, o.end());
            if (std::abs(*middle) <= tol) supported |= bit;
          } else if (near_plane & bit) {
            supported |= bit;
          }
        }
        local_views[v] = supported;
      }
    });
  }
  std::vector<char> keep(keys.size(), 0);
  for (std::size_t v = 0; v < keys.size(); ++v) {
    std::uint64_t views = voxels->views[v];
    if (local) {
      views = local_views[v];
    } else {
      for_block(v, r, [&](std::size_t w) {
        const std::uint64_t more = voxels->views[w] & ~views;
        if (more && (!along_normal || on_plane(v, w))) views |= more;
        return std::popcount(views) < options.min_views;
      });
    }
    // Sparse but consistent: another view's points farther along the
    // surface, each on the other's tangent plane with normals alike, and
    // around the voxel, not only to one side of it (a face one view saw
    // squarely and the others obliquely, their samples a few millimetres
    // apart; a surface that stops at an edge or a silhouette is not carried
    // past it).
    if (std::popcount(views) < options.min_views && along_normal && r_plane > r) {
      std::uint64_t plane_views = 0;
      cv::Vec3f around(0, 0, 0);
      int n_around = 0;
      const cv::Vec3f& nv = cloud.normals[v];
      for_block(v, r_plane, [&](std::size_t w) {
        const std::uint64_t more = voxels->views[w] & ~voxels->views[v];
        if (!more) return true;
        const cv::Vec3f d = cloud.points_mm[w] - cloud.points_mm[v];
        if (std::abs(d.dot(nv)) > tol || std::abs(d.dot(cloud.normals[w])) > tol ||
            nv.dot(cloud.normals[w]) < kPlaneCos)
          return true;
        const cv::Vec3f along = d - d.dot(nv) * nv;
        const float length = static_cast<float>(cv::norm(along));
        if (length <= 0) return true;
        around += along / length;
        ++n_around;
        plane_views |= more;
        return true;
      });
      if (n_around >= 2 && cv::norm(around) < 0.5 * n_around &&
          std::popcount(views | plane_views) >= options.min_views) {
        views |= plane_views;
        ++s->plane_supported_voxels;
      }
    }
    keep[v] = std::popcount(views) >= options.min_views;
    if (!keep[v] && shadow && in_shadow(v)) {
      ++s->platter_shadow_voxels;
      continue;
    }
    if (!keep[v] && lone > 0) {
      const std::uint64_t around = ViewsAroundCell(cells, CellKey(keys[v], options.voxel_mm, lone));
      if ((around & ~voxels->views[v]) == 0) {
        keep[v] = 1;
        ++s->lone_view_voxels;
      }
    }
    if (!keep[v] && sole) {
      const std::uint64_t own = voxels->views[v];
      const std::uint64_t facing = FacingCameras(cloud.points_mm[v], cloud.normals[v], *centers,
                                                 options.sole_view_incidence_deg);
      if ((facing & own) != 0 && (facing & ~own) == 0) {
        keep[v] = 1;
        ++s->sole_view_voxels;
      }
    }
    if (!keep[v] && hidden) {
      const std::uint64_t own = voxels->views[v];
      const cv::Vec3f& p = cloud.points_mm[v];
      const cv::Vec3f& n = cloud.normals[v];
      if ((FacingCameras(p, n, *centers, options.hidden_view_incidence_deg) & own) != 0 &&
          (FacingCameras(p, n, *centers, kInFrontDeg) & ~own) == 0) {
        keep[v] = 1;
        ++s->hidden_view_voxels;
      }
    }
  }
  s->single_view_voxels += FilterVoxels(keep, voxels);
  s->output_points = voxels->cloud.size();
}

// Keeps the voxels whose cluster (cells of cluster_gap_mm joined by the
// 26-neighbourhood, union-find) holds at least min_cluster_fraction × the
// largest cluster's voxels.
void KeepLargeClusters(const FusionOptions& options, Voxels* voxels, FusionStats* s) {
  const std::vector<std::uint64_t>& keys = voxels->keys;
  const auto cell_of = [&options](std::uint64_t key) {
    return CellKey(key, options.voxel_mm, options.cluster_gap_mm);
  };
  std::unordered_map<std::uint64_t, std::size_t> cells;  // cell key → cell index
  std::vector<std::size_t> cell_of_voxel(keys.size());
  std::vector<std::uint64_t> cell_keys;
  for (std::size_t v = 0; v < keys.size(); ++v) {
    const std::uint64_t c = cell_of(keys[v]);
    const auto [it, added] = cells.emplace(c, cell_keys.size());
    if (added) cell_keys.push_back(c);
    cell_of_voxel[v] = it->second;
  }
  std::vector<std::size_t> parent(cell_keys.size());
  for (std::size_t c = 0; c < parent.size(); ++c) parent[c] = c;
  const auto find = [&](std::size_t c) {
    while (parent[c] != c) c = parent[c] = parent[parent[c]];
    return c;
  };
  for (std::size_t c = 0; c < cell_keys.size(); ++c)
    for (std::int64_t dx = -1; dx <= 1; ++dx)
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          std::uint64_t neighbour = 0;
          if (!NeighbourKey(cell_keys[c], dx, dy, dz, &neighbour)) continue;
          const auto it = cells.find(neighbour);
          if (it != cells.end()) parent[find(it->second)] = find(c);
        }
  std::vector<std::size_t> size(cell_keys.size(), 0);
  for (std::size_t v = 0; v < keys.size(); ++v) ++size[find(cell_of_voxel[v])];
  std::size_t largest = 0;
  for (std::size_t c = 0; c < size.size(); ++c) {
    if (size[c] > 0) ++s->clusters;
    largest = std::max(largest, size[c]);
  }
  const double min_size = options.min_cluster_fraction * static_cast<double>(largest);
  std::vector<char> keep(keys.size());
  for (std::size_t v = 0; v < keys.size(); ++v)
    keep[v] = static_cast<double>(size[find(cell_of_voxel[v])]) >= min_size;
  s->small_cluster_voxels += FilterVoxels(keep, voxels);
  s->output_points = voxels->cloud.size();
}

// Moves each point along its normal to the plane through the mean of the
// 3×3×3 voxels around it.
void RefineAlongNormals(Voxels* voxels) {
  PointCloud& out = voxels->cloud;
  const std::vector<std::uint64_t>& keys = voxels->keys;
  std::vector<cv::Vec3f> refined(out.size());
  for (std::size_t v = 0; v < out.size(); ++v) {
    cv::Vec3d sum(0, 0, 0);
    double count = 0;
    for (std::int64_t dx = -1; dx <= 1; ++dx)
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          std::uint64_t k = 0;
          if (!NeighbourKey(keys[v], dx, dy, dz, &k)) continue;
          const auto it = std::lower_bound(keys.begin(), keys.end(), k);
          if (it == keys.end() || *it != k) continue;
          const auto& [block_sum, block_count] =
              voxels->sums[static_cast<std::size_t>(it - keys.begin())];
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

}  // namespace

bool FusionOptions::IsValid(std::string* why) const {
  if (!(voxel_mm > 0) || !std::isfinite(voxel_mm))
    return Fail(why, "FusionOptions.voxel_mm must be finite and > 0");
  if (min_points_per_voxel < 1) return Fail(why, "FusionOptions.min_points_per_voxel must be >= 1");
  if (min_views < 1) return Fail(why, "FusionOptions.min_views must be >= 1");
  if (min_local_points < 1) return Fail(why, "FusionOptions.min_local_points must be >= 1");
  if (num_threads < 1) return Fail(why, "FusionOptions.num_threads must be >= 1");
  if (!(local_support_normal_deg > 0 && local_support_normal_deg <= 180))
    return Fail(why, "FusionOptions.local_support_normal_deg must be in (0, 180]");
  if (!(local_support_incidence_deg >= 0 && local_support_incidence_deg < 90))
    return Fail(why, "FusionOptions.local_support_incidence_deg must be in [0, 90)");
  if (!(view_support_mm > 0) || !std::isfinite(view_support_mm))
    return Fail(why, "FusionOptions.view_support_mm must be > 0");
  if (!(view_support_normal_mm >= 0) || !std::isfinite(view_support_normal_mm))
    return Fail(why, "FusionOptions.view_support_normal_mm must be finite and >= 0");
  if (!(plane_support_mm >= 0) || !std::isfinite(plane_support_mm) || plane_support_mm > 20)
    return Fail(why, "FusionOptions.plane_support_mm must be in [0, 20]");
  if (!(lone_view_radius_mm >= 0) || !std::isfinite(lone_view_radius_mm))
    return Fail(why, "FusionOptions.lone_view_radius_mm must be finite and >= 0");
  if (!(sole_view_incidence_deg >= 0 && sole_view_incidence_deg < 90))
    return Fail(why, "FusionOptions.sole_view_incidence_deg must be in [0, 90)");
  if (!(hidden_view_incidence_deg >= 0 && hidden_view_incidence_deg < 90))
    return Fail(why, "FusionOptions.hidden_view_incidence_deg must be in [0, 90)");
  if (!(min_normal_agreement >= 0 && min_normal_agreement <= 1))
    return Fail(why, "FusionOptions.min_normal_agreement must be within 0..1");
  if (!(min_cluster_fraction >= 0 && min_cluster_fraction <= 1))
    return Fail(why, "FusionOptions.min_cluster_fraction must be within 0..1");
  if (!(platter_shadow_mm >= 0) || !std::isfinite(platter_shadow_mm))
    return Fail(why, "FusionOptions.platter_shadow_mm must be finite and >= 0");
  if (!(platter_shadow_normal_deg >= 0 && platter_shadow_normal_deg < 90))
    return Fail(why, "FusionOptions.platter_shadow_normal_deg must be within [0, 90)");
  for (int i = 0; i < 4; ++i)
    if (!std::isfinite(platter[i])) return Fail(why, "FusionOptions.platter must be finite");
  if (!(cluster_gap_mm >= voxel_mm) || !std::isfinite(cluster_gap_mm))
    return Fail(why, "FusionOptions.cluster_gap_mm must be finite and >= voxel_mm");
  return true;
}

PointCloud FuseClouds(const std::vector<PointCloud>& clouds, const FusionOptions& options,
                      std::string* error, FusionStats* stats,
                      const std::vector<cv::Vec3d>* camera_centers_mm) {
  FusionStats local_stats;
  FusionStats& s = stats ? *stats : local_stats;
  s = FusionStats{};
  if (error) error->clear();
  try {
    InputSummary summary;
    if (!CheckInputs(clouds, options, &summary, &s, error)) return {};
    if (camera_centers_mm && !camera_centers_mm->empty()) {
      if (camera_centers_mm->size() != clouds.size()) {
        Fail(error, "fusion: " + std::to_string(camera_centers_mm->size()) +
                        " camera centres for " + std::to_string(clouds.size()) + " clouds");
        return {};
      }
      for (const cv::Vec3d& c : *camera_centers_mm)
        if (!std::isfinite(c[0]) || !std::isfinite(c[1]) || !std::isfinite(c[2])) {
          Fail(error, "fusion: a camera centre is not finite");
          return {};
        }
    }
    const KeyedPoints keyed = KeyPoints(clouds, options, &s);
    if (keyed.keyed.empty()) {
      Fail(error, "fusion: no finite input point within range (" +
                      std::to_string(s.nonfinite_points) + " non-finite, " +
                      std::to_string(s.out_of_range_points) + " out of range)");
      return {};
    }
    Voxels voxels = AverageVoxels(clouds, keyed, options, summary, &s);
    if (voxels.cloud.empty()) {
      Fail(error, "fusion: no voxel holds min_points_per_voxel = " +
                      std::to_string(options.min_points_per_voxel) + " points (" +
                      std::to_string(keyed.keyed.size()) + " finite points)");
      return {};
    }
    if (options.min_views > 1) {
      KeepMultiViewVoxels(options, camera_centers_mm, &voxels, &s);
      if (voxels.cloud.empty()) {
        Fail(error, "fusion: no voxel is supported by min_views = " +
                        std::to_string(options.min_views) + " clouds");
        return {};
      }
    }
    if (options.min_cluster_fraction > 0) KeepLargeClusters(options, &voxels, &s);
    if (options.refine_along_normal && voxels.cloud.HasNormals()) RefineAlongNormals(&voxels);
    return std::move(voxels.cloud);
  } catch (const std::exception& e) {  // std::bad_alloc: never throws, as documented
    s = FusionStats{};
    Fail(error, std::string("fusion: ") + e.what());
    return {};
  }
}

}  // namespace craftscan
