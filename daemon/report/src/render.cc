// Software preview renderers for clouds and meshes (preview.h).
//
// Why a rasteriser of our own: OpenCV draws 2-D primitives only (fillPoly
// has no depth test), and VTK's offscreen rendering needs an X display or a
// GL context, which the daemon (a system service) does not have. A z-buffer
// point splatter and a barycentric triangle rasteriser are ~150 lines and
// render 300k triangles at 640×480 in tens of milliseconds.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "craftscan/daemon/preview.h"
#include "render_internal.h"

namespace craftscan::daemon {
namespace {

// A projected vertex: image position (supersampled px) and nearness (see
// FrameBuffer); `ok` false for a non-finite input or one behind the camera.
struct Projected {
  float x = 0, y = 0, near = 0;
  bool ok = false;
};

std::vector<Projected> ProjectAll(const std::vector<cv::Vec3f>& points,
                                  const PreviewCamera& camera) {
  std::vector<Projected> out(points.size());
  const bool ortho = camera.projection == PreviewProjection::kOrthographic;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const cv::Vec3f& p = points[i];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
    cv::Point2d px;
    double depth = 0;
    if (!camera.Project({p[0], p[1], p[2]}, &px, &depth)) continue;
    out[i] = {static_cast<float>(px.x), static_cast<float>(px.y),
              static_cast<float>(ortho ? -depth : 1.0 / depth), true};
  }
  return out;
}

// Pixel offsets of a disc of radius `r` px (r < 0.5: the centre pixel only).
std::vector<cv::Point> DiscOffsets(double r) {
  std::vector<cv::Point> offsets;
  const int n = static_cast<int>(std::floor(r + 0.5));
  for (int dy = -n; dy <= n; ++dy)
    for (int dx = -n; dx <= n; ++dx)
      if (dx * dx + dy * dy <= r * r + r + 0.25) offsets.push_back({dx, dy});
  return offsets;
}

// Splat radius (output px) that closes the surface. About half the points
// face the camera, spread over a surface about twice the ellipse inscribed in
// their image extents (a hemisphere is twice its disc), which gives the point
// spacing where the surface faces the camera (it is denser where it turns
// away). A disc covers a hexagonal lattice when its radius + ½ px reaches
// spacing/√3 ≈ 0.58·spacing; 0.7 leaves room for irregular sampling.
double AutoPointRadius(const std::vector<Projected>& projected, int factor) {
  float x0 = 1e30f, x1 = -1e30f, y0 = 1e30f, y1 = -1e30f;
  std::size_t n = 0;
  for (const Projected& p : projected) {
    if (!p.ok) continue;
    ++n;
    x0 = std::min(x0, p.x), x1 = std::max(x1, p.x), y0 = std::min(y0, p.y), y1 = std::max(y1, p.y);
  }
  if (n < 2) return 1;
  const double area = M_PI / 4 * ((x1 - x0) / factor + 1) * ((y1 - y0) / factor + 1);
  const double spacing = std::sqrt(2 * area / std::max<double>(1, n / 2.0));
  return std::clamp(0.7 * spacing - 0.4, 0.0, 16.0);
}

// What both renderers share: validation, the camera fit, the supersampled
// frame buffer and the guard against OpenCV exceptions. `input_error` is the
// input's own problem ("" when valid); `draw(camera, fine, buffer)` renders
// into the buffer with the supersampled camera `fine` and returns how many
// primitives reached the image.
template <typename Draw>
PreviewImage Render(const char* what, const std::string& input_error,
                    const std::vector<cv::Vec3f>& points, const PreviewView& view,
                    const PreviewOptions& options, Draw&& draw) {
  PreviewImage out;
  std::string why;
  if (!options.IsValid(&why)) {
    out.error = "preview options: " + why;
  } else if (!input_error.empty()) {
    out.error = std::string(what) + " preview: " + input_error;
  } else if (PreviewCamera camera; !FitPreviewCamera(points, view, options, &camera, &why)) {
    out.error = std::string(what) + " " + why;
  } else {
    try {
      const PreviewCamera fine = ScaleCamera(camera, options.supersample);
      FrameBuffer buffer(fine.size, options.background_bgr);
      out.drawn = draw(camera, fine, buffer);
      FinishPreview(buffer, camera, options, &out);
    } catch (const cv::Exception& e) {
      out = PreviewImage();
      out.error = std::string(what) + " preview: OpenCV: " + e.what();
    }
  }
  return out;
}

}  // namespace

