// Census transform, matching cost and cross arms.
#include <hwy/highway.h>
#include <sys/mman.h>

#if defined(__AVX512BW__) && defined(__AVX512VPOPCNTDQ__)
#include <immintrin.h>
#define CRAFTSCAN_COST_PERMUTE 1
#else
#define CRAFTSCAN_COST_PERMUTE 0
#endif
#if !CRAFTSCAN_COST_PERMUTE && defined(__AVX2__)
#include <immintrin.h>
#define CRAFTSCAN_COST_AVX2 1
#else
#define CRAFTSCAN_COST_AVX2 0
#endif

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <opencv2/core.hpp>

#include "adcensus_internal.h"

namespace craftscan::adcensus {

void CostVolume::SetOffsets(std::vector<std::int32_t> offsets, int total_ndisp) {
  CV_Assert(offsets.size() == static_cast<std::size_t>(width_) * height_ && ndisp_ == stride_ &&
            total_ndisp >= ndisp_);
  for (const std::int32_t o : offsets) CV_Assert(o >= 0 && o <= total_ndisp - ndisp_);
  offsets_ = std::move(offsets);
  total_ndisp_ = total_ndisp;
}

void CostVolume::Reshape(int width, int height, int ndisp) {
  width_ = width;
  height_ = height;
  ndisp_ = ndisp;
  stride_ = StrideFor(ndisp);
  total_ndisp_ = ndisp;
  offsets_.clear();
  const std::size_t costs = static_cast<std::size_t>(width) * height * stride_;
  if (costs <= capacity_) return;
  data_.reset();
  capacity_ = 0;
  // Volumes are tens to hundreds of MB: ask for transparent huge pages so the
  // first touch costs one fault per 2 MB instead of one per 4 kB.
  constexpr std::size_t kHugePage = std::size_t{2} << 20;
  const std::size_t bytes = costs * sizeof(Cost);
  const std::size_t rounded = (bytes + kHugePage - 1) / kHugePage * kHugePage;
  void* p = std::aligned_alloc(kHugePage, rounded);
  if (!p) throw std::bad_alloc();
  ::madvise(p, rounded, MADV_HUGEPAGE);  // advisory; ignore failure
  data_.reset(static_cast<Cost*>(p));
  capacity_ = costs;
}

std::vector<std::uint64_t> CensusTransform(const cv::Mat& grey, int win_w, int win_h,
                                           const Parallel& parallel) {
  std::vector<std::uint64_t> census;
  CensusTransform(grey, win_w, win_h, parallel, &census);
  return census;
}

#if defined(__AVX2__)
namespace {

// 32 census words of one row from x0 on, into out[0 … 31] (AVX2). Each
// neighbour's comparison for 32 pixels is a byte mask (the image is biased
// by 0x80, so that the signed compare orders it as unsigned); its bit goes
// into byte plane bit / 8 of the word, and the eight planes are transposed
// into 32 words at the end. `rows[dy + rh]` point at the biased padded rows
// (each readable 32 bytes past the last pixel), `bits` = neighbours.
void CensusRun32(const std::uint8_t* const* rows, int rw, int rh, int x0, int bits,
                 std::uint64_t* out) {
  const __m256i centre = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rows[rh] + x0));
  __m256i plane[8];
  for (__m256i& p : plane) p = _mm256_setzero_si256();
  int bit = bits - 1;  // the first neighbour is the highest bit
  for (int dy = -rh; dy <= rh; ++dy) {
    const std::uint8_t* row = rows[dy + rh] + x0;
    for (int dx = -rw; dx <= rw; ++dx, --bit) {
      if (dx == 0 && dy == 0) {
        ++bit;
        continue;
      }
      const __m256i darker =
          _mm256_cmpgt_epi8(centre, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row + dx)));
      plane[bit >> 3] = _mm256_or_si256(
          plane[bit >> 3],
          _mm256_and_si256(darker, _mm256_set1_epi8(static_cast<char>(1u << (bit & 7)))));
    }
  }
  // Byte planes → words: three levels of unpacks give, per register, the
  // words of pixels (2i, 2i + 1) in its low half and (2i + 16, 2i + 17) in
  // its high half.
  __m256i a[8], b[8], w[8];
  for (int j = 0; j < 4; ++j) {
    a[2 * j] = _mm256_unpacklo_epi8(plane[2 * j], plane[2 * j + 1]);      // x 0–7 | 16–23
    a[2 * j + 1] = _mm256_unpackhi_epi8(plane[2 * j], plane[2 * j + 1]);  // x 8–15 | 24–31
  }
  for (int j = 0; j < 2; ++j) {
    for (int h = 0; h < 2; ++h) {
      const __m256i lo = a[4 * j + h], hi = a[4 * j + 2 + h];
      b[4 * j + 2 * h] = _mm256_unpacklo_epi16(lo, hi);
      b[4 * j + 2 * h + 1] = _mm256_unpackhi_epi16(lo, hi);
    }
  }
  // b[0 … 3]: planes 0–3 of x 0–3, 4–7, 8–11, 12–15 (| +16); b[4 … 7]: planes 4–7.
  for (int q = 0; q < 4; ++q) {
    w[2 * q] = _mm256_unpacklo_epi32(b[q], b[4 + q]);
    w[2 * q + 1] = _mm256_unpackhi_epi32(b[q], b[4 + q]);
  }
  for (int q = 0; q < 4; ++q) {
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + 4 * q),
                        _mm256_permute2x128_si256(w[2 * q], w[2 * q + 1], 0x20));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + 16 + 4 * q),
                        _mm256_permute2x128_si256(w[2 * q], w[2 * q + 1], 0x31));
  }
}

}  // namespace
#endif

