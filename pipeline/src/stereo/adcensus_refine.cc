// Mei et al.'s multi-step disparity refinement: outlier detection with
// occlusion/mismatch labels, iterative region voting, proper interpolation,
// depth-discontinuity adjustment, sub-pixel enhancement and a median filter.
//
// Every step reads the previous step's maps and writes new ones, so results
// never depend on the order in which threads visit pixels.
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

void DetectOutliers(const cv::Mat& left_index, const cv::Mat& right_index, int min_disparity,
                    int ndisp, double tolerance, const Parallel& parallel, cv::Mat* labels) {
  const int width = left_index.cols;
  labels->create(left_index.size(), CV_8UC1);
  parallel.For(0, left_index.rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* l = left_index.ptr<float>(y);
      const float* r = right_index.ptr<float>(y);
      std::uint8_t* out = labels->ptr<std::uint8_t>(y);
      for (int x = 0; x < width; ++x) {
        const int k = static_cast<int>(l[x]);
        const int xr = x - min_disparity - k;
        if (xr >= 0 && xr < width && IsValidDisparity(r[xr]) &&
            std::abs(r[xr] - l[x]) <= tolerance) {
          out[x] = kReliable;
          continue;
        }
        // A mismatch if some disparity on the epipolar line is consistent in
        // the right view; otherwise the pixel is occluded there.
        out[x] = kOccluded;
        for (int j = 0; j < ndisp; ++j) {
          const int xj = x - min_disparity - j;
          if (xj >= 0 && xj < width && r[xj] == static_cast<float>(j)) {
            out[x] = kMismatch;
            break;
          }
        }
      }
    }
  });
}

// Reliable pixels whose cost curve has no clear minimum become kAmbiguous:
// c[k] > (1 − uniqueness) · min over |j − k| ≥ 2 of c[j]. The neighbours of
// the winner are excluded: they are the same minimum, blurred.
void MarkAmbiguous(const CostVolume& cost, const cv::Mat& left_index, double uniqueness,
                   const Parallel& parallel, cv::Mat* labels) {
  const int ndisp = cost.ndisp();
  const float keep = static_cast<float>(1 - uniqueness);
  parallel.For(0, left_index.rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* l = left_index.ptr<float>(y);
      std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      for (int x = 0; x < left_index.cols; ++x) {
        if (lab[x] != kReliable) continue;
        const float* c = cost.at(y, x);
        const int k = static_cast<int>(l[x]);
        float second = std::numeric_limits<float>::infinity();
        for (int j = 0; j < k - 1; ++j) second = std::min(second, c[j]);
        for (int j = k + 2; j < ndisp; ++j) second = std::min(second, c[j]);
        if (c[k] > keep * second) lab[x] = kAmbiguous;
      }
    }
  });
}

void RegionVoting(const Arms& arms, int ndisp, const RefinementOptions& options,
                  const Parallel& parallel, cv::Mat* disparity, cv::Mat* labels) {
  // bins: the disparity index of reliable pixels, ndisp for the others, so the
  // histogram loop needs no branch (bin ndisp collects the unreliable ones).
  cv::Mat bins(disparity->size(), CV_16SC1);
  for (int it = 0; it < options.voting_iterations; ++it) {
    for (int y = 0; y < bins.rows; ++y) {
      const float* d = disparity->ptr<float>(y);
      const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      std::int16_t* b = bins.ptr<std::int16_t>(y);
      for (int x = 0; x < bins.cols; ++x)
        b[x] = static_cast<std::int16_t>(lab[x] == kReliable ? static_cast<int>(d[x]) : ndisp);
    }
    cv::Mat new_disp = disparity->clone(), new_labels = labels->clone();
    std::vector<int> changed_rows(disparity->rows, 0);
    parallel.For(0, disparity->rows, [&](int y0, int y1) {
      std::vector<int> histogram(ndisp + 1);
      for (int y = y0; y < y1; ++y) {
        const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
        for (int x = 0; x < disparity->cols; ++x) {
          if (lab[x] == kReliable) continue;
          std::fill(histogram.begin(), histogram.end(), 0);
          int region = 0;
          const std::size_t i = arms.index(y, x);
          for (int v = y - arms.up[i]; v <= y + arms.down[i]; ++v) {
            const std::size_t j = arms.index(v, x);
            const std::int16_t* b = bins.ptr<std::int16_t>(v);
            const int u0 = x - arms.left[j], u1 = x + arms.right[j];
            for (int u = u0; u <= u1; ++u) ++histogram[b[u]];
            region += u1 - u0 + 1;
          }
          const int votes = region - histogram[ndisp];
          if (votes <= options.tau_s) continue;
          const auto best = std::max_element(histogram.begin(), histogram.end() - 1);
          if (*best <= options.tau_h * votes) continue;
          new_disp.at<float>(y, x) = static_cast<float>(best - histogram.begin());
          new_labels.at<std::uint8_t>(y, x) = kReliable;
          ++changed_rows[y];
        }
      }
    });
    int changed = 0;
    for (int c : changed_rows) changed += c;
    *disparity = new_disp;
    *labels = new_labels;
    if (changed == 0) break;
  }
}

