#include "craftscan/pipeline/surface/visibility.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <optional>
#include <unordered_set>

#include <opencv2/imgproc.hpp>

#include "common/parallel.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

constexpr float kNone = std::numeric_limits<float>::infinity();

// Occupied cells of the confirmed surface, for "is there a confirmed point
// within about a cell of here".
class CellSet {
 public:
  CellSet(const PointCloud& cloud, double cell_mm) : cell_mm_(cell_mm) {
    cells_.reserve(cloud.size());
    for (const cv::Vec3f& p : cloud.points_mm)
      if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))
        cells_.insert(Key(Cell(p[0]), Cell(p[1]), Cell(p[2])));
  }
  bool Near(const cv::Vec3d& p) const {
    const long x = Cell(p[0]), y = Cell(p[1]), z = Cell(p[2]);
    if (cells_.count(Key(x, y, z))) return true;  // most often
    for (long dz = -1; dz <= 1; ++dz)
      for (long dy = -1; dy <= 1; ++dy)
        for (long dx = -1; dx <= 1; ++dx)
          if (cells_.count(Key(x + dx, y + dy, z + dz))) return true;
    return false;
  }

 private:
  long Cell(double v) const { return static_cast<long>(std::floor(v / cell_mm_)); }
  static std::uint64_t Key(long x, long y, long z) {
    constexpr std::uint64_t kMask = (std::uint64_t{1} << 21) - 1;
    return ((static_cast<std::uint64_t>(x) & kMask) << 42) |
           ((static_cast<std::uint64_t>(y) & kMask) << 21) |
           (static_cast<std::uint64_t>(z) & kMask);
  }
  double cell_mm_;
  std::unordered_set<std::uint64_t> cells_;
};

// The nearest depth each pixel of the camera saw (z-buffer of `seen`, in the
// camera's frame), +inf where it saw nothing, into *depth (its buffer
// reused). With `confirmed` (and `world_from_view`), only what lies on the
// confirmed surface counts.
void DepthMap(const PointCloud& seen, const RectifiedCamera& camera, const CellSet* confirmed,
              const cv::Matx44d& world_from_view, cv::Mat* depth_map) {
  depth_map->create(camera.size, CV_32FC1);
  depth_map->setTo(cv::Scalar(kNone));
  cv::Mat& depth = *depth_map;
  for (const cv::Vec3f& p : seen.points_mm) {
    if (!(p[2] > 0) || !std::isfinite(p[0]) || !std::isfinite(p[1])) continue;
    const double u = camera.fx * p[0] / p[2] + camera.cx;
    const double v = camera.fy * p[1] / p[2] + camera.cy;
    const long x = std::lround(u), y = std::lround(v);
    if (x < 0 || y < 0 || x >= camera.size.width || y >= camera.size.height) continue;
    float& z = depth.at<float>(static_cast<int>(y), static_cast<int>(x));
    if (!(p[2] < z)) continue;  // no nearer than what the pixel holds
    if (confirmed) {
      const cv::Vec4d w = world_from_view * cv::Vec4d(p[0], p[1], p[2], 1);
      if (!confirmed->Near(cv::Vec3d(w[0], w[1], w[2]))) continue;
    }
    z = p[2];
  }
}

enum class Verdict { kNoInformation, kSupported, kContradicted };

// One view's depth map with, per pixel, the nearest and farthest depth and
// the number of depths in the window around it (options.window_radius_px):
// most points are judged from these alone, without reading the window.
// Buffers are reused from view to view (fresh pages cost more than the
// filters).
struct ViewDepth {
  cv::Mat depth, nearest, farthest, count;  // CV_32FC1 each
  cv::Mat seen, scratch;

  void Summarise(int r) {
    const cv::Mat kernel =
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 1, 2 * r + 1));
    cv::erode(depth, nearest, kernel);  // +inf (nothing seen) never wins a minimum
    cv::compare(depth, kNone, seen, cv::CMP_NE);
    depth.copyTo(scratch);
    scratch.setTo(-kNone, ~seen);
    cv::dilate(scratch, farthest, kernel);
    seen.convertTo(scratch, CV_32F, 1.0 / 255);
    cv::boxFilter(scratch, count, CV_32F, cv::Size(2 * r + 1, 2 * r + 1), cv::Point(-1, -1),
                  /*normalize=*/false);
  }
};

