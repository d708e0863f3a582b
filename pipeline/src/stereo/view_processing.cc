#include "craftscan/pipeline/stereo/view_processing.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/common/status.h"
#include "craftscan/pipeline/stereo/reproject.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan {
namespace {

// The station's scanline penalties (ADCensusOptions::pi1, pi2; the paper's
// 1 and 3 go with its cross-based aggregation, which the station does not
// run). Without aggregation each pixel's cost comes from its census window
// alone; a slanted surface (a face seen at 60°, a base seen by the oblique
// views of a second turn) or a flat, weakly textured one (satin stitches
// along the rows, a plain base) needs steps of one disparity every pixel or
// two, which a P1 of 1 made dearer than a wrong match, and a P2 of 3 let the
// paths jump to the noise's minimum. Measured at 1280×1024 (README 11.9):
// sim-depth seed 9191 (station clean-up), valid % and bad-2 %: box
// 81.5 / 2.85 → 89.2 / 3.01, embroidery 28.5 / 9.17 → 49.9 / 6.33, egg
// 52.7 / 5.80 → 54.0 / 3.11; 6-view scans at seed 4242: embroidery
// completeness 81.5 → 93.5 %, largest mesh component 73 → 100 %; the box's
// relief smooths slightly (fused p95 0.39 → 0.47 mm), which a larger P2
// worsens (8: 0.49 mm) and a smaller one trades against the embroidery
// (4: 89.6 %). Penalties drop at colour edges as before (tau_so).
constexpr double kStationScanlinePi1 = 0.5;
constexpr double kStationScanlinePi2 = 6.0;
// The same smoothness turns pure noise into coherent patches: a dark
// backdrop brightened eight times by exposure bracketing is random texture
// in both views, and with these penalties its paths settle on smooth
// surfaces that pass the left-right check and are too large for speckle
// removal (the bracketed egg at 640×512 with the projector: 38 % of the
// fused points floaters, its box 237 mm long). Such a surface has no
// distinct cost minimum: the uniqueness test (RefinementOptions) drops a
// pixel whose winning cost is not 10 % below the best two or more
// disparities away. It leaves that egg 0.39 % floaters; 0.05 left 5 %. Its
// price elsewhere (seed 4242, 6 views): the embroidery's completeness
// 93.5 → 89.7 %, the box's 97.9 → 97.1 % (its p95 0.47 → 0.44 mm, outliers
// 0.15 → 0.07 %); sim-depth valid, box 89.2 → 87.0 %.
constexpr double kStationUniqueness = 0.1;

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace

bool ViewProcessorOptions::IsValid(std::string* why) const {
  if (num_threads < 1 || num_threads > 256) return Fail(why, "num_threads must be in 1..256");
  std::string sub;
  if (!volume.IsValid(&sub)) return Fail(why, "volume." + sub);
  if (disparity_margin_px < 0 || disparity_margin_px > 64)
    return Fail(why, "disparity_margin_px must be in 0..64");
  if (max_num_disparities < 16) return Fail(why, "max_num_disparities must be >= 16");
  if (!(min_texture_std >= 0)) return Fail(why, "min_texture_std must be >= 0");
  if (!(platter_radius_mm >= 0 && platter_radius_mm <= 10000))
    return Fail(why, "platter_radius_mm must be in [0, 10000]");
  if (depth_edge_radius_px < 0 || depth_edge_radius_px > 5)
    return Fail(why, "depth_edge_radius_px must be in 0..5");
  if (!(depth_edge_jump_px > 0 && depth_edge_jump_px <= 1000))
    return Fail(why, "depth_edge_jump_px must be in (0, 1000]");
  if (aggregation_iterations < 0 || aggregation_iterations > 16)
    return Fail(why, "aggregation_iterations must be in 0..16");
  if (!(speckle_max_area_pct >= 0 && speckle_max_area_pct <= 1))
    return Fail(why, "speckle_max_area_pct must be in [0, 1]");
  if (!(speckle_range_px > 0 && speckle_range_px <= 64))
    return Fail(why, "speckle_range_px must be in (0, 64]");
  if (!(match_gamma >= 1 && match_gamma <= 4)) return Fail(why, "match_gamma must be in [1, 4]");
  return true;
}

std::size_t RemoveDisparitySpeckles(int max_area_px, double range_px, cv::Mat* disparity) {
  if (max_area_px <= 0 || disparity == nullptr || disparity->empty()) return 0;
  CV_Assert(disparity->type() == CV_32FC1);
  // cv::filterSpeckles takes 16-bit disparities: 1/16 px as StereoSGBM's,
  // counted from the smallest valid one (coarser if the span needs it).
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (int y = 0; y < disparity->rows; ++y) {
    const float* d = disparity->ptr<float>(y);
    for (int x = 0; x < disparity->cols; ++x) {
      if (!std::isfinite(d[x])) continue;
      lo = std::min(lo, static_cast<double>(d[x]));
      hi = std::max(hi, static_cast<double>(d[x]));
    }
  }
  if (!(hi >= lo)) return 0;  // no valid pixel
  const double scale = std::min(16.0, 32000.0 / std::max(hi - lo, 1.0));
  constexpr std::int16_t kInvalid = -1;
  cv::Mat fixed(disparity->size(), CV_16SC1);
  for (int y = 0; y < disparity->rows; ++y) {
    const float* d = disparity->ptr<float>(y);
    auto* f = fixed.ptr<std::int16_t>(y);
    for (int x = 0; x < disparity->cols; ++x)
      f[x] = std::isfinite(d[x]) ? static_cast<std::int16_t>(std::lround((d[x] - lo) * scale))
                                 : kInvalid;
  }
  cv::filterSpeckles(fixed, kInvalid, max_area_px, range_px * scale);
  std::size_t removed = 0;
  for (int y = 0; y < disparity->rows; ++y) {
    float* d = disparity->ptr<float>(y);
    const auto* f = fixed.ptr<std::int16_t>(y);
    for (int x = 0; x < disparity->cols; ++x) {
      if (f[x] == kInvalid && std::isfinite(d[x])) {
        d[x] = std::numeric_limits<float>::quiet_NaN();
        ++removed;
      }
    }
  }
  return removed;
}

std::size_t EraseNearDepthEdges(int radius_px, double jump_px, cv::Mat* disparity) {
  if (radius_px <= 0 || disparity == nullptr || disparity->empty()) return 0;
  CV_Assert(disparity->type() == CV_32FC1);
  // The largest valid disparity around every pixel (the nearest surface);
  // invalid pixels count as none (a hole is not a depth edge).
  cv::Mat nearest = disparity->clone();
  cv::patchNaNs(nearest, -std::numeric_limits<float>::max());
  cv::dilate(
      nearest, nearest,
      cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius_px + 1, 2 * radius_px + 1)));
  std::size_t erased = 0;
  const auto jump = static_cast<float>(jump_px);
  for (int y = 0; y < disparity->rows; ++y) {
    float* d = disparity->ptr<float>(y);
    const float* near = nearest.ptr<float>(y);
    for (int x = 0; x < disparity->cols; ++x) {
      if (std::isfinite(d[x]) && near[x] - d[x] > jump) {
        d[x] = std::numeric_limits<float>::quiet_NaN();
        ++erased;
      }
    }
  }
  return erased;
}

