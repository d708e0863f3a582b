#include "craftscan/pipeline/stereo/exposure_merge.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

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

}  // namespace craftscan