void CensusTransform(const cv::Mat& grey, int win_w, int win_h, const Parallel& parallel,
                     std::vector<std::uint64_t>* census_out) {
  CV_Assert(grey.type() == CV_8UC1 && win_w % 2 == 1 && win_h % 2 == 1 && win_w * win_h <= 65);
  const int rw = win_w / 2, rh = win_h / 2;
  const int width = grey.cols;
  std::vector<std::uint64_t>& census = *census_out;
  census.resize(grey.total());  // every word is written below
#if defined(__AVX2__)
  // 32 pixels at a time (CensusRun32): the padded rows get 32 more columns
  // on the right for the last run's reads, and the image is biased by 0x80.
  cv::Mat padded;
  cv::copyMakeBorder(grey, padded, rh, rh, rw, rw + 32, cv::BORDER_REPLICATE);
  cv::bitwise_xor(padded, cv::Scalar(0x80), padded);
  const int bits = win_w * win_h - 1;
  parallel.For(0, grey.rows, [&](int y0, int y1) {
    std::vector<const std::uint8_t*> rows(win_h);
    alignas(32) std::uint64_t last[32];
    for (int y = y0; y < y1; ++y) {
      for (int dy = 0; dy < win_h; ++dy) rows[dy] = padded.ptr<std::uint8_t>(y + dy) + rw;
      std::uint64_t* out = census.data() + static_cast<std::size_t>(y) * width;
      int x = 0;
      for (; x + 32 <= width; x += 32) CensusRun32(rows.data(), rw, rh, x, bits, out + x);
      if (x < width) {
        CensusRun32(rows.data(), rw, rh, x, bits, last);
        std::copy_n(last, width - x, out + x);
      }
    }
  });
#else
  cv::Mat padded;
  cv::copyMakeBorder(grey, padded, rh, rh, rw, rw, cv::BORDER_REPLICATE);
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
#endif
}

namespace {

// out[k] = lut[hamming[k] · ad_size + Σ_c |a_c − r_c[k]|] for k in [k0, k1):
// one table of ρ_AD + ρ_census in fixed point, so one gather per vector.
void CostRun(const std::int32_t* a, const std::int32_t* const* r, int channels,
             const std::int32_t* hamming, const std::int32_t* lut, int ad_size, int k0, int k1,
             Cost* out) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<std::int32_t> di;
  const hn::Rebind<Cost, decltype(di)> dc;
  const int lanes = static_cast<int>(hn::Lanes(di));
  const auto row = hn::Set(di, ad_size);
  int k = k0;
  for (; k + lanes <= k1; k += lanes) {
    auto sad = hn::Abs(hn::Sub(hn::Set(di, a[0]), hn::LoadU(di, r[0] + k)));
    for (int c = 1; c < channels; ++c)
      sad = hn::Add(sad, hn::Abs(hn::Sub(hn::Set(di, a[c]), hn::LoadU(di, r[c] + k))));
    const auto index = hn::Add(hn::Mul(hn::LoadU(di, hamming + k), row), sad);
    hn::StoreU(hn::DemoteTo(dc, hn::GatherIndex(di, lut, index)), dc, out + k);
  }
  for (; k < k1; ++k) {
    int sad = 0;
    for (int c = 0; c < channels; ++c) sad += std::abs(a[c] - r[c][k]);
    out[k] = static_cast<Cost>(lut[hamming[k] * ad_size + sad]);
  }
}

// What both ways of computing a row share. The right row reversed (j =
// width − 1 − x_r) into *rev_census and *rev_colour (one plane per channel),
// so that for a left pixel the candidates x_r = x − d_min − k are contiguous
// and increasing in k; then each left pixel x: lanes(x, j0, k_lo, k_hi, out)
// computes its valid lanes [k_lo, k_hi) (j0: j of k = 0, out: the pixel's
// costs), and the lanes outside the image get `outside`, the padding
// kPadCost.
template <class Colour, class Lanes>
void EachPixel(const cv::Mat& right, const std::uint64_t* census_right, int y, int min_disparity,
               int ndisp, int stride, Cost outside, const std::int32_t* offsets,
               std::vector<std::uint64_t>* rev_census, std::vector<Colour>* rev_colour, Cost* out,
               Lanes lanes) {
  const int width = right.cols, channels = right.channels();
  rev_census->resize(width);
  rev_colour->resize(static_cast<std::size_t>(channels) * width);
  const std::uint8_t* pr = right.ptr<std::uint8_t>(y);
  const std::uint64_t* cr = census_right + static_cast<std::size_t>(y) * width;
  for (int j = 0; j < width; ++j) {
    const int xr = width - 1 - j;
    (*rev_census)[j] = cr[xr];
    for (int c = 0; c < channels; ++c)
      (*rev_colour)[static_cast<std::size_t>(c) * width + j] = pr[channels * xr + c];
  }
  for (int x = 0; x < width; ++x, out += stride) {
    const int d0 = min_disparity + (offsets ? offsets[x] : 0);  // disparity of k = 0
    // Valid k: 0 ≤ x − (d0 + k) < width.
    const int k_lo = std::clamp(x - width + 1 - d0, 0, ndisp);
    const int k_hi = std::max(k_lo, std::clamp(x - d0 + 1, 0, ndisp));
    for (int k = 0; k < k_lo; ++k) out[k] = outside;
    lanes(x, width - 1 - x + d0, k_lo, k_hi, out);
    for (int k = k_hi; k < ndisp; ++k) out[k] = outside;
    for (int k = ndisp; k < stride; ++k) out[k] = CostVolume::kPadCost;
  }
}