PreviewImage RenderCloudPreview(const PointCloud& cloud, const PreviewView& view,
                                const PreviewOptions& options) {
  std::string why;
  const std::string input_error = cloud.IsValid(&why) ? "" : "invalid cloud: " + why;
  auto draw = [&](const PreviewCamera& camera, const PreviewCamera& fine, FrameBuffer& buffer) {
    const int ss = options.supersample;
    std::size_t drawn_points = 0;
    const std::vector<Projected> projected = ProjectAll(cloud.points_mm, fine);
    const double radius =
        options.point_radius_px >= 0 ? options.point_radius_px : AutoPointRadius(projected, ss);
    const std::vector<cv::Point> disc = DiscOffsets(radius * ss + (ss - 1) * 0.5);

    const cv::Vec3d light = LightInWorld(camera, options);
    const bool colors = options.point_colors && cloud.HasColors();
    const bool normals = cloud.HasNormals();
    // Height colouring when there is nothing else to show the shape with.
    float h0 = 0, h_scale = 0;
    const cv::Vec3d up = options.up / cv::norm(options.up);
    if (!colors && !normals) {
      float lo = 1e30f, hi = -1e30f;
      for (std::size_t i = 0; i < cloud.size(); ++i) {
        if (!projected[i].ok) continue;
        const float h = static_cast<float>(up.dot(cv::Vec3d(cloud.points_mm[i])));
        lo = std::min(lo, h), hi = std::max(hi, h);
      }
      h0 = lo;
      h_scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
    }
    const cv::Mat& lut = TurboLut();
    const cv::Vec3b grey(215, 215, 215);

    for (std::size_t i = 0; i < cloud.size(); ++i) {
      const Projected& p = projected[i];
      if (!p.ok) continue;
      const int cx = static_cast<int>(std::lround(p.x)), cy = static_cast<int>(std::lround(p.y));
      if (cx < -64 || cy < -64 || cx >= buffer.width + 64 || cy >= buffer.height + 64) continue;
      cv::Vec3b bgr;
      if (colors) {
        const cv::Vec3b& rgb = cloud.colors_rgb[i];
        bgr = {rgb[2], rgb[1], rgb[0]};
        if (normals)
          bgr = Scaled(bgr, Lambert(cv::Vec3d(cloud.normals[i]), light, camera.toward_camera,
                                    std::max(options.ambient, 0.55)));
      } else if (normals) {
        bgr = Scaled(grey, Lambert(cv::Vec3d(cloud.normals[i]), light, camera.toward_camera,
                                   options.ambient));
      } else {
        const float h = (static_cast<float>(up.dot(cv::Vec3d(cloud.points_mm[i]))) - h0) * h_scale;
        bgr = lut.at<cv::Vec3b>(std::clamp(static_cast<int>(h + 0.5f), 0, 255));
      }
      bool drawn = false;
      for (const cv::Point& o : disc) {
        const int x = cx + o.x, y = cy + o.y;
        if (x < 0 || y < 0 || x >= buffer.width || y >= buffer.height) continue;
        buffer.Put(x, y, p.near, bgr);
        drawn = true;
      }
      drawn_points += drawn;
    }
    return drawn_points;
  };
  return Render("cloud", input_error, cloud.points_mm, view, options, draw);
}