cv::Mat RectifiedPlatterRegion(const StereoCalibration& c, double radius_mm) {
  if (!c.turntable.valid || !(radius_mm > 0)) return cv::Mat();
  const cv::Matx44d rig_from_turntable = TurntableFromRig(c.turntable).inv();
  // Clamped far outside the image, so fillPoly's fixed point stays in range.
  const double lim = 4.0 * std::max(c.image_size.width, c.image_size.height);
  std::vector<cv::Point> outline;
  for (int i = 0; i < 360; ++i) {
    const double a = i * CV_PI / 180;
    const cv::Vec4d p =
        rig_from_turntable * cv::Vec4d(radius_mm * std::cos(a), radius_mm * std::sin(a), 0, 1);
    if (!(p[2] > 1)) return cv::Mat();  // the disc reaches the camera plane
    const cv::Vec3d l = c.P1 * cv::Vec4d(p[0], p[1], p[2], 1);
    outline.emplace_back(static_cast<int>(std::lround(std::clamp(l[0] / l[2], -lim, lim))),
                         static_cast<int>(std::lround(std::clamp(l[1] / l[2], -lim, lim))));
  }
  cv::Mat region = cv::Mat::zeros(c.image_size, CV_8UC1);
  cv::fillPoly(region, std::vector<std::vector<cv::Point>>{outline}, cv::Scalar(255));
  return region;
}

