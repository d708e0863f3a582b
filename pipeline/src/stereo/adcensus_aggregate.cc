// Cross-based cost aggregation, scanline optimization and winner-take-all.
//
// All passes run over the [y][x][d] volume with the disparity axis innermost,
// so every inner loop is a contiguous, vectorizable loop over d. Horizontal
// passes are row-local (one row of the volume fits in L2); vertical passes
// walk rows top to bottom over a band of columns, keeping one row of state.
#include <hwy/highway.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>

#include "adcensus_internal.h"

namespace craftscan::adcensus {
namespace {

using Buffer = std::vector<float>;

// Columns per vertical-pass work item: small enough to balance two threads,
// large enough that each row access is a long contiguous run.
constexpr int kColumnBand = 4;
// How far ahead (rows) vertical passes prefetch the volume.
constexpr int kPrefetchRows = 4;

// out[k] = (hi[k] − lo[k]) · scale over the padded disparity axis.
inline void WindowSum(const float* __restrict hi, const float* __restrict lo, float scale, int n,
                      float* __restrict out) {
  for (int k = 0; k < n; ++k) out[k] = (hi[k] - lo[k]) * scale;
}

inline void Accumulate(const float* __restrict prev, const float* __restrict add, int n,
                       float* __restrict out) {
  for (int k = 0; k < n; ++k) out[k] = prev[k] + add[k];
}

// One pass of cross aggregation along one axis: each pixel's value becomes
// the sum along its arm, scaled by the pixel's 1 / support size when the pass
// ends an iteration (scale given) or left as a raw sum (nullptr).
using PassScale = const std::vector<float>*;

// Runs consecutive horizontal passes on each row while the row is in cache:
// one read and one write of the volume however many passes there are.
void HorizontalPasses(const Arms& arms, std::initializer_list<PassScale> passes,
                      const Parallel& parallel, CostVolume* cost) {
  const int width = cost->width(), stride = cost->stride();
  parallel.For(0, cost->height(), [&](int y0, int y1) {
    Buffer prefix(static_cast<std::size_t>(width + 1) * stride);
    for (int y = y0; y < y1; ++y) {
      for (PassScale inv_count : passes) {
        std::fill_n(prefix.data(), stride, 0.f);
        for (int x = 0; x < width; ++x)
          Accumulate(&prefix[static_cast<std::size_t>(x) * stride], cost->at(y, x), stride,
                     &prefix[static_cast<std::size_t>(x + 1) * stride]);
        for (int x = 0; x < width; ++x) {
          const std::size_t i = arms.index(y, x);
          const float scale = inv_count ? (*inv_count)[i] : 1.f;
          WindowSum(&prefix[static_cast<std::size_t>(x + arms.right[i] + 1) * stride],
                    &prefix[static_cast<std::size_t>(x - arms.left[i]) * stride], scale, stride,
                    cost->at(y, x));
        }
      }
    }
  });
}

// The vertical counterpart on bands of columns: the band is copied out once,
// every pass runs on the copy (prefix sums down the band), and it is written
// back once.
void VerticalPasses(const Arms& arms, std::initializer_list<PassScale> passes,
                    const Parallel& parallel, CostVolume* cost) {
  const int width = cost->width(), height = cost->height(), stride = cost->stride();
  const int bands = (width + kColumnBand - 1) / kColumnBand;
  parallel.For(0, bands, [&](int b0, int b1) {
    Buffer prefix, data;
    for (int b = b0; b < b1; ++b) {
      const int x0 = b * kColumnBand, x1 = std::min(width, x0 + kColumnBand);
      const std::size_t band = static_cast<std::size_t>(x1 - x0) * stride;
      prefix.resize((height + 1) * band);
      data.resize(height * band);
      for (int y = 0; y < height; ++y) {
        // Rows of a band lie one volume row apart: the hardware prefetcher
        // does not follow, so fetch a few rows ahead by hand.
        if (y + kPrefetchRows < height) {
          const char* ahead = reinterpret_cast<const char*>(cost->at(y + kPrefetchRows, x0));
          for (std::size_t off = 0; off < band * sizeof(float); off += 64)
            __builtin_prefetch(ahead + off);
        }
        std::copy_n(cost->at(y, x0), band, &data[y * band]);
      }
      for (PassScale inv_count : passes) {
        std::fill_n(prefix.data(), band, 0.f);
        for (int y = 0; y < height; ++y)
          Accumulate(&prefix[y * band], &data[y * band], static_cast<int>(band),
                     &prefix[(y + 1) * band]);
        for (int y = 0; y < height; ++y) {
          for (int x = x0; x < x1; ++x) {
            const std::size_t i = arms.index(y, x);
            const float scale = inv_count ? (*inv_count)[i] : 1.f;
            const std::size_t off = static_cast<std::size_t>(x - x0) * stride;
            WindowSum(&prefix[(y + arms.down[i] + 1) * band + off],
                      &prefix[(y - arms.up[i]) * band + off], scale, stride, &data[y * band + off]);
          }
        }
      }
      for (int y = 0; y < height; ++y) std::copy_n(&data[y * band], band, cost->at(y, x0));
    }
  });
}

// 1 / support size for each pixel.
std::vector<float> InverseSupportSizes(const Arms& arms, bool horizontal_first,
                                       const Parallel& parallel) {
  std::vector<float> inv(static_cast<std::size_t>(arms.width) * arms.height);
  parallel.For(0, arms.height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < arms.width; ++x)
        inv[arms.index(y, x)] = 1.f / static_cast<float>(SupportSize(arms, y, x, horizontal_first));
  });
  return inv;
}

}  // namespace

