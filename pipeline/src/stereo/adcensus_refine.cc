// Mei et al.'s multi-step disparity refinement: outlier detection with
// occlusion/mismatch labels, iterative region voting, proper interpolation,
// depth-discontinuity adjustment, sub-pixel enhancement and a median filter.
//
// Every step reads the previous step's maps and writes new ones, so results
// never depend on the order in which threads visit pixels.
#include <hwy/highway.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "adcensus_internal.h"

namespace craftscan::adcensus {
namespace {

enum Label : std::uint8_t { kReliable = 0, kOccluded = 1, kMismatch = 2, kAmbiguous = 3 };

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The left-right check on a slanted surface. Where a surface turns away
// from the right camera more than from the left one, the right view holds
// it on fewer pixels: dR steps by (1 − r) / r from one right pixel to the
// next (r: the right's pixels per left pixel), and a left pixel's disparity
// falls between two right pixels' values rather than within the tolerance
// of the one it lands on. With exact disparities that happens once r < 1/3,
// and sooner with a matcher's ±1 px (the box's side face seen at a grazing
// angle, the egg's lower cap): a sampling effect, not a mismatch. So where
// the right pixel it lands on and a neighbour differ by kMinRightStepPx to
// kMaxRightStepPx (r between 1/4 and 1/2: one steep surface, not the two
// sides of a depth edge), the check also passes a left disparity between
// their two values, within the tolerance. Gentler slopes (steps of 0 or
// 1 px) keep the plain check: there it holds by geometry, and widening it
// would only let noise through.
constexpr float kMinRightStepPx = 2.f;
constexpr float kMaxRightStepPx = 3.f;

inline bool OnRightSlope(const float* r, int xr, int width, float dl, double tolerance) {
  const float tol = static_cast<float>(tolerance);
  for (int a = std::max(0, xr - 1); a <= std::min(xr, width - 2); ++a) {
    const float r0 = r[a], r1 = r[a + 1];
    if (!IsValidDisparity(r0) || !IsValidDisparity(r1)) continue;
    const float step = std::abs(r1 - r0);
    if (step < kMinRightStepPx || step > kMaxRightStepPx) continue;
    if (dl >= std::min(r0, r1) - tol && dl <= std::max(r0, r1) + tol) return true;
  }
  return false;
}

// With per-pixel ranges (cost has offsets) the mismatch search covers the
// disparities the pixel searched.
void DetectOutliers(const cv::Mat& left_index, const cv::Mat& right_index, int min_disparity,
                    const CostVolume& cost, double tolerance, const Parallel& parallel,
                    cv::Mat* labels) {
  const int width = left_index.cols;
  labels->create(left_index.size(), CV_8UC1);
  parallel.For(0, left_index.rows, [&](int y0, int y1) {
    // The right pixels whose winner points back at left pixel x, as lists:
    // right pixel x_r with integer index j points at x = x_r + d_min + j.
    std::vector<int> head(width), next(width);
    for (int y = y0; y < y1; ++y) {
      const float* l = left_index.ptr<float>(y);
      const float* r = right_index.ptr<float>(y);
      std::uint8_t* out = labels->ptr<std::uint8_t>(y);
      std::fill(head.begin(), head.end(), -1);
      for (int xr = 0; xr < width; ++xr) {
        // Only an integer index can equal a disparity index j (NaN fails too).
        if (!(r[xr] >= 0.f && r[xr] < static_cast<float>(cost.total_ndisp()))) continue;
        const int j = static_cast<int>(r[xr]);
        const int x = xr + min_disparity + j;
        if (static_cast<float>(j) != r[xr] || x < 0 || x >= width) continue;
        next[xr] = head[x];
        head[x] = xr;
      }
      for (int x = 0; x < width; ++x) {
        const int k = static_cast<int>(l[x]);
        const int xr = x - min_disparity - k;
        if (xr >= 0 && xr < width && IsValidDisparity(r[xr]) &&
            (std::abs(r[xr] - l[x]) <= tolerance || OnRightSlope(r, xr, width, l[x], tolerance))) {
          out[x] = kReliable;
          continue;
        }
        // A mismatch if some disparity j the pixel searched is consistent
        // in the right view (r(x − d_min − j) = j); otherwise the pixel is
        // occluded there.
        out[x] = kOccluded;
        const int j0 = cost.offset(y, x);
        const int j1 = cost.has_offsets() ? j0 + cost.ndisp() : cost.total_ndisp();
        for (int xj = head[x]; xj >= 0; xj = next[xj]) {
          const int j = x - min_disparity - xj;
          if (j >= j0 && j < j1) {
            out[x] = kMismatch;
            break;
          }
        }
      }
    }
  });
}

// Reliable pixels whose cost curve has no clear minimum become kAmbiguous:
// c[k] > (1 − uniqueness) · min over |j − k| ≥ 2 of c[j] (over the
// disparities the pixel holds). The neighbours of the winner are excluded:
// they are the same minimum, blurred.
// The winning and runner-up costs (RunnerUpCost) come from `runner_up` when
// given (the scanline pass's, taken while each pixel's sum was in cache),
// else from `cost`.
void MarkAmbiguous(const CostVolume& cost, const cv::Mat& left_index, double uniqueness,
                   const cv::Mat* runner_up, const Parallel& parallel, cv::Mat* labels) {
  const int ndisp = cost.ndisp();
  const float keep = static_cast<float>(1 - uniqueness);
  parallel.For(0, left_index.rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* l = left_index.ptr<float>(y);
      const std::int32_t* given = runner_up ? runner_up->ptr<std::int32_t>(y) : nullptr;
      std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      for (int x = 0; x < left_index.cols; ++x) {
        if (lab[x] != kReliable) continue;
        int winner, second;
        if (given) {
          winner = given[2 * x];
          second = given[2 * x + 1];
        } else {
          const Cost* c = cost.at(y, x);
          const int k = static_cast<int>(l[x]) - cost.offset(y, x);
          winner = c[k];
          second = RunnerUpCost(c, ndisp, cost.stride(), k);
        }
        if (second != kNoRunnerUp && static_cast<float>(winner) > keep * static_cast<float>(second))
          lab[x] = kAmbiguous;
      }
    }
  });
}

