// Census transform, matching cost and cross arms.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

#include <opencv2/core.hpp>

#include "adcensus_internal.h"

namespace craftscan::adcensus {

CostVolume::CostVolume(int width, int height, int ndisp)
    : width_(width), height_(height), ndisp_(ndisp), stride_((ndisp + 15) / 16 * 16) {
  const std::size_t n = static_cast<std::size_t>(width) * height * stride_;
  data_.reset(static_cast<float*>(::operator new[](n * sizeof(float), std::align_val_t(64))));
}

std::vector<std::uint64_t> CensusTransform(const cv::Mat& grey, int win_w, int win_h,
                                           const Parallel& parallel) {
  CV_Assert(grey.type() == CV_8UC1 && win_w % 2 == 1 && win_h % 2 == 1 && win_w * win_h <= 65);
  const int rw = win_w / 2, rh = win_h / 2;
  cv::Mat padded;
  cv::copyMakeBorder(grey, padded, rh, rh, rw, rw, cv::BORDER_REPLICATE);
  const int width = grey.cols;
  std::vector<std::uint64_t> census(grey.total());
  parallel.For(0, grey.rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      std::uint64_t* out = census.data() + static_cast<std::size_t>(y) * width;
      std::memset(out, 0, sizeof(std::uint64_t) * width);
      const std::uint8_t* centre = padded.ptr<std::uint8_t>(y + rh) + rw;
      // Bit order: window row-major, centre skipped. One pass per window
      // position over the whole row keeps the inner loop branch-free.
      for (int dy = -rh; dy <= rh; ++dy) {
        const std::uint8_t* nb_row = padded.ptr<std::uint8_t>(y + rh + dy) + rw;
        for (int dx = -rw; dx <= rw; ++dx) {
          if (dx == 0 && dy == 0) continue;
          const std::uint8_t* nb = nb_row + dx;
          for (int x = 0; x < width; ++x) out[x] = (out[x] << 1) | (nb[x] < centre[x] ? 1u : 0u);
        }
      }
    }
  });
  return census;
}

void ComputeCost(const cv::Mat& left, const cv::Mat& right,
                 const std::vector<std::uint64_t>& census_left,
                 const std::vector<std::uint64_t>& census_right, int min_disparity,
                 double lambda_ad, double lambda_census, const Parallel& parallel,
                 CostVolume* cost) {
  const int width = left.cols, height = left.rows, channels = left.channels();
  const int ndisp = cost->ndisp(), stride = cost->stride();
  // ρ as tables: AD indexed by the channel sum of absolute differences,
  // census by the Hamming distance.
  std::vector<float> lut_ad(255 * channels + 1);
  for (std::size_t s = 0; s < lut_ad.size(); ++s)
    lut_ad[s] = static_cast<float>(1.0 - std::exp(-(static_cast<double>(s) / channels) / lambda_ad));
  float lut_census[65];
  for (int h = 0; h <= 64; ++h) lut_census[h] = static_cast<float>(1.0 - std::exp(-h / lambda_census));

  parallel.For(0, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* pl = left.ptr<std::uint8_t>(y);
      const std::uint8_t* pr = right.ptr<std::uint8_t>(y);
      const std::uint64_t* cl = census_left.data() + static_cast<std::size_t>(y) * width;
      const std::uint64_t* cr = census_right.data() + static_cast<std::size_t>(y) * width;
      for (int x = 0; x < width; ++x) {
        float* c = cost->at(y, x);
        // Valid k: 0 ≤ x − (min_disparity + k) < width.
        const int k_lo = std::clamp(x - width + 1 - min_disparity, 0, ndisp);
        const int k_hi = std::clamp(x - min_disparity + 1, 0, ndisp);
        for (int k = 0; k < k_lo; ++k) c[k] = kOutOfImageCost;
        const std::uint64_t census_anchor = cl[x];
        if (channels == 1) {
          const int a = pl[x];
          for (int k = k_lo; k < k_hi; ++k) {
            const int xr = x - min_disparity - k;
            c[k] = lut_ad[std::abs(a - pr[xr])] +
                   lut_census[std::popcount(census_anchor ^ cr[xr])];
          }
        } else {
          const std::uint8_t* a = pl + 3 * x;
          for (int k = k_lo; k < k_hi; ++k) {
            const int xr = x - min_disparity - k;
            const std::uint8_t* b = pr + 3 * xr;
            const int sad = std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2]);
            c[k] = lut_ad[sad] + lut_census[std::popcount(census_anchor ^ cr[xr])];
          }
        }
        for (int k = std::max(k_hi, k_lo); k < ndisp; ++k) c[k] = kOutOfImageCost;
        for (int k = ndisp; k < stride; ++k) c[k] = CostVolume::kPadCost;
      }
    }
  });
}