int SupportSize(const Arms& arms, int y, int x, bool horizontal_first) {
  const std::size_t i = arms.index(y, x);
  int n = 0;
  if (horizontal_first) {
    for (int v = y - arms.up[i]; v <= y + arms.down[i]; ++v) {
      const std::size_t j = arms.index(v, x);
      n += arms.left[j] + arms.right[j] + 1;
    }
  } else {
    for (int u = x - arms.left[i]; u <= x + arms.right[i]; ++u) {
      const std::size_t j = arms.index(y, u);
      n += arms.up[j] + arms.down[j] + 1;
    }
  }
  return n;
}

void Aggregate(const Arms& arms, int iterations, const Parallel& parallel, CostVolume* cost) {
  if (iterations <= 0) return;
  const std::vector<float> inv_h = InverseSupportSizes(arms, true, parallel);
  const std::vector<float> inv_v =
      iterations > 1 ? InverseSupportSizes(arms, false, parallel) : std::vector<float>();
  // Iteration i is horizontal-first (H, then V scaled by inv_h) for even i and
  // vertical-first (V, then H scaled by inv_v) for odd i. Consecutive passes
  // along the same axis run fused: H | V V | H H | V V | H for 4 iterations.
  HorizontalPasses(arms, {nullptr}, parallel, cost);
  for (int it = 0; it < iterations; ++it) {
    const bool last = it + 1 == iterations;
    if (it % 2 == 0) {
      if (last) {
        VerticalPasses(arms, {&inv_h}, parallel, cost);
      } else {
        VerticalPasses(arms, {&inv_h, nullptr}, parallel, cost);
      }
    } else {
      if (last) {
        HorizontalPasses(arms, {&inv_v}, parallel, cost);
      } else {
        HorizontalPasses(arms, {&inv_v, nullptr}, parallel, cost);
      }
    }
  }
}

// ---------------------------------------------------------------------------
// Scanline optimization