// Adds `delta` (±1) to the bins of b[u0 … u1] in four interleaved histograms
// h[0 … 3] (each `stride` ints apart): "++histogram[b[u]]" on one bin
// (disparities are piecewise constant) is a chain of dependent
// read-modify-writes through memory; four chains overlap.
inline void CountBins(const std::int16_t* b, int u0, int u1, int delta, int* h, int stride) {
  int* h0 = h;
  int* h1 = h + stride;
  int* h2 = h + 2 * stride;
  int* h3 = h + 3 * stride;
  int u = u0;
  for (; u + 3 <= u1; u += 4) {
    h0[b[u]] += delta;
    h1[b[u + 1]] += delta;
    h2[b[u + 2]] += delta;
    h3[b[u + 3]] += delta;
  }
  for (; u <= u1; ++u) h0[b[u]] += delta;
}

// out[k] = the sum of the four interleaved histograms (each `nb` bins apart)
// at bin k, for k in [0, n).
inline void SumPartials(const int* __restrict h, int nb, int n, int* __restrict out) {
  for (int k = 0; k < n; ++k) out[k] = h[k] + h[nb + k] + h[2 * nb + k] + h[3 * nb + k];
}

// Mei's vote on bins 0 … n−1 of one pixel's support-region histogram, given
// the region's reliable pixel count `votes`: the winning bin, or −1 when the
// vote is not decisive.
inline int Vote(const int* histogram, int n, int votes, const RefinementOptions& options,
                int* largest = nullptr) {
  if (votes <= options.tau_s) return -1;
  int most = 0;  // a plain max reduction vectorizes; std::max_element does not
  for (int k = 0; k < n; ++k) most = std::max(most, histogram[k]);
  if (largest) *largest = most;
  if (most <= options.tau_h * votes) return -1;
  return static_cast<int>(std::find(histogram, histogram + n, most) - histogram);
}

// How many pixels counted in `prefix` (per row, prefix counts over x) row v
// of the horizontal-first support region of a pixel of column x holds (the
// segment of v's own horizontal arms).
inline int SegmentCount(const Arms& arms, const cv::Mat& prefix, int v, int x) {
  const std::size_t j = arms.index(v, x);
  const int* cp = prefix.ptr<int>(v);
  return cp[x + arms.right[j] + 1] - cp[x - arms.left[j]];
}

