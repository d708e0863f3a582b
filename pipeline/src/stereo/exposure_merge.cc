#include "craftscan/pipeline/stereo/exposure_merge.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <numbers>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace craftscan {

bool ExposureMergeOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(gamma >= 1 && gamma <= 4)) return fail("gamma must be in [1, 4]");
  if (!(clip_level > 0 && clip_level <= 255)) return fail("clip_level must be in (0, 255]");
  if (!(clip_ramp >= 0 && clip_ramp < clip_level))
    return fail("clip_ramp must be in [0, clip_level)");
  return true;
}

bool IsValidExposureBracket(const std::vector<double>& multiples, std::string* why) {
  if (multiples.size() > 4) {
    if (why) *why = "must list at most 4 multiples, got " + std::to_string(multiples.size());
    return false;
  }
  for (std::size_t i = 0; i < multiples.size(); ++i) {
    const double m = multiples[i];
    if (!(m > 1 && m <= 64) || (i > 0 && !(m > multiples[i - 1]))) {
      char text[32];
      std::snprintf(text, sizeof text, "%g", m);
      if (why) {
        *why = "entry " + std::to_string(i + 1) +
               " must be a multiple of the exposure in (1, 64], larger than the one before, got '" +
               text + "'";
      }
      return false;
    }
  }
  return true;
}

bool MergeExposures(const std::vector<cv::Mat>& images,
                    const std::vector<double>& relative_exposure,
                    const ExposureMergeOptions& options, cv::Mat* merged, std::string* error) {
  auto fail = [&](const std::string& m) {
    if (error) *error = "exposure merge: " + m;
    return false;
  };
  if (std::string why; !options.IsValid(&why)) return fail(why);
  if (images.empty()) return fail("no images");
  if (relative_exposure.size() != images.size())
    return fail(std::to_string(images.size()) + " images but " +
                std::to_string(relative_exposure.size()) + " exposures");
  const cv::Mat& first = images.front();
  if (first.empty() || (first.type() != CV_8UC1 && first.type() != CV_8UC3))
    return fail("image 0 is empty or not 8-bit grey or BGR");
  for (std::size_t i = 0; i < images.size(); ++i) {
    if (images[i].size() != first.size() || images[i].type() != first.type())
      return fail("image " + std::to_string(i) + " differs in size or type from image 0");
    const double t = relative_exposure[i];
    if (!(std::isfinite(t) && t > 0)) return fail("exposure " + std::to_string(i) + " is not > 0");
    if (i == 0 ? t != 1 : !(t > relative_exposure[i - 1]))
      return fail("exposures must ascend from 1 (the reference, shortest, first)");
  }

  // Per-level tables: the clip ramp's weight, and the gamma encoding of
  // radiance on a 1/16-level grid (radiance ≤ 255: the reference is shortest).
  std::array<float, 256> weight{};
  for (int z = 0; z < 256; ++z) {
    const double top = options.clip_level, ramp = options.clip_ramp;
    weight[z] = z >= top                     ? 0.f
                : ramp > 0 && z > top - ramp ? static_cast<float>((top - z) / ramp)
                                             : 1.f;
  }
  constexpr int kSteps = 16;
  std::vector<std::uint8_t> encode(255 * kSteps + 1);
  for (std::size_t i = 0; i < encode.size(); ++i)
    encode[i] = cv::saturate_cast<std::uint8_t>(
        255.0 * std::pow(static_cast<double>(i) / (255.0 * kSteps), 1.0 / options.gamma));

  const int channels = first.channels();
  const std::size_t n = images.size();
  std::vector<float> t(relative_exposure.begin(), relative_exposure.end());
  cv::Mat out(first.size(), first.type());
  for (int y = 0; y < first.rows; ++y) {
    std::vector<const std::uint8_t*> rows(n);
    for (std::size_t i = 0; i < n; ++i) rows[i] = images[i].ptr<std::uint8_t>(y);
    std::uint8_t* o = out.ptr<std::uint8_t>(y);
    for (int x = 0; x < first.cols * channels; ++x) {
      float num = 0, den = 0;
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint8_t z = rows[i][x];
        const float w = weight[z];
        num += w * t[i] * z;
        den += w * t[i] * t[i];
      }
      const float r = den > 0 ? num / den : static_cast<float>(rows[0][x]);
      o[x] = encode[std::clamp(static_cast<int>(std::lround(r * kSteps)), 0, 255 * kSteps)];
    }
  }
  *merged = out;
  return true;
}