// A cost on Mei's [0, 2] scale in fixed point.
std::int32_t ToFixed(double cost) {
  return static_cast<std::int32_t>(std::lround(cost * kCostScale));
}

}  // namespace

CostComputer::CostComputer(const cv::Mat& left, const cv::Mat& right,
                           const std::vector<std::uint64_t>& census_left,
                           const std::vector<std::uint64_t>& census_right, int min_disparity,
                           int ndisp, double lambda_ad, double lambda_census,
                           double out_of_image_cost)
    : left_(left),
      right_(right),
      census_left_(census_left),
      census_right_(census_right),
      min_disparity_(min_disparity),
      ndisp_(ndisp),
      stride_(CostVolume::StrideFor(ndisp)),
      outside_(static_cast<Cost>(ToFixed(out_of_image_cost))),
      ad_size_(255 * left.channels() + 1),
      lut_(static_cast<std::size_t>(65) * ad_size_) {
  // ρ_AD indexed by the channel sum of absolute differences, ρ_census by the
  // Hamming distance, each rounded, then their sums in one table
  // lut_[h · ad_size_ + s] (65 × 766 entries for colour: 200 kB, in L2).
  const int channels = left.channels();
  std::vector<std::int32_t> ad(ad_size_);
  for (int s = 0; s < ad_size_; ++s)
    ad[s] = ToFixed(1.0 - std::exp(-(static_cast<double>(s) / channels) / lambda_ad));
  for (int h = 0; h <= 64; ++h) {
    const std::int32_t census = ToFixed(1.0 - std::exp(-h / lambda_census));
    for (int s = 0; s < ad_size_; ++s)
      lut_[static_cast<std::size_t>(h) * ad_size_ + s] = ad[s] + census;
    census16_[h] = static_cast<std::int16_t>(census);
  }
  // In-register look-ups need ρ_AD to be constant from a sum of 255 on (it
  // saturates at 1 from about 7.6 λ_AD per channel: 229 for colour with
  // Mei's λ_AD of 10, 77 for grey) and every cost to fit 16 bits.
  bool saturated = true;
  for (int s = 0; s < ad_size_; ++s) {
    if (s < 256) ad16_[s] = static_cast<std::int16_t>(ad[s]);
    if (s > 255 && ad[s] != ad[255]) saturated = false;
  }
  const bool fits = saturated && ad_size_ >= 256 &&
                    *std::max_element(lut_.begin(), lut_.end()) <= std::numeric_limits<Cost>::max();
  permute_ = CRAFTSCAN_COST_PERMUTE && fits;
  if (CRAFTSCAN_COST_AVX2 && fits) {
    lut16_.assign(65 * 256, 0);
    for (int h = 0; h <= 64; ++h)
      for (int s = 0; s < 256; ++s)
        lut16_[static_cast<std::size_t>(h) * 256 + s] =
            static_cast<std::int16_t>(ad16_[s] + census16_[h]);
  }
}