// Iterative region voting. Each unreliable pixel's histogram is the sum over
// its vertical arm of the histograms of the horizontal segments (its
// horizontal-first support region).
//
// Most unreliable pixels never get that far: a vote needs more than tau_s
// reliable pixels in the region, and a region whose pixels did not change
// since its vote failed fails again. Those counts are exact and cost two
// loads a pixel: `region` holds, per column, prefix sums down the rows of
// each row's segment count (the reliable pixels on the pixel's own
// horizontal arms), so a region's count is region(hi, x) − region(lo, x).
// Votes only make pixels reliable, so a region's count rises by exactly the
// pixels that changed in it, and a bin by at most that: what a pixel's last
// histogram found (its largest bin) bounds the next, and settles most
// pixels whose region changed a little.
//
// Each iteration then (1) settles every unreliable pixel it can from the
// counts, row by row, and lists the rest by column; (2) takes their
// histograms column by column, down each column's list, in one running
// histogram of a window of rows (moving from one pixel's vertical arm to the
// next adds the rows that enter and removes those that leave, instead of
// counting each region from scratch; the counts are the same integers);
// (3) writes the votes, and updates the bins and the counts in the rows that
// changed. Every iteration reads the maps as the previous one left them.
//
// With per-pixel ranges (cost has offsets) a pixel takes its region's vote
// only among the disparities it searched (the votes for others still count
// in the total): one range of bins to sum and search instead of the band.
void RegionVoting(const Arms& arms, const CostVolume& cost, const RefinementOptions& options,
                  const Parallel& parallel, cv::Mat* disparity, cv::Mat* labels,
                  RefineWorkspace* ws) {
  const int width = disparity->cols, height = disparity->rows;
  const int ndisp = cost.total_ndisp();
  const int range = cost.has_offsets() ? cost.ndisp() : ndisp;
  if (options.voting_iterations <= 0) return;
  // bins: the disparity index of reliable pixels, ndisp for the others, so the
  // histogram loop needs no branch (bin ndisp collects the unreliable ones).
  cv::Mat& bins = ws->bins;
  bins.create(disparity->size(), CV_16SC1);
  const int nb = ndisp + 1;  // bins per histogram
  // Per row, prefix counts over x of the reliable pixels (then of the
  // pixels each iteration changed, in its dirty rows).
  cv::Mat& row_prefix = ws->reliable_prefix;
  row_prefix.create(height, width + 1, CV_32SC1);
  // region(v, x): over rows 0 … v − 1 of column x, the sum of each row's
  // segment count. Row-parallel first (each row's segment counts in row
  // v + 1), then summed down the columns on chunks of columns.
  cv::Mat& region = ws->region;
  region.create(height + 1, width, CV_32SC1);
  constexpr int kColumnGrain = 64;
  const auto segment = [&](int v, int x) {
    const std::size_t j = arms.index(v, x);
    const int* rp = row_prefix.ptr<int>(v);
    return rp[x + arms.right[j] + 1] - rp[x - arms.left[j]];
  };
  parallel.For(0, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* d = disparity->ptr<float>(y);
      const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      std::int16_t* b = bins.ptr<std::int16_t>(y);
      int* rp = row_prefix.ptr<int>(y);
      rp[0] = 0;
      for (int x = 0; x < width; ++x) {
        const bool reliable = lab[x] == kReliable;
        b[x] = static_cast<std::int16_t>(reliable ? static_cast<int>(d[x]) : ndisp);
        rp[x + 1] = rp[x] + (reliable ? 1 : 0);
      }
      int* seg = region.ptr<int>(y + 1);
      for (int x = 0; x < width; ++x) seg[x] = segment(y, x);
    }
  });
  std::fill_n(region.ptr<int>(0), width, 0);
  parallel.For(
      0, width,
      [&](int x0, int x1) {
        for (int v = 1; v <= height; ++v) {
          const int* above = region.ptr<int>(v - 1);
          int* row = region.ptr<int>(v);
          for (int x = x0; x < x1; ++x) row[x] += above[x];
        }
      },
      kColumnGrain);
  // The unreliable pixels row by row (row y: todo[row_start[y] …
  // row_start[y + 1])), with their vertical arms.
  std::vector<int>& row_start = ws->todo_start;
  std::vector<RefineWorkspace::VotingPixel>& todo = ws->todo;
  row_start.assign(static_cast<std::size_t>(height) + 1, 0);
  parallel.For(0, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      int n = 0;
      for (int x = 0; x < width; ++x) n += lab[x] != kReliable ? 1 : 0;
      row_start[y + 1] = n;
    }
  });
  for (int y = 0; y < height; ++y) row_start[y + 1] += row_start[y];
  todo.resize(static_cast<std::size_t>(row_start[height]));
  parallel.For(0, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      std::size_t t = static_cast<std::size_t>(row_start[y]);
      for (int x = 0; x < width; ++x) {
        if (lab[x] == kReliable) continue;
        const std::size_t i = arms.index(y, x);
        todo[t++] = {x, y - arms.up[i], y + arms.down[i] + 1};
      }
    }
  });
  // The workspace keeps these between calls: fresh ones each call would be
  // fresh pages (README 11.4).
  std::vector<RefineWorkspace::VotingState>& known = ws->known;
  known.assign(todo.size(), {});
  using Pending = RefineWorkspace::VotingPending;
  using Vote1 = RefineWorkspace::Vote;
  constexpr int kRowBlock = 16;
  const int row_blocks = (height + kRowBlock - 1) / kRowBlock;
  std::vector<std::vector<Pending>>& block_pending = ws->block_pending;
  block_pending.resize(static_cast<std::size_t>(row_blocks));
  std::vector<int> column_start(static_cast<std::size_t>(width) + 1);
  std::vector<Pending>& pending = ws->pending;
  std::vector<std::vector<Vote1>>& votes = ws->votes;
  votes.resize(static_cast<std::size_t>(width));
  cv::Mat& changed_flag = ws->changed_flag;
  changed_flag.create(height, width, CV_8UC1);
  changed_flag.setTo(0);
  std::vector<int> dirty_rows;
  std::vector<std::uint8_t> row_is_dirty(static_cast<std::size_t>(height), 0);
  std::vector<int> first_changed(static_cast<std::size_t>(height), 0);
  for (int it = 0; it < options.voting_iterations; ++it) {
    // (1) Settle what the counts settle; list the rest.
    parallel.For(0, row_blocks, [&](int b0, int b1) {
      for (int b = b0; b < b1; ++b) {
        std::vector<Pending>& out = block_pending[static_cast<std::size_t>(b)];
        out.clear();
        for (int y = b * kRowBlock; y < std::min(height, (b + 1) * kRowBlock); ++y) {
          for (int t = row_start[y]; t < row_start[y + 1]; ++t) {
            RefineWorkspace::VotingState& kn = known[static_cast<std::size_t>(t)];
            if (kn.voted) continue;
            const RefineWorkspace::VotingPixel& p = todo[static_cast<std::size_t>(t)];
            const int reliable = region.at<int>(p.hi, p.x) - region.at<int>(p.lo, p.x);
            if (kn.reliable >= 0) {
              const int added = reliable - kn.reliable;
              if (added == 0) continue;  // the region did not change: it fails again
              if (kn.most >= 0) kn.most = static_cast<std::int16_t>(kn.most + added);
            }
            kn.reliable = static_cast<std::int16_t>(reliable);
            if (reliable <= options.tau_s) continue;                            // too few votes
            if (kn.most >= 0 && kn.most <= options.tau_h * reliable) continue;  // not decisive
            out.push_back({t, y, p.lo, p.hi, reliable});
          }
        }
      }
    });
    // By column, each column's rows in order.
    std::fill(column_start.begin(), column_start.end(), 0);
    std::size_t n_pending = 0;
    for (const std::vector<Pending>& block : block_pending) {
      for (const Pending& q : block)
        ++column_start[static_cast<std::size_t>(todo[static_cast<std::size_t>(q.t)].x) + 1];
      n_pending += block.size();
    }
    for (int x = 0; x < width; ++x) column_start[x + 1] += column_start[x];
    pending.resize(n_pending);
    {
      std::vector<int> fill(column_start.begin(), column_start.end() - 1);
      for (const std::vector<Pending>& block : block_pending)
        for (const Pending& q : block)
          pending[static_cast<std::size_t>(
              fill[static_cast<std::size_t>(todo[static_cast<std::size_t>(q.t)].x)]++)] = q;
    }
    // (2) The histograms, column by column.
    parallel.For(0, width, [&](int x0, int x1) {
      std::vector<int> histogram(range), partial(4 * static_cast<std::size_t>(nb));
      for (int x = x0; x < x1; ++x) {
        std::vector<Vote1>& column_votes = votes[static_cast<std::size_t>(x)];
        column_votes.clear();
        // The running window holds rows [w_lo, w_hi) of column x.
        int w_lo = 0, w_hi = 0;
        const auto add_row = [&](int v, int delta) {
          const std::size_t j = arms.index(v, x);
          const int u0 = x - arms.left[j], u1 = x + arms.right[j];
          CountBins(bins.ptr<std::int16_t>(v), u0, u1, delta, partial.data(), nb);
        };
        for (int q = column_start[x]; q < column_start[x + 1]; ++q) {
          const Pending& p = pending[static_cast<std::size_t>(q)];
          if (p.lo >= w_hi || p.hi <= w_lo) {  // no overlap: start afresh
            std::fill(partial.begin(), partial.end(), 0);
            w_lo = w_hi = p.lo;
          }
          for (; w_hi < p.hi; ++w_hi) add_row(w_hi, 1);
          for (; w_lo > p.lo; --w_lo) add_row(w_lo - 1, 1);
          for (; w_hi > p.hi; --w_hi) add_row(w_hi - 1, -1);
          for (; w_lo < p.lo; ++w_lo) add_row(w_lo, -1);
          const int offset = cost.offset(p.y, x);
          SumPartials(partial.data() + offset, nb, range, histogram.data());
          int most = 0;
          const int k = Vote(histogram.data(), range, p.reliable, options, &most);
          RefineWorkspace::VotingState& kn = known[static_cast<std::size_t>(p.t)];
          kn.most = static_cast<std::int16_t>(most);
          if (k >= 0) {
            column_votes.push_back({p.y, static_cast<float>(offset + k)});
            kn.voted = true;
          }
        }
      }
    });
    // (3) Write the votes; note the rows they touch, and in each the first
    // column changed (columns go in order).
    dirty_rows.clear();
    for (int x = 0; x < width; ++x) {
      for (const Vote1& v : votes[static_cast<std::size_t>(x)]) {
        disparity->at<float>(v.y, x) = v.disparity;
        labels->at<std::uint8_t>(v.y, x) = kReliable;
        changed_flag.at<std::uint8_t>(v.y, x) = 1;
        if (!row_is_dirty[static_cast<std::size_t>(v.y)]) {
          row_is_dirty[static_cast<std::size_t>(v.y)] = 1;
          first_changed[static_cast<std::size_t>(v.y)] = x;
          dirty_rows.push_back(v.y);
        }
      }
    }
    if (dirty_rows.empty()) break;
    if (it + 1 < options.voting_iterations) {
      // The changed pixels' bins; the dirty rows' prefix counts of them
      // (row_prefix now counts the changes there); then every region sum
      // below the first dirty row gains the changes' segment counts above.
      parallel.For(0, static_cast<int>(dirty_rows.size()), [&](int r0, int r1) {
        for (int r = r0; r < r1; ++r) {
          const int y = dirty_rows[static_cast<std::size_t>(r)];
          const float* d = disparity->ptr<float>(y);
          std::int16_t* b = bins.ptr<std::int16_t>(y);
          std::uint8_t* flag = changed_flag.ptr<std::uint8_t>(y);
          int* cp = row_prefix.ptr<int>(y);
          const int first = first_changed[static_cast<std::size_t>(y)];
          std::fill(cp, cp + first + 1, 0);
          int changed = 0;
          for (int x = first; x < width; ++x) {
            if (flag[x]) {
              b[x] = static_cast<std::int16_t>(static_cast<int>(d[x]));
              flag[x] = 0;
              ++changed;
            }
            cp[x + 1] = changed;
          }
        }
      });
      const int top = *std::min_element(dirty_rows.begin(), dirty_rows.end());
      parallel.For(
          0, width,
          [&](int x0, int x1) {
            std::vector<int> gained(static_cast<std::size_t>(x1 - x0), 0);
            for (int v = top; v < height; ++v) {
              if (row_is_dirty[static_cast<std::size_t>(v)])
                for (int x = x0; x < x1; ++x) gained[x - x0] += segment(v, x);
              int* row = region.ptr<int>(v + 1);
              for (int x = x0; x < x1; ++x) row[x] += gained[x - x0];
            }
          },
          kColumnGrain);
    } else {
      for (int y : dirty_rows) {
        std::uint8_t* flag = changed_flag.ptr<std::uint8_t>(y);
        std::fill(flag, flag + width, 0);
      }
    }
    for (int y : dirty_rows) row_is_dirty[static_cast<std::size_t>(y)] = 0;
  }
}