namespace {

// Whether the colour difference of the right image between each pixel and its
// predecessor along x (horizontal) or y (vertical) reaches tau_so (1 or 0), stored per row reversed
// and padded so that for a left pixel x the values at x_r = x − d_min − k are
// contiguous and increasing in k.
class RightDiffs {
 public:
  RightDiffs(const cv::Mat& right, int min_disparity, int ndisp, bool vertical, int tau_so)
      : width_(right.cols), xr_hi_(right.cols + std::abs(min_disparity) + 2) {
    const int xr_lo = -std::abs(min_disparity) - ndisp - 2;  // ndisp: the padded stride
    len_ = xr_hi_ - xr_lo + 1;
    data_.assign(static_cast<std::size_t>(right.rows + 1) * len_, 0.f);
    const int ch = right.channels();
    for (int y = 0; y < right.rows; ++y) {
      if (vertical && y == 0) continue;
      const std::uint8_t* r = right.ptr<std::uint8_t>(y);
      const std::uint8_t* prev = vertical ? right.ptr<std::uint8_t>(y - 1) : r;
      float* out = &data_[static_cast<std::size_t>(y) * len_];
      for (int xr = vertical ? 0 : 1; xr < width_; ++xr)
        out[xr_hi_ - xr] =
            ColourDiff(r + ch * xr, prev + ch * (vertical ? xr : xr - 1), ch) >= tau_so ? 1.f : 0.f;
    }
  }
  // Row y (0 … rows; row `rows` is all zero), values for x_r = base − k.
  const float* At(int y, int base_xr) const {
    return &data_[static_cast<std::size_t>(y) * len_ + (xr_hi_ - base_xr)];
  }

 private:
  int width_, xr_hi_, len_;
  std::vector<float> data_;  // 32-bit like the costs, so PathStep vectorizes at full width
};

struct Penalties {
  float p1[3], p2[3];  // index: number of colour differences at or above tau_so
};

// One step of a path: out = a + min(prev, prev(k±1) + P1, prev_min + P2) − prev_min,
// over the whole padded disparity axis [0, n) (n a multiple of the vector
// width). prev has one sentinel before and after (prev[-1], prev[n]). Padding
// lanes carry costs ≥ kPadCost, so they never win the minimum.
// Returns min over k of out.
inline float PathStep(const float* __restrict a, const float* __restrict prev, float prev_min,
                      bool d1_big, const float* __restrict d2_big, const Penalties& pen, int n,
                      float* __restrict out) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<float> d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  // Penalties when the right image's difference is below / at or above tau_so.
  const float p1_small = pen.p1[d1_big ? 1 : 0], p1_big = pen.p1[d1_big ? 2 : 1];
  const float p2_small = pen.p2[d1_big ? 1 : 0], p2_big = pen.p2[d1_big ? 2 : 1];
  const auto p1_lo = hn::Set(d, p1_small), p1_step = hn::Set(d, p1_big - p1_small);
  const auto p2_lo = hn::Set(d, p2_small), p2_step = hn::Set(d, p2_big - p2_small);
  const auto vprev_min = hn::Set(d, prev_min);
  auto vmin = hn::Set(d, std::numeric_limits<float>::infinity());
  for (int k = 0; k < n; k += lanes) {
    const auto big = hn::LoadU(d, d2_big + k);
    const auto p1 = hn::MulAdd(big, p1_step, p1_lo);
    const auto p2 = hn::MulAdd(big, p2_step, p2_lo);
    auto best = hn::Min(hn::LoadU(d, prev + k), hn::Add(vprev_min, p2));
    best =
        hn::Min(best, hn::Add(hn::Min(hn::LoadU(d, prev + k - 1), hn::LoadU(d, prev + k + 1)), p1));
    const auto v = hn::Sub(hn::Add(hn::LoadU(d, a + k), best), vprev_min);
    hn::StoreU(v, d, out + k);
    vmin = hn::Min(vmin, v);
  }
  return hn::GetLane(hn::MinOfLanes(d, vmin));
}

}  // namespace

