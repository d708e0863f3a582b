// Report pictures (daemon/report, preview.h): disparity colour mapping and
// the cloud and mesh preview renderers against analytic projections.
#include <cmath>
#include <limits>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/preview.h"
#include "synthetic.h"

namespace craftscan::daemon {
namespace {

using craftscan::testing::CubeMesh;
using craftscan::testing::CubePoints;
using craftscan::testing::SpherePoints;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

cv::Vec3b TurboAt(int index) {
  static const cv::Mat table = [] {
    cv::Mat ramp(256, 1, CV_8UC1), colored;
    for (int i = 0; i < 256; ++i) ramp.at<uchar>(i) = static_cast<uchar>(i);
    cv::applyColorMap(ramp, colored, cv::COLORMAP_TURBO);
    return colored;
  }();
  return table.at<cv::Vec3b>(index);
}

// Exact options for geometry checks: no anti-aliasing, no scale bar.
PreviewOptions Exact() {
  PreviewOptions o;
  o.supersample = 1;
  o.scale_bar = false;
  o.background_bgr = {0, 0, 0};
  return o;
}

double CoveredPixels(const PreviewImage& image) { return cv::sum(image.coverage)[0] / 255.0; }

cv::Point2d CoverageCentroid(const PreviewImage& image) {
  const cv::Moments m = cv::moments(image.coverage, false);
  return {m.m10 / m.m00, m.m01 / m.m00};
}

// --- disparity colour map ----------------------------------------------------

TEST(ColorizeDisparity, EndsOfTheRangeGetTheEndsOfTheMapAndInvalidIsBlack) {
  cv::Mat d(40, 200, CV_32FC1, cv::Scalar(50.0f));
  d.at<float>(0, 0) = 10.0f;  // min
  d.at<float>(0, 1) = 90.0f;  // max
  d.at<float>(0, 2) = kNaN;   // invalid
  d.at<float>(0, 3) = std::numeric_limits<float>::infinity();
  d.at<float>(0, 4) = -5.0f;   // below the range: clamped to min
  d.at<float>(0, 5) = 500.0f;  // above: clamped to max
  std::string error;
  const cv::Mat c = ColorizeDisparity(d, 10, 90, &error);
  ASSERT_FALSE(c.empty()) << error;
  ASSERT_EQ(c.type(), CV_8UC3);
  EXPECT_EQ(c.cols, d.cols);
  EXPECT_EQ(c.rows, d.rows + ColorBarHeight(d.cols));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 0), TurboAt(0));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 1), TurboAt(255));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 2), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 3), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 4), TurboAt(0));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 5), TurboAt(255));
  EXPECT_EQ(c.at<cv::Vec3b>(10, 10), TurboAt(128));  // 50 is the middle: 127.5 rounds to 128
  // Turbo itself never gives black, so black means "no disparity".
  for (int i = 0; i < 256; ++i) EXPECT_NE(TurboAt(i), cv::Vec3b(0, 0, 0)) << i;
  // The strip holds the bar: its row through the bar shows both map ends.
  const cv::Mat strip = c.rowRange(d.rows, c.rows);
  int bar_pixels = 0;
  for (int y = 0; y < strip.rows; ++y)
    for (int x = 0; x < strip.cols; ++x)
      bar_pixels +=
          strip.at<cv::Vec3b>(y, x) == TurboAt(0) || strip.at<cv::Vec3b>(y, x) == TurboAt(255);
  EXPECT_GT(bar_pixels, 4);
}

TEST(ColorizeDisparity, NanRangeIsTakenFromTheData) {
  cv::Mat d(8, 8, CV_32FC1, cv::Scalar(kNaN));
  d.at<float>(1, 1) = -3.0f;
  d.at<float>(2, 2) = 7.0f;
  const cv::Mat c = ColorizeDisparity(d, std::nan(""), std::nan(""));
  ASSERT_FALSE(c.empty());
  EXPECT_EQ(c.at<cv::Vec3b>(1, 1), TurboAt(0));
  EXPECT_EQ(c.at<cv::Vec3b>(2, 2), TurboAt(255));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  // No valid pixel at all: still a picture (all black), not an error.
  EXPECT_FALSE(ColorizeDisparity(cv::Mat(4, 4, CV_32FC1, cv::Scalar(kNaN)), NAN, NAN).empty());
}