void Interpolate(const cv::Mat& image, const Parallel& parallel, cv::Mat* disparity,
                 cv::Mat* labels, cv::Mat* scratch) {
  constexpr int kDirections = 16;
  const int width = image.cols, height = image.rows, ch = image.channels();
  const int max_steps = std::max(width, height);
  // Integer offsets of every step along each direction, computed once.
  std::vector<cv::Point> steps(static_cast<std::size_t>(kDirections) * max_steps);
  for (int i = 0; i < kDirections; ++i) {
    const double a = 2 * std::numbers::pi * i / kDirections;
    for (int s = 1; s < max_steps; ++s) {
      const std::size_t k = static_cast<std::size_t>(i) * max_steps + s;
      steps[k] = cv::Point(static_cast<int>(std::lround(s * std::cos(a))),
                           static_cast<int>(std::lround(s * std::sin(a))));
    }
  }
  // The first step of each direction that leaves the image, per column and
  // per row (a ray's offsets grow monotonically along each axis, so once
  // outside it stays outside): a walk from (y, x) ends before
  // min(leave_x[x], leave_y[y]).
  std::vector<int> leave_x(static_cast<std::size_t>(kDirections) * width, max_steps);
  std::vector<int> leave_y(static_cast<std::size_t>(kDirections) * height, max_steps);
  const auto first_exits = [&](int i, int n, bool along_x, int* leave) {
    const cv::Point* ray = &steps[static_cast<std::size_t>(i) * max_steps];
    int low = 0, high = n - 1;  // positions not yet assigned: [low, high]
    for (int s = 1; s < max_steps && low <= high; ++s) {
      const int d = along_x ? ray[s].x : ray[s].y;
      while (high >= low && high + d >= n) leave[high--] = s;
      while (low <= high && low + d < 0) leave[low++] = s;
    }
  };
  for (int i = 0; i < kDirections; ++i) {
    first_exits(i, width, true, &leave_x[static_cast<std::size_t>(i) * width]);
    first_exits(i, height, false, &leave_y[static_cast<std::size_t>(i) * height]);
  }
  disparity->copyTo(*scratch);
  cv::Mat& out = *scratch;
  // Pixel (y, x) from the first step of each direction that meets a reliable
  // pixel (found[i], 0 where the ray leaves the image first).
  const auto settle = [&](int y, int x, const int* found) {
    const std::uint8_t* colour = image.ptr<std::uint8_t>(y) + ch * x;
    float lowest = std::numeric_limits<float>::infinity(), most_similar = kNaN;
    int best_diff = std::numeric_limits<int>::max();
    for (int i = 0; i < kDirections; ++i) {
      if (found[i] == 0) continue;
      const cv::Point& step = steps[static_cast<std::size_t>(i) * max_steps + found[i]];
      const int qx = x + step.x, qy = y + step.y;
      const float d = disparity->at<float>(qy, qx);
      lowest = std::min(lowest, d);
      const int diff = ColourDiff(colour, image.ptr<std::uint8_t>(qy) + ch * qx, ch);
      if (diff < best_diff) {
        best_diff = diff;
        most_similar = d;
      }
    }
    if (best_diff == std::numeric_limits<int>::max()) {
      out.at<float>(y, x) = kNaN;  // no reliable pixel in any direction
    } else {
      // Occlusions take the background (lowest disparity); mismatches the
      // neighbour that looks most alike.
      out.at<float>(y, x) = labels->at<std::uint8_t>(y, x) == kOccluded ? lowest : most_similar;
    }
  };
  // The walks of a run of pixels of one row, one direction at a time, in the
  // lanes of a vector: step s reads the labels at the same offset from every
  // pixel, one load for the run. A run costs its longest walk rather than
  // the sum of its walks, which in a wide occluded or unmatched region are
  // all long. The load is whole: while any lane's ray is inside the image,
  // the vector's other lanes lie within `lanes` labels of it, so the labels
  // (as 16-bit, row after row) get `lanes` of padding before and after, and
  // lanes whose ray has left are masked out of the comparison.
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<std::uint16_t> d16;
  const int lanes = static_cast<int>(hn::Lanes(d16));
  std::vector<std::uint16_t> labels16_memory(static_cast<std::size_t>(width) * height + 2 * lanes,
                                             kMismatch);
  std::uint16_t* const labels16 = labels16_memory.data() + lanes;
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
    std::copy_n(lab, width, labels16 + static_cast<std::size_t>(y) * width);
  }
  const std::ptrdiff_t step16 = width;
  std::vector<std::ptrdiff_t> linear16(steps.size(), 0);
  for (std::size_t k = 0; k < steps.size(); ++k)
    linear16[k] = static_cast<std::ptrdiff_t>(steps[k].y) * step16 + steps[k].x;
  std::vector<std::uint16_t> leave_x16(leave_x.size() + lanes, 0);  // padded alike
  std::copy(leave_x.begin(), leave_x.end(), leave_x16.begin());
  parallel.For(0, height, [&](int y0, int y1) {
    std::vector<std::uint16_t> found16(static_cast<std::size_t>(kDirections) * lanes);
    const auto zero = hn::Zero(d16);
    for (int y = y0; y < y1; ++y) {
      const std::uint16_t* row = labels16 + static_cast<std::size_t>(y) * width;
      for (int x0 = 0; x0 < width; x0 += lanes) {
        const auto in_row = hn::FirstN(d16, static_cast<std::size_t>(std::min(lanes, width - x0)));
        const auto unreliable = hn::And(in_row, hn::Ne(hn::LoadU(d16, row + x0), zero));
        if (hn::AllFalse(d16, unreliable)) continue;
        for (int i = 0; i < kDirections; ++i) {
          const std::size_t base = static_cast<std::size_t>(i) * max_steps;
          const auto limit =
              hn::Min(hn::LoadU(d16, &leave_x16[static_cast<std::size_t>(i) * width + x0]),
                      hn::Set(d16, static_cast<std::uint16_t>(
                                       leave_y[static_cast<std::size_t>(i) * height + y])));
          auto found = zero;
          auto active = unreliable;
          for (int st = 1;; ++st) {
            const auto vs = hn::Set(d16, static_cast<std::uint16_t>(st));
            active = hn::And(active, hn::Lt(vs, limit));
            if (hn::AllFalse(d16, active)) break;
            const auto hit =
                hn::And(active, hn::Eq(hn::LoadU(d16, row + x0 + linear16[base + st]), zero));
            found = hn::IfThenElse(hit, vs, found);
            active = hn::AndNot(hit, active);
          }
          hn::StoreU(found, d16, &found16[static_cast<std::size_t>(i) * lanes]);
        }
        const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
        for (int j = 0; j < lanes && x0 + j < width; ++j) {
          if (lab[x0 + j] == kReliable) continue;
          int found[kDirections];
          for (int i = 0; i < kDirections; ++i)
            found[i] = found16[static_cast<std::size_t>(i) * lanes + j];
          settle(y, x0 + j, found);
        }
      }
    }
  });
  cv::swap(*disparity, *scratch);
}

