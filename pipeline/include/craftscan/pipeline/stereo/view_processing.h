// One stereo view → disparity map → point cloud, as the daemon runs it for
// every capture (DESIGN.md "Data flow of one scan"): rectify with cached
// maps, match with AD-Census over the disparity band the working volume
// spans, reproject with Q, drop textureless pixels, crop to the working
// volume (a cylinder about the calibrated turntable axis).
#pragma once

#include <cstddef>
#include <memory>
#include <mutex>
#include <string>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/calib/rectify.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/working_volume.h"
#include "craftscan/pipeline/stereo/adcensus.h"

namespace craftscan {

struct ViewProcessorOptions {
  int num_threads = 2;   // matcher threads
  WorkingVolume volume;  // cylinder about the turntable axis: the band and the crop
  // Disparity band: the volume's disparities (with the platter) widened by this
  // margin on both sides, so calibration error cannot cut the object off.
  int disparity_margin_px = 8;
  // The platter's radius (mm, [0, 10000]; 0 or ≤ the volume's radius: not
  // used): the band reaches down to the disparity of its far edge, which
  // the cameras see above a low object (see ViewProcessor::Init).
  double platter_radius_mm = 0;
  int max_num_disparities = 1024;  // refuse absurd bands (a bad calibration)
  // A fixed band instead of the working volume's (num_disparities > 0).
  int min_disparity = 0, num_disparities = 0;
  // ReprojectOptions::min_texture_std (grey levels; 0 = off). With a
  // turntable calibration it applies only outside the platter disc's image
  // (the backdrop it exists for); over the platter it removed mostly right
  // pixels: 75 % (the egg's black paint) to 99 % (the embroidery under the
  // projector) lay within 1 px of the truth (craftscan-bench sim-depth).
  double min_texture_std = 2.5;
  // The matcher sees the pair gamma-encoded with this exponent, [1, 4]
  // (out = 255·(in/255)^(1/γ) for a linear pair; 1 = as captured). Its
  // constants (λ_AD, the arms' colour limits, the scanline penalties'
  // intensity test) are Mei et al.'s, chosen on Middlebury's photographs,
  // which are gamma-encoded; machine-vision cameras and the simulator
  // deliver linear intensities, where a bright surface's small differences
  // between the views (the sheen of satin stitches) weigh as much in the AD
  // term as a dark surface's texture. An exposure merge is encoded with 2.2
  // already (and passed on as it is, Process), so with 2.2 every view is
  // matched alike, bracketed or not. On the default station (README 11.9,
  // stop 46) 2.2 raised the light embroidery's fused completeness 92.8 →
  // 98.1 % (seed 4242) and 94.0 → 98.9 % (seed 23) with fewer outliers; the
  // box, the owl and the jug stayed within their goals at four seeds. (Stops
  // 40–43 kept 1: the owl's long axis came out 0.7–0.8 mm shorter then,
  // through the 1.5 mm bottom of the time.) The 8-bit re-encoding still
  // merges the faint levels of bright, weakly textured paint: a pair not
  // bracketed loses a little there (sim-depth's egg, median 0.175 → 0.206
  // mm). The texture test and the colours keep the pair as captured.
  double match_gamma = 2.2;
  // Erosion at depth discontinuities (EraseNearDepthEdges): pixels within
  // depth_edge_radius_px (0..5; 0 = off) of a nearer surface whose disparity
  // is more than depth_edge_jump_px ((0, 1000]) above theirs are dropped
  // before reprojection.
  int depth_edge_radius_px = 1;
  double depth_edge_jump_px = 3;
  // The matcher's cross-based aggregation iterations
  // (ADCensusOptions::aggregation_iterations, 0..16). The paper's 4 smooth
  // the cost over support regions that grow with every iteration; on a
  // station's slanted, weakly textured surfaces (dark cloth, painted
  // shoulders, a vase's belly) that flattens the disparity into fronto-
  // parallel plateaus, whose ends come out as sheets a millimetre off the
  // surface, consistent enough in two views to survive fusion. The census
  // window and the scanline optimization alone do better on every object
  // measured (README 11.9), so the station runs with none.
  int aggregation_iterations = 0;
  // Per-pixel disparity ranges from a coarse pass (CoarseToFineOptions):
  // the working volume's band is hundreds of disparities wide at full size.
  bool coarse_to_fine = true;
  // Speckles (RemoveDisparitySpeckles): connected patches of valid
  // disparities (neighbours within speckle_range_px, (0, 64]) of at most
  // speckle_max_area_pct percent of the image's pixels ([0, 1]; 0 = off) are
  // dropped before reprojection: 52 pixels at 1280×1024, 13 at 640×512.
  // Without aggregation the matcher finds scattered patches in noise (a dark
  // backdrop brightened by exposure bracketing) that pass the left-right
  // check; in the bracketed egg at 1280×1024 they made 36 % of the model.
  double speckle_max_area_pct = 0.004;
  double speckle_range_px = 2.0;