namespace {

// Largest absolute channel difference (Mei's D_c).
inline int ColourDiff(const std::uint8_t* a, const std::uint8_t* b, int channels) {
  int d = std::abs(a[0] - b[0]);
  for (int c = 1; c < channels; ++c) d = std::max(d, std::abs(a[c] - b[c]));
  return d;
}

struct ArmLimits {
  int max_len;        // arm length must stay below this (D_s < L)
  double l2;          // beyond this length the tighter colour limit applies
  double tau;         // colour limit to the anchor and to the previous pixel
  double tau2;        // colour limit to the anchor beyond l2
  double beta1;       // gradient difference limit; < 0 disables
};

// Length of the arm from (y, x) in direction (dx, dy).
int ArmLength(const cv::Mat& image, const cv::Mat& gradient, int y, int x, int dx, int dy,
              const ArmLimits& lim) {
  const int channels = image.channels();
  const std::uint8_t* anchor = image.ptr<std::uint8_t>(y) + channels * x;
  const float g_anchor = lim.beta1 >= 0 ? gradient.at<float>(y, x) : 0.f;
  int len = 1;
  for (; len < lim.max_len; ++len) {
    const int qx = x + len * dx, qy = y + len * dy;
    if (qx < 0 || qy < 0 || qx >= image.cols || qy >= image.rows) break;
    const std::uint8_t* q = image.ptr<std::uint8_t>(qy) + channels * qx;
    const std::uint8_t* prev =
        image.ptr<std::uint8_t>(qy - dy) + channels * (qx - dx);
    const int to_anchor = ColourDiff(q, anchor, channels);
    if (to_anchor >= lim.tau) break;
    if (ColourDiff(q, prev, channels) >= lim.tau) break;
    if (len > lim.l2 && to_anchor >= lim.tau2) break;
    if (lim.beta1 >= 0 && std::abs(gradient.at<float>(qy, qx) - g_anchor) >= lim.beta1) break;
  }
  return len - 1;
}

}  // namespace

bool IsEdgePixel(const cv::Mat& gradient, const cv::Mat& edges, int y, int x,
                 const ImprovedArmOptions& options) {
  if (gradient.at<float>(y, x) >= options.beta_max) return true;
  return options.canny_edges_are_edges && !edges.empty() && edges.at<std::uint8_t>(y, x) != 0;
}

Arms BuildArms(const cv::Mat& image, const cv::Mat& gradient, const cv::Mat& edges,
               const ADCensusOptions& options, const Parallel& parallel) {
  Arms arms;
  arms.width = image.cols;
  arms.height = image.rows;
  const std::size_t n = image.total();
  arms.left.resize(n);
  arms.right.resize(n);
  arms.up.resize(n);
  arms.down.resize(n);

  const bool improved = options.arm_rule == ArmRule::kImproved;
  ArmLimits weak{}, edge{};
  if (improved) {
    const ImprovedArmOptions& o = options.improved;
    weak = {o.l_max_px, static_cast<double>(o.l2_px), o.tau_max, o.tau2, o.beta1};
    edge = {static_cast<int>(std::lround(o.l_max_px * o.edge_length_scale)),
            o.l2_px * o.edge_length_scale, o.tau_max * o.edge_tau_scale, o.tau2, o.beta1};
  } else {
    const ClassicArmOptions& o = options.classic;
    weak = edge = {o.l1_px, static_cast<double>(o.l2_px), o.tau1, o.tau2, -1.0};
  }

  parallel.For(0, image.rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        const ArmLimits& lim =
            improved && IsEdgePixel(gradient, edges, y, x, options.improved) ? edge : weak;
        const std::size_t i = arms.index(y, x);
        arms.left[i] = static_cast<std::uint8_t>(ArmLength(image, gradient, y, x, -1, 0, lim));
        arms.right[i] = static_cast<std::uint8_t>(ArmLength(image, gradient, y, x, 1, 0, lim));
        arms.up[i] = static_cast<std::uint8_t>(ArmLength(image, gradient, y, x, 0, -1, lim));
        arms.down[i] = static_cast<std::uint8_t>(ArmLength(image, gradient, y, x, 0, 1, lim));
      }
    }
  });
  return arms;
}

}  // namespace craftscan::adcensus