bool ViewProcessor::Init(const StereoCalibration& calibration, const ViewProcessorOptions& options,
                         std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) return Fail(error, "view processing: " + why);
  if (!rectifier_.Init(calibration, &why)) return Fail(error, "calibration: " + why);
  options_ = options;
  const StereoCalibration& c = rectifier_.calibration();

  // The band: project points spread over the working volume (and the
  // platter at height 0) into both rectified cameras; d = u_left − u_right.
  std::vector<cv::Vec3d> samples_in_rig;
  crop_ = c.turntable.valid;
  if (crop_) {
    turntable_from_rig_ = TurntableFromRig(c.turntable);
    const cv::Matx44d rig_from_turntable = turntable_from_rig_.inv();
    for (double z : {0.0, options.volume.max_height_mm}) {
      for (double r : {0.0, options.volume.radius_mm}) {
        for (int i = 0; i < 72; ++i) {
          const double a = i * CV_PI / 36;
          const cv::Vec4d p =
              rig_from_turntable * cv::Vec4d(r * std::cos(a), r * std::sin(a), z, 1);
          samples_in_rig.emplace_back(p[0], p[1], p[2]);
        }
      }
    }
  } else {
    for (double z : {300.0, 1500.0}) samples_in_rig.emplace_back(0, 0, z);
  }
  double d_min = 1e9, d_max = -1e9;
  for (const cv::Vec3d& p : samples_in_rig) {
    if (!(p[2] > 1))
      return Fail(error, "calibration: the working volume reaches behind the cameras");
    const cv::Vec3d l = c.P1 * cv::Vec4d(p[0], p[1], p[2], 1);
    const cv::Vec3d r = c.P2 * cv::Vec4d(p[0], p[1], p[2], 1);
    const double d = l[0] / l[2] - r[0] / r[2];
    d_min = std::min(d_min, d);
    d_max = std::max(d_max, d);
  }
  // What the left camera sees over the platter disc (the platter's radius,
  // else the volume's) is the platter or what stands on it, never the
  // backdrop: the texture filter, there to drop the matcher's guesses on a
  // textureless backdrop, leaves it alone. Over an object it mostly removed
  // right pixels (dark paint, dark cloth; README 11.9).
  over_platter_ = RectifiedPlatterRegion(
      c, options.platter_radius_mm > 0 ? options.platter_radius_mm : options.volume.radius_mm);
  // Above a low object the cameras see the far side of the platter: the
  // band reaches down to its disparity there, else the matcher carries the
  // object's disparity into it (consistent in both images, so the
  // left-right check keeps it: a sheet of points above the object).
  if (crop_ && options.platter_radius_mm > options.volume.radius_mm) {
    const cv::Matx44d rig_from_turntable = turntable_from_rig_.inv();
    for (int i = 0; i < 72; ++i) {
      const double a = i * CV_PI / 36, r = options.platter_radius_mm;
      const cv::Vec4d p = rig_from_turntable * cv::Vec4d(r * std::cos(a), r * std::sin(a), 0, 1);
      if (!(p[2] > 1)) continue;
      const cv::Vec3d l = c.P1 * cv::Vec4d(p[0], p[1], p[2], 1);
      const cv::Vec3d q = c.P2 * cv::Vec4d(p[0], p[1], p[2], 1);
      d_min = std::min(d_min, l[0] / l[2] - q[0] / q[2]);
    }
  }
  min_disparity_ = static_cast<int>(std::floor(d_min)) - options.disparity_margin_px;
  num_disparities_ =
      static_cast<int>(std::ceil(d_max)) + options.disparity_margin_px - min_disparity_ + 1;
  if (options.num_disparities > 0) {
    min_disparity_ = options.min_disparity;
    num_disparities_ = options.num_disparities;
  }
  if (num_disparities_ > options.max_num_disparities) {
    return Fail(error, "calibration: the working volume spans " + std::to_string(num_disparities_) +
                           " disparities (more than " +
                           std::to_string(options.max_num_disparities) +
                           "); make pipeline.volume_* smaller or set pipeline.num_disparities");
  }
  ADCensusOptions matcher;
  matcher.min_disparity = min_disparity_;
  matcher.num_disparities = num_disparities_;
  matcher.num_threads = options.num_threads;
  matcher.refinement.interpolate = false;  // a point cloud wants no invented surface
  matcher.aggregation_iterations = options.aggregation_iterations;
  matcher.coarse_to_fine.enabled = options.coarse_to_fine;
  matcher.pi1 = kStationScanlinePi1;
  matcher.pi2 = kStationScanlinePi2;
  matcher.refinement.uniqueness = kStationUniqueness;
  if (!matcher.IsValid(&why)) return Fail(error, "matcher: " + why);
  matcher_ = std::make_unique<StereoMatcher>(matcher);
  return true;
}

