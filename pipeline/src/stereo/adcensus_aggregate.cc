// Cross-based cost aggregation, scanline optimization and winner-take-all.
//
// All passes run over [y][x][d] volumes of 16-bit fixed-point costs
// (adcensus_internal.h) with the disparity axis innermost, so every inner
// loop is a contiguous loop over d that vectorizes across disparities.
// Horizontal passes are row-local (one row of the volume stays in L2);
// vertical passes walk rows top to bottom over a band of columns, keeping one
// row of state per column. All arithmetic is on integers (or rounds each
// value on its own), so results do not depend on how rows or bands are split
// between threads.
#include <hwy/highway.h>
#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <memory>
#include <thread>

#include "adcensus_internal.h"

namespace craftscan::adcensus {
namespace {

namespace hn = hwy::HWY_NAMESPACE;
// 16 costs (256 bits) per vector: the padded stride is a multiple of 16.
using CostTag = hn::CappedTag<Cost, 16>;

constexpr Cost kMaxCost = std::numeric_limits<Cost>::max();

// The smallest lane of v, whose lanes are all ≥ 0. With AVX2 the two halves'
// minimum goes through phminposuw (unsigned, the same order for
// non-negative costs): three instructions instead of Highway's generic
// shuffle-and-min ladder, which sits on the path's chain from one pixel to
// the next.
inline Cost MinLane(hn::Vec<CostTag> v) {
#if defined(__AVX2__) && HWY_TARGET <= HWY_AVX2
  if constexpr (sizeof(v.raw) == 32) {
    const __m128i halves =
        _mm_min_epu16(_mm256_castsi256_si128(v.raw), _mm256_extracti128_si256(v.raw, 1));
    return static_cast<Cost>(_mm_cvtsi128_si32(_mm_minpos_epu16(halves)) & 0xFFFF);
  }
#endif
  return hn::GetLane(hn::MinOfLanes(CostTag(), v));
}

// The vector (first, first + 1, …): a constant vector plus one broadcast.
// (Highway 1.0's Iota for 16-bit lanes builds it lane by lane through the
// stack, and the winners' loops asked for one per pixel.)
inline hn::Vec<CostTag> LaneIndex(int first) {
  alignas(64) static constexpr Cost kIndex[16] = {0, 1, 2,  3,  4,  5,  6,  7,
                                                  8, 9, 10, 11, 12, 13, 14, 15};
  const CostTag d;
  return hn::Add(hn::Load(d, kIndex), hn::Set(d, static_cast<Cost>(first)));
}

// Columns per vertical-aggregation work item: small enough to balance two
// threads, large enough that each row access is a long contiguous run.
constexpr int kColumnBand = 4;
// Columns per vertical-scanline work item. Its state is one padded disparity
// row per column (a few kB) and the band's top→bottom path values,
// height × kScanBand × stride costs (2.6 MB at 1280×1024×160).
constexpr int kScanBand = 8;
// How far ahead (rows) vertical passes prefetch the volume.
constexpr int kPrefetchRows = 4;

// Fetches the costs of columns [x0, x0 + n) of row y into cache.
inline void PrefetchRun(const CostVolume& cost, int y, int x0, int n) {
  const char* p = reinterpret_cast<const char*>(cost.at(y, x0));
  const std::size_t bytes = static_cast<std::size_t>(n) * cost.stride() * sizeof(Cost);
  for (std::size_t off = 0; off < bytes; off += 64) __builtin_prefetch(p + off);
}

// ---------------------------------------------------------------------------
// Aggregation
//
// A pass along one axis computes, for every pixel p and disparity,
//   out(p) = round(scale(p) · Σ_{q on p's arm along the axis} weight(q) · in(q)).
// Values between passes are always rounded costs, never raw sums (they would
// overflow 16 bits): a pass that ends an iteration stores the support-region
// mean (scale = 1 / support size); a pass that starts one stores the mean
// over the pixel's own arm segment (scale = 1 / segment length), and the next
// pass, along the other axis, weights it by that length to get the segment
// sum back. The result is the exact region mean up to one rounding per pass.

struct Pass {
  const std::vector<std::int32_t>* weight;  // per pixel; nullptr = 1
  const std::vector<float>* scale;          // per pixel
};

// Prefix sums are unsigned: a whole column of padding lanes (kPadCost times
// an arm length per row) can pass 2^31, and unsigned arithmetic wraps with
// defined behaviour. A window's difference is exact, as every window sum
// (at most 69 × 69 × kPadCost) is far below 2^31.
using Prefix = std::uint32_t;

// out[k] = prev[k] + w · add[k] over the padded disparity axis (add ≥ 0).
template <class T>
inline void AccumulateWeighted(const Prefix* __restrict prev, const T* __restrict add,
                               std::int32_t w, int n, Prefix* __restrict out) {
  const Prefix weight = static_cast<Prefix>(w);
  // n is a multiple of 16 (the padded stride): blocks of 16 compile to whole
  // vectors with no scalar remainder.
  for (int k0 = 0; k0 < n; k0 += 16)
    for (int k = k0; k < k0 + 16; ++k) out[k] = prev[k] + static_cast<Prefix>(add[k]) * weight;
}

// out[k] = round((hi[k] − lo[k]) · scale); sums are non-negative.
template <class T>
inline void WindowMean(const Prefix* __restrict hi, const Prefix* __restrict lo, float scale, int n,
                       T* __restrict out) {
  for (int k0 = 0; k0 < n; k0 += 16)  // as above
    for (int k = k0; k < k0 + 16; ++k)
      out[k] = static_cast<T>(static_cast<std::int32_t>(
          static_cast<float>(static_cast<std::int32_t>(hi[k] - lo[k])) * scale + 0.5f));
}

// Runs consecutive horizontal passes on each row while the row is in cache:
// one read and one write of the volume however many passes there are.
// With `source`, the first pass takes each row's matching costs from it
// (computed into a row buffer) instead of reading them from the volume.
// Working memory per thread: a prefix-sum row, (width + 1) × stride uint32.
void HorizontalPasses(const Arms& arms, std::initializer_list<Pass> passes,
                      const Parallel& parallel, CostVolume* cost,
                      const CostComputer* source = nullptr) {
  const int width = cost->width(), stride = cost->stride();
  parallel.For(0, cost->height(), [&](int y0, int y1) {
    // Per thread, kept between chunks and calls: a fresh buffer per chunk
    // is a fresh mapping, page faults and zeroing each time.
    thread_local std::vector<Prefix> prefix;
    thread_local std::vector<Cost> costs;
    thread_local CostComputer::Scratch scratch;
    prefix.resize(static_cast<std::size_t>(width + 1) * stride);
    if (source) costs.resize(static_cast<std::size_t>(width) * stride);
    for (int y = y0; y < y1; ++y) {
      const Cost* in = cost->at(y, 0);
      if (source) {
        source->Row(y, &scratch, costs.data(), cost->offset_row(y));
        in = costs.data();
      }
      for (const Pass& pass : passes) {
        std::fill_n(prefix.data(), stride, 0);
        for (int x = 0; x < width; ++x) {
          const std::int32_t w = pass.weight ? (*pass.weight)[arms.index(y, x)] : 1;
          AccumulateWeighted(&prefix[static_cast<std::size_t>(x) * stride],
                             in + static_cast<std::size_t>(x) * stride, w, stride,
                             &prefix[static_cast<std::size_t>(x + 1) * stride]);
        }
        for (int x = 0; x < width; ++x) {
          const std::size_t i = arms.index(y, x);
          WindowMean(&prefix[static_cast<std::size_t>(x + arms.right[i] + 1) * stride],
                     &prefix[static_cast<std::size_t>(x - arms.left[i]) * stride], (*pass.scale)[i],
                     stride, cost->at(y, x));
        }
        in = cost->at(y, 0);  // the next pass reads this one's output
      }
    }
  });
}

// The vertical counterpart on bands of columns: the first pass reads the
// band from the volume, passes in between run on a copy (height × band ×
// stride costs; prefix sums down the band), the last writes the volume. Every pass's output is a
// weighted mean of costs, so it fits a cost: the copy stays 16-bit, and the
// band and its prefix sums stay in L2.
void VerticalPasses(const Arms& arms, std::initializer_list<Pass> passes, const Parallel& parallel,
                    CostVolume* cost) {
  const int width = cost->width(), height = cost->height(), stride = cost->stride();
  const int bands = (width + kColumnBand - 1) / kColumnBand;
  const int num_passes = static_cast<int>(passes.size());
  parallel.For(0, bands, [&](int b0, int b1) {
    thread_local std::vector<Prefix> prefix;  // per thread, as above
    thread_local std::vector<Cost> data;
    for (int b = b0; b < b1; ++b) {
      const int x0 = b * kColumnBand, x1 = std::min(width, x0 + kColumnBand);
      const std::size_t band = static_cast<std::size_t>(x1 - x0) * stride;
      prefix.resize((height + 1) * band);
      data.resize(height * band);
      // The first pass reads the band from the volume and the last writes
      // it back there; the copy holds what passes in between.
      int p = 0;
      for (const Pass& pass : passes) {
        const bool from_volume = p == 0, to_volume = p + 1 == num_passes;
        ++p;
        std::fill_n(prefix.data(), band, 0);
        for (int y = 0; y < height; ++y) {
          // Rows of a band lie one volume row apart: the hardware prefetcher
          // does not follow, so fetch a few rows ahead by hand.
          if (from_volume && y + kPrefetchRows < height)
            PrefetchRun(*cost, y + kPrefetchRows, x0, x1 - x0);
          const Cost* in = from_volume ? cost->at(y, x0) : &data[y * band];
          for (int x = x0; x < x1; ++x) {
            const std::int32_t w = pass.weight ? (*pass.weight)[arms.index(y, x)] : 1;
            const std::size_t off = static_cast<std::size_t>(x - x0) * stride;
            AccumulateWeighted(&prefix[y * band + off], in + off, w, stride,
                               &prefix[(y + 1) * band + off]);
          }
        }
        for (int y = 0; y < height; ++y) {
          Cost* out = to_volume ? cost->at(y, x0) : &data[y * band];
          for (int x = x0; x < x1; ++x) {
            const std::size_t i = arms.index(y, x);
            const std::size_t off = static_cast<std::size_t>(x - x0) * stride;
            WindowMean(&prefix[(y + arms.down[i] + 1) * band + off],
                       &prefix[(y - arms.up[i]) * band + off], (*pass.scale)[i], stride, out + off);
          }
        }
      }
    }
  });
}

// Fills *f (its vectors resized, kept where large enough). The loops run on
// rows, marked free of dependences between iterations: the arms are bytes,
// which may alias anything (GCC ignores restrict on local pointers), and
// otherwise nothing here vectorizes (a scalar division per pixel and factor).
void ComputePassFactors(const Arms& arms, bool need_vertical_first, const Parallel& parallel,
                        PassFactors* out) {
  PassFactors& f = *out;
  const int width = arms.width, height = arms.height;
  const std::size_t n = static_cast<std::size_t>(width) * height;
  f.len_h.resize(n);
  f.len_v.resize(n);
  f.inv_len_h.resize(n);
  f.inv_len_v.resize(n);
  f.inv_support_h.resize(n);
  if (need_vertical_first) f.inv_support_v.resize(n);
  // The lambdas copy `width` into a local: a captured one is read through
  // the closure, which every store through an int pointer might change, and
  // the loops would not vectorize.
  parallel.For(0, height, [&](int y0, int y1) {
    const int cols = width;
    for (int y = y0; y < y1; ++y) {
      const std::size_t row = arms.index(y, 0);
      const std::uint8_t* __restrict left = arms.left.data() + row;
      const std::uint8_t* __restrict right = arms.right.data() + row;
      const std::uint8_t* __restrict up = arms.up.data() + row;
      const std::uint8_t* __restrict down = arms.down.data() + row;
      std::int32_t* __restrict len_h = f.len_h.data() + row;
      std::int32_t* __restrict len_v = f.len_v.data() + row;
      float* __restrict inv_len_h = f.inv_len_h.data() + row;
      float* __restrict inv_len_v = f.inv_len_v.data() + row;
#pragma GCC ivdep
      for (int x = 0; x < cols; ++x) {
        const std::int32_t h = left[x] + right[x] + 1, v = up[x] + down[x] + 1;
        len_h[x] = h;
        len_v[x] = v;
        inv_len_h[x] = 1.f / static_cast<float>(h);
        inv_len_v[x] = 1.f / static_cast<float>(v);
      }
    }
  });
  // Support sizes (as SupportSize) from prefix sums of the segment lengths:
  // horizontal-first, len_h summed down each column over the vertical arm;
  // vertical-first, len_v summed along each row over the horizontal arm.
  std::vector<std::int32_t>& down_column = f.down_column;
  down_column.resize(static_cast<std::size_t>(height + 1) * width);
  std::fill_n(down_column.begin(), width, 0);
  for (int y = 0; y < height; ++y) {
    const std::int32_t* __restrict above = down_column.data() + static_cast<std::size_t>(y) * width;
    const std::int32_t* __restrict len_h = f.len_h.data() + arms.index(y, 0);
    std::int32_t* __restrict sum = down_column.data() + static_cast<std::size_t>(y + 1) * width;
#pragma GCC ivdep
    for (int x = 0; x < width; ++x) sum[x] = above[x] + len_h[x];
  }
  parallel.For(0, height, [&](int y0, int y1) {
    const int cols = width;
    std::vector<std::int32_t> along_row(width + 1, 0);
    std::vector<std::int32_t> size_h(width);
    for (int y = y0; y < y1; ++y) {
      const std::size_t row = arms.index(y, 0);
      const std::uint8_t* __restrict left = arms.left.data() + row;
      const std::uint8_t* __restrict right = arms.right.data() + row;
      const std::uint8_t* __restrict up = arms.up.data() + row;
      const std::uint8_t* __restrict down = arms.down.data() + row;
      const std::int32_t* __restrict columns = down_column.data();
      std::int32_t* __restrict sizes = size_h.data();
#pragma GCC ivdep
      for (int x = 0; x < cols; ++x)
        sizes[x] = columns[static_cast<std::size_t>(y + down[x] + 1) * cols + x] -
                   columns[static_cast<std::size_t>(y - up[x]) * cols + x];
      float* __restrict inv_h = f.inv_support_h.data() + row;
#pragma GCC ivdep
      for (int x = 0; x < cols; ++x) inv_h[x] = 1.f / static_cast<float>(sizes[x]);
      if (need_vertical_first) {
        const std::int32_t* __restrict len_v = f.len_v.data() + row;
        std::int32_t* __restrict along = along_row.data();
        for (int x = 0; x < cols; ++x) along[x + 1] = along[x] + len_v[x];
        float* __restrict inv_v = f.inv_support_v.data() + row;
#pragma GCC ivdep
        for (int x = 0; x < cols; ++x)
          inv_v[x] = 1.f / static_cast<float>(along[x + right[x] + 1] - along[x - left[x]]);
      }
    }
  });
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

void Aggregate(const Arms& arms, int iterations, const Parallel& parallel, CostVolume* cost,
               PassFactors* factors, const CostComputer* source) {
  if (iterations <= 0) {
    if (source) ComputeCost(*source, parallel, cost);
    return;
  }
  PassFactors temporary;
  PassFactors& f = factors ? *factors : temporary;
  ComputePassFactors(arms, iterations > 1, parallel, &f);
  // Iteration i is horizontal-first for even i: H (segment means), then V
  // weighted by the horizontal lengths and scaled to the region mean; odd i
  // is the transpose. Consecutive passes along the same axis run fused:
  // H | V V | H H | V V | H for 4 iterations.
  const Pass h_start{nullptr, &f.inv_len_h}, v_start{nullptr, &f.inv_len_v};
  const Pass v_end{&f.len_h, &f.inv_support_h}, h_end{&f.len_v, &f.inv_support_v};
  HorizontalPasses(arms, {h_start}, parallel, cost, source);
  for (int it = 0; it < iterations; ++it) {
    const bool last = it + 1 == iterations;
    if (it % 2 == 0) {
      if (last) {
        VerticalPasses(arms, {v_end}, parallel, cost);
      } else {
        VerticalPasses(arms, {v_end, v_start}, parallel, cost);
      }
    } else {
      if (last) {
        HorizontalPasses(arms, {h_end}, parallel, cost);
      } else {
        HorizontalPasses(arms, {h_end, h_start}, parallel, cost);
      }
    }
  }
}

// ---------------------------------------------------------------------------
// Winner-take-all

namespace {

// Index of the first minimum of c[0 … n) (n a multiple of the vector width;
// lanes past the real disparities hold large costs and never win).
inline int ArgMin(const Cost* __restrict c, int n) {
  const CostTag d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  auto best = hn::Set(d, kMaxCost);
  auto best_k = hn::Zero(d);
  auto k_vec = LaneIndex(0);
  const auto step = hn::Set(d, static_cast<Cost>(lanes));
  for (int k = 0; k < n; k += lanes) {
    const auto v = hn::LoadU(d, c + k);
    const auto better = hn::Lt(v, best);  // strict: each lane keeps its first minimum
    best = hn::IfThenElse(better, v, best);
    best_k = hn::IfThenElse(better, k_vec, best_k);
    k_vec = hn::Add(k_vec, step);
  }
  // Among lanes holding the minimum, the smallest index: the first minimum.
  const auto at_min = hn::Eq(best, hn::Set(d, MinLane(best)));
  return MinLane(hn::IfThenElse(at_min, best_k, hn::Set(d, kMaxCost)));
}

// The right view's winners, gathered in the same pass over a row of the
// volume as the left view's (no diagonal walk): left pixel x at index k
// matches x_r = x − d_min − k. Entries are kept reversed,
// j = width − 1 − x_r + margin, so that each pixel's candidates form one
// contiguous run j0 + k. Runs also touch entries outside the image (ignored)
// and padding lanes (never a real winner).
class RightWinners {
 public:
  // `span`: the largest offset plus the stride (the stride without offsets).
  RightWinners(int width, int min_disparity, int stride, int span)
      : width_(width),
        min_disparity_(min_disparity),
        stride_(stride),
        margin_(span + std::abs(min_disparity) + 1),
        best_(width + 2 * margin_),
        best_k_(width + 2 * margin_) {}

  void Reset() {
    std::fill(best_.begin(), best_.end(), kMaxCost);
    std::fill(best_k_.begin(), best_k_.end(), Cost{-1});
  }

  // Offers the costs of left pixel x, whose lane k is index offset + k. Each
  // entry must end with its first minimum (lowest index): with pixels offered
  // in increasing x (increasing index per entry) a strict "<" keeps it, in
  // decreasing x a "≤" does.
  void Offer(int x, const Cost* __restrict c, bool decreasing_x, int offset) {
    const CostTag d;
    const int lanes = static_cast<int>(hn::Lanes(d));
    Cost* __restrict best = &best_[width_ - 1 - x + min_disparity_ + offset + margin_];
    Cost* __restrict best_k = &best_k_[width_ - 1 - x + min_disparity_ + offset + margin_];
    auto k_vec = LaneIndex(offset);
    const auto step = hn::Set(d, static_cast<Cost>(lanes));
    for (int k = 0; k < stride_; k += lanes) {
      const auto v = hn::LoadU(d, c + k);
      const auto b = hn::LoadU(d, best + k);
      const auto better = decreasing_x ? hn::Not(hn::Lt(b, v)) : hn::Lt(v, b);  // v ≤ b : v < b
      hn::StoreU(hn::IfThenElse(better, v, b), d, best + k);
      hn::StoreU(hn::IfThenElse(better, k_vec, hn::LoadU(d, best_k + k)), d, best_k + k);
      k_vec = hn::Add(k_vec, step);
    }
  }

  // out = saturate(out + saturate(a + b)), then as Offer with out as the
  // costs; returns ArgMin(out) (the first minimum). One pass over the lanes
  // while they are in registers, for the scanline's last sum.
  int AddSumOffer(int x, const Cost* __restrict a, const Cost* __restrict b, Cost* __restrict out,
                  bool decreasing_x, int offset) {
    const CostTag d;
    const int lanes = static_cast<int>(hn::Lanes(d));
    Cost* __restrict best = &best_[width_ - 1 - x + min_disparity_ + offset + margin_];
    Cost* __restrict best_k = &best_k_[width_ - 1 - x + min_disparity_ + offset + margin_];
    auto k_vec = LaneIndex(offset);
    auto index = LaneIndex(0);
    const auto step = hn::Set(d, static_cast<Cost>(lanes));
    auto low = hn::Set(d, kMaxCost);
    auto low_k = hn::Zero(d);
    for (int k = 0; k < stride_; k += lanes) {
      const auto sum = hn::SaturatedAdd(hn::LoadU(d, a + k), hn::LoadU(d, b + k));
      const auto v = hn::SaturatedAdd(hn::LoadU(d, out + k), sum);
      hn::StoreU(v, d, out + k);
      const auto lower = hn::Lt(v, low);  // strict: each lane keeps its first minimum
      low = hn::IfThenElse(lower, v, low);
      low_k = hn::IfThenElse(lower, index, low_k);
      index = hn::Add(index, step);
      const auto bb = hn::LoadU(d, best + k);
      const auto better = decreasing_x ? hn::Not(hn::Lt(bb, v)) : hn::Lt(v, bb);  // v ≤ b : v < b
      hn::StoreU(hn::IfThenElse(better, v, bb), d, best + k);
      hn::StoreU(hn::IfThenElse(better, k_vec, hn::LoadU(d, best_k + k)), d, best_k + k);
      k_vec = hn::Add(k_vec, step);
    }
    const auto at_min = hn::Eq(low, hn::Set(d, MinLane(low)));
    return MinLane(hn::IfThenElse(at_min, low_k, hn::Set(d, kMaxCost)));
  }

  // Writes the winning index per right pixel (NaN where no real winner).
  void Write(int ndisp, float* r) const {
    for (int xr = 0; xr < width_; ++xr) {
      const int k = best_k_[width_ - 1 - xr + margin_];
      r[xr] = k < 0 || k >= ndisp ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(k);
    }
  }

 private:
  int width_, min_disparity_, stride_, margin_;
  std::vector<Cost> best_, best_k_;
};

}  // namespace

namespace {

inline int RunnerUp(const Cost* __restrict c, int n, int stride, int k) {
  // j ∈ [0, k − 1) or [k + 2, n): is either run non-empty?
  if (k - 1 <= 0 && k + 2 >= n) return kNoRunnerUp;
  const CostTag d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  // Excluded: k − 1 … k + 1 (k − 2 < j < k + 2) and j ≥ n (j > n − 1).
  const auto below = hn::Set(d, static_cast<Cost>(k - 2));
  const auto above = hn::Set(d, static_cast<Cost>(k + 2));
  const auto last_held = hn::Set(d, static_cast<Cost>(n - 1));
  const auto none = hn::Set(d, kMaxCost);
  const auto step = hn::Set(d, static_cast<Cost>(lanes));
  auto j = LaneIndex(0);
  auto best = none;
  for (int i = 0; i < stride; i += lanes) {
    const auto out = hn::Or(hn::And(hn::Gt(j, below), hn::Lt(j, above)), hn::Gt(j, last_held));
    best = hn::Min(best, hn::IfThenElse(out, none, hn::LoadU(d, c + i)));
    j = hn::Add(j, step);
  }
  return MinLane(best);
}

}  // namespace

int RunnerUpCost(const Cost* c, int n, int stride, int k) { return RunnerUp(c, n, stride, k); }

void WinnerTakeAll(const CostVolume& cost, int min_disparity, const Parallel& parallel,
                   cv::Mat* left_index, cv::Mat* right_index) {
  const int width = cost.width(), height = cost.height(), stride = cost.stride();
  left_index->create(height, width, CV_32FC1);
  right_index->create(height, width, CV_32FC1);
  const int span = cost.total_ndisp() - cost.ndisp() + stride;
  parallel.For(0, height, [&](int y0, int y1) {
    RightWinners right(width, min_disparity, stride, span);
    for (int y = y0; y < y1; ++y) {
      float* l = left_index->ptr<float>(y);
      const std::int32_t* offsets = cost.offset_row(y);
      right.Reset();
      for (int x = 0; x < width; ++x) {
        const Cost* c = cost.at(y, x);
        const int o = offsets ? offsets[x] : 0;
        l[x] = static_cast<float>(o + ArgMin(c, stride));
        right.Offer(x, c, false, o);
      }
      right.Write(cost.total_ndisp(), right_index->ptr<float>(y));
    }
  });
}

// ---------------------------------------------------------------------------
// Scanline optimization
//
// Two passes over the aggregated volume C:
//  1. vertical paths on bands of columns (one padded disparity row of state
//     per column, the band's top→bottom values in a band buffer):
//     S(y, x) = L_top→bottom + L_bottom→top, S in *result (which may be C's
//     own memory: S(y, x) is written after C(y, x) is read for the last time);
//  2. horizontal paths row by row (C's row read or recomputed, the row's
//     left→right values in a row buffer of width × stride costs, in L2),
//     fused with the final sum S += L_left→right + L_right→left and the
//     winner-take-all of both views, so S is read and written once more and
//     never walked again for the winners.

namespace {

// flags[x] = 1 where the colour difference D_c(a[x], b[x]) reaches tau, for
// x in [0, n): one pass over two rows that vectorizes (the paths' steps read
// the flags instead of comparing pixels one by one).
void ColourFlags(const std::uint8_t* __restrict a, const std::uint8_t* __restrict b, int channels,
                 int n, int tau, std::uint8_t* __restrict flags) {
  if (channels == 3) {
    for (int x = 0; x < n; ++x) {
      const int d0 = std::abs(a[3 * x] - b[3 * x]), d1 = std::abs(a[3 * x + 1] - b[3 * x + 1]),
                d2 = std::abs(a[3 * x + 2] - b[3 * x + 2]);
      flags[x] = std::max(d0, std::max(d1, d2)) >= tau ? 1 : 0;
    }
  } else {
    for (int x = 0; x < n; ++x)
      flags[x] = ColourDiff(a + channels * x, b + channels * x, channels) >= tau ? 1 : 0;
  }
}

// Whether the colour difference of the right image between each pixel and its
// predecessor along x (horizontal) or y (vertical) reaches tau_so (1 or 0), stored per row reversed
// and padded so that for a left pixel x the values at x_r = x − d_min − k are
// contiguous and increasing in k.
class RightDiffs {
 public:
  // Without `all_rows` the table holds one row, filled by Fill (each sweep
  // of the scanline its own, as it goes).
  RightDiffs(const cv::Mat& right, int min_disparity, int ndisp, bool vertical, int tau_so,
             bool all_rows = true)
      : right_(right),
        vertical_(vertical),
        tau_so_(tau_so),
        width_(right.cols),
        xr_hi_(right.cols + std::abs(min_disparity) + 2) {
    const int xr_lo = -std::abs(min_disparity) - ndisp - 2;  // ndisp: the span of lanes
    len_ = xr_hi_ - xr_lo + 1;
    data_.assign(static_cast<std::size_t>(all_rows ? right.rows + 1 : 1) * len_, 0);
    if (all_rows)
      for (int y = 0; y < right.rows; ++y) FillRow(y, &data_[static_cast<std::size_t>(y) * len_]);
  }
  // Row y (0 … rows; row `rows` is all zero), values for x_r = base − k,
  // from the whole table.
  const Cost* At(int y, int base_xr) const {
    return &data_[static_cast<std::size_t>(y) * len_ + (xr_hi_ - base_xr)];
  }
  // The one-row table: row y (0 … rows), values for x_r = base − k.
  void Fill(int y) {
    if (y == filled_) return;
    if (y < right_.rows && !(vertical_ && y == 0)) {
      FillRow(y, data_.data());
    } else {
      std::fill(data_.begin(), data_.end(), Cost{0});
    }
    filled_ = y;
  }
  const Cost* At(int base_xr) const { return &data_[xr_hi_ - base_xr]; }

 private:
  // Row y's flags (entries no x_r reaches stay as they are: zero).
  void FillRow(int y, Cost* out) {
    if (vertical_ && y == 0) return;
    const int ch = right_.channels();
    const std::uint8_t* r = right_.ptr<std::uint8_t>(y);
    const std::uint8_t* prev = vertical_ ? right_.ptr<std::uint8_t>(y - 1) : r;
    const int x0 = vertical_ ? 0 : 1;  // horizontally, x_r − 1 must exist
    flags_.resize(width_);
    ColourFlags(r + ch * x0, prev + ch * (vertical_ ? x0 : x0 - 1), ch, width_ - x0, tau_so_,
                flags_.data());
    for (int xr = x0; xr < width_; ++xr) out[xr_hi_ - xr] = flags_[xr - x0];
  }
  const cv::Mat& right_;
  bool vertical_;
  int tau_so_, width_, xr_hi_, len_;
  int filled_ = -1;
  std::vector<Cost> data_;           // 16-bit like the costs, so PathStep loads them at full width
  std::vector<std::uint8_t> flags_;  // one row's, in increasing x_r
};

struct Penalties {
  Cost p1[3], p2[3];  // index: number of colour differences at or above tau_so
};

// One step of a path: out = a + min(prev, prev(k±1) + P1, prev_min + P2) − prev_min,
// over the whole padded disparity axis [0, n) (n a multiple of the vector
// width). prev has one sentinel (kMaxCost) before and after (prev[-1],
// prev[n]); additions saturate. Padding lanes carry costs ≥ kPadCost, more
// than any real path value, so they never win the minimum.
// Returns min over k of out.
inline Cost PathStep(const Cost* __restrict a, const Cost* __restrict prev, Cost prev_min,
                     bool d1_big, const Cost* __restrict d2_big, const Penalties& pen, int n,
                     Cost* __restrict out) {
  const CostTag d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  // Penalties when the right image's difference is below / at or above tau_so.
  const auto p1_small = hn::Set(d, pen.p1[d1_big ? 1 : 0]);
  const auto p1_big = hn::Set(d, pen.p1[d1_big ? 2 : 1]);
  const auto vprev_min = hn::Set(d, prev_min);
  const auto jump_small = hn::SaturatedAdd(vprev_min, hn::Set(d, pen.p2[d1_big ? 1 : 0]));
  const auto jump_big = hn::SaturatedAdd(vprev_min, hn::Set(d, pen.p2[d1_big ? 2 : 1]));
  const auto zero = hn::Zero(d);
  auto vmin = hn::Set(d, kMaxCost);
  for (int k = 0; k < n; k += lanes) {
    const auto big = hn::Ne(hn::LoadU(d, d2_big + k), zero);
    const auto p1 = hn::IfThenElse(big, p1_big, p1_small);
    auto best = hn::Min(hn::LoadU(d, prev + k), hn::IfThenElse(big, jump_big, jump_small));
    best = hn::Min(best, hn::SaturatedAdd(
                             hn::Min(hn::LoadU(d, prev + k - 1), hn::LoadU(d, prev + k + 1)), p1));
    // best ≥ prev_min (the minimum of prev), so the difference is ≥ 0.
    const auto v = hn::SaturatedAdd(hn::LoadU(d, a + k), hn::Sub(best, vprev_min));
    hn::StoreU(v, d, out + k);
    vmin = hn::Min(vmin, v);
  }
  return MinLane(vmin);
}

// The first value of a path: the costs themselves.
inline Cost PathStart(const Cost* __restrict a, int n, Cost* __restrict out) {
  std::copy_n(a, n, out);
  return *std::min_element(a, a + n);
}

// out[k] = saturate(out[k] + add[k]).
inline void AddSaturated(const Cost* __restrict add, int n, Cost* __restrict out) {
  const CostTag d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  for (int k = 0; k < n; k += lanes)
    hn::StoreU(hn::SaturatedAdd(hn::LoadU(d, out + k), hn::LoadU(d, add + k)), d, out + k);
}

// out[k] = saturate(a[k] + b[k]).
inline void SumSaturated(const Cost* __restrict a, const Cost* __restrict b, int n,
                         Cost* __restrict out) {
  const CostTag d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  for (int k = 0; k < n; k += lanes)
    hn::StoreU(hn::SaturatedAdd(hn::LoadU(d, a + k), hn::LoadU(d, b + k)), d, out + k);
}

Cost ToPenalty(double value) {
  return static_cast<Cost>(std::clamp(std::lround(value * kCostScale), 0L, 16383L));
}

}  // namespace

void ScanlineOptimize(const cv::Mat& left, const cv::Mat& right, int min_disparity,
                      const ADCensusOptions& options, const Parallel& parallel,
                      const CostVolume* cost, const CostComputer* recompute, CostVolume* result,
                      cv::Mat* left_index, cv::Mat* right_index, cv::Mat* runner_up,
                      cv::Mat* winner_sums, CostVolume* store) {
  if (cost) {
    result->Reshape(cost->width(), cost->height(), cost->ndisp());
    result->CopyOffsetsFrom(*cost);
  }
  // C: read from `cost`, or from *result before it is overwritten.
  const CostVolume& in = cost ? *cost : *result;
  const int width = in.width(), height = in.height();
  const int total = in.total_ndisp(), stride = in.stride();
  // Lanes reach up to this far past a pixel's offset 0.
  const int span = in.total_ndisp() - in.ndisp() + stride;
  const int ch = left.channels();
  const int tau_so = static_cast<int>(std::ceil(options.tau_so));  // integer differences
  const Penalties pen{
      {ToPenalty(options.pi1), ToPenalty(options.pi1 / 4), ToPenalty(options.pi1 / 10)},
      {ToPenalty(options.pi2), ToPenalty(options.pi2 / 4), ToPenalty(options.pi2 / 10)}};
  // One path's state with sentinels around it: one each side without
  // offsets; with offsets, enough that the previous pixel's lanes can be
  // read shifted to the current pixel's offset (by at most stride + 1, which
  // already leaves no overlap).
  const int pad = in.has_offsets() ? stride + 2 : 1;
  const std::size_t lane = stride + 2 * pad;
  const auto shift = [&](int o, int o_prev) {
    return std::clamp(o - o_prev, -stride - 1, stride + 1);
  };

  left_index->create(height, width, CV_32FC1);
  right_index->create(height, width, CV_32FC1);
  if (runner_up) runner_up->create(height, width, CV_32SC2);
  if (winner_sums) winner_sums->create(height, width, CV_16SC3);
  const int held = in.ndisp();
  // What the refinement reads of a winner's sum while it is in cache.
  const auto keep = [&](int y, int x, const Cost* out, int k) {
    if (runner_up) {
      std::int32_t* u = runner_up->ptr<std::int32_t>(y) + 2 * x;
      u[0] = out[k];
      u[1] = RunnerUp(out, held, stride, k);
    }
    if (winner_sums) {
      Cost* w = winner_sums->ptr<Cost>(y) + 3 * x;
      w[0] = k > 0 ? out[k - 1] : Cost{0};
      w[1] = out[k];
      w[2] = k + 1 < stride ? out[k + 1] : Cost{0};
    }
  };
  // The winners of the final sum S(y, x) (`out`), pixels offered to the right
  // view's winners in decreasing x or all in increasing x.
  const auto finish = [&](int y, int x, int o, const Cost* out, float* l, bool decreasing_x,
                          RightWinners* winners) {
    const int k = ArgMin(out, stride);
    l[x] = static_cast<float>(o + k);
    keep(y, x, out, k);
    winners->Offer(x, out, decreasing_x, o);
  };

  // One step of row y's path along x (step 1: left→right, −1: right→left)
  // at pixel x, the j-th of the path, with offset o and costs a: `cur` from
  // `prev` (each a padded lane), *min the path's minimum, *prev_offset the
  // previous pixel's offset.
  // `h_flags`: row y's horizontal colour-difference flags (RightDiffs) at
  // x_r = 0, those of x_r at h_flags − x_r.
  // `d1_big`: whether the left image's colour difference between x and
  // x − step reaches tau_so (unused at j = 0).
  const auto horizontal_step = [&](bool d1_big, const Cost* h_flags, int x, int j, int step, int o,
                                   const Cost* a, const Cost* prev, Cost* cur, Cost* min,
                                   int* prev_offset) {
    if (j == 0) {
      *min = PathStart(a, stride, cur + pad);
    } else {
      // Right-image pair (x_r, x_r − step): left→right uses hdiff(x_r),
      // right→left uses hdiff(x_r + 1).
      const int base_xr = x - min_disparity - o + (step > 0 ? 0 : 1);
      *min = PathStep(a, prev + pad + shift(o, *prev_offset), *min, d1_big, h_flags - base_xr, pen,
                      stride, cur + pad);
    }
    *prev_offset = o;
  };

  if (parallel.num_threads() <= 2) {
    // Two sweeps over whole rows, at once on two threads (one after the
    // other on one): top→bottom with left→right, bottom→top with
    // right→left. Each gets C's rows in order (recomputed, or read once,
    // sequentially) and keeps one row of vertical state per column in cache.
    // The first sweep to reach a row writes its two paths' sum as S(y); the
    // second adds its own as it goes, which completes S(y, x), and takes the
    // winners. S is written and read once, in order, and C is never stored:
    // the volume's traffic of the band passes below, which walk columns
    // through DRAM, was most of their time. Saturating sums of non-negative
    // costs do not depend on the order of the terms, so the result is the
    // band passes' exactly. Rows: 0 untouched, 1 being written by the first
    // sweep, 2 written.
    std::unique_ptr<std::atomic<std::uint8_t>[]> state(new std::atomic<std::uint8_t>[height]);
    for (int y = 0; y < height; ++y) state[y].store(0, std::memory_order_relaxed);
    // Vertical state: stride costs per column between two sentinels; a
    // column whose offset changed from the row before is read shifted
    // through `shifted`, whose pads always hold sentinels.
    const std::size_t vlane = stride + 2;
    // Without a store each sweep computes every row's costs itself.
    if (!cost && store) store->Reshape(width, height, in.ndisp());
    const bool shared = !cost && store;
    parallel.For(0, 2, [&](int s0, int s1) {
      std::vector<Cost> costs(cost || shared ? 0 : static_cast<std::size_t>(width) * stride);
      std::vector<Cost> vprev(width * vlane, kMaxCost), vcur(width * vlane, kMaxCost);
      std::vector<Cost> hprev(lane, kMaxCost), hcur(lane, kMaxCost), shifted(lane, kMaxCost);
      std::vector<Cost> vmin(width);
      std::vector<int> voffset(width);
      std::vector<std::uint8_t> v_big(width), h_big(width, 0);
      CostComputer::Scratch scratch;
      RightWinners winners(width, min_disparity, stride, span);
      // Each sweep's colour-difference flags, row by row as it goes.
      RightDiffs hdiff(right, min_disparity, span, false, tau_so, /*all_rows=*/false);
      RightDiffs vdiff(right, min_disparity, span, true, tau_so, /*all_rows=*/false);
      for (int sweep = s0; sweep < s1; ++sweep) {
        const int ystep = sweep == 0 ? 1 : -1, xstep = ystep;
        for (int i = 0, y = sweep == 0 ? 0 : height - 1; i < height; ++i, y += ystep) {
          const std::uint8_t* row = left.ptr<std::uint8_t>(y);
          const std::uint8_t* prow = i == 0 ? row : left.ptr<std::uint8_t>(y - ystep);
          const std::int32_t* offsets = in.offset_row(y);
          const Cost* c_row = cost ? cost->at(y, 0) : shared ? store->row(y) : costs.data();
          if (!cost && !shared) recompute->Row(y, &scratch, costs.data(), offsets);
          std::uint8_t untouched = 0;
          const bool first =
              state[y].compare_exchange_strong(untouched, 1, std::memory_order_acq_rel);
          // The first sweep at the row computes its costs for both.
          if (first && shared) recompute->Row(y, &scratch, store->row(y), offsets);
          // Second: the other sweep is writing the row (both are at the same
          // row, where they cross) or has written it.
          if (!first)
            while (state[y].load(std::memory_order_acquire) != 2) std::this_thread::yield();
          Cost* s_row = result->at(y, 0);
          float* l = left_index->ptr<float>(y);
          winners.Reset();
          // Top→bottom pairs (y, y−1): vdiff row y; bottom→top: vdiff row y+1.
          const int vy = sweep == 0 ? y : y + 1;
          hdiff.Fill(y);
          vdiff.Fill(vy);
          // The left image's flags of the row: with the row before along the
          // sweep, and with the pixel before along it (x − xstep).
          ColourFlags(row, prow, ch, width, tau_so, v_big.data());
          if (xstep > 0) {
            ColourFlags(row + ch, row, ch, width - 1, tau_so, h_big.data() + 1);
          } else {
            ColourFlags(row, row + ch, ch, width - 1, tau_so, h_big.data());
          }
          Cost hmin = 0;
          int hoffset = 0;
          for (int j = 0, x = sweep == 0 ? 0 : width - 1; j < width; ++j, x += xstep) {
            const Cost* a = c_row + static_cast<std::size_t>(x) * stride;
            const int o = offsets ? offsets[x] : 0;
            Cost* vc = &vcur[x * vlane + 1];
            if (i == 0) {
              vmin[x] = PathStart(a, stride, vc);
            } else {
              const bool d1_big = v_big[x] != 0;
              const Cost* vp = &vprev[x * vlane + 1];
              if (o != voffset[x]) {
                std::copy_n(vp, stride, &shifted[pad]);
                vp = &shifted[pad + shift(o, voffset[x])];
              }
              vmin[x] = PathStep(a, vp, vmin[x], d1_big, vdiff.At(x - min_disparity - o), pen,
                                 stride, vc);
            }
            voffset[x] = o;
            horizontal_step(h_big[x] != 0, hdiff.At(0), x, j, xstep, o, a, hprev.data(),
                            hcur.data(), &hmin, &hoffset);
            Cost* out = s_row + static_cast<std::size_t>(x) * stride;
            if (first) {
              SumSaturated(vc, &hcur[pad], stride, out);
            } else {
              const int k = winners.AddSumOffer(x, vc, &hcur[pad], out, sweep == 1, o);
              l[x] = static_cast<float>(o + k);
              keep(y, x, out, k);
            }
            std::swap(hprev, hcur);
          }
          std::swap(vprev, vcur);
          if (first)
            state[y].store(2, std::memory_order_release);
          else
            winners.Write(total, right_index->ptr<float>(y));
        }
      }
    });
    return;
  }

  // More threads: passes over the whole volume, split between them.
  if (!cost) ComputeCost(*recompute, parallel, result);  // C, overwritten by S below
  const RightDiffs hdiff(right, min_disparity, span, false, tau_so);
  const RightDiffs vdiff(right, min_disparity, span, true, tau_so);
  // Pass 1: vertical paths over bands of columns, one row of state per
  // column. Top→bottom values go to a band buffer (height × band × stride);
  // bottom→top then reads C(y, x) and writes S(y, x) = L_tb + L_bt in its
  // place, so C is read twice and S written once.
  const int bands = (width + kScanBand - 1) / kScanBand;
  parallel.For(0, bands, [&](int b0, int b1) {
    std::vector<Cost> prev(kScanBand * lane, kMaxCost), cur(kScanBand * lane, kMaxCost);
    std::vector<Cost> down(static_cast<std::size_t>(height) * kScanBand * stride);
    Cost prev_min[kScanBand] = {};
    int prev_offset[kScanBand] = {};
    for (int b = b0; b < b1; ++b) {
      const int x0 = b * kScanBand, x1 = std::min(width, x0 + kScanBand);
      for (int dir = 0; dir < 2; ++dir) {
        const int y_start = dir == 0 ? 0 : height - 1, step = dir == 0 ? 1 : -1;
        for (int i = 0, y = y_start; i < height; ++i, y += step) {
          const int y_ahead = y + kPrefetchRows * step;
          if (y_ahead >= 0 && y_ahead < height) PrefetchRun(in, y_ahead, x0, x1 - x0);
          const std::uint8_t* row = left.ptr<std::uint8_t>(y);
          const std::uint8_t* prow = i == 0 ? row : left.ptr<std::uint8_t>(y - step);
          const std::int32_t* offsets = in.offset_row(y);
          for (int x = x0; x < x1; ++x) {
            const int c = x - x0;
            const Cost* a = in.at(y, x);
            const int o = offsets ? offsets[x] : 0;
            Cost* cl = &cur[c * lane + pad];
            if (i == 0) {
              prev_min[c] = PathStart(a, stride, cl);
            } else {
              const bool d1_big = ColourDiff(row + ch * x, prow + ch * x, ch) >= tau_so;
              // Top→bottom pairs (y, y−1): vdiff row y; bottom→top: vdiff row y+1.
              const int vy = dir == 0 ? y : y + 1;
              prev_min[c] =
                  PathStep(a, &prev[c * lane + pad + shift(o, prev_offset[c])], prev_min[c], d1_big,
                           vdiff.At(vy, x - min_disparity - o), pen, stride, cl);
            }
            prev_offset[c] = o;
            Cost* tb = &down[(static_cast<std::size_t>(y) * kScanBand + c) * stride];
            if (dir == 0) {
              std::copy_n(cl, stride, tb);
            } else {
              AddSaturated(cl, stride, tb);
              std::copy_n(tb, stride, result->at(y, x));  // may overwrite C(y, x): read above
            }
          }
          std::swap(prev, cur);
        }
      }
    }
  });

  // Pass 2: horizontal paths row by row, the sum and the winners.
  parallel.For(0, height, [&](int y0, int y1) {
    std::vector<Cost> prev(lane, kMaxCost), cur(lane, kMaxCost);
    std::vector<Cost> forward(static_cast<std::size_t>(width) * stride);  // L left→right
    std::vector<Cost> costs(cost ? 0 : static_cast<std::size_t>(width) * stride);
    CostComputer::Scratch scratch;
    RightWinners winners(width, min_disparity, stride, span);
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* row = left.ptr<std::uint8_t>(y);
      float* l = left_index->ptr<float>(y);
      const std::int32_t* offsets = in.offset_row(y);
      const Cost* c_row = cost ? cost->at(y, 0) : costs.data();
      if (!cost) recompute->Row(y, &scratch, costs.data(), offsets);
      winners.Reset();
      for (int dir = 0; dir < 2; ++dir) {
        const int x_start = dir == 0 ? 0 : width - 1, step = dir == 0 ? 1 : -1;
        Cost prev_min = 0;
        int prev_offset = 0;
        for (int i = 0, x = x_start; i < width; ++i, x += step) {
          const Cost* a = c_row + static_cast<std::size_t>(x) * stride;
          const int o = offsets ? offsets[x] : 0;
          const bool d1_big =
              i > 0 && ColourDiff(row + ch * x, row + ch * (x - step), ch) >= tau_so;
          horizontal_step(d1_big, hdiff.At(y, 0), x, i, step, o, a, prev.data(), cur.data(),
                          &prev_min, &prev_offset);
          Cost* fwd = &forward[static_cast<std::size_t>(x) * stride];
          if (dir == 0) {
            std::copy_n(&cur[pad], stride, fwd);
          } else {
            Cost* out = result->at(y, x);
            AddSaturated(fwd, stride, out);
            AddSaturated(&cur[pad], stride, out);
            finish(y, x, o, out, l, true, &winners);
          }
          std::swap(prev, cur);
        }
      }
      winners.Write(total, right_index->ptr<float>(y));
    }
  });
}

}  // namespace craftscan::adcensus
