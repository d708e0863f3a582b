// Exposure bracketing: one view captured at several exposure times, merged
// into one 8-bit image for the matcher. A surface with flat dark paint (the
// egg's black, albedo ~0.04) spans a dozen grey levels at an exposure that
// keeps the white paint unclipped: its texture (or a projector's pattern on
// it) is a few levels against a sensor noise of ~1, and the matcher finds
// nothing. A longer exposure lifts it clear of the noise but clips the rest.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan {

struct ExposureMergeOptions {
  // Output encoding: out = 255 · (r / 255)^(1 / gamma), r the merged radiance
  // in grey levels of the reference (shortest) exposure; > 1 spreads the dark
  // levels the longer exposures resolved. [1, 4].
  double gamma = 2.2;
  // A sample at or above `clip_level` is clipped (weight 0); the weight ramps
  // down from 1 over the `clip_ramp` levels below it, so the switch between
  // exposures leaves no seam. clip_level (0, 255], clip_ramp [0, clip_level).
  double clip_level = 250;
  double clip_ramp = 20;

  bool IsValid(std::string* why) const;
};

// A bracket: the multiples of the reference exposure captured besides it,
// each in (1, 64], ascending, at most 4 (empty: no bracketing). False with
// *why (may be null) naming the first bad entry.
bool IsValidExposureBracket(const std::vector<double>& multiples, std::string* why);

// Merges `images` (8-bit, all of one size and type, CV_8UC1 or CV_8UC3) of
// one view, exposed `relative_exposure[i]` times the first (> 0; the first
// must be the shortest, 1), into *merged (same size and type). Per pixel and
// channel the radiance is the least-squares estimate under fixed read noise,
// r = Σ wᵢ tᵢ zᵢ / Σ wᵢ tᵢ² over the unclipped samples (wᵢ the clip ramp), so
// the longest unclipped exposure dominates; where every sample is clipped, the
// shortest exposure's value. Deterministic and the same for the left and the
// right image, so the pair stays photometrically consistent. One image: its
// gamma encoding. False with *error naming what is wrong (no images, sizes or
// types differ, exposures not ascending from 1, options invalid).
//
// Why not cv::MergeDebevec + cv::Tonemap: MergeDebevec works in the log
// domain of a response curve (log 0 for black: the dark paint this is for),
// and Tonemap normalises each image by its own maximum, which differs between
// the left and the right camera and breaks the matcher's absolute-difference
// term.
bool MergeExposures(const std::vector<cv::Mat>& images,
                    const std::vector<double>& relative_exposure,
                    const ExposureMergeOptions& options, cv::Mat* merged, std::string* error);

// Automatic bracketing: a view is bracketed when enough of what stands on
// the platter is too dark to carry texture at the reference exposure (dark
// cloth, black paint), so a longer exposure could give the matcher texture
// there. Only pixels whose rays meet the platter disc are judged: they see
// the platter or an object in front of it, never the backdrop (black in the
// simulator and in many real stations, and never matched anyway).
struct AutoBracketOptions {
  double multiple = 8;           // the exposure added, (1, 64]: the bracket is {multiple}
  int window = 9;                // px, odd, [3, 31]: the texture window
  double dark_level = 32;        // grey levels (0, 255): a window darker than this on average …
  double max_texture_std = 2.5;  // … with a standard deviation at most this carries no texture
  double min_share_pct = 1.0;    // (0, 100]: bracket at or above this share of the region

  bool IsValid(std::string* why) const;
};

// The pixels of the raw (unrectified) left image whose rays meet the
// platter, a disc of `platter_radius_mm` about the calibrated turntable
// axis through its point on the platter (CV_8UC1, 255 inside). Empty when
// the calibration has no turntable axis or the disc is not in view.
cv::Mat PlatterRegionMask(const StereoCalibration& calibration, double platter_radius_mm);

// The share (%) of `region`'s pixels (CV_8UC1, the image's size; empty =
// the whole image) whose window in `image` (8-bit, 1 or 3 channels) is dark
// and without texture by `options`. NaN when the region is empty or the
// sizes differ.
double DarkUntexturedSharePct(const cv::Mat& image, const cv::Mat& region,
                              const AutoBracketOptions& options);

}  // namespace craftscan
