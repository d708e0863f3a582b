// Image preprocessing of method.md §2: histogram equalization, then Canny
// edges with thresholds derived from image statistics, dilated to close gaps.
#pragma once

#include <opencv2/core/mat.hpp>
#include <string>

namespace craftscan {

struct PreprocessOptions {
  // Equalize the histogram of the luminance (grey images: the image itself;
  // colour images: Y of YCrCb, so hue is kept).
  bool equalize = true;
  // Adaptive Canny thresholds around the median m of the equalized grey image:
  // low = max(min_threshold, (1 - canny_sigma)·m), high = min(255, (1 + canny_sigma)·m).
  double canny_sigma = 0.33;        // dimensionless, (0, 1]
  double canny_min_threshold = 10;  // grey levels, floor for the low threshold
  int canny_aperture = 3;           // Sobel aperture for Canny: 3, 5 or 7
  int dilate_radius_px = 1;         // radius of the square dilation; 0 = none

  bool IsValid(std::string* why) const;
};

struct Preprocessed {
  enum class Status { kOk, kInvalidInput, kFailed };
  Status status = Status::kFailed;
  std::string message;   // why not kOk
  cv::Mat image;         // equalized image, same type as the input (CV_8UC1 or CV_8UC3)
  cv::Mat grey;          // equalized grey, CV_8UC1
  cv::Mat gradient;      // Sobel (3×3) gradient magnitude of `grey`, CV_32FC1
  cv::Mat edges;         // dilated Canny edge map, CV_8UC1, 255 = edge
  double canny_low = 0;  // thresholds actually used
  double canny_high = 0;

  bool IsUsable() const { return status == Status::kOk; }
};

// What to compute: everything, or only the equalized images (the right view
// of a stereo pair needs no gradient or edge map); the *Grey* parts leave
// out the equalized image of the input's type (`image`), which a matcher
// that matches the raw colours never reads.
enum class PreprocessParts { kAll, kEqualizedOnly, kGreyAndEdges, kGreyOnly };

// Preprocesses one 8-bit grey (CV_8UC1) or BGR (CV_8UC3) image. With
// kEqualizedOnly or kGreyOnly, `gradient` and `edges` stay empty and the
// thresholds 0; with kGreyAndEdges or kGreyOnly, `image` stays empty.
// Fails (kInvalidInput, the message says why) for an empty image, another
// type, or invalid options; kFailed if OpenCV reports an error. Never throws.
// Thread-safe (no shared state).
Preprocessed Preprocess(const cv::Mat& image, const PreprocessOptions& options,
                        PreprocessParts parts = PreprocessParts::kAll);

// Intermediate images of Preprocess, kept by a caller that preprocesses
// images of one size over and over (a matcher): fresh ones are new pages to
// fault in on every call.
struct PreprocessScratch {
  cv::Mat ycrcb, channels[3], gx, gy;
};

// The same into *out, whose images (and *scratch's) are written in place
// where their size and type already fit. `out` must not share memory with
// `image`; earlier results taken from *out are overwritten.
void Preprocess(const cv::Mat& image, const PreprocessOptions& options, PreprocessParts parts,
                Preprocessed* out, PreprocessScratch* scratch);

// The gradient and the edge map of out->grey, with its thresholds: what
// kAll and kGreyAndEdges add to kEqualizedOnly and kGreyOnly, for a caller
// that wants the grey image first (a matcher computes its census transforms
// while these run). `out` must be a usable result of Preprocess; on an
// unusable one, or if OpenCV fails, `out` becomes a failed result that says
// why. Never throws.
void PreprocessEdges(const PreprocessOptions& options, Preprocessed* out,
                     PreprocessScratch* scratch);

}  // namespace craftscan
