// Pictures for session reports, made by craftscan itself (OpenCV only, no
// external renderer, no X/GL context): colour-mapped disparity maps and
// software renders of point clouds and triangle meshes from a camera that
// orbits the object.
//
//   cv::Mat shown = ColorizeDisparity(disparity_px, 0, 96);   // BGR + colour bar
//   PreviewOptions options;                                   // 640×480, orthographic
//   for (const PreviewView& view : DefaultPreviewViews()) {
//     PreviewImage cloud = RenderCloudPreview(result.fused, view, options);
//     if (cloud.ok()) cv::imencode(".png", cloud.image_bgr, bytes);
//   }
//
// Units: millimetres for geometry, pixels for images, degrees for the view
// angles (they are user-facing). Images are OpenCV BGR, CV_8UC3.
// Every function is pure and thread-safe (no shared state) and never throws.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::daemon {

// ------------------------------------------------------------ disparity ----

// Colour-maps a disparity map (CV_32FC1, px; NaN or ±inf = invalid) with
// OpenCV's Turbo map: min_d → the map's first colour (dark blue), max_d → its
// last (dark red), so nearer surfaces are warmer. Values outside
// [min_d, max_d] are clamped; invalid pixels are black (0, 0, 0), which Turbo
// never produces. Below the map (rows disparity.rows and down) a strip holds a
// colour bar and the range labels ("12.0 px" … "96.0 px"); the top
// disparity.rows × disparity.cols pixels are the map itself.
// When min_d or max_d is NaN, the range is taken from the finite values
// (a map without any gives the range 0…1).
// Returns an empty Mat and sets *error (may be null) for an empty map, a
// type other than CV_32FC1, an infinite bound or min_d ≥ max_d.
cv::Mat ColorizeDisparity(const cv::Mat& disparity_px, double min_d, double max_d,
                          std::string* error = nullptr);

// Height (px) of the colour-bar strip ColorizeDisparity adds below a map
// `width_px` wide.
int ColorBarHeight(int width_px);

// ------------------------------------------------------------- previews ----

// Where the camera sits: on a sphere about the object's centre, at
// `azimuth_deg` about the up axis (0 = along PreviewOptions::azimuth_zero,
// 90 = a quarter turn right-handed about up) and `elevation_deg` above the
// horizontal plane (90 = looking straight down).
struct PreviewView {
  std::string name = "az000";  // file-name part: [a-z0-9_-], 1..32 characters
  double azimuth_deg = 0;
  double elevation_deg = 30;  // −90..90

  bool IsValid(std::string* why) const;  // names the offending field
};

// Four sides at 30° elevation (az000, az090, az180, az270) and the top.
std::vector<PreviewView> DefaultPreviewViews();

enum class PreviewProjection { kOrthographic, kPerspective };
const char* ToString(PreviewProjection projection);  // "orthographic", "perspective"
bool PreviewProjectionFromString(const std::string& text, PreviewProjection* projection);

struct PreviewOptions {
  cv::Size size{640, 480};  // output image, px; each side 16..8192
  PreviewProjection projection = PreviewProjection::kOrthographic;
  // Perspective: the cone (full angle) the bounding sphere fills, which sets
  // the camera distance (how strong the perspective is). 5..120.
  double fov_deg = 35;
  double margin = 0.06;  // fraction of the image kept free on each side, 0..0.4
  // Rendering at supersample × size, then area-downsampling (anti-aliasing). 1..4.
  int supersample = 2;

  // World frame of the input: `up` is the orbit's axis (the turntable frame's
  // +Z); `azimuth_zero` is where the camera sits at azimuth 0 (made
  // orthogonal to up; must not be parallel to it).
  cv::Vec3d up{0, 0, 1};
  cv::Vec3d azimuth_zero{1, 0, 0};

  // Light: a directional light given in the camera frame (x right, y up,
  // z towards the viewer), plus ambient. Intensity = ambient + (1 − ambient)
  // · max(0, n·l), two-sided (a normal facing away from the viewer is
  // flipped first).
  cv::Vec3d light_in_camera{-0.35, 0.5, 0.8};
  double ambient = 0.25;  // 0..1

  cv::Vec3b background_bgr{246, 246, 246};
  bool scale_bar = true;  // orthographic only: a bar with its length in mm, bottom left