#if CRAFTSCAN_COST_PERMUTE
// Row() with both terms looked up in registers, 32 lanes at a time: ρ_census
// from two vectors of 32 entries (one permute), ρ_AD of the clamped sum
// from eight (four permutes and three blends). The table's one gather per
// 16 lanes is bound by its 16 loads. Same values as the table's.
void CostComputer::PermuteRow(int y, Scratch* scratch, Cost* out,
                              const std::int32_t* offsets) const {
  const int width = left_.cols, channels = left_.channels();
  const std::uint8_t* pl = left_.ptr<std::uint8_t>(y);
  const std::uint64_t* cl = census_left_.data() + static_cast<std::size_t>(y) * width;
  __m512i ad[8];
  for (int t = 0; t < 8; ++t) ad[t] = _mm512_loadu_si512(ad16_ + 32 * t);
  const __m512i census_lo = _mm512_loadu_si512(census16_);
  const __m512i census_hi = _mm512_loadu_si512(census16_ + 32);
  const __m512i census_64 = _mm512_set1_epi16(census16_[64]);
  const __m512i h64 = _mm512_set1_epi16(64), bit6 = _mm512_set1_epi16(64);
  const __m512i bit7 = _mm512_set1_epi16(128), top = _mm512_set1_epi16(255);
  EachPixel(
      right_, census_right_.data(), y, min_disparity_, ndisp_, stride_, outside_, offsets,
      &scratch->rev_census, &scratch->rev_colour16, out,
      [&](int x, int j0, int k_lo, int k_hi, Cost* o) {
        const __m512i anchor = _mm512_set1_epi64(static_cast<long long>(cl[x]));
        __m512i a[3];
        const std::int16_t* r[3] = {};
        for (int c = 0; c < channels; ++c) {
          a[c] = _mm512_set1_epi16(pl[channels * x + c]);
          r[c] = scratch->rev_colour16.data() + static_cast<std::size_t>(c) * width + j0;
        }
        const std::uint64_t* rc = scratch->rev_census.data() + j0;
        for (int k = k_lo; k < k_hi; k += 32) {
          const int n = std::min(32, k_hi - k);
          const __mmask32 m = n == 32 ? ~__mmask32{0} : (__mmask32{1} << n) - 1;
          // Hamming distances of four groups of 8, narrowed to 16 bits.
          __m128i q[4];
          for (int g = 0; g < 4; ++g) {
            const auto mg = static_cast<__mmask8>(m >> (8 * g));
            const __m512i w = _mm512_maskz_loadu_epi64(mg, rc + k + 8 * g);
            q[g] = _mm512_cvtepi64_epi16(_mm512_popcnt_epi64(_mm512_xor_si512(w, anchor)));
          }
          const __m512i h =
              _mm512_inserti64x4(_mm512_castsi256_si512(_mm256_inserti128_si256(
                                     _mm256_castsi128_si256(q[0]), q[1], 1)),
                                 _mm256_inserti128_si256(_mm256_castsi128_si256(q[2]), q[3], 1), 1);
          __m512i sad = _mm512_setzero_si512();
          for (int c = 0; c < channels; ++c)
            sad = _mm512_add_epi16(sad, _mm512_abs_epi16(_mm512_sub_epi16(
                                            a[c], _mm512_maskz_loadu_epi16(m, r[c] + k))));
          const __m512i s = _mm512_min_epu16(sad, top);
          const __mmask32 m6 = _mm512_test_epi16_mask(s, bit6);
          const __mmask32 m7 = _mm512_test_epi16_mask(s, bit7);
          const __m512i lo = _mm512_mask_blend_epi16(m6, _mm512_permutex2var_epi16(ad[0], s, ad[1]),
                                                     _mm512_permutex2var_epi16(ad[2], s, ad[3]));
          const __m512i hi = _mm512_mask_blend_epi16(m6, _mm512_permutex2var_epi16(ad[4], s, ad[5]),
                                                     _mm512_permutex2var_epi16(ad[6], s, ad[7]));
          const __m512i rho_census = _mm512_mask_blend_epi16(
              _mm512_cmpeq_epi16_mask(h, h64), _mm512_permutex2var_epi16(census_lo, h, census_hi),
              census_64);
          _mm512_mask_storeu_epi16(
              o + k, m, _mm512_add_epi16(_mm512_mask_blend_epi16(m7, lo, hi), rho_census));
        }
      });
}
#else
void CostComputer::PermuteRow(int, Scratch*, Cost*, const std::int32_t*) const {}
#endif

#if CRAFTSCAN_COST_AVX2
// Row() on AVX2 (no AVX-512), 16 lanes at a time: the Hamming distances by
// nibble look-ups (vpshufb) and vpsadbw (AVX2 has no vector popcount), the
// sums of differences and each lane's index into lut16_ as 16-bit vectors,
// then the entries read one by one: on Zen 3 a 32-bit gather of the 16-bit
// table was slower (Teddy's volume on one thread: the int32 table's gathers
// 13.7 ms, 8 lanes of lut16_ gathered 12.5, read one by one 10.0). The last
// lanes (fewer than 16) one by one. Same values as the table's.
void CostComputer::TableRow(int y, Scratch* scratch, Cost* out, const std::int32_t* offsets) const {
  const int width = left_.cols, channels = left_.channels();
  const std::uint8_t* pl = left_.ptr<std::uint8_t>(y);
  const std::uint64_t* cl = census_left_.data() + static_cast<std::size_t>(y) * width;
  const __m256i nibble_counts = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0,
                                                 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low_nibble = _mm256_set1_epi8(0x0f);
  const __m256i in_order = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
  const __m256i top = _mm256_set1_epi16(255);
  alignas(32) std::uint16_t index[16];
  // Population counts of four 64-bit words, one per 64-bit lane.
  const auto popcount4 = [&](__m256i v) {
    const __m256i lo = _mm256_and_si256(v, low_nibble);
    const __m256i hi = _mm256_and_si256(_mm256_srli_epi16(v, 4), low_nibble);
    const __m256i bytes = _mm256_add_epi8(_mm256_shuffle_epi8(nibble_counts, lo),
                                          _mm256_shuffle_epi8(nibble_counts, hi));
    return _mm256_sad_epu8(bytes, _mm256_setzero_si256());
  };
  EachPixel(
      right_, census_right_.data(), y, min_disparity_, ndisp_, stride_, outside_, offsets,
      &scratch->rev_census, &scratch->rev_colour16, out,
      [&](int x, int j0, int k_lo, int k_hi, Cost* o) {
        const __m256i anchor = _mm256_set1_epi64x(static_cast<long long>(cl[x]));
        __m256i a[3];
        const std::int16_t* r[3] = {};
        for (int c = 0; c < channels; ++c) {
          a[c] = _mm256_set1_epi16(pl[channels * x + c]);
          r[c] = scratch->rev_colour16.data() + static_cast<std::size_t>(c) * width + j0;
        }
        const std::uint64_t* rc = scratch->rev_census.data() + j0;
        int k = k_lo;
        for (; k + 16 <= k_hi; k += 16) {
          const auto words = [&](int at) {
            return _mm256_xor_si256(
                _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rc + k + at)), anchor);
          };
          // Pairs of four counts as (c0₀, c1₀, c0₁, c1₁, …) 32-bit lanes, put
          // in lane order; then narrowed to 16 bits (the pack works per
          // 128-bit half, the permute puts the halves in order).
          const auto eight = [&](__m256i c0, __m256i c1) {
            return _mm256_permutevar8x32_epi32(
                _mm256_blend_epi32(c0, _mm256_slli_epi64(c1, 32), 0xaa), in_order);
          };
          const __m256i h = _mm256_permute4x64_epi64(
              _mm256_packus_epi32(eight(popcount4(words(0)), popcount4(words(4))),
                                  eight(popcount4(words(8)), popcount4(words(12)))),
              0xd8);
          __m256i sad = _mm256_setzero_si256();
          for (int c = 0; c < channels; ++c)
            sad = _mm256_add_epi16(
                sad, _mm256_abs_epi16(_mm256_sub_epi16(
                         a[c], _mm256_loadu_si256(reinterpret_cast<const __m256i*>(r[c] + k)))));
          _mm256_store_si256(reinterpret_cast<__m256i*>(index),
                             _mm256_add_epi16(_mm256_slli_epi16(h, 8), _mm256_min_epu16(sad, top)));
          for (int i = 0; i < 16; ++i) o[k + i] = lut16_[index[i]];
        }
        for (; k < k_hi; ++k) {
          int sad = 0;
          for (int c = 0; c < channels; ++c)
            sad += std::abs(static_cast<int>(pl[channels * x + c]) - r[c][k]);
          const int h = std::popcount(cl[x] ^ rc[k]);
          o[k] = lut16_[static_cast<std::size_t>(h) * 256 + std::min(sad, 255)];
        }
      });
}
#else
void CostComputer::TableRow(int, Scratch*, Cost*, const std::int32_t*) const {}
#endif