void AdjustDiscontinuities(const CostVolume& cost, const Parallel& parallel, cv::Mat* disparity,
                           cv::Mat* scratch) {
  const int width = disparity->cols;
  disparity->copyTo(*scratch);
  cv::Mat& out = *scratch;
  parallel.For(0, disparity->rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* d = disparity->ptr<float>(y);
      float* o = out.ptr<float>(y);
      for (int x = 1; x + 1 < width; ++x) {
        if (!IsValidDisparity(d[x]) || !IsValidDisparity(d[x - 1]) || !IsValidDisparity(d[x + 1]))
          continue;
        if (std::abs(d[x - 1] - d[x + 1]) <= 1.f) continue;  // not on a disparity edge
        // Lanes of this pixel; a neighbour's disparity it does not hold
        // cannot be compared.
        const Cost* c = cost.at(y, x);
        const int offset = cost.offset(y, x), n = cost.ndisp();
        const int k = static_cast<int>(d[x]) - offset, k1 = static_cast<int>(d[x - 1]) - offset,
                  k2 = static_cast<int>(d[x + 1]) - offset;
        if (k < 0 || k >= n) continue;
        int best = k;
        if (k1 >= 0 && k1 < n && c[k1] < c[best]) best = k1;
        if (k2 >= 0 && k2 < n && c[k2] < c[best]) best = k2;
        o[x] = static_cast<float>(best + offset);
      }
    }
  });
  cv::swap(*disparity, *scratch);
}