  // Clouds: splat radius in output pixels (a disc about 2r+1 across); −1
  // picks it from the point density so that surfaces look closed. −1..16.
  int point_radius_px = -1;
  // Clouds: colours from the cloud when it has them (shaded by the light when
  // it has normals too); without colours, grey shaded by the normals; without
  // either, coloured by height along `up` (Turbo).
  bool point_colors = true;
  // Meshes: interpolated vertex normals when the mesh has them (smooth);
  // false, or a mesh without normals: one normal per face (flat).
  bool smooth_shading = true;
  cv::Vec3b mesh_base_bgr{170, 190, 208};  // meshes without vertex colours (clay)

  bool IsValid(std::string* why) const;  // names the offending field
};

// The camera a preview was rendered with, so callers (and tests) can map
// points into the image.
struct PreviewCamera {
  PreviewProjection projection = PreviewProjection::kOrthographic;
  cv::Size size;                 // output image size, px
  cv::Vec3d center_mm{0, 0, 0};  // orbit centre (bounding-box centre of the input)
  cv::Vec3d right{1, 0, 0};      // unit vectors of the camera in the input frame:
  cv::Vec3d up{0, 1, 0};         //   image right, image up, and towards the camera
  cv::Vec3d toward_camera{0, 0, 1};
  // With q = p − center_mm and (cx, cy) the image centre:
  //  orthographic: px = cx + pixels_per_mm·(q·right − offset_right),
  //                py = cy − pixels_per_mm·(q·up − offset_up)      (offsets in mm);
  //  perspective: a pinhole at distance_mm from center_mm looking at it, z =
  //                distance_mm − q·toward_camera,
  //                px = cx + focal_px·(q·right / z − offset_right),
  //                py = cy − focal_px·(q·up / z − offset_up)      (offsets unitless).
  double pixels_per_mm = 1;
  double focal_px = 1;
  double distance_mm = 1;
  double offset_right = 0, offset_up = 0;

  // Image position (px; x right, y down; pixel centres at integers) of
  // `p_mm` and its depth (mm along the viewing direction, larger = farther;
  // orthographic: relative to the plane through center_mm). False for a
  // point at or behind a perspective camera.
  bool Project(const cv::Vec3d& p_mm, cv::Point2d* pixel, double* depth_mm) const;
};

// Outcome of one render.
struct PreviewImage {
  std::string error;  // non-empty: nothing was rendered, this says why
  cv::Mat image_bgr;  // CV_8UC3, options.size
  // CV_8UC1, options.size: how much of each pixel the object covers
  // (0 = background, 255 = fully; in between along edges when supersampled).
  cv::Mat coverage;
  PreviewCamera camera;
  std::size_t drawn = 0;    // points or triangles that reached the image
  double scale_bar_mm = 0;  // length the scale bar shows (0: none)

  bool ok() const { return error.empty(); }
};

// Places the camera for `view`: orbit centre = centre of the axis-aligned
// bounding box of the finite points; perspective: at the distance where the
// bounding sphere fills fov_deg (so every point is in front of it). Then the
// scale (orthographic) or focal length (perspective) and the offsets are
// chosen so that the points' projection fills the image less the margins,
// centred. Non-finite points are ignored. False with *error for invalid
// options or view, or no finite point.
bool FitPreviewCamera(const std::vector<cv::Vec3f>& points_mm, const PreviewView& view,
                      const PreviewOptions& options, PreviewCamera* camera, std::string* error);

// Renders a point cloud: each finite point is splatted as a disc with a
// z-buffer (the nearest point wins a pixel), coloured as PreviewOptions says.
// Fails (error set) for invalid options, view or cloud (PointCloud::IsValid),
// or a cloud without finite points. About 50 ms of CPU for 200k points at
// 640×480 (supersample 2), one thread.
PreviewImage RenderCloudPreview(const PointCloud& cloud, const PreviewView& view,
                                const PreviewOptions& options);

// Renders a triangle mesh with a z-buffer (per-pixel barycentric depth),
// Lambert shading (smooth or flat, see PreviewOptions) and vertex colours.
// Fails for invalid options, view or mesh (TriangleMesh::IsValid: e.g. a
// non-finite vertex or an index out of range), or a mesh without faces.
// About 90 ms of CPU for 300k triangles at 640×480 (supersample 2), one thread.
PreviewImage RenderMeshPreview(const TriangleMesh& mesh, const PreviewView& view,
                               const PreviewOptions& options);

}  // namespace craftscan::daemon
