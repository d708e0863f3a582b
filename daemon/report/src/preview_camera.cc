// Preview views, options and camera placement (preview.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/preview.h"
#include "render_internal.h"

namespace craftscan::daemon {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

bool Fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

bool Finite(const cv::Vec3d& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

bool PreviewView::IsValid(std::string* why) const {
  const PreviewView& view = *this;
  if (view.name.empty() || view.name.size() > 32)
    return Fail(why, "view name must have 1..32 characters, got '" + view.name + "'");
  for (char c : view.name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
    if (!ok) return Fail(why, "view name '" + view.name + "' may hold only [a-z0-9_-]");
  }
  if (!std::isfinite(view.azimuth_deg))
    return Fail(why, "view " + view.name + ": azimuth_deg must be finite");
  if (!(view.elevation_deg >= -90 && view.elevation_deg <= 90))
    return Fail(why, "view " + view.name + ": elevation_deg must be within -90..90");
  return true;
}

std::vector<PreviewView> DefaultPreviewViews() {
  return {
      {"az000", 0, 30}, {"az090", 90, 30}, {"az180", 180, 30}, {"az270", 270, 30}, {"top", 0, 90}};
}

const char* ToString(PreviewProjection projection) {
  return projection == PreviewProjection::kPerspective ? "perspective" : "orthographic";
}

bool PreviewProjectionFromString(const std::string& text, PreviewProjection* projection) {
  if (text == "orthographic")
    *projection = PreviewProjection::kOrthographic;
  else if (text == "perspective")
    *projection = PreviewProjection::kPerspective;
  else
    return false;
  return true;
}

bool PreviewOptions::IsValid(std::string* why) const {
  if (size.width < 16 || size.height < 16 || size.width > 8192 || size.height > 8192)
    return Fail(why, "size must be 16..8192 px per side");
  if (!(fov_deg >= 5 && fov_deg <= 120)) return Fail(why, "fov_deg must be within 5..120");
  if (!(margin >= 0 && margin <= 0.4)) return Fail(why, "margin must be within 0..0.4");
  if (supersample < 1 || supersample > 4) return Fail(why, "supersample must be 1..4");
  if (static_cast<double>(size.width) * supersample * size.height * supersample > 1.2e8)
    return Fail(why, "size × supersample is too large (over 120 Mpx)");
  if (!Finite(up) || cv::norm(up) < 1e-9) return Fail(why, "up must be a finite non-zero vector");
  if (!Finite(azimuth_zero)) return Fail(why, "azimuth_zero must be finite");
  const cv::Vec3d u = up / cv::norm(up);
  const cv::Vec3d side = azimuth_zero - u * u.dot(azimuth_zero);
  if (cv::norm(side) < 1e-6 * std::max(1.0, cv::norm(azimuth_zero)))
    return Fail(why, "azimuth_zero must not be parallel to up (or zero)");
  if (!Finite(light_in_camera) || cv::norm(light_in_camera) < 1e-9)
    return Fail(why, "light_in_camera must be a finite non-zero vector");
  if (!(ambient >= 0 && ambient <= 1)) return Fail(why, "ambient must be within 0..1");
  if (point_radius_px < -1 || point_radius_px > 16)
    return Fail(why, "point_radius_px must be -1..16");
  return true;
}

bool PreviewCamera::Project(const cv::Vec3d& p_mm, cv::Point2d* pixel, double* depth_mm) const {
  const cv::Vec3d q = p_mm - center_mm;
  const double cx = (size.width - 1) * 0.5, cy = (size.height - 1) * 0.5;
  if (projection == PreviewProjection::kOrthographic) {
    *pixel = {cx + pixels_per_mm * (q.dot(right) - offset_right),
              cy - pixels_per_mm * (q.dot(up) - offset_up)};
    *depth_mm = -q.dot(toward_camera);
    return true;
  }
  const double z = distance_mm - q.dot(toward_camera);
  if (!(z > 1e-9)) return false;
  *pixel = {cx + focal_px * (q.dot(right) / z - offset_right),
            cy - focal_px * (q.dot(up) / z - offset_up)};
  *depth_mm = z;
  return true;
}

bool FitPreviewCamera(const std::vector<cv::Vec3f>& points_mm, const PreviewView& view,
                      const PreviewOptions& options, PreviewCamera* camera, std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) return Fail(error, "preview options: " + why);
  if (!view.IsValid(&why)) return Fail(error, "preview " + why);
  auto finite = [](const cv::Vec3f& p) {
    return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
  };

  cv::Vec3d lo(std::numeric_limits<double>::max()), hi(std::numeric_limits<double>::lowest());
  std::size_t count = 0;
  for (const cv::Vec3f& p : points_mm) {
    if (!finite(p)) continue;
    ++count;
    for (int k = 0; k < 3; ++k)
      lo[k] = std::min(lo[k], double(p[k])), hi[k] = std::max(hi[k], double(p[k]));
  }
  if (count == 0) return Fail(error, "preview: no finite point to show");

  PreviewCamera c;
  c.projection = options.projection;
  c.size = options.size;
  c.center_mm = (lo + hi) * 0.5;
  // Orbit frame: z = up, x = azimuth 0, y = z × x (azimuth 90).
  const cv::Vec3d z = options.up / cv::norm(options.up);
  cv::Vec3d x = options.azimuth_zero - z * z.dot(options.azimuth_zero);
  x /= cv::norm(x);
  const cv::Vec3d y = z.cross(x);
  const double az = view.azimuth_deg * kDegToRad, el = view.elevation_deg * kDegToRad;
  c.toward_camera = std::cos(el) * (std::cos(az) * x + std::sin(az) * y) + std::sin(el) * z;
  // The azimuth tangent stays defined looking straight down or up.
  c.right = -std::sin(az) * x + std::cos(az) * y;
  c.up = c.toward_camera.cross(c.right);

  const bool ortho = options.projection == PreviewProjection::kOrthographic;
  if (!ortho) {
    double radius = 1e-3;
    for (const cv::Vec3f& p : points_mm)
      if (finite(p)) radius = std::max(radius, cv::norm(cv::Vec3d(p[0], p[1], p[2]) - c.center_mm));
    c.distance_mm = radius / std::sin(options.fov_deg * 0.5 * kDegToRad);
  }
  // Extents of the projection before scaling: mm (orthographic) or x/z, y/z.
  double u0 = std::numeric_limits<double>::max(), u1 = std::numeric_limits<double>::lowest();
  double v0 = u0, v1 = u1;
  for (const cv::Vec3f& p : points_mm) {
    if (!finite(p)) continue;
    const cv::Vec3d q = cv::Vec3d(p[0], p[1], p[2]) - c.center_mm;
    double u = q.dot(c.right), v = q.dot(c.up);
    if (!ortho) {
      const double depth = c.distance_mm - q.dot(c.toward_camera);  // > 0: outside the sphere
      u /= depth, v /= depth;
    }
    u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
  }
  // A single point or a line seen end-on still gets a finite scale.
  const double min_span = ortho ? 1e-3 : 1e-6;
  const double free = 1 - 2 * options.margin;
  const double scale = std::min(options.size.width * free / std::max(u1 - u0, min_span),
                                options.size.height * free / std::max(v1 - v0, min_span));
  (ortho ? c.pixels_per_mm : c.focal_px) = scale;
  c.offset_right = (u0 + u1) * 0.5;
  c.offset_up = (v0 + v1) * 0.5;
  *camera = c;
  return true;
}

PreviewCamera ScaleCamera(const PreviewCamera& camera, int factor) {
  PreviewCamera c = camera;
  c.size = {camera.size.width * factor, camera.size.height * factor};
  c.pixels_per_mm *= factor;
  c.focal_px *= factor;
  return c;
}

cv::Vec3d LightInWorld(const PreviewCamera& camera, const PreviewOptions& options) {
  const cv::Vec3d& l = options.light_in_camera;
  const cv::Vec3d w = l[0] * camera.right + l[1] * camera.up + l[2] * camera.toward_camera;
  return w / cv::norm(w);
}

const cv::Mat& TurboLut() {
  static const cv::Mat lut = [] {
    cv::Mat ramp(256, 1, CV_8UC1), colored;
    for (int i = 0; i < 256; ++i) ramp.at<uchar>(i) = static_cast<uchar>(i);
    cv::applyColorMap(ramp, colored, cv::COLORMAP_TURBO);
    return colored;
  }();
  return lut;
}

void FinishPreview(FrameBuffer& buffer, const PreviewCamera& camera, const PreviewOptions& options,
                   PreviewImage* out) {
  if (buffer.width == camera.size.width && buffer.height == camera.size.height) {
    out->image_bgr = buffer.color;
    out->coverage = buffer.coverage;
  } else {
    cv::resize(buffer.color, out->image_bgr, camera.size, 0, 0, cv::INTER_AREA);
    cv::resize(buffer.coverage, out->coverage, camera.size, 0, 0, cv::INTER_AREA);
  }
  out->camera = camera;
  if (!options.scale_bar || camera.projection != PreviewProjection::kOrthographic) return;

  // The largest 1-2-5 length that spans at most a fifth of the width.
  const double max_mm = 0.2 * camera.size.width / camera.pixels_per_mm;
  double length = std::pow(10.0, std::floor(std::log10(max_mm)));
  for (double f : {5.0, 2.0}) {
    if (length * f <= max_mm) {
      length *= f;
      break;
    }
  }
  const int bar_px = static_cast<int>(std::lround(length * camera.pixels_per_mm));
  if (bar_px < 8 || camera.size.height < 48) return;
  const double scale = std::clamp(camera.size.width / 1400.0, 0.35, 1.2);
  const int x0 = std::max(6, camera.size.width / 50);
  const int y0 = camera.size.height - std::max(6, camera.size.height / 40);
  const int tick = std::max(3, camera.size.height / 80);
  const cv::Scalar ink(70, 70, 70);
  cv::line(out->image_bgr, {x0, y0}, {x0 + bar_px, y0}, ink, 2);
  cv::line(out->image_bgr, {x0, y0 - tick}, {x0, y0}, ink, 2);
  cv::line(out->image_bgr, {x0 + bar_px, y0 - tick}, {x0 + bar_px, y0}, ink, 2);
  char text[32];
  std::snprintf(text, sizeof text, "%g mm", length);
  cv::putText(out->image_bgr, text, {x0, y0 - tick - 4}, cv::FONT_HERSHEY_SIMPLEX, scale, ink, 1,
              cv::LINE_AA);
  out->scale_bar_mm = length;
}

}  // namespace craftscan::daemon