// `winner_sums` (may be null): the volume's values around each pixel's
// winner (`winners`: the winner-take-all's indices), read instead of the
// volume where the disparity is still the winner: the volume is far larger
// than the caches, and a pixel's read of it is a miss.
void Subpixel(const CostVolume& cost, const cv::Mat& winners, const cv::Mat* winner_sums,
              const Parallel& parallel, cv::Mat* disparity) {
  const int ndisp = cost.ndisp();
  parallel.For(0, disparity->rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      float* d = disparity->ptr<float>(y);
      const float* won = winners.ptr<float>(y);
      const Cost* sums = winner_sums ? winner_sums->ptr<Cost>(y) : nullptr;
      for (int x = 0; x < disparity->cols; ++x) {
        if (!IsValidDisparity(d[x])) continue;
        const int offset = cost.offset(y, x);
        const int k = static_cast<int>(d[x]) - offset;
        if (k <= 0 || k >= ndisp - 1) continue;
        int before, at, after;  // the sums at k − 1, k, k + 1
        if (sums && static_cast<int>(won[x]) == k + offset) {
          const Cost* w = sums + 3 * x;
          before = w[0], at = w[1], after = w[2];
        } else {
          const Cost* c = cost.at(y, x);
          before = c[k - 1], at = c[k], after = c[k + 1];
        }
        const int denom = before + after - 2 * at;  // integer costs: > 0 or flat
        if (denom <= 0) continue;
        const float shift = static_cast<float>(before - after) / static_cast<float>(2 * denom);
        d[x] = static_cast<float>(k + offset) + std::clamp(shift, -0.5f, 0.5f);
      }
    }
  });
}