void CostComputer::Row(int y, Scratch* scratch, Cost* out, const std::int32_t* offsets) const {
  if (permute_) return PermuteRow(y, scratch, out, offsets);
  if (!lut16_.empty()) return TableRow(y, scratch, out, offsets);
  const int width = left_.cols, channels = left_.channels();
  scratch->hamming.resize(ndisp_ + 16);
  std::int32_t* hamming = scratch->hamming.data();
  const std::uint8_t* pl = left_.ptr<std::uint8_t>(y);
  const std::uint64_t* cl = census_left_.data() + static_cast<std::size_t>(y) * width;
  EachPixel(right_, census_right_.data(), y, min_disparity_, ndisp_, stride_, outside_, offsets,
            &scratch->rev_census, &scratch->rev_colour, out,
            [&](int x, int j0, int k_lo, int k_hi, Cost* o) {
              // Hamming distances first (scalar popcount, independent
              // iterations), then the table look-ups and sums as vectors.
              const std::uint64_t anchor = cl[x];
              const std::uint64_t* rc = scratch->rev_census.data() + j0;
              for (int k = k_lo; k < k_hi; ++k)
                hamming[k] = static_cast<std::int32_t>(std::popcount(anchor ^ rc[k]));
              std::int32_t a[3] = {};
              const std::int32_t* r[3] = {};
              for (int c = 0; c < channels; ++c) {
                a[c] = pl[channels * x + c];
                r[c] = scratch->rev_colour.data() + static_cast<std::size_t>(c) * width + j0;
              }
              CostRun(a, r, channels, hamming, lut_.data(), ad_size_, k_lo, k_hi, o);
            });
}

void ComputeCost(const cv::Mat& left, const cv::Mat& right,
                 const std::vector<std::uint64_t>& census_left,
                 const std::vector<std::uint64_t>& census_right, int min_disparity,
                 double lambda_ad, double lambda_census, float out_of_image_cost,
                 const Parallel& parallel, CostVolume* cost) {
  ComputeCost(CostComputer(left, right, census_left, census_right, min_disparity, cost->ndisp(),
                           lambda_ad, lambda_census, out_of_image_cost),
              parallel, cost);
}

void ComputeCost(const CostComputer& computer, const Parallel& parallel, CostVolume* cost) {
  parallel.For(0, cost->height(), [&](int y0, int y1) {
    CostComputer::Scratch scratch;
    for (int y = y0; y < y1; ++y) computer.Row(y, &scratch, cost->row(y), cost->offset_row(y));
  });
}

