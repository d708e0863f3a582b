// Free-space consistency between the views of a scan: a point that one view
// reconstructed is dropped when other views look straight through it.
//
// Each view's camera saw a surface at some depth along every ray it matched;
// the space between the camera and that surface is empty. A fused point that
// lies in that empty space, seen from another view, cannot be real: it is a
// stereo mismatch (the foreground fattened across a silhouette, a guess on a
// dark or textureless patch, a reflection). This is the visibility rule of
// multi-view depth-map fusion (Merrell et al., "Real-time visibility-based
// fusion of depth maps", ICCV 2007: "free-space violations"; COLMAP's
// fusion checks depth agreement between views in the same way).
//
//   RectifiedCamera camera = RectifiedLeftCamera(calibration);
//   auto kept = RemoveFreeSpaceViolations(candidates, seen, poses, camera, {}, &stats);
//
// A point of view i is tested in every other view j: projected into j's
// rectified left camera, it is *supported* when j saw a surface within
// `tolerance_mm` of it (any pixel of the window), *contradicted* when every
// surface j saw there lies more than `tolerance_mm` behind it (j looked
// through it), and neither when j saw nothing there or saw something in
// front of it (an occlusion says nothing). A point is dropped when some
// other view contradicts it and no more views support it than contradict it.
// A tie drops it: stereo leaves sheets a millimetre or two above a periodic
// texture (an embroidery's satin stitches), matched one period off alike by
// the views that see the stitches alike, which then support each other,
// while the views that saw the surface under them contradict them
// (craftscan-bench scan, 1280×1024, 6 views: the embroidery's fused
// thickness 3.5 mm for 2.3 mm at seed 4242, 2.5 mm with ties dropped;
// README 11.9).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

// The rectified left camera, whose frame is the rig frame of every view
// cloud: pixel (u, v) = (fx·x/z + cx, fy·y/z + cy).
struct RectifiedCamera {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  cv::Size size;

  bool IsValid(std::string* why) const;
};

// From a calibration's P1 and image size.
RectifiedCamera RectifiedLeftCamera(const StereoCalibration& calibration);

struct VisibilityOptions {
  // Depth agreement (mm, > 0): stereo noise, calibration and registration
  // error together. A point nearer the camera than every surface of the
  // window by more than this is in free space.
  double tolerance_mm = 1.0;
  // The window around the projected pixel (radius in pixels, 0..5): a
  // silhouette or a thin part one pixel off is not free space.
  int window_radius_px = 1;
  // A contradiction needs this many pixels of the window with a depth, and
  // those depths no steeper than a surface seen at max_incidence_deg (a
  // surface seen at a grazing angle or across the view's own depth edge is
  // measured badly there). 1..window pixels; (0, 90).
  int min_window_pixels = 3;
  double max_incidence_deg = 75;
  int num_threads = 1;

  bool IsValid(std::string* why) const;
};

struct VisibilityStats {
  std::size_t checked_points = 0;
  std::size_t removed_points = 0;
  std::vector<std::size_t> removed_per_view;
  // Points no other view supports (kept unless contradicted): the part of
  // the model only one view saw.
  std::size_t unsupported_points = 0;
};

// `candidates[k]`: view k's points to keep or drop, in view k's rig frame;
// `seen[k]`: everything view k's camera reconstructed (its depth map, as
// points in its rig frame); `view0_from_view[k]`: view k's pose (into any
// common frame). With `confirmed` (in that common frame: the surface fused
// from all views), only what a view saw within about `tolerance_mm` of it
// can contradict a point: a view's own mismatched patch (a wrong disparity
// over a region, dense enough to survive outlier removal) then does not
// make good points of other views "seen through". Returns the
// candidates without their free-space violations (attributes kept). With
// invalid options or mismatched sizes returns the candidates unchanged and
// sets *error. Never throws; deterministic for any thread count.
std::vector<PointCloud> RemoveFreeSpaceViolations(const std::vector<PointCloud>& candidates,
                                                  const std::vector<PointCloud>& seen,
                                                  const std::vector<cv::Matx44d>& view0_from_view,
                                                  const RectifiedCamera& camera,
                                                  const VisibilityOptions& options,
                                                  VisibilityStats* stats, std::string* error,
                                                  const PointCloud* confirmed = nullptr);

}  // namespace craftscan