// What view j's depth map says of a point at `p` in j's rig frame.
Verdict Judge(const cv::Vec3d& p, const ViewDepth& view, const RectifiedCamera& camera,
              const VisibilityOptions& options) {
  if (!(p[2] > 0)) return Verdict::kNoInformation;
  const long x = std::lround(camera.fx * p[0] / p[2] + camera.cx);
  const long y = std::lround(camera.fy * p[1] / p[2] + camera.cy);
  const int r = options.window_radius_px;
  if (x < r || y < r || x >= camera.size.width - r || y >= camera.size.height - r)
    return Verdict::kNoInformation;
  const int px = static_cast<int>(x), py = static_cast<int>(y);
  const float count = view.count.at<float>(py, px);
  if (count < 0.5f) return Verdict::kNoInformation;
  float z_min = view.nearest.at<float>(py, px);
  float z_max = view.farthest.at<float>(py, px);
  if (!(z_min > p[2] + options.tolerance_mm)) {
    // Some depth of the window is not behind the point: if one lies within
    // the tolerance it supports the point, else the point is in front of
    // nothing it could be seen through.
    if (z_max < p[2] - options.tolerance_mm) return Verdict::kNoInformation;
    for (long yy = y - r; yy <= y + r; ++yy) {
      const float* row = view.depth.ptr<float>(static_cast<int>(yy));
      for (long xx = x - r; xx <= x + r; ++xx) {
        const float z = row[xx];
        if (z != kNone && std::abs(z - p[2]) <= options.tolerance_mm) return Verdict::kSupported;
      }
    }
    return Verdict::kNoInformation;
  }
  if (count < options.min_window_pixels - 0.5f) return Verdict::kNoInformation;
  // A surface the view saw at a grazing angle, or across one of its own
  // depth edges, was measured badly there: it contradicts nothing.
  const double span_mm =
      2.0 * r * p[2] / camera.fx;  // the window's width on a fronto-parallel plane
  const double slope_limit = std::tan(options.max_incidence_deg * M_PI / 180);
  if (r > 0 && z_max - z_min > slope_limit * span_mm) return Verdict::kNoInformation;
  return Verdict::kContradicted;
}

PointCloud Subset(const PointCloud& cloud, const std::vector<char>& keep) {
  PointCloud out;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!keep[i]) continue;
    out.points_mm.push_back(cloud.points_mm[i]);
    if (cloud.HasNormals()) out.normals.push_back(cloud.normals[i]);
    if (cloud.HasColors()) out.colors_rgb.push_back(cloud.colors_rgb[i]);
  }
  return out;
}

}  // namespace

bool RectifiedCamera::IsValid(std::string* why) const {
  if (!(std::isfinite(fx) && fx > 0 && std::isfinite(fy) && fy > 0))
    return Fail(why, "the focal lengths must be finite and > 0");
  if (!(std::isfinite(cx) && std::isfinite(cy))) return Fail(why, "the centre must be finite");
  if (size.width <= 0 || size.height <= 0) return Fail(why, "the image size must be > 0");
  return true;
}

RectifiedCamera RectifiedLeftCamera(const StereoCalibration& calibration) {
  RectifiedCamera c;
  c.fx = calibration.P1(0, 0);
  c.fy = calibration.P1(1, 1);
  c.cx = calibration.P1(0, 2);
  c.cy = calibration.P1(1, 2);
  c.size = calibration.image_size;
  return c;
}

bool VisibilityOptions::IsValid(std::string* why) const {
  if (!(std::isfinite(tolerance_mm) && tolerance_mm > 0))
    return Fail(why, "tolerance_mm must be finite and > 0");
  if (window_radius_px < 0 || window_radius_px > 5)
    return Fail(why, "window_radius_px must be in 0..5");
  if (min_window_pixels < 1 ||
      min_window_pixels > (2 * window_radius_px + 1) * (2 * window_radius_px + 1))
    return Fail(why, "min_window_pixels must be in 1..(2 window_radius_px + 1)^2");
  if (!(max_incidence_deg > 0 && max_incidence_deg < 90))
    return Fail(why, "max_incidence_deg must be in (0, 90)");
  if (num_threads < 1) return Fail(why, "num_threads must be >= 1");
  return true;
}