namespace {

struct ArmLimits {
  int max_len;  // arm length must stay below this (D_s < L)
  double l2;    // beyond this length the tighter colour limit applies
  double tau;   // colour limit to the anchor and to the previous pixel
  double tau2;  // colour limit to the anchor beyond l2
};

// The image as planes (one per channel) so that loops over x vectorize.
struct Planes {
  int channels = 0, width = 0, height = 0;
  const std::vector<cv::Mat>& plane;  // CV_8UC1 each
  const std::uint8_t* row(int c, int y) const { return plane[c].ptr<std::uint8_t>(y); }
};

// Bytes readable past the end of every row buffer the arms' vector loops
// read (and writable past those they write): their last vector reads and
// writes whole, masked by its lanes (a vector is at most 64 bytes).
constexpr int kArmPad = 64;

// The image's planes, written into *memory, each with kArmPad readable bytes
// after its last row (its rows are views of a taller buffer).
Planes Split(const cv::Mat& image, std::vector<cv::Mat>* memory) {
  const int channels = image.channels();
  memory->resize(channels);
  const int extra = 1 + kArmPad / image.cols;
  for (cv::Mat& plane : *memory) {
    if (plane.rows == image.rows && plane.cols == image.cols && plane.type() == CV_8UC1 &&
        plane.isContinuous() && plane.datalimit - plane.dataend >= kArmPad)
      continue;
    plane = cv::Mat(image.rows + extra, image.cols, CV_8UC1).rowRange(0, image.rows);
  }
  std::vector<const std::uint8_t*> kept;
  for (const cv::Mat& plane : *memory) kept.push_back(plane.data);
  cv::split(image, *memory);
  for (int c = 0; c < channels; ++c) CV_Assert((*memory)[c].data == kept[c]);
  return Planes{channels, image.cols, image.rows, *memory};
}

inline std::uint8_t AbsDiff(std::uint8_t a, std::uint8_t b) {
  return static_cast<std::uint8_t>(a > b ? a - b : b - a);
}

// Per-pixel limits of one row: for the classic rule all pixels share one set.
struct RowLimits {
  std::vector<std::uint8_t> max_len, l2, tau, tau2;  // integer forms of the limits
};

// One step of arm growth for the anchors [x0, x1): an anchor still active
// stays so while its arm pixel at length `len` passes every test (length,
// colour to the anchor and to the previous arm pixel, the tighter colour
// limit beyond l2, the gradient), and each active anchor's arm grows by one.
// Returns whether any anchor is still active. Whole vectors, the last one
// masked (the compiler's version ended in a scalar loop of up to 63 pixels,
// as long as the rest, for every length of every row; AVX2 has no masked
// byte loads, so the buffers are padded instead).
bool GrowArms(std::uint8_t len, const RowLimits& lim, const std::uint8_t* __restrict d_anchor,
              const std::uint8_t* __restrict d_prev, const std::uint8_t* __restrict grad_ok, int x0,
              int x1, std::uint8_t* __restrict active, std::uint8_t* __restrict out) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<std::uint8_t> d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  const auto vlen = hn::Set(d, len);
  const auto zero = hn::Zero(d);
  auto any = zero;
  // Anchors [x, x + lanes) where `valid` (the last vector: those before x1).
  const auto step = [&](int x, hn::Mask<decltype(d)> valid) {
    const auto load = [&](const std::uint8_t* p) { return hn::LoadU(d, p); };
    const auto anchor = load(d_anchor + x);
    const auto tau = load(lim.tau.data() + x);
    const auto ok =
        hn::And(hn::And(hn::And(hn::Lt(vlen, load(lim.max_len.data() + x)), hn::Lt(anchor, tau)),
                        hn::And(hn::Lt(load(d_prev + x), tau), hn::Ne(load(grad_ok + x), zero))),
                hn::Or(hn::Not(hn::Lt(load(lim.l2.data() + x), vlen)),
                       hn::Lt(anchor, load(lim.tau2.data() + x))));
    const auto a = hn::IfThenElseZero(hn::And(ok, valid), load(active + x));
    hn::StoreU(a, d, active + x);
    hn::StoreU(hn::Add(load(out + x), a), d, out + x);
    any = hn::Or(any, a);
  };
  int x = x0;
  for (; x + lanes <= x1; x += lanes) step(x, hn::FirstN(d, static_cast<std::size_t>(lanes)));
  // The last vector whole (every buffer has kArmPad bytes after x1, see
  // BuildArms), its lanes from x1 on masked: there `active` becomes 0 (it is
  // 0 already, or padding) and `out` gets + 0.
  if (x < x1) step(x, hn::FirstN(d, static_cast<std::size_t>(x1 - x)));
  return !hn::AllTrue(d, hn::Eq(any, zero));
}

// d = max over channels |a − b| for whole rows: out[x] = D_c(a[x + da], b[x + db]).
// All channels in one pass of whole vectors, the last one masked with
// AVX-512, elsewhere read whole from the padded planes and stored in part.
void RowColourDiff(const Planes& p, int ya, int da, int yb, int db, int n, std::uint8_t* out) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<std::uint8_t> d;
  const int lanes = static_cast<int>(hn::Lanes(d));
  const int channels = p.channels;
  const std::uint8_t* a[3];
  const std::uint8_t* b[3];
  for (int c = 0; c < channels && c < 3; ++c) {
    a[c] = p.row(c, ya) + da;
    b[c] = p.row(c, yb) + db;
  }
  if (channels > 3) {  // not an image this matcher takes; kept general
    for (int c = 0; c < channels; ++c) {
      const std::uint8_t* pa = p.row(c, ya) + da;
      const std::uint8_t* pb = p.row(c, yb) + db;
      for (int x = 0; x < n; ++x)
        out[x] = c == 0 ? AbsDiff(pa[x], pb[x]) : std::max(out[x], AbsDiff(pa[x], pb[x]));
    }
    return;
  }
  const auto diff = [&](int x, auto load) {
    auto m = hn::Zero(d);
    for (int c = 0; c < channels; ++c) {
      const auto va = load(a[c] + x), vb = load(b[c] + x);
      m = hn::Max(m, hn::Or(hn::SaturatedSub(va, vb), hn::SaturatedSub(vb, va)));
    }
    return m;
  };
  int x = 0;
  for (; x + lanes <= n; x += lanes)
    hn::StoreU(diff(x, [&](const std::uint8_t* q) { return hn::LoadU(d, q); }), d, out + x);
