// Session reports (daemon/report, report.h): the page's content and escaping,
// the files MakeReportFiles returns, and (printed, not asserted) how long
// the pictures take.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/daemon/report.h"
#include "craftscan/daemon/session_manifest.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"
#include "synthetic.h"

namespace craftscan::daemon {
namespace {

using craftscan::testing::SphereMesh;
using craftscan::testing::SpherePoints;

RegistrationResult Registration(double fitness, double rmse, int iterations, bool converged,
                                bool prior) {
  RegistrationResult r;
  r.status = RegistrationResult::Status::kOk;
  r.fitness = fitness;
  r.rmse_mm = rmse;
  r.inliers = 4321;
  r.iterations = iterations;
  r.converged = converged;
  r.prior_kept = prior;
  return r;
}

// A finished scan with recognisable figures.
ScanResult MakeScan() {
  ScanResult r;
  r.status = ScanResult::Status::kOk;
  r.message = "fitness < 0.5 on one pair";  // pipeline text with markup characters
  r.views.resize(3);
  for (int k = 0; k < 3; ++k) r.views[k].input_points = 50000 + k;
  r.pairwise.resize(3);
  r.pairwise[1] = Registration(0.873, 0.217, 17, true, true);
  r.pairwise[2] = Registration(0.654, 0.301, 23, false, false);
  LoopClosureResult loop;
  loop.status = LoopClosureResult::Status::kOk;
  loop.model = LoopClosureResult::Model::kTurntableAxis;
  loop.open_loop_rot_deg = 0.412;
  loop.open_loop_rms_mm = 0.356;
  loop.axis_rms_mm = 0.129;
  loop.rms_mm = 0.118;
  loop.max_mm = 0.402;
  loop.angles_rad = {0, 2.0944, 4.1888};
  r.loop = loop;
  r.turntable_from_view0 = cv::Matx44d::eye();
  r.fused = SpherePoints(3000, {0, 0, 60}, 50, true);
  r.fusion.single_view_voxels = 4321;
  r.fusion.lone_view_voxels = 210;
  r.fusion.sole_view_voxels = 987;
  r.fusion.hidden_view_voxels = 123;
  r.fusion.small_cluster_voxels = 65;
  r.fusion.output_points = 3000;
  r.box.extents_mm = {120.25, 80.5, 40.75};
  r.box.center_mm = {1.5, -2.5, 20.375};
  r.box.points = 3000;
  BoxMeasurement m;
  m.status = BoxMeasurement::Status::kOk;
  m.message = "base plane given";
  m.vertex_method = VertexMethod::kPointCircle;
  m.dims_mm = {119.87, 80.12, 40.33};
  m.vertices_mm.assign(8, cv::Vec3d(0, 0, 0));
  m.refined_vertices_mm.assign(8, cv::Vec3d(0, 0, 0));
  m.circle_radius_mm.assign(8, 0.5);
  m.circle_fallback.assign(8, false);
  for (int e = 0; e < 12; ++e) {
    BoxEdge edge;
    edge.axis = e / 4;
    edge.a = e;
    edge.b = e + 1;
    edge.length_mm = m.dims_mm[edge.axis] + 0.01 * (e % 4);
    edge.intersection_length_mm = edge.length_mm + 0.2;
    edge.circle_length_mm = edge.length_mm;
    m.edges.push_back(edge);
  }
  m.face_rms_mm = 0.087;
  m.max_orthogonality_error_deg = 0.61;
  r.box_measurement = m;
  r.condition_ms = 1234;
  r.register_ms = 5678;
  r.mesh_ms = 4321;
  return r;
}

StereoCalibration MakeCalibration() {
  StereoCalibration c;
  c.image_size = {1280, 960};
  c.T = {-60, 0, 0};
  c.P1(0, 0) = 1400;
  c.report.rms_left_px = 0.201;
  c.report.rms_right_px = 0.213;
  c.report.rms_stereo_px = 0.234;
  c.report.epipolar_mean_px = 0.061;
  c.report.epipolar_max_px = 0.233;
  c.report.coverage_left = 0.72;
  c.report.coverage_right = 0.69;
  c.report.views_used = 18;
  c.report.views.resize(20);
  c.report.verdict = CalibrationVerdict::kAccept;
  c.report.verdict_reason = "all limits met";
  c.turntable.valid = true;
  c.report.turntable_steps = 12;
  c.report.turntable_residual_mm = 0.0871;
  c.report.turntable_max_angle_error_deg = 0.052;
  return c;
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// Every src="..." of the page.
std::set<std::string> ImageSources(const std::string& html) {
  std::set<std::string> out;
  const std::string key = "src=\"";
  for (std::size_t at = html.find(key); at != std::string::npos; at = html.find(key, at + 1)) {
    const std::size_t begin = at + key.size();
    out.insert(html.substr(begin, html.find('"', begin) - begin));
  }
  return out;
}

TEST(ReportHtml, ShowsTheMeasurementsCalibrationAndRegistration) {
  const ScanResult scan = MakeScan();
  const StereoCalibration calibration = MakeCalibration();
  ReportInputs in;
  in.session_id = "20240501-093000-box";
  in.object_name = "Carved box";
  in.created_utc = "2024-05-01T09:30:00.000Z";
  in.calibration_id = "rig-a";
  in.scan_report_json = ScanReportJson(scan);
  in.calibration = &calibration;
  in.disparities.push_back({1, 120.0, {}, 0, 64});
  std::string html, error;
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  EXPECT_EQ(html.rfind("<!DOCTYPE html>", 0), 0u);
  EXPECT_TRUE(Contains(html, "</html>"));
  EXPECT_FALSE(Contains(html, "<script"));
  // Title: object, session, date.
  EXPECT_TRUE(Contains(html, "<h1>Carved box</h1>"));
  EXPECT_TRUE(Contains(html, "20240501-093000-box"));
  EXPECT_TRUE(Contains(html, "2024-05-01T09:30:00.000Z"));
  // Measurements: box extents, box edges, dims, mm.
  for (const char* figure : {"120.25 mm", "80.50 mm", "40.75 mm", "119.87", "80.12", "40.33",
                             "119.90", "point_circle", "0.087 mm"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Calibration: id, RMS, epipolar error, coverage, verdict, turntable residual.
  for (const char* figure : {"rig-a", "0.234 px", "0.061 / 0.233 px", "72 % / 69 %", "accepted",
                             "all limits met", "0.087 mm over 12 steps", "60.00 mm", "18 of 20"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Registration per view: fitness, RMSE, iterations, converged, prior kept; commanded angle.
  for (const char* figure : {"0.873", "0.217", ">17<", "0.654", "0.301", ">23<", "120.0", "120.00"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Loop closure and stage times.
  for (const char* figure :
       {"turntable_axis", "0.412", "0.118 mm RMS", "0.402 mm max", "5.68", "11.23"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Fusion: what multi-view support dropped and kept.
  for (const char* figure :
       {"4321 voxels no second view confirmed dropped", "210 with no other",
        "987 that only their own camera faced", "123 that every other camera saw from behind",
        "65 in detached clusters"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Pipeline text is escaped too.
  EXPECT_TRUE(Contains(html, "fitness &lt; 0.5 on one pair"));
}

TEST(ReportHtml, EscapesHostileNames) {
  ReportInputs in;
  in.object_name = "<script>alert('x')</script> & \"egg\"";
  in.session_id = "20240501-093000-x\"><img src=x onerror=alert(1)>";
  in.calibration_id = "<b>rig</b>";
  in.generated_utc = "<i>now</i>";
  std::string html, error;
  ASSERT_TRUE(ReportHtml(in, {}, {"<note>"}, &html, &error)) << error;
  EXPECT_FALSE(Contains(html, "<script"));
  EXPECT_FALSE(Contains(html, "<img"));
  EXPECT_FALSE(Contains(html, "<b>rig"));
  EXPECT_FALSE(Contains(html, "<i>now"));
  EXPECT_FALSE(Contains(html, "<note>"));
  EXPECT_TRUE(
      Contains(html, "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; &quot;egg&quot;"));
  EXPECT_TRUE(Contains(html, "&lt;note&gt;"));
  EXPECT_EQ(HtmlEscape("a<b>&'\""), "a&lt;b&gt;&amp;&#39;&quot;");
}

TEST(ReportHtml, RefusesBadJsonAndBadPictureNames) {
  ReportInputs in;
  in.scan_report_json = "{not json";
  std::string html = "untouched", error;
  EXPECT_FALSE(ReportHtml(in, {}, {}, &html, &error));
  EXPECT_TRUE(Contains(error, "scan_report_json")) << error;
  EXPECT_EQ(html, "untouched");
  in.scan_report_json = "[1, 2]";
  EXPECT_FALSE(ReportHtml(in, {}, {}, &html, &error));
  in.scan_report_json = "";
  for (const char* name : {"../etc/passwd.png", "/abs.png", "a\"b.png", ""}) {
    EXPECT_FALSE(ReportHtml(in, {{name, "cloud", "x", {1, 1}}}, {}, &html, &error)) << name;
    EXPECT_TRUE(Contains(error, "picture name")) << error;
  }
  // No scan figures at all is a (thin) page, not an error.
  EXPECT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
}

TEST(MakeReportFiles, PicturesThenThePageThatReferencesEachOfThem) {
  const ScanResult scan = MakeScan();
  const StereoCalibration calibration = MakeCalibration();
  const TriangleMesh mesh = SphereMesh(20, 40, {0, 0, 60}, 50);
  ReportInputs in;
  in.session_id = "20240501-093000-box";
  in.object_name = "box";
  in.scan_report_json = ScanReportJson(scan);
  in.calibration = &calibration;
  in.fused = &scan.fused;
  in.mesh = &mesh;
  cv::Mat small(120, 160, CV_32FC1, cv::Scalar(20.0f));
  small(cv::Rect(0, 0, 40, 40)).setTo(std::numeric_limits<float>::quiet_NaN());
  cv::Mat large(960, 1280, CV_32FC1, cv::Scalar(30.0f));
  in.disparities.push_back({1, 120, large, 0, 64});
  in.disparities.push_back({0, 0, small, 0, 64});
  in.disparities.push_back({2, 240, cv::Mat(10, 10, CV_8UC1), 0, 64});  // wrong type: left out
  ReportFiles files;
  std::string error;
  ASSERT_TRUE(MakeReportFiles(in, &files, &error)) << error;

  // 2 disparity maps + 5 cloud + 5 mesh previews + the page.
  ASSERT_EQ(files.files.size(), 13u);
  ASSERT_EQ(files.pictures.size(), 12u);
  EXPECT_EQ(files.files.back().name, "report.html");
  EXPECT_EQ(files.files[0].name, "previews/disparity_000.png");
  EXPECT_EQ(files.files[1].name, "previews/disparity_001.png");
  std::set<std::string> pngs;
  for (std::size_t i = 0; i + 1 < files.files.size(); ++i) {
    const ReportFile& f = files.files[i];
    std::string why;
    EXPECT_TRUE(IsValidOutputName(f.name, &why)) << f.name << ": " << why;
    EXPECT_TRUE(pngs.insert(f.name).second) << f.name << " twice";
    EXPECT_EQ(files.pictures[i].name, f.name);
    const cv::Mat decoded =
        cv::imdecode(std::vector<uchar>(f.bytes.begin(), f.bytes.end()), cv::IMREAD_COLOR);
    ASSERT_FALSE(decoded.empty()) << f.name;
    EXPECT_EQ(decoded.size(), files.pictures[i].size) << f.name;
  }
  EXPECT_TRUE(pngs.count("previews/cloud_az000.png"));
  EXPECT_TRUE(pngs.count("previews/mesh_top.png"));
  // The large map is shown 640 wide; the small one at its own size.
  EXPECT_EQ(files.pictures[1].size, cv::Size(640, 480 + ColorBarHeight(640)));
  EXPECT_EQ(files.pictures[0].size, cv::Size(160, 120 + ColorBarHeight(160)));
  EXPECT_TRUE(Contains(files.pictures[0].caption, "92 % valid")) << files.pictures[0].caption;

  const std::string& html = files.files.back().bytes;
  EXPECT_EQ(ImageSources(html), pngs);
  ASSERT_EQ(files.notes.size(), 1u);
  EXPECT_TRUE(Contains(files.notes[0], "view 2 disparity")) << files.notes[0];
  EXPECT_TRUE(Contains(html, "view 2 disparity"));
}

TEST(MakeReportFiles, MissingPartsAreNotedAndBadOptionsRefused) {
  ReportInputs in;
  in.scan_report_json = ScanReportJson(MakeScan());
  ReportFiles files;
  std::string error;
  ASSERT_TRUE(MakeReportFiles(in, &files, &error)) << error;
  ASSERT_EQ(files.files.size(), 1u);
  EXPECT_EQ(files.notes,
            (std::vector<std::string>{"cloud previews: no fused cloud", "mesh previews: no mesh"}));
  EXPECT_TRUE(Contains(files.files[0].bytes, "No mesh previews."));

  in.options.views.push_back(in.options.views[0]);
  EXPECT_FALSE(MakeReportFiles(in, &files, &error));
  EXPECT_TRUE(Contains(error, "used twice")) << error;
  in.options = ReportOptions();
  in.options.disparity_max_width_px = 10;
  EXPECT_FALSE(MakeReportFiles(in, &files, &error));
  EXPECT_TRUE(Contains(error, "disparity_max_width_px")) << error;
  in.options = ReportOptions();
  in.scan_report_json = "nope";
  EXPECT_FALSE(MakeReportFiles(in, &files, &error));
  EXPECT_TRUE(Contains(error, "scan_report_json")) << error;
}

// Bench-like figures, printed and not asserted. Set CRAFTSCAN_REPORT_DUMP to
// a folder to get the files for a look.
TEST(ReportTiming, LargeCloudAndMesh) {
  const PointCloud cloud = SpherePoints(200000, {0, 0, 40}, 40, true);
  const TriangleMesh mesh = SphereMesh(388, 388, {0, 0, 40}, 40);  // 301k triangles
  const PreviewOptions options;
  // CPU time of this (single-threaded) work: the machine may be shared.
  auto ms = [](auto&& f) {
    const std::clock_t start = std::clock();
    f();
    return 1000.0 * static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
  };
  PreviewImage image;
  const double cloud_ms = ms([&] {
    image = RenderCloudPreview(cloud, {"az030", 30, 30}, options);
  });
  ASSERT_TRUE(image.ok()) << image.error;
  const double mesh_ms = ms([&] { image = RenderMeshPreview(mesh, {"az030", 30, 30}, options); });
  ASSERT_TRUE(image.ok()) << image.error;

  ScanResult scan = MakeScan();
  ReportInputs in;
  in.session_id = "20240501-093000-sphere";
  in.object_name = "sphere";
  in.scan_report_json = ScanReportJson(scan);
  in.fused = &cloud;
  in.mesh = &mesh;
  // A smooth map with noise and holes, like the matcher's.
  cv::Mat disparity(960, 1280, CV_32FC1), noise(960, 1280, CV_32FC1);
  cv::randn(noise, 0, 0.3);
  for (int y = 0; y < disparity.rows; ++y)
    for (int x = 0; x < disparity.cols; ++x) {
      const double r = std::hypot(x - 640.0, y - 480.0);
      disparity.at<float>(y, x) =
          r < 400
              ? static_cast<float>(20 + 30 * std::cos(r / 400 * M_PI / 2)) + noise.at<float>(y, x)
              : std::numeric_limits<float>::quiet_NaN();
    }
  for (int k = 0; k < 24; ++k) in.disparities.push_back({k, 15.0 * k, disparity, 0, 64});
  ReportFiles files;
  std::string error;
  const double files_cpu_ms =
      ms([&] { ASSERT_TRUE(MakeReportFiles(in, &files, &error)) << error; });
  std::size_t bytes = 0;
  for (const ReportFile& f : files.files) bytes += f.bytes.size();
  std::printf("[ report ] cloud preview %zu points %dx%d (supersample %d): %.1f ms CPU\n",
              cloud.size(), options.size.width, options.size.height, options.supersample, cloud_ms);
  std::printf("[ report ] mesh preview %zu triangles %dx%d (supersample %d): %.1f ms CPU\n",
              mesh.faces.size(), options.size.width, options.size.height, options.supersample,
              mesh_ms);
  std::printf(
      "[ report ] MakeReportFiles (5+5 previews, 24 disparity maps 1280x960): %.0f ms CPU "
      "(%.0f ms wall), %zu files, %.1f MB\n",
      files_cpu_ms, files.render_ms, files.files.size(), bytes / 1e6);
  RecordProperty("cloud_preview_ms", std::to_string(cloud_ms));
  RecordProperty("mesh_preview_ms", std::to_string(mesh_ms));
  RecordProperty("report_files_ms", std::to_string(files.render_ms));

  if (const char* dump = std::getenv("CRAFTSCAN_REPORT_DUMP")) {
    for (const ReportFile& f : files.files) {
      const std::filesystem::path path = std::filesystem::path(dump) / f.name;
      std::filesystem::create_directories(path.parent_path());
      std::ofstream(path, std::ios::binary)
          .write(f.bytes.data(), static_cast<std::streamsize>(f.bytes.size()));
    }
  }
}

}  // namespace
}  // namespace craftscan::daemon
