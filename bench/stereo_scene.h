// Stereo benchmark scenes (Middlebury layout of /work/shared/data/stereo, see
// its README.md) and the standard disparity error metrics.
#pragma once

#include <cstdint>
#include <string>

#include <opencv2/core/mat.hpp>

namespace craftscan {

// One rectified pair with left ground truth and evaluation masks.
struct StereoScene {
  std::string name;       // scene.json "name", else the folder name
  std::string directory;  // the folder it was loaded from
  cv::Mat left, right;    // CV_8UC3 (BGR) or CV_8UC1, same type and size
  cv::Mat gt;             // CV_32FC1 left disparity in px; NaN = no ground truth
  int ndisp = 0;          // px, > 0: disparities searched are 0 … ndisp − 1
  // The PNG ground truth's scale (gt = PNG value / gt_scale); 0 for a PFM
  // ground truth. Middlebury's v2 evaluation (the 2001/2003 scenes) scored
  // uploads saved the same way: disparities rounded to 1 / gt_scale.
  double gt_scale = 0;
  // CV_8UC1, 255 = pixel belongs to the region (other values, e.g. 128 =
  // occluded in 2014 masks, do not). mask_nonocc is never empty after loading
  // (without a "mask_nonocc" key: 255 wherever gt is valid); mask_all and
  // mask_disc are empty unless scene.json names them (2001/2003 scenes).
  cv::Mat mask_nonocc, mask_all, mask_disc;

  bool HasAllAndDiscMasks() const { return !mask_all.empty() && !mask_disc.empty(); }
};

// Loads the scene in folder `dir` from its scene.json:
//   "left", "right": image files (required). Read unchanged; 16-bit is scaled
//     to 8-bit, alpha dropped, grey kept as CV_8UC1, colour as CV_8UC3. If one
//     image is grey and the other colour, the grey one is converted to BGR.
//   "gt": PNG (any 8/16-bit single-channel format OpenCV reads; divided by
//     "gt_scale", required) or ".pfm" (via ReadPfm, divided by the optional
//     "gt_scale", default 1). Zero or non-finite values become NaN.
//   "ndisp": integer in 1..100000 (required).
//   "mask_nonocc", "mask_all", "mask_disc": optional mask images.
//   "name": optional string.
// File names are relative to `dir`. Returns false and sets *error (naming the
// file or key at fault) for: a missing folder, missing or malformed
// scene.json, a missing or mistyped key, an unreadable image, size mismatch
// between images, gt and masks, ndisp ≤ 0 or gt_scale ≤ 0. *scene is only
// written on success. Never throws. Thread-safe.
bool LoadStereoScene(const std::string& dir, StereoScene* scene, std::string* error);

// Disparity error statistics over the evaluated pixels E = {mask == 255 and gt
// valid}. A disparity estimate is valid when finite (NaN = no estimate).
struct DisparityMetrics {
  double bad1 = 0;         // %, of E: no estimate or |d − gt| > 1 px
  double bad2 = 0;         // %, of E: no estimate or |d − gt| > 2 px
  double avgerr = 0;       // px, mean |d − gt| over the pixels of E with an estimate
  double density = 0;      // %, of E with an estimate
  std::int64_t count = 0;  // |E|, pixels evaluated

  // With count == 0 every metric is NaN; avgerr is NaN when density is 0.
  bool IsUsable() const { return count > 0; }
};

// Scores `disp` (CV_32FC1, NaN = no estimate) against `gt` (CV_32FC1, px;
// zero or non-finite = no ground truth) inside `mask` (CV_8UC1, 255 =
// evaluated; empty = every pixel). Throws std::invalid_argument for other
// types or mismatched sizes. Thread-safe.
DisparityMetrics EvaluateDisparity(const cv::Mat& disp, const cv::Mat& gt, const cv::Mat& mask);

}  // namespace craftscan