void Interpolate(const cv::Mat& image, const Parallel& parallel, cv::Mat* disparity,
                 cv::Mat* labels) {
  constexpr int kDirections = 16;
  const int width = image.cols, height = image.rows, ch = image.channels();
  const int max_steps = std::max(width, height);
  // Integer offsets of every step along each direction, computed once.
  std::vector<cv::Point> steps(static_cast<std::size_t>(kDirections) * max_steps);
  for (int i = 0; i < kDirections; ++i) {
    const double a = 2 * std::numbers::pi * i / kDirections;
    for (int s = 1; s < max_steps; ++s)
      steps[static_cast<std::size_t>(i) * max_steps + s] =
          cv::Point(static_cast<int>(std::lround(s * std::cos(a))),
                    static_cast<int>(std::lround(s * std::sin(a))));
  }
  cv::Mat out = disparity->clone();
  parallel.For(0, height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const std::uint8_t* lab = labels->ptr<std::uint8_t>(y);
      for (int x = 0; x < width; ++x) {
        if (lab[x] == kReliable) continue;
        const std::uint8_t* colour = image.ptr<std::uint8_t>(y) + ch * x;
        float lowest = std::numeric_limits<float>::infinity(), most_similar = kNaN;
        int best_diff = std::numeric_limits<int>::max();
        for (int i = 0; i < kDirections; ++i) {
          const cv::Point* ray = &steps[static_cast<std::size_t>(i) * max_steps];
          for (int s = 1; s < max_steps; ++s) {
            const int qx = x + ray[s].x, qy = y + ray[s].y;
            if (qx < 0 || qy < 0 || qx >= width || qy >= height) break;
            if (labels->at<std::uint8_t>(qy, qx) != kReliable) continue;
            const float d = disparity->at<float>(qy, qx);
            lowest = std::min(lowest, d);
            const int diff = ColourDiff(colour, image.ptr<std::uint8_t>(qy) + ch * qx, ch);
            if (diff < best_diff) {
              best_diff = diff;
              most_similar = d;
            }
            break;
          }
        }
        if (best_diff == std::numeric_limits<int>::max()) {
          out.at<float>(y, x) = kNaN;  // no reliable pixel in any direction
        } else {
          // Occlusions take the background (lowest disparity); mismatches the
          // neighbour that looks most alike.
          out.at<float>(y, x) = lab[x] == kOccluded ? lowest : most_similar;
        }
      }
    }
  });
  *disparity = out;
}