// Orders nine values (floats or vectors of them) with a 25-exchange sorting
// network (checked on all 0/1 inputs); cas(a, b) leaves a ≤ b.
template <class T, class Cas>
inline void SortNine(T (&v)[9], const Cas& cas) {
  cas(v[0], v[3]), cas(v[1], v[7]), cas(v[2], v[5]), cas(v[4], v[8]);
  cas(v[0], v[7]), cas(v[2], v[4]), cas(v[3], v[8]), cas(v[5], v[6]);
  cas(v[0], v[2]), cas(v[1], v[3]), cas(v[4], v[5]), cas(v[7], v[8]);
  cas(v[1], v[4]), cas(v[3], v[6]), cas(v[5], v[7]);
  cas(v[0], v[1]), cas(v[2], v[4]), cas(v[3], v[5]), cas(v[6], v[8]);
  cas(v[2], v[3]), cas(v[4], v[5]), cas(v[6], v[7]);
  cas(v[1], v[2]), cas(v[3], v[4]), cas(v[5], v[6]);
}

// The 3×3 median over the valid pixels for the interior pixels x0 … x1−1 of
// `row` (with the rows above and below), written where the centre is valid.
// Branch-free across x: invalid neighbours become +inf, a sorting network
// orders the nine (finite values first), and the median of the n valid ones
// is element n/2, as nth_element picks it.
void Median3x3Valid(const float* above, const float* row, const float* below, int x0, int x1,
                    float* out) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const auto cas = [](float& a, float& b) {  // compare and swap: a ≤ b afterwards
    const float lo = b < a ? b : a, hi = b < a ? a : b;
    a = lo;
    b = hi;
  };
  // Whole vectors first: the same steps lane by lane (each exchange as
  // the scalar one selects, so equal values, ±0 included, end up alike).
  namespace hn = hwy::HWY_NAMESPACE;
  const hn::ScalableTag<float> df;
  using V = hn::Vec<decltype(df)>;
  const int lanes = static_cast<int>(hn::Lanes(df));
  const auto vinf = hn::Set(df, kInf), one = hn::Set(df, 1.f), half = hn::Set(df, 0.5f);
  const auto vcas = [](V& a, V& b) {
    const auto swap = hn::Lt(b, a);
    const V lo = hn::IfThenElse(swap, b, a), hi = hn::IfThenElse(swap, a, b);
    a = lo;
    b = hi;
  };
  for (; x0 + lanes <= x1; x0 += lanes) {
    const int x = x0;
    const V c = hn::LoadU(df, row + x);
    V v[9] = {hn::LoadU(df, above + x - 1),
              hn::LoadU(df, above + x),
              hn::LoadU(df, above + x + 1),
              hn::LoadU(df, row + x - 1),
              c,
              hn::LoadU(df, row + x + 1),
              hn::LoadU(df, below + x - 1),
              hn::LoadU(df, below + x),
              hn::LoadU(df, below + x + 1)};
    V n = hn::Zero(df);  // valid values, counted in floats (exact up to 9)
    for (V& e : v) {
      const auto valid = hn::Eq(e, e);
      n = hn::Add(n, hn::IfThenElseZero(valid, one));
      e = hn::IfThenElse(valid, e, vinf);
    }
    SortNine(v, vcas);
    const V mid = hn::Floor(hn::Mul(n, half));  // n / 2
    V median = v[0];
    for (int j = 1; j < 9; ++j)
      median = hn::IfThenElse(hn::Eq(mid, hn::Set(df, static_cast<float>(j))), v[j], median);
    hn::StoreU(hn::IfThenElse(hn::Eq(c, c), median, c), df, out + x);
  }
  for (int x = x0; x < x1; ++x) {
    const float c = row[x];
    float v[9] = {above[x - 1], above[x],     above[x + 1], row[x - 1],  c,
                  row[x + 1],   below[x - 1], below[x],     below[x + 1]};
    int n = 0;
    for (float& e : v) {
      const bool valid = e == e;
      n += valid ? 1 : 0;
      e = valid ? e : kInf;
    }
    SortNine(v, cas);  // then element n/2 picked without a branch
    const int mid = n / 2;
    float median = v[0];
    for (int j = 1; j < 9; ++j) median = mid == j ? v[j] : median;
    out[x] = c == c ? median : c;
  }
}

}  // namespace