double ViewProcessor::focal_px() const { return rectifier_.calibration().P1(0, 0); }

double ViewProcessor::baseline_mm() const {
  const auto& P2 = rectifier_.calibration().P2;
  return P2(0, 0) != 0 ? std::abs(P2(0, 3) / P2(0, 0)) : 0;
}

namespace {

// Colours from the rectified texture frame: each point came from the pixel
// P1 projects it to (reprojection with Q inverts exactly that).
void Recolour(const cv::Mat& texture, const cv::Matx34d& P1, PointCloud* cloud) {
  const double fx = P1(0, 0), fy = P1(1, 1), cx = P1(0, 2), cy = P1(1, 2);
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    const cv::Vec3f& p = cloud->points_mm[i];
    const long x = std::lround(fx * p[0] / p[2] + cx), y = std::lround(fy * p[1] / p[2] + cy);
    if (x < 0 || y < 0 || x >= texture.cols || y >= texture.rows) continue;
    const int r = static_cast<int>(y), c = static_cast<int>(x);
    if (texture.type() == CV_8UC3) {
      const cv::Vec3b bgr = texture.at<cv::Vec3b>(r, c);
      cloud->colors_rgb[i] = cv::Vec3b(bgr[2], bgr[1], bgr[0]);
    } else if (texture.type() == CV_8UC1) {
      const std::uint8_t g = texture.at<std::uint8_t>(r, c);
      cloud->colors_rgb[i] = cv::Vec3b(g, g, g);
    }
  }
}

}  // namespace