void AdjustDiscontinuities(const CostVolume& cost, const Parallel& parallel, cv::Mat* disparity) {
  const int width = disparity->cols;
  cv::Mat out = disparity->clone();
  parallel.For(0, disparity->rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* d = disparity->ptr<float>(y);
      float* o = out.ptr<float>(y);
      for (int x = 1; x + 1 < width; ++x) {
        if (!IsValidDisparity(d[x]) || !IsValidDisparity(d[x - 1]) || !IsValidDisparity(d[x + 1]))
          continue;
        if (std::abs(d[x - 1] - d[x + 1]) <= 1.f) continue;  // not on a disparity edge
        const float* c = cost.at(y, x);
        const int k = static_cast<int>(d[x]), k1 = static_cast<int>(d[x - 1]),
                  k2 = static_cast<int>(d[x + 1]);
        int best = k;
        if (c[k1] < c[best]) best = k1;
        if (c[k2] < c[best]) best = k2;
        o[x] = static_cast<float>(best);
      }
    }
  });
  *disparity = out;
}

void Subpixel(const CostVolume& cost, const Parallel& parallel, cv::Mat* disparity) {
  const int ndisp = cost.ndisp();
  parallel.For(0, disparity->rows, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      float* d = disparity->ptr<float>(y);
      for (int x = 0; x < disparity->cols; ++x) {
        if (!IsValidDisparity(d[x])) continue;
        const int k = static_cast<int>(d[x]);
        if (k <= 0 || k >= ndisp - 1) continue;
        const float* c = cost.at(y, x);
        const float denom = c[k - 1] + c[k + 1] - 2 * c[k];
        if (denom <= 1e-6f) continue;
        const float offset = (c[k - 1] - c[k + 1]) / (2 * denom);
        d[x] = static_cast<float>(k) + std::clamp(offset, -0.5f, 0.5f);
      }
    }
  });
}

// Median over the valid pixels of each window; NaN stays NaN. Without
// invalid pixels this is exactly OpenCV's median filter, which is far faster.
void MedianFilter(int size, const Parallel& parallel, cv::Mat* disparity) {
  if (cv::checkRange(*disparity, true)) {  // no NaN
    cv::Mat out;
    cv::medianBlur(*disparity, out, size);
    *disparity = out;
    return;
  }
  const int r = size / 2, width = disparity->cols, height = disparity->rows;
  cv::Mat out = disparity->clone();
  parallel.For(0, height, [&](int y0, int y1) {
    std::vector<float> window;
    window.reserve(static_cast<std::size_t>(size) * size);
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < width; ++x) {
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
  *disparity = out;
}

}  // namespace

cv::Mat Refine(const cv::Mat& left_index, const cv::Mat& right_index, const CostVolume& cost,
               int min_disparity, const cv::Mat& left_image, const Arms& arms,
               const RefinementOptions& options, const Parallel& parallel, RefineStats* stats) {
  cv::Mat labels;
  DetectOutliers(left_index, right_index, min_disparity, cost.ndisp(), options.lr_tolerance_px,
                 parallel, &labels);
  if (stats) {
    const double n = static_cast<double>(labels.total());
    stats->occluded_pct = 100.0 * cv::countNonZero(labels == kOccluded) / n;
    stats->mismatch_pct = 100.0 * cv::countNonZero(labels == kMismatch) / n;
  }
  if (options.uniqueness > 0) {
    MarkAmbiguous(cost, left_index, options.uniqueness, parallel, &labels);
    if (stats)
      stats->ambiguous_pct =
          100.0 * cv::countNonZero(labels == kAmbiguous) / static_cast<double>(labels.total());
  }
  cv::Mat disparity = left_index.clone();
  RegionVoting(arms, cost.ndisp(), options, parallel, &disparity, &labels);
  if (options.interpolate) {
    Interpolate(left_image, parallel, &disparity, &labels);
  } else {
    disparity.setTo(kNaN, labels != kReliable);
  }
  if (options.adjust_discontinuities) AdjustDiscontinuities(cost, parallel, &disparity);
  if (options.subpixel) Subpixel(cost, parallel, &disparity);
  if (options.median_size > 1) MedianFilter(options.median_size, parallel, &disparity);
  return disparity;
}

}  // namespace craftscan::adcensus