TEST(ColorizeDisparity, BadInputIsRefusedWithAReason) {
  std::string error;
  EXPECT_TRUE(ColorizeDisparity(cv::Mat(), 0, 1, &error).empty());
  EXPECT_NE(error.find("empty"), std::string::npos) << error;
  EXPECT_TRUE(ColorizeDisparity(cv::Mat(4, 4, CV_8UC1), 0, 1, &error).empty());
  EXPECT_NE(error.find("CV_32FC1"), std::string::npos) << error;
  EXPECT_TRUE(ColorizeDisparity(cv::Mat(4, 4, CV_32FC1, cv::Scalar(1)), 5, 5, &error).empty());
  EXPECT_NE(error.find("min < max"), std::string::npos) << error;
  EXPECT_TRUE(
      ColorizeDisparity(cv::Mat(4, 4, CV_32FC1, cv::Scalar(1)), 0, INFINITY, &error).empty());
  EXPECT_NE(error.find("infinite"), std::string::npos) << error;
}

// --- cloud previews ----------------------------------------------------------------

TEST(CloudPreview, OrthographicSphereSilhouetteMatchesItsProjection) {
  const cv::Vec3f center(10, -20, 35);
  const PointCloud cloud = SpherePoints(120000, center, 50, true);
  PreviewOptions options = Exact();
  options.point_radius_px = 1;
  const PreviewImage image = RenderCloudPreview(cloud, {"test", 30, 20}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  ASSERT_EQ(image.image_bgr.size(), options.size);
  EXPECT_GT(image.drawn, cloud.size() * 9 / 10);
  // Height-limited fit: the 100 mm diameter spans the image height less the margins.
  const double s = image.camera.pixels_per_mm;
  EXPECT_NEAR(s, 480 * (1 - 2 * options.margin) / 100, 0.01);
  // A disc of radius 50·s, widened by the 1 px splat radius (±1 px of radius).
  const double r = 50 * s;
  EXPECT_NEAR(CoveredPixels(image), M_PI * (r + 1) * (r + 1), M_PI * 2 * r * 1.2);
  cv::Point2d px;
  double depth = 0;
  ASSERT_TRUE(image.camera.Project(cv::Vec3d(center), &px, &depth));
  EXPECT_NEAR(px.x, 319.5, 0.5);
  EXPECT_NEAR(px.y, 239.5, 0.5);
  const cv::Point2d c = CoverageCentroid(image);
  EXPECT_NEAR(c.x, px.x, 0.7);
  EXPECT_NEAR(c.y, px.y, 0.7);
  // The inside is closed: no background pixel well within the disc.
  int holes = 0, inside = 0;
  for (int y = 0; y < image.coverage.rows; ++y)
    for (int x = 0; x < image.coverage.cols; ++x)
      if (std::hypot(x - px.x, y - px.y) < r - 3)
        ++inside, holes += image.coverage.at<uchar>(y, x) == 0;
  EXPECT_LT(holes, inside / 1000) << holes << " holes of " << inside;
}

TEST(CloudPreview, AutomaticSplatSizeClosesASparseSurface) {
  const PointCloud cloud = SpherePoints(8000, {0, 0, 0}, 40, false);
  PreviewOptions options = Exact();
  const PreviewImage image = RenderCloudPreview(cloud, {"test", 0, 30}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  const double r = 40 * image.camera.pixels_per_mm;
  int holes = 0, inside = 0;
  for (int y = 0; y < image.coverage.rows; ++y)
    for (int x = 0; x < image.coverage.cols; ++x)
      if (std::hypot(x - 319.5, y - 239.5) < r - 6)
        ++inside, holes += image.coverage.at<uchar>(y, x) == 0;
  EXPECT_LT(holes, inside / 100) << holes << " holes of " << inside;
  // Not absurdly fat either: the silhouette grows by less than 6 px of radius.
  EXPECT_LT(CoveredPixels(image), M_PI * (r + 6) * (r + 6));
}

TEST(CloudPreview, PerspectiveSphereSilhouetteMatchesItsProjection) {
  const PointCloud cloud = SpherePoints(150000, {5, 5, 5}, 30, false);
  PreviewOptions options = Exact();
  options.projection = PreviewProjection::kPerspective;
  options.point_radius_px = 1;
  const PreviewImage image = RenderCloudPreview(cloud, {"persp", 45, 10}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  const PreviewCamera& cam = image.camera;
  EXPECT_NEAR(cam.distance_mm, 30 / std::sin(17.5 * M_PI / 180), 0.01);
  // The silhouette of a sphere centred on the optical axis: a circle of
  // radius f·tan(asin(R/D)).
  const double r = cam.focal_px * std::tan(std::asin(30 / cam.distance_mm));
  EXPECT_NEAR(r, 240 * (1 - 2 * options.margin), 2.0);  // fitted to the margins
  EXPECT_NEAR(CoveredPixels(image), M_PI * (r + 1) * (r + 1), M_PI * 2 * r * 1.5);
  const cv::Point2d c = CoverageCentroid(image);
  EXPECT_NEAR(c.x, 319.5, 0.7);
  EXPECT_NEAR(c.y, 239.5, 0.7);
}

TEST(CloudPreview, CubeSeenAlongADiagonalIsFittedToTheWidth) {
  const float side = 60;
  const PointCloud cloud = CubePoints(200000, {100, 0, 0}, side);
  PreviewOptions options = Exact();
  options.point_radius_px = 1;
  const PreviewImage image = RenderCloudPreview(cloud, {"diag", 45, 0}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  // Silhouette: a rectangle side·√2 wide and side high; width-limited.
  const double s = 640 * (1 - 2 * options.margin) / (side * std::sqrt(2.0));
  EXPECT_NEAR(image.camera.pixels_per_mm, s, 0.02);
  const double w = side * std::sqrt(2.0) * s, h = side * s;
  EXPECT_NEAR(CoveredPixels(image), (w + 2) * (h + 2), 2 * (w + h) * 1.2);
  cv::Rect box = cv::boundingRect(image.coverage);
  EXPECT_NEAR(box.width, w + 3, 3);
  EXPECT_NEAR(box.height, h + 3, 3);
  EXPECT_NEAR(box.x + box.width / 2.0, 320, 1.5);
  EXPECT_NEAR(box.y + box.height / 2.0, 240, 1.5);
}

TEST(CloudPreview, NearPointHidesFarPointWhateverTheOrder) {
  for (const PreviewProjection projection :
       {PreviewProjection::kOrthographic, PreviewProjection::kPerspective}) {
    for (const bool red_first : {true, false}) {
      PointCloud cloud;
      auto add = [&](cv::Vec3f p, cv::Vec3b rgb) {
        cloud.points_mm.push_back(p);
        cloud.colors_rgb.push_back(rgb);
      };
      const cv::Vec3f near(10, 0, 0), far(-10, 0, 0);  // the camera is on +x at azimuth 0
      if (red_first) add(near, {255, 0, 0});
      add(far, {0, 0, 255});
      if (!red_first) add(near, {255, 0, 0});
      for (float y : {-30.0f, 30.0f})
        for (float z : {-30.0f, 30.0f}) add({0, y, z}, {0, 255, 0});
      PreviewOptions options = Exact();
      options.projection = projection;
      options.point_radius_px = 2;
      const PreviewImage image = RenderCloudPreview(cloud, {"zbuf", 0, 0}, options);
      ASSERT_TRUE(image.ok()) << image.error;
      cv::Point2d px;
      double depth_near = 0, depth_far = 0;
      ASSERT_TRUE(image.camera.Project(cv::Vec3d(near), &px, &depth_near));
      ASSERT_TRUE(image.camera.Project(cv::Vec3d(far), &px, &depth_far));
      EXPECT_LT(depth_near, depth_far);
      const cv::Vec3b at = image.image_bgr.at<cv::Vec3b>(240, 320);
      EXPECT_EQ(at, cv::Vec3b(0, 0, 255)) << ToString(projection) << " red_first " << red_first;
    }
  }
}

TEST(CloudPreview, TopViewLooksDownTheUpAxis) {
  // A flat disc in the x-y plane seen from the top is a full circle.
  PointCloud cloud;
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j) {
      const float x = -50 + i * 0.5f, y = -50 + j * 0.5f;
      if (x * x + y * y <= 2500) cloud.points_mm.push_back({x, y, 3});
    }
  const PreviewImage image = RenderCloudPreview(cloud, {"top", 0, 90}, Exact());
  ASSERT_TRUE(image.ok()) << image.error;
  const double r = 50 * image.camera.pixels_per_mm;
  EXPECT_NEAR(CoveredPixels(image), M_PI * r * r, 2 * M_PI * r * 2.5);
}

TEST(CloudPreview, SupersamplingGivesPartialCoverageButTheSameArea) {
  const PointCloud cloud = SpherePoints(100000, {0, 0, 0}, 50, true);
  PreviewOptions options = Exact();
  options.supersample = 3;
  options.point_radius_px = 1;
  const PreviewImage image = RenderCloudPreview(cloud, {"aa", 0, 30}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  const double r = 50 * image.camera.pixels_per_mm;
  // A 1 px splat radius covers (1 + ½) px about each point, like without supersampling.
  EXPECT_NEAR(CoveredPixels(image), M_PI * (r + 1.5) * (r + 1.5), 2 * M_PI * r * 0.5);
  int partial = 0;
  for (int y = 0; y < image.coverage.rows; ++y)
    for (int x = 0; x < image.coverage.cols; ++x) {
      const uchar v = image.coverage.at<uchar>(y, x);
      partial += v > 0 && v < 255;
    }
  EXPECT_GT(partial, 2 * r);  // along the rim
}

TEST(CloudPreview, ScaleBarShowsANiceLength) {
  const PointCloud cloud = SpherePoints(20000, {0, 0, 0}, 50, true);
  PreviewOptions options;
  const PreviewImage image = RenderCloudPreview(cloud, {"bar", 0, 30}, options);
  ASSERT_TRUE(image.ok()) << image.error;
  // At most a fifth of the width: 0.2·640 / 4.13 px/mm ≈ 31 mm → 20 mm.
  EXPECT_DOUBLE_EQ(image.scale_bar_mm, 20);
  options.projection = PreviewProjection::kPerspective;
  EXPECT_EQ(RenderCloudPreview(cloud, {"bar", 0, 30}, options).scale_bar_mm, 0);
}

TEST(CloudPreview, BadInputIsRefusedWithAReason) {
  const PointCloud good = SpherePoints(100, {0, 0, 0}, 10, false);
  PreviewOptions options;
  options.size = {0, 480};
  EXPECT_NE(RenderCloudPreview(good, {}, options).error.find("size"), std::string::npos);
  options = PreviewOptions();
  options.up = {0, 0, 1};
  options.azimuth_zero = {0, 0, 2};
  EXPECT_NE(RenderCloudPreview(good, {}, options).error.find("azimuth_zero"), std::string::npos);
  EXPECT_NE(RenderCloudPreview(good, {"Bad Name", 0, 30}, {}).error.find("name"),
            std::string::npos);
  EXPECT_NE(RenderCloudPreview(good, {"x", 0, 95}, {}).error.find("elevation"), std::string::npos);
  PointCloud mismatched = good;
  mismatched.colors_rgb.resize(3);
  EXPECT_NE(RenderCloudPreview(mismatched, {}, {}).error.find("invalid cloud"), std::string::npos);
  EXPECT_NE(RenderCloudPreview(PointCloud(), {}, {}).error.find("no finite point"),
            std::string::npos);
  PointCloud nan_only;
  nan_only.points_mm.assign(10, cv::Vec3f(kNaN, 0, 0));
  EXPECT_FALSE(RenderCloudPreview(nan_only, {}, {}).ok());
  // One point: a finite camera and a picture.
  PointCloud one;
  one.points_mm.push_back({1, 2, 3});
  const PreviewImage single = RenderCloudPreview(one, {}, {});
  ASSERT_TRUE(single.ok()) << single.error;
  EXPECT_TRUE(std::isfinite(single.camera.pixels_per_mm));
  EXPECT_EQ(single.drawn, 1u);
}

TEST(PreviewOptions, ProjectionNamesRoundTrip) {
  for (const PreviewProjection p :
       {PreviewProjection::kOrthographic, PreviewProjection::kPerspective}) {
    PreviewProjection back = PreviewProjection::kOrthographic;
    ASSERT_TRUE(PreviewProjectionFromString(ToString(p), &back));
    EXPECT_EQ(back, p);
  }
  PreviewProjection unchanged = PreviewProjection::kPerspective;
  EXPECT_FALSE(PreviewProjectionFromString("Orthographic", &unchanged));
  EXPECT_EQ(unchanged, PreviewProjection::kPerspective);
  for (const PreviewView& v : DefaultPreviewViews()) EXPECT_TRUE(v.IsValid(nullptr)) << v.name;
  EXPECT_TRUE(PreviewOptions().IsValid(nullptr));
}

// --- mesh previews -----------------------------------------------------------------

TEST(MeshPreview, CubeFacesAreLitByLambertAndTheSilhouetteMatches) {
  const float side = 50;
  const cv::Vec3f center(0, 0, 20);
  const TriangleMesh cube = CubeMesh(center, side);
  PreviewOptions options = Exact();
  options.mesh_base_bgr = {200, 200, 200};
  const PreviewView view{"cube", 30, 25};
  const PreviewImage image = RenderMeshPreview(cube, view, options);
  ASSERT_TRUE(image.ok()) << image.error;
  // Two-sided (trimmed Poisson meshes have holes): the back faces are
  // rasterised too and lose the depth test.
  EXPECT_EQ(image.drawn, 12u);
  const PreviewCamera& cam = image.camera;
  const cv::Vec3d& d = cam.toward_camera;
  const double s = cam.pixels_per_mm;
  // Orthographic silhouette of a cube: side² · (|dx| + |dy| + |dz|).
  const double area = side * side * (std::abs(d[0]) + std::abs(d[1]) + std::abs(d[2])) * s * s;
  EXPECT_NEAR(CoveredPixels(image), area, area * 0.02);

  const cv::Vec3d& lc = options.light_in_camera;
  cv::Vec3d light = lc[0] * cam.right + lc[1] * cam.up + lc[2] * cam.toward_camera;
  light /= cv::norm(light);
  struct Face {
    cv::Vec3d normal;
    double expected = 0;
    int measured = 0;
  };
  Face faces[3] = {{{1, 0, 0}}, {{0, 1, 0}}, {{0, 0, 1}}};
  for (Face& f : faces) {
    ASSERT_GT(f.normal.dot(d), 0);  // visible
    f.expected =
        200 * (options.ambient + (1 - options.ambient) * std::max(0.0, f.normal.dot(light)));
    cv::Point2d px;
    double depth = 0;
    ASSERT_TRUE(cam.Project(cv::Vec3d(center) + f.normal * (side / 2), &px, &depth));
    const cv::Vec3b bgr = image.image_bgr.at<cv::Vec3b>(static_cast<int>(std::lround(px.y)),
                                                        static_cast<int>(std::lround(px.x)));
    f.measured = bgr[0];
    EXPECT_EQ(bgr[0], bgr[1]);
    EXPECT_NEAR(f.measured, f.expected, 1.5) << f.normal;
  }
  // The face turned most to the light is the brightest, the least the darkest.
  for (const Face& a : faces)
    for (const Face& b : faces)
      if (a.normal.dot(light) > b.normal.dot(light) + 0.05) {
        EXPECT_GT(a.measured, b.measured);
      }
}

TEST(MeshPreview, NearTriangleHidesFarTriangleWhateverTheOrder) {
  for (const PreviewProjection projection :
       {PreviewProjection::kOrthographic, PreviewProjection::kPerspective}) {
    for (const bool red_first : {true, false}) {
      TriangleMesh mesh;
      auto add = [&](float x, cv::Vec3b rgb) {
        const int base = static_cast<int>(mesh.vertices_mm.size());
        for (const cv::Vec3f& p :
             {cv::Vec3f(x, -40, -30), cv::Vec3f(x, 40, -30), cv::Vec3f(x, 0, 40)}) {
          mesh.vertices_mm.push_back(p);
          mesh.colors_rgb.push_back(rgb);
        }
        mesh.faces.push_back({base, base + 1, base + 2});
      };
      if (red_first) add(5, {255, 0, 0});
      add(-5, {0, 0, 255});
      if (!red_first) add(5, {255, 0, 0});
      PreviewOptions options = Exact();
      options.projection = projection;
      const PreviewImage image = RenderMeshPreview(mesh, {"zbuf", 0, 0}, options);
      ASSERT_TRUE(image.ok()) << image.error;
      const cv::Vec3b at = image.image_bgr.at<cv::Vec3b>(240, 320);
      EXPECT_GT(at[2], 100) << ToString(projection) << " red_first " << red_first;
      EXPECT_EQ(at[0], 0) << ToString(projection) << " red_first " << red_first;
    }
  }
}

TEST(MeshPreview, SmoothShadingUsesVertexNormals) {
  const TriangleMesh sphere = craftscan::testing::SphereMesh(40, 80, {0, 0, 0}, 30);
  PreviewOptions options = Exact();
  const PreviewImage smooth = RenderMeshPreview(sphere, {"s", 0, 30}, options);
  options.smooth_shading = false;
  const PreviewImage flat = RenderMeshPreview(sphere, {"s", 0, 30}, options);
  ASSERT_TRUE(smooth.ok() && flat.ok());
  // Same silhouette, different shading (flat shows facets).
  EXPECT_NEAR(CoveredPixels(smooth), CoveredPixels(flat), 1);
  cv::Mat diff;
  cv::absdiff(smooth.image_bgr, flat.image_bgr, diff);
  EXPECT_GT(cv::norm(diff, cv::NORM_L1), 1e4);
  // A sphere of radius 30 fills the height-limited fit.
  const double r = 30 * smooth.camera.pixels_per_mm;
  EXPECT_NEAR(CoveredPixels(smooth), M_PI * r * r, M_PI * r * r * 0.02);
}

TEST(MeshPreview, BadInputIsRefusedWithAReason) {
  TriangleMesh cube = CubeMesh({0, 0, 0}, 10);
  cube.faces.push_back({0, 1, 99});
  EXPECT_NE(RenderMeshPreview(cube, {}, {}).error.find("invalid mesh"), std::string::npos);
  EXPECT_NE(RenderMeshPreview(TriangleMesh(), {}, {}).error.find("no faces"), std::string::npos);
  TriangleMesh bad_normals = CubeMesh({0, 0, 0}, 10);
  bad_normals.normals.resize(2);
  EXPECT_FALSE(RenderMeshPreview(bad_normals, {}, {}).ok());
  PreviewOptions options;
  options.supersample = 9;
  EXPECT_NE(RenderMeshPreview(CubeMesh({0, 0, 0}, 10), {}, options).error.find("supersample"),
            std::string::npos);
  // Degenerate triangles (all on a line) render nothing but do not fail.
  TriangleMesh line;
  line.vertices_mm = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}};
  line.faces = {{0, 1, 2}};
  const PreviewImage image = RenderMeshPreview(line, {}, {});
  ASSERT_TRUE(image.ok()) << image.error;
  EXPECT_EQ(image.drawn, 0u);
}

}  // namespace
}  // namespace craftscan::daemon