std::vector<PointCloud> RemoveFreeSpaceViolations(const std::vector<PointCloud>& candidates,
                                                  const std::vector<PointCloud>& seen,
                                                  const std::vector<cv::Matx44d>& view0_from_view,
                                                  const RectifiedCamera& camera,
                                                  const VisibilityOptions& options,
                                                  VisibilityStats* stats, std::string* error,
                                                  const PointCloud* confirmed) {
  VisibilityStats local;
  VisibilityStats& s = stats ? *stats : local;
  s = VisibilityStats{};
  std::string why;
  if (!options.IsValid(&why) || !camera.IsValid(&why)) {
    Fail(error, "visibility: " + why);
    return candidates;
  }
  const std::size_t n = candidates.size();
  if (seen.size() != n || view0_from_view.size() != n) {
    Fail(error, "visibility: " + std::to_string(n) + " candidate clouds, " +
                    std::to_string(seen.size()) + " seen clouds and " +
                    std::to_string(view0_from_view.size()) + " poses");
    return candidates;
  }
  try {
    const Parallel parallel(options.num_threads);
    std::optional<CellSet> cells;
    if (confirmed) cells.emplace(*confirmed, options.tolerance_mm / 2);
    std::vector<cv::Matx44d> view_from_view0(n);
    for (std::size_t j = 0; j < n; ++j) view_from_view0[j] = InvertRigid(view0_from_view[j]);

    // View by view (a few depth maps in memory at a time, not one per
    // view), each candidate point's supporting and contradicting views
    // counted.
    std::vector<std::vector<std::uint8_t>> support(n), against(n);
    for (std::size_t i = 0; i < n; ++i) {
      support[i].assign(candidates[i].size(), 0);
      against[i].assign(candidates[i].size(), 0);
    }
    const std::size_t batch = static_cast<std::size_t>(std::max(1, options.num_threads));
    std::vector<ViewDepth> views(batch);
    for (std::size_t first = 0; first < n; first += batch) {
      const std::size_t last = std::min(n, first + batch);
      parallel.For(static_cast<int>(first), static_cast<int>(last), [&](int b, int e) {
        for (int j = b; j < e; ++j) {
          ViewDepth& view = views[static_cast<std::size_t>(j) - first];
          DepthMap(seen[j], camera, cells ? &*cells : nullptr, view0_from_view[j], &view.depth);
          view.Summarise(options.window_radius_px);
        }
      });
      for (std::size_t i = 0; i < n; ++i) {
        const PointCloud& cloud = candidates[i];
        parallel.For(
            0, static_cast<int>(cloud.size()),
            [&](int b, int e) {
              for (std::size_t j = first; j < last; ++j) {
                if (j == i) continue;
                const cv::Matx44d j_from_i = view_from_view0[j] * view0_from_view[i];
                for (int k = b; k < e; ++k) {
                  const cv::Vec3f& q = cloud.points_mm[static_cast<std::size_t>(k)];
                  const cv::Vec4d p = j_from_i * cv::Vec4d(q[0], q[1], q[2], 1);
                  switch (Judge(cv::Vec3d(p[0], p[1], p[2]), views[j - first], camera, options)) {
                    case Verdict::kSupported:
                      ++support[i][static_cast<std::size_t>(k)];
                      break;
                    case Verdict::kContradicted:
                      ++against[i][static_cast<std::size_t>(k)];
                      break;
                    case Verdict::kNoInformation:
                      break;
                  }
                }
              }
            },
            1024);
      }
    }

    std::vector<PointCloud> out(n);
    s.removed_per_view.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const PointCloud& cloud = candidates[i];
      // A tie goes against the point: a view that looked through it saw
      // past it, while one that agrees may share its mismatch (views that
      // see a periodic texture alike).
      std::vector<char> keep(cloud.size(), 1);
      for (std::size_t k = 0; k < cloud.size(); ++k) {
        keep[k] = against[i][k] == 0 || against[i][k] < support[i][k];
        s.unsupported_points += keep[k] && support[i][k] == 0;
      }
      out[i] = Subset(cloud, keep);
      s.checked_points += cloud.size();
      s.removed_per_view[i] = cloud.size() - out[i].size();
      s.removed_points += s.removed_per_view[i];
    }
    return out;
  } catch (const std::exception& e) {
    Fail(error, std::string("visibility: ") + e.what());
    return candidates;
  }
}

}  // namespace craftscan