  bool IsValid(std::string* why) const;
};

struct ProcessedView {
  bool ok = false;
  std::string message;     // why not ok
  cv::Mat rectified_left;  // CV_8UC1 or CV_8UC3 as captured
  cv::Mat disparity;       // CV_32FC1, rectified left; NaN = invalid
  int min_disparity = 0, num_disparities = 0;
  std::size_t edge_pixels_erased = 0;  // by EraseNearDepthEdges
  std::size_t speckle_pixels = 0;      // by RemoveDisparitySpeckles
  PointCloud cloud_in_rig;             // mm, rig frame (rectified left camera), colours RGB
  double rectify_ms = 0, match_ms = 0, reproject_ms = 0;
};

// Erosion at depth discontinuities: every valid pixel of `disparity`
// (CV_32FC1, NaN = invalid) whose (2r+1)² window holds a valid disparity
// more than `jump_px` above its own (a nearer surface beside it) is set to
// NaN; returns how many. Aggregation windows straddle a silhouette or a
// step, and the farther side's pixels next to it take a blend of both depths
// (the foreground fattened), consistently in both images, so the left-right
// check keeps them: points 1–5 mm off the surface. The nearer side is left
// alone: eroding it too removed a little more (the owl with the projector
// 0.54 → 0.21 % outliers at 640x512, against 0.48 % for the far side only)
// but ate thin near parts: the jug's handle went from the default station's
// model at 1280x1024 (its OBB 72.1 → 62.5 mm long, truth 73.3; far side
// only: 71.3). Invalid pixels are not edges. radius_px ≤ 0: nothing.
std::size_t EraseNearDepthEdges(int radius_px, double jump_px, cv::Mat* disparity);

// Speckle removal (cv::filterSpeckles, as OpenCV's StereoSGBM does): every
// 4-connected patch of valid pixels of `disparity` (CV_32FC1, NaN = invalid)
// whose neighbours differ by at most `range_px` and which covers at most
// `max_area_px` pixels is set to NaN; returns how many pixels. On noise (a
// dark backdrop brightened by exposure bracketing, sensor noise in a
// shadow) the matcher finds scattered small patches that pass the
// left-right check; a surface gives large connected patches. Disparities
// are quantised to 1/16 px (coarser when they span more than 2000 px) for
// the test only; the kept values are unchanged. max_area_px ≤ 0: nothing.
std::size_t RemoveDisparitySpeckles(int max_area_px, double range_px, cv::Mat* disparity);

// The platter disc (radius_mm about the turntable axis, at its height) as
// the rectified left camera sees it: CV_8UC1 of the calibration's image
// size, 255 over the disc. What is seen there is the platter or what stands
// on it, never the backdrop. Empty without a turntable calibration, for a
// radius ≤ 0, or when the disc reaches the camera's plane.
cv::Mat RectifiedPlatterRegion(const StereoCalibration& calibration, double radius_mm);

// Thread-safety: Init before use; Process may be called from one thread at a
// time (the matcher keeps buffers); band() and calibration() are const.
class ViewProcessor {
 public:
  // False with *error when the calibration is not usable (no rectification)
  // or the options are invalid. The turntable axis may be invalid: then the
  // band spans 300–1500 mm depth and there is no crop.
  bool Init(const StereoCalibration& calibration, const ViewProcessorOptions& options,
            std::string* error);

  const StereoCalibration& calibration() const { return rectifier_.calibration(); }
  int min_disparity() const { return min_disparity_; }
  int num_disparities() const { return num_disparities_; }
  // Rectified focal length (px) and baseline (mm) for the disparity topic.
  double focal_px() const;
  double baseline_mm() const;

  // Never throws; images must be the calibration's size. `texture_left_raw`
  // (optional: a station with a pattern projector, drivers::StereoFrame::
  // texture_left) is the left view with the projector off, the same size
  // and type as left_raw: the points take their colours from it (the pair,
  // with the pattern, is matched and judged for texture).
  // `pair_gamma` is the pair's own encoding: 1 for a camera's linear
  // images (encoded for the matcher with options' match_gamma), more for an
  // exposure merge (MergeExposures' gamma: matched as it is). [1, 4].
  ProcessedView Process(const cv::Mat& left_raw, const cv::Mat& right_raw,
                        const cv::Mat& texture_left_raw = cv::Mat(), double pair_gamma = 1.0);

 private:
  Rectifier rectifier_;
  ViewProcessorOptions options_;
  int min_disparity_ = 0, num_disparities_ = 0;
  cv::Matx44d turntable_from_rig_ = cv::Matx44d::eye();
  bool crop_ = false;
  // The platter disc's image in the rectified left view (CV_8UC1, 255 over
  // it; empty without a turntable calibration): exempt from the texture
  // filter (ReprojectOptions::texture_exempt).
  cv::Mat over_platter_;
  std::unique_ptr<StereoMatcher> matcher_;
};

}  // namespace craftscan