void ScanlineOptimize(const cv::Mat& left, const cv::Mat& right, int min_disparity,
                      const ADCensusOptions& options, const Parallel& parallel, CostVolume* cost,
                      CostVolume* scratch) {
  const int width = cost->width(), height = cost->height();
  const int ndisp = cost->ndisp(), stride = cost->stride();
  const int ch = left.channels();
  const int tau_so = static_cast<int>(std::ceil(options.tau_so));  // integer differences
  const float pi1 = static_cast<float>(options.pi1), pi2 = static_cast<float>(options.pi2);
  const Penalties pen{{pi1, pi1 / 4, pi1 / 10}, {pi2, pi2 / 4, pi2 / 10}};
  const float inf = std::numeric_limits<float>::infinity();
  const RightDiffs hdiff(right, min_disparity, stride, false, tau_so);
  const RightDiffs vdiff(right, min_disparity, stride, true, tau_so);
  scratch->Reshape(width, height, ndisp);
  CostVolume& result = *scratch;

  // Horizontal paths: result = L(left→right) + L(right→left).
  parallel.For(0, height, [&](int y0, int y1) {
    Buffer prev(stride + 2, inf), cur(stride + 2, inf);
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* row = left.ptr<std::uint8_t>(y);
      for (int dir = 0; dir < 2; ++dir) {
        const int x_start = dir == 0 ? 0 : width - 1, step = dir == 0 ? 1 : -1;
        float prev_min = 0;
        for (int i = 0, x = x_start; i < width; ++i, x += step) {
          const float* a = cost->at(y, x);
          if (i == 0) {
            std::copy_n(a, ndisp, &cur[1]);
            prev_min = *std::min_element(a, a + ndisp);
          } else {
            const bool d1_big = ColourDiff(row + ch * x, row + ch * (x - step), ch) >= tau_so;
            // Right-image pair (x_r, x_r − step): left→right uses hdiff(x_r),
            // right→left uses hdiff(x_r + 1).
            const int base_xr = x - min_disparity + (dir == 0 ? 0 : 1);
            prev_min =
                PathStep(a, &prev[1], prev_min, d1_big, hdiff.At(y, base_xr), pen, stride, &cur[1]);
          }
          float* out = result.at(y, x);
          if (dir == 0) {
            std::copy_n(&cur[1], ndisp, out);
          } else {
            for (int k = 0; k < ndisp; ++k) out[k] += cur[1 + k];
          }
          std::swap(prev, cur);
        }
      }
    }
  });

  // Vertical paths over bands of columns, one row of state per column.
  const int bands = (width + kColumnBand - 1) / kColumnBand;
  parallel.For(0, bands, [&](int b0, int b1) {
    const std::size_t lane = stride + 2;
    Buffer prev(kColumnBand * lane, inf), cur(kColumnBand * lane, inf);
    std::vector<float> prev_min(kColumnBand);
    for (int b = b0; b < b1; ++b) {
      const int x0 = b * kColumnBand, x1 = std::min(width, x0 + kColumnBand);
      for (int dir = 0; dir < 2; ++dir) {
        const int y_start = dir == 0 ? 0 : height - 1, step = dir == 0 ? 1 : -1;
        for (int i = 0, y = y_start; i < height; ++i, y += step) {
          const std::uint8_t* row = left.ptr<std::uint8_t>(y);
          const std::uint8_t* prow = i == 0 ? row : left.ptr<std::uint8_t>(y - step);
          for (int x = x0; x < x1; ++x) {
            const int c = x - x0;
            const float* a = cost->at(y, x);
            float* cl = &cur[c * lane + 1];
            if (i == 0) {
              std::copy_n(a, ndisp, cl);
              prev_min[c] = *std::min_element(a, a + ndisp);
            } else {
              const bool d1_big = ColourDiff(row + ch * x, prow + ch * x, ch) >= tau_so;
              // Top→bottom pairs (y, y−1): vdiff row y; bottom→top: vdiff row y+1.
              const int vy = dir == 0 ? y : y + 1;
              prev_min[c] = PathStep(a, &prev[c * lane + 1], prev_min[c], d1_big,
                                     vdiff.At(vy, x - min_disparity), pen, stride, cl);
            }
            float* out = result.at(y, x);
            if (dir == 0) {
              for (int k = 0; k < ndisp; ++k) out[k] += cl[k];
            } else {
              for (int k = 0; k < ndisp; ++k) out[k] = (out[k] + cl[k]) * 0.25f;
              for (int k = ndisp; k < stride; ++k) out[k] = CostVolume::kPadCost;
            }
          }
          std::swap(prev, cur);
        }
      }
    }
  });
  cost->swap(result);
}