// Without invalid pixels this is exactly OpenCV's median filter, which is
// far faster.
void MedianFilter(int size, const Parallel& parallel, cv::Mat* disparity, cv::Mat* scratch) {
  if (cv::checkRange(*disparity, true)) {  // no NaN
    cv::medianBlur(*disparity, *scratch, size);
    cv::swap(*disparity, *scratch);
    return;
  }
  const int r = size / 2, width = disparity->cols, height = disparity->rows;
  disparity->copyTo(*scratch);
  cv::Mat& out = *scratch;
  parallel.For(0, height, [&](int y0, int y1) {
    std::vector<float> window;
    window.reserve(static_cast<std::size_t>(size) * size);
    for (int y = y0; y < y1; ++y) {
      // 3×3 inside the image: the branch-free form; borders and 5×5 below.
      const bool fast = size == 3 && y > 0 && y + 1 < height && width > 2;
      if (fast)
        Median3x3Valid(disparity->ptr<float>(y - 1), disparity->ptr<float>(y),
                       disparity->ptr<float>(y + 1), 1, width - 1, out.ptr<float>(y));
      for (int x = 0; x < width; ++x) {
        if (fast && x > 0 && x + 1 < width) continue;
        if (!IsValidDisparity(disparity->at<float>(y, x))) continue;
        window.clear();
        for (int v = std::max(0, y - r); v <= std::min(height - 1, y + r); ++v) {
          const float* row = disparity->ptr<float>(v);
          for (int u = std::max(0, x - r); u <= std::min(width - 1, x + r); ++u)
            if (IsValidDisparity(row[u])) window.push_back(row[u]);
        }
        auto mid = window.begin() + window.size() / 2;
        std::nth_element(window.begin(), mid, window.end());
        out.at<float>(y, x) = *mid;
      }
    }
  });
  cv::swap(*disparity, *scratch);
}

namespace {

// Pixels labelled `label` (without the temporary mask `labels == label`).
std::size_t CountLabel(const cv::Mat& labels, Label label) {
  std::size_t n = 0;
  for (int y = 0; y < labels.rows; ++y) {
    const std::uint8_t* l = labels.ptr<std::uint8_t>(y);
    for (int x = 0; x < labels.cols; ++x) n += l[x] == label ? 1 : 0;
  }
  return n;
}

}  // namespace

cv::Mat Refine(const cv::Mat& left_index, const cv::Mat& right_index, const CostVolume& cost,
               int min_disparity, const cv::Mat& left_image, const Arms& arms,
               const RefinementOptions& options, const Parallel& parallel, RefineStats* stats,
               const cv::Mat* runner_up, RefineWorkspace* workspace, const cv::Mat* winner_sums) {
  RefineWorkspace own;
  RefineWorkspace& ws = workspace ? *workspace : own;
  cv::Mat& labels = ws.labels;
  DetectOutliers(left_index, right_index, min_disparity, cost, options.lr_tolerance_px, parallel,
                 &labels);
  if (stats) {
    const double n = static_cast<double>(labels.total());
    stats->occluded_pct = 100.0 * CountLabel(labels, kOccluded) / n;
    stats->mismatch_pct = 100.0 * CountLabel(labels, kMismatch) / n;
  }
  if (options.uniqueness > 0) {
    MarkAmbiguous(cost, left_index, options.uniqueness, runner_up, parallel, &labels);
    if (stats)
      stats->ambiguous_pct =
          100.0 * CountLabel(labels, kAmbiguous) / static_cast<double>(labels.total());
  }
  cv::Mat& disparity = ws.disparity;
  left_index.copyTo(disparity);
  RegionVoting(arms, cost, options, parallel, &disparity, &labels, &ws);
  if (options.interpolate) {
    Interpolate(left_image, parallel, &disparity, &labels, &ws.scratch);
  } else {
    disparity.setTo(kNaN, labels != kReliable);
  }
  if (options.adjust_discontinuities)
    AdjustDiscontinuities(cost, parallel, &disparity, &ws.scratch);
  if (options.subpixel) Subpixel(cost, left_index, winner_sums, parallel, &disparity);
  if (options.median_size > 1) MedianFilter(options.median_size, parallel, &disparity, &ws.scratch);
  return disparity;
}

}  // namespace craftscan::adcensus