bool AutoBracketOptions::IsValid(std::string* why) const {
  const auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!IsValidExposureBracket({multiple}, why)) return false;
  if (window < 3 || window > 31 || window % 2 == 0) return fail("window must be odd, in [3, 31]");
  if (!(dark_level > 0 && dark_level < 255)) return fail("dark_level must be in (0, 255)");
  if (!(max_texture_std >= 0 && max_texture_std < 255))
    return fail("max_texture_std must be in [0, 255)");
  if (!(min_share_pct > 0 && min_share_pct <= 100))
    return fail("min_share_pct must be in (0, 100]");
  return true;
}

cv::Mat PlatterRegionMask(const StereoCalibration& calibration, double platter_radius_mm) {
  const TurntableAxis& axis = calibration.turntable;
  const cv::Size size = calibration.image_size;
  if (!axis.valid || !(platter_radius_mm > 0) || size.width <= 0 || size.height <= 0) return {};
  // The disc's rim in the rig frame (the rectified left camera), then into
  // the raw left camera (x_raw = R1ᵀ x_rig) and through its lens.
  const cv::Vec3d n = cv::normalize(axis.direction_in_rig);
  const cv::Vec3d helper = std::abs(n[0]) < 0.9 ? cv::Vec3d(1, 0, 0) : cv::Vec3d(0, 1, 0);
  const cv::Vec3d u = cv::normalize(n.cross(helper)), v = n.cross(u);
  const cv::Matx33d raw_from_rig = calibration.R1.t();
  constexpr int kRim = 180;
  std::vector<cv::Point3d> rim;
  for (int i = 0; i < kRim; ++i) {
    const double a = 2 * std::numbers::pi * i / kRim;
    const cv::Vec3d p = raw_from_rig * (axis.point_in_rig_mm +
                                        platter_radius_mm * (std::cos(a) * u + std::sin(a) * v));
    if (!(p[2] > 1)) return {};  // part of the rim behind the camera: not a station's view
    rim.emplace_back(p);
  }
  std::vector<cv::Point2d> image;
  const CameraIntrinsics& left = calibration.left;
  std::vector<double> distortion(left.distortion.val, left.distortion.val + 5);
  if (left.distortion_rational != cv::Vec3d(0, 0, 0))
    distortion.insert(distortion.end(), left.distortion_rational.val,
                      left.distortion_rational.val + 3);
  cv::projectPoints(rim, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), left.camera_matrix, distortion,
                    image);
  std::vector<cv::Point> polygon;
  for (const cv::Point2d& q : image) {
    if (!std::isfinite(q.x) || !std::isfinite(q.y)) return {};
    polygon.emplace_back(cvRound(q.x), cvRound(q.y));
  }
  cv::Mat mask(size, CV_8UC1, cv::Scalar(0));
  cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{polygon}, cv::Scalar(255));
  if (cv::countNonZero(mask) == 0) return {};
  return mask;
}

double DarkUntexturedSharePct(const cv::Mat& image, const cv::Mat& region,
                              const AutoBracketOptions& options) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  if (image.empty() || image.depth() != CV_8U) return kNaN;
  if (!region.empty() && (region.size() != image.size() || region.type() != CV_8UC1)) return kNaN;
  cv::Mat grey;
  if (image.channels() == 3)
    cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  else if (image.channels() == 1)
    grey = image;
  else
    return kNaN;
  // Window mean and variance by box filters over I and I².
  cv::Mat g, mean, mean_sq;
  grey.convertTo(g, CV_32F);
  const cv::Size w(options.window, options.window);
  cv::boxFilter(g, mean, CV_32F, w, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::boxFilter(g.mul(g), mean_sq, CV_32F, w, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  const float dark = static_cast<float>(options.dark_level);
  const float max_var = static_cast<float>(options.max_texture_std * options.max_texture_std);
  long inside = 0, hits = 0;
  for (int y = 0; y < g.rows; ++y) {
    const std::uint8_t* r = region.empty() ? nullptr : region.ptr<std::uint8_t>(y);
    const float* m = mean.ptr<float>(y);
    const float* m2 = mean_sq.ptr<float>(y);
    for (int x = 0; x < g.cols; ++x) {
      if (r && !r[x]) continue;
      ++inside;
      hits += m[x] < dark && m2[x] - m[x] * m[x] <= max_var;
    }
  }
  return inside > 0 ? 100.0 * static_cast<double>(hits) / static_cast<double>(inside) : kNaN;
}

}  // namespace craftscan