namespace {

// Index of the first minimum of c[0 … n) (n a multiple of the vector width;
// lanes past the real disparities hold kPadCost and never win).
inline int ArgMin(const float* __restrict c, int n) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<float> df;
  const hn::RebindToSigned<decltype(df)> di;
  const int lanes = static_cast<int>(hn::Lanes(df));
  auto best = hn::Set(df, std::numeric_limits<float>::infinity());
  auto best_k = hn::Zero(di);
  auto k_vec = hn::Iota(di, 0);
  const auto step = hn::Set(di, lanes);
  for (int k = 0; k < n; k += lanes) {
    const auto v = hn::LoadU(df, c + k);
    const auto better = hn::Lt(v, best);  // strict: each lane keeps its first minimum
    best = hn::IfThenElse(better, v, best);
    best_k = hn::IfThenElse(hn::RebindMask(di, better), k_vec, best_k);
    k_vec = hn::Add(k_vec, step);
  }
  // Among lanes holding the minimum, the smallest index: the first minimum.
  const auto min_all = hn::MinOfLanes(df, best);
  const auto at_min = hn::RebindMask(di, hn::Eq(best, min_all));
  const auto candidates =
      hn::IfThenElse(at_min, best_k, hn::Set(di, std::numeric_limits<int>::max()));
  return hn::GetLane(hn::MinOfLanes(di, candidates));
}

// For the right view: best[j0 + k] = min(best[j0 + k], c[k]) over a padded
// run, with the index of the winner. Strict "<" keeps the first (lowest k)
// winner because callers visit candidates of each entry in increasing k.
inline void RightMinUpdate(const float* __restrict c, int n, float* __restrict best,
                           std::int32_t* __restrict best_k) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<float> df;
  const hn::RebindToSigned<decltype(df)> di;
  const int lanes = static_cast<int>(hn::Lanes(df));
  auto k_vec = hn::Iota(di, 0);
  const auto step = hn::Set(di, lanes);
  for (int k = 0; k < n; k += lanes) {
    const auto v = hn::LoadU(df, c + k);
    const auto b = hn::LoadU(df, best + k);
    const auto better = hn::Lt(v, b);
    hn::StoreU(hn::IfThenElse(better, v, b), df, best + k);
    hn::StoreU(hn::IfThenElse(hn::RebindMask(di, better), k_vec, hn::LoadU(di, best_k + k)), di,
               best_k + k);
    k_vec = hn::Add(k_vec, step);
  }
}

}  // namespace

void WinnerTakeAll(const CostVolume& cost, int min_disparity, const Parallel& parallel,
                   cv::Mat* left_index, cv::Mat* right_index) {
  const int width = cost.width(), height = cost.height(), ndisp = cost.ndisp();
  const int stride = cost.stride();
  left_index->create(height, width, CV_32FC1);
  right_index->create(height, width, CV_32FC1);
  // Right view, in the same pass over each row (no diagonal walk through the
  // volume): left pixel x at index k matches x_r = x − d_min − k. Entries are
  // kept reversed, j = width − 1 − x_r + margin, so that each pixel's
  // candidates form one contiguous run j0 + k. Runs also touch entries outside
  // the image (ignored) and padding lanes (cost kPadCost: never a real winner).
  const int margin = stride + std::abs(min_disparity) + 1;
  const int entries = width + 2 * margin;
  parallel.For(0, height, [&](int y0, int y1) {
    std::vector<float> best(entries);
    std::vector<std::int32_t> best_k(entries);
    for (int y = y0; y < y1; ++y) {
      float* l = left_index->ptr<float>(y);
      float* r = right_index->ptr<float>(y);
      std::fill(best.begin(), best.end(), std::numeric_limits<float>::infinity());
      std::fill(best_k.begin(), best_k.end(), -1);
      for (int x = 0; x < width; ++x) {
        const float* c = cost.at(y, x);
        l[x] = static_cast<float>(ArgMin(c, stride));
        const int j0 = width - 1 - x + min_disparity + margin;
        RightMinUpdate(c, stride, &best[j0], &best_k[j0]);
      }
      for (int xr = 0; xr < width; ++xr) {
        const int j = width - 1 - xr + margin;
        const int k = best_k[j];
        r[xr] =
            k < 0 || k >= ndisp ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(k);
      }
    }
  });
}

}  // namespace craftscan::adcensus