PreviewImage RenderMeshPreview(const TriangleMesh& mesh, const PreviewView& view,
                               const PreviewOptions& options) {
  std::string why;
  std::string input_error;
  if (!mesh.IsValid(&why))
    input_error = "invalid mesh: " + why;
  else if (mesh.empty())
    input_error = "the mesh has no faces";
  auto draw = [&](const PreviewCamera& camera, const PreviewCamera& fine, FrameBuffer& buffer) {
    std::size_t drawn_faces = 0;
    const std::vector<Projected> projected = ProjectAll(mesh.vertices_mm, fine);
    const cv::Vec3d light = LightInWorld(camera, options);
    const cv::Vec3d& toward = camera.toward_camera;
    const bool smooth = options.smooth_shading && !mesh.normals.empty();

    // Per-vertex colour (BGR, float), already lit when shading is smooth.
    std::vector<cv::Vec3f> vertex_color(mesh.vertices_mm.size());
    for (std::size_t v = 0; v < vertex_color.size(); ++v) {
      cv::Vec3f c =
          mesh.colors_rgb.empty()
              ? cv::Vec3f(options.mesh_base_bgr[0], options.mesh_base_bgr[1],
                          options.mesh_base_bgr[2])
              : cv::Vec3f(mesh.colors_rgb[v][2], mesh.colors_rgb[v][1], mesh.colors_rgb[v][0]);
      if (smooth) c *= Lambert(cv::Vec3d(mesh.normals[v]), light, toward, options.ambient);
      vertex_color[v] = c;
    }

    const float width = static_cast<float>(buffer.width),
                height = static_cast<float>(buffer.height);
    for (const cv::Vec3i& f : mesh.faces) {
      const Projected &a = projected[f[0]], &b = projected[f[1]], &c = projected[f[2]];
      if (!a.ok || !b.ok || !c.ok) continue;
      // Pixel centres at integer coordinates inside the triangle's box.
      const float fx0 = std::min({a.x, b.x, c.x}), fx1 = std::max({a.x, b.x, c.x});
      const float fy0 = std::min({a.y, b.y, c.y}), fy1 = std::max({a.y, b.y, c.y});
      if (fx1 < 0 || fy1 < 0 || fx0 > width - 1 || fy0 > height - 1) continue;
      const int x0 = std::max(0, static_cast<int>(std::ceil(fx0)));
      const int x1 = std::min(buffer.width - 1, static_cast<int>(std::floor(fx1)));
      const int y0 = std::max(0, static_cast<int>(std::ceil(fy0)));
      const int y1 = std::min(buffer.height - 1, static_cast<int>(std::floor(fy1)));
      if (x0 > x1 || y0 > y1) continue;
      const float area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
      if (std::abs(area) < 1e-12f) continue;
      const float inv_area = 1.0f / area;

      float flat = 1;
      if (!smooth) {
        const cv::Vec3d pa(mesh.vertices_mm[f[0]]), pb(mesh.vertices_mm[f[1]]),
            pc(mesh.vertices_mm[f[2]]);
        flat = Lambert((pb - pa).cross(pc - pa), light, toward, options.ambient);
      }
      const cv::Vec3f ca = vertex_color[f[0]] * flat, cb = vertex_color[f[1]] * flat,
                      cc = vertex_color[f[2]] * flat;
      // Inclusive edges (with a little slack) so shared edges leave no cracks;
      // the z-test settles pixels drawn twice.
      constexpr float kSlack = -1e-5f;
      bool drawn = false;
      for (int y = y0; y <= y1; ++y) {
        const float py = static_cast<float>(y);
        for (int x = x0; x <= x1; ++x) {
          const float px = static_cast<float>(x);
          const float wa = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) * inv_area;
          const float wb = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) * inv_area;
          const float wc = 1.0f - wa - wb;
          if (wa < kSlack || wb < kSlack || wc < kSlack) continue;
          const float near = wa * a.near + wb * b.near + wc * c.near;
          const cv::Vec3f col = wa * ca + wb * cb + wc * cc;
          buffer.Put(x, y, near,
                     {cv::saturate_cast<uchar>(col[0]), cv::saturate_cast<uchar>(col[1]),
                      cv::saturate_cast<uchar>(col[2])});
          drawn = true;
        }
      }
      drawn_faces += drawn;
    }
    return drawn_faces;
  };
  return Render("mesh", input_error, mesh.vertices_mm, view, options, draw);
}

}  // namespace craftscan::daemon