ProcessedView ViewProcessor::Process(const cv::Mat& left_raw, const cv::Mat& right_raw,
                                     const cv::Mat& texture_left_raw, double pair_gamma) {
  ProcessedView out;
  if (!matcher_) {
    out.message = "view processor not initialised";
    return out;
  }
  try {
    auto start = std::chrono::steady_clock::now();
    cv::Mat right;
    std::string why;
    if (!rectifier_.Rectify(left_raw, right_raw, &out.rectified_left, &right, &why)) {
      out.message = "rectify: " + why;
      return out;
    }
    cv::Mat texture;  // rectified, when given
    if (!texture_left_raw.empty()) {
      if (texture_left_raw.type() != left_raw.type()) {
        out.message = "texture frame: its pixel type differs from the left image's";
        return out;
      }
      if (!rectifier_.RectifyLeft(texture_left_raw, &texture, &why)) {
        out.message = "texture frame: " + why;
        return out;
      }
    }
    out.rectify_ms = MsSince(start);
    start = std::chrono::steady_clock::now();
    // New buffers when re-encoded: LUT into a header of out.rectified_left
    // would change the colours and the texture test's image.
    cv::Mat match_left = out.rectified_left, match_right = right;
    if (!(pair_gamma >= 1 && pair_gamma <= 4)) {
      out.message = "the pair's gamma must be in [1, 4]";
      return out;
    }
    // Only a linear pair is encoded; an encoded one (a merge) is matched as
    // it is, never decoded to fewer dark levels.
    if (pair_gamma == 1.0 && options_.match_gamma != 1.0) {
      cv::Mat table(1, 256, CV_8U);
      const double exponent = 1 / options_.match_gamma;
      for (int i = 0; i < 256; ++i)
        table.at<std::uint8_t>(i) =
            cv::saturate_cast<std::uint8_t>(255 * std::pow(i / 255.0, exponent));
      match_left = cv::Mat();
      match_right = cv::Mat();
      cv::LUT(out.rectified_left, table, match_left);
      cv::LUT(right, table, match_right);
    }
    DisparityResult match = matcher_->Compute(match_left, match_right);
    out.match_ms = MsSince(start);
    if (!match.IsUsable()) {
      out.message = "matcher: " + match.message;
      return out;
    }
    out.disparity = std::move(match.disparity);
    out.speckle_pixels = RemoveDisparitySpeckles(
        static_cast<int>(std::lround(options_.speckle_max_area_pct / 100 *
                                     static_cast<double>(out.disparity.total()))),
        options_.speckle_range_px, &out.disparity);
    out.edge_pixels_erased = EraseNearDepthEdges(options_.depth_edge_radius_px,
                                                 options_.depth_edge_jump_px, &out.disparity);
    out.min_disparity = min_disparity_;
    out.num_disparities = num_disparities_;

    start = std::chrono::steady_clock::now();
    ReprojectOptions reproject;
    reproject.min_texture_std = options_.min_texture_std;
    reproject.texture_exempt = over_platter_;
    const ReprojectResult reprojected = ReprojectToPoints(
        out.disparity, cv::Mat(rectifier_.calibration().Q), out.rectified_left, reproject);
    if (!reprojected.IsUsable()) {
      out.message = "reproject: " + reprojected.message;
      return out;
    }
    const std::vector<ColoredPoint>& points = reprojected.points;
    PointCloud& cloud = out.cloud_in_rig;
    cloud.points_mm.reserve(points.size());
    cloud.colors_rgb.reserve(points.size());
    for (const ColoredPoint& p : points) {
      if (crop_) {
        const cv::Vec4d q = turntable_from_rig_ * cv::Vec4d(p.x, p.y, p.z, 1);
        if (!options_.volume.Contains(cv::Vec3d(q[0], q[1], q[2]))) continue;
      }
      cloud.points_mm.emplace_back(p.x, p.y, p.z);
      cloud.colors_rgb.emplace_back(p.r, p.g, p.b);
    }
    if (!texture.empty()) Recolour(texture, rectifier_.calibration().P1, &cloud);
    out.reproject_ms = MsSince(start);
    out.ok = true;
  } catch (const std::exception& e) {
    out.message = std::string("view processing: ") + e.what();
  }
  return out;
}

}  // namespace craftscan