#if HWY_TARGET <= HWY_AVX3
  if (x < n) {
    const auto m = hn::FirstN(d, static_cast<std::size_t>(n - x));
    hn::BlendedStore(diff(x, [&](const std::uint8_t* q) { return hn::MaskedLoad(m, d, q); }), m, d,
                     out + x);
  }
#else
  // The planes have kArmPad readable bytes after their last row (Split):
  // the last vector is read whole and its first n − x lanes kept.
  if (x < n) {
    alignas(64) std::uint8_t last[64];
    hn::Store(diff(x, [&](const std::uint8_t* q) { return hn::LoadU(d, q); }), d, last);
    std::memcpy(out + x, last, static_cast<std::size_t>(n - x));
  }
#endif
}

// Integer thresholds: with integer colour differences, "d < tau" equals
// "d < ceil(tau)"; lengths compare as integers too ("len > l2" ⇔ len > floor(l2)).
std::uint8_t CeilU8(double v) {
  return static_cast<std::uint8_t>(std::clamp(std::ceil(v), 0.0, 255.0));
}
std::uint8_t FloorU8(double v) {
  return static_cast<std::uint8_t>(std::clamp(std::floor(v), 0.0, 255.0));
}

// ok[x] = |a[x] − b[x]| < limit for x in [x0, x1). Explicit SIMD: GCC does
// not vectorize this float-to-byte loop on its own.
void GradientWithin(const float* a, const float* b, float limit, int x0, int x1, std::uint8_t* ok) {
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<float> df;
  const hn::RebindToSigned<decltype(df)> di;
  const hn::Rebind<std::uint8_t, decltype(df)> du8;
  const int lanes = static_cast<int>(hn::Lanes(df));
  const auto vlimit = hn::Set(df, limit);
  const auto one = hn::Set(di, 1);
  int x = x0;
#if defined(__AVX2__)
  // 32 at a time, packed to bytes in one chain (the loop below packs each 8
  // on its own, and was most of the arms' time on AVX2).
  const __m256 sign = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  const __m256 vlim = _mm256_set1_ps(limit);
  const __m256i order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
  const __m256i ones = _mm256_set1_epi8(1);
  const auto within8 = [&](int at) {
    const __m256 diff = _mm256_sub_ps(_mm256_loadu_ps(a + at), _mm256_loadu_ps(b + at));
    return _mm256_castps_si256(_mm256_cmp_ps(_mm256_and_ps(diff, sign), vlim, _CMP_LT_OQ));
  };
  for (; x + 32 <= x1; x += 32) {
    // Per 128-bit half the packs give 4 lanes of each quarter in turn; the
    // permute puts the quarters' halves back in order.
    const __m256i packed = _mm256_packs_epi16(_mm256_packs_epi32(within8(x), within8(x + 8)),
                                              _mm256_packs_epi32(within8(x + 16), within8(x + 24)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(ok + x),
                        _mm256_and_si256(_mm256_permutevar8x32_epi32(packed, order), ones));
  }
#endif
  for (; x + lanes <= x1; x += lanes) {
    const auto within =
        hn::Lt(hn::Abs(hn::Sub(hn::LoadU(df, a + x), hn::LoadU(df, b + x))), vlimit);
    hn::StoreU(hn::DemoteTo(du8, hn::IfThenElseZero(hn::RebindMask(di, within), one)), du8, ok + x);
  }
  for (; x < x1; ++x) ok[x] = std::abs(a[x] - b[x]) < limit ? 1 : 0;
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
  BuildArms(image, gradient, edges, options, parallel, &arms);
  return arms;
}

void BuildArms(const cv::Mat& image, const cv::Mat& gradient, const cv::Mat& edges,
               const ADCensusOptions& options, const Parallel& parallel, Arms* out) {
  Arms& arms = *out;
  const int width = image.cols, height = image.rows;
  arms.width = width;
  arms.height = height;
  const std::size_t n = image.total();
  arms.left.assign(n, 0);
  arms.right.assign(n, 0);
  arms.up.assign(n, 0);
  arms.down.assign(n, 0);

  const bool improved = options.arm_rule == ArmRule::kImproved;
  ArmLimits weak{}, edge{};
  float beta1 = 0;
  if (improved) {
    const ImprovedArmOptions& o = options.improved;
    weak = {o.l_max_px, static_cast<double>(o.l2_px), o.tau_max, o.tau2};
    edge = {static_cast<int>(std::lround(o.l_max_px * o.edge_length_scale)),
            o.l2_px * o.edge_length_scale, o.tau_max * o.edge_tau_scale, o.tau2};
    beta1 = static_cast<float>(o.beta1);
  } else {
    const ClassicArmOptions& o = options.classic;
    weak = edge = {o.l1_px, static_cast<double>(o.l2_px), o.tau1, o.tau2};
  }
  const int longest = std::max(weak.max_len, edge.max_len);
  const Planes planes = Split(image, &arms.planes);
  // vertical_diff row y = D_c(I(y), I(y − 1)) for y ≥ 1: the vertical arms'
  // step test reads it for every anchor row whose arm passes row y.
  std::vector<std::uint8_t>& vertical_diff = arms.vertical_diff;
  vertical_diff.assign(static_cast<std::size_t>(width) * height + kArmPad, 0);  // padded
  parallel.For(1, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      RowColourDiff(planes, y, 0, y - 1, 0, width,
                    vertical_diff.data() + static_cast<std::size_t>(y) * width);
  });

  // Each direction is one loop over arm length L with an inner, branch-free
  // loop over x: a pixel's arm grows while it is still "active".
  parallel.For(0, height, [&](int y0, int y1) {
    // Every row buffer GrowArms reads has kArmPad bytes after the row.
    const std::size_t padded = static_cast<std::size_t>(width) + kArmPad;
    RowLimits lim;
    lim.max_len.resize(padded);
    lim.l2.resize(padded);
    lim.tau.resize(padded);
    lim.tau2.resize(padded);
    std::vector<std::uint8_t> active(padded), d_anchor(padded), arm(padded);
    std::vector<std::uint8_t> prev_diff_h(padded), grad_ok(padded, 1);
    const double beta_max = options.improved.beta_max;
    const bool canny = options.improved.canny_edges_are_edges && !edges.empty();
    for (int y = y0; y < y1; ++y) {
      const float* g = improved ? gradient.ptr<float>(y) : nullptr;
      const std::uint8_t* e = improved && canny ? edges.ptr<std::uint8_t>(y) : nullptr;
      for (int x = 0; x < width; ++x) {
        // IsEdgePixel, on the row's pointers.
        const bool is_edge =
            improved && (static_cast<double>(g[x]) >= beta_max || (e && e[x] != 0));
        const ArmLimits& l = is_edge ? edge : weak;
        lim.max_len[x] = static_cast<std::uint8_t>(std::min(l.max_len, 255));
        lim.l2[x] = FloorU8(l.l2);
        lim.tau[x] = CeilU8(l.tau);
        lim.tau2[x] = CeilU8(l.tau2);
      }
      // prev_diff_h[x] = D_c(I(x), I(x − 1)), x ≥ 1.
      if (width > 1) RowColourDiff(planes, y, 1, y, 0, width - 1, prev_diff_h.data() + 1);

      const std::size_t base = static_cast<std::size_t>(y) * width;
      for (int dir = 0; dir < 4; ++dir) {
        // dir 0: right, 1: left, 2: down, 3: up.
        // The arms grow in `arm` (padded, and this thread's own), then are
        // copied to the row.
        std::uint8_t* out = arm.data();
        std::fill(arm.begin(), arm.end(), 0);
        std::fill_n(active.begin(), width, 1);
        for (int len = 1; len < longest; ++len) {
          // Anchors x whose arm pixel q is inside the image: [x_lo, x_hi).
          int x_lo = 0, x_hi = width, qy = y, dx = 0;
          if (dir == 0) {
            x_hi = width - len;
            dx = len;
          } else if (dir == 1) {
            x_lo = len;
            dx = -len;
          } else {
            qy = dir == 2 ? y + len : y - len;
            if (qy < 0 || qy >= height) break;
          }
          if (x_hi <= x_lo) break;
          // Anchors outside [x_lo, x_hi) stop here.
          for (int x = 0; x < x_lo; ++x) active[x] = 0;
          for (int x = x_hi; x < width; ++x) active[x] = 0;
          const int m = x_hi - x_lo;
          RowColourDiff(planes, qy, x_lo + dx, y, x_lo, m, d_anchor.data() + x_lo);
          // d_prev[x]: D_c(q, the pixel before q on the arm), q the arm pixel of anchor x.
          const std::uint8_t* d_prev =
              dir == 0   ? prev_diff_h.data() + dx
              : dir == 1 ? prev_diff_h.data() + dx + 1  // D_c(q, q + 1) = prev_diff_h[q + 1]
              : dir == 2 ? vertical_diff.data() + static_cast<std::size_t>(qy) * width
                         : vertical_diff.data() + static_cast<std::size_t>(qy + 1) * width;
          if (improved)
            GradientWithin(gradient.ptr<float>(qy) + dx, g, beta1, x_lo, x_hi, grad_ok.data());
          if (!GrowArms(static_cast<std::uint8_t>(len), lim, d_anchor.data(), d_prev,
                        grad_ok.data(), x_lo, x_hi, active.data(), out))
            break;
        }
        std::uint8_t* row = (dir == 0   ? arms.right
                             : dir == 1 ? arms.left
                             : dir == 2 ? arms.down
                                        : arms.up)
                                .data() +
                            base;
        std::copy_n(arm.data(), width, row);
      }
    }
  });
}

}  // namespace craftscan::adcensus
