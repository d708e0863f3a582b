// Session reports (daemon/report, report.h): the page's content and escaping,
// the files MakeReportFiles returns, the 3D view's inlined viewer and model
// (decoded back to the points and triangles given), and (printed, not
// asserted) how long the pictures take and how large the page is.
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <vector>

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
  loop.calibrated_axis = true;
  loop.axis_disagreement_deg = 0.0734;
  loop.axis_disagreement_mm = 0.214;
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
       {"turntable_axis", "0.412", "0.118 mm RMS", "0.402 mm max", "5.68", "11.23",
        "the calibrated one (the views' own fit is 0.073&deg; and 0.21 mm from it)"})
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

// Two turns (report.json "turns" and "turn_join", as the daemon writes
// them for scan --add-to): each turn's views and state, the join's figures.
TEST(ReportHtml, ShowsBothTurnsAndHowTheyWereJoined) {
  nlohmann::json report = nlohmann::json::parse(ScanReportJson(MakeScan()));
  report["turns"] = {{{"turn", 1},
                      {"first_view", 0},
                      {"views", 6},
                      {"step_deg", 60},
                      {"state", "done"},
                      {"contact_dropped", 312}},
                     {{"turn", 2},
                      {"first_view", 6},
                      {"views", 6},
                      {"step_deg", 60},
                      {"state", "joined"},
                      {"contact_dropped", 1045}}};
  report["turn_join"] = {{"status", "joined"}, {"message", "<fine>"}, {"overlap_pct", 72.64},
                         {"rmse_mm", 0.1834},  {"ambiguity", 0.0},    {"constraint", 0.2077},
                         {"hypotheses", 23},   {"points_a", 19893},   {"points_b", 20468},
                         {"time_ms", 8123.0}};
  ReportInputs in;
  in.scan_report_json = report.dump();
  std::string html, error;
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  for (const char* figure :
       {"id=\"turns\"", "href=\"#turns\"", "6&ndash;11", "312", "1045", ">joined<",
        "72.6 % of the later turn", "0.183 mm", "no other placement fits", "0.208", ">23<",
        "19893 of turn 1", "8.12 s", "&lt;fine&gt;"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  EXPECT_FALSE(Contains(html, "held weakly"));
  // Held weakly (one small feature holds it): the constraint's row says so.
  report["turn_join"]["constraint"] = 0.0152;
  report["turn_join"]["held"] = "weakly";
  in.scan_report_json = report.dump();
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  for (const char* figure : {"0.015 (the least held", "held weakly, by one small feature"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // Refused: its status as the verdict, the rival's figures.
  report["turn_join"]["status"] = "refused_ambiguous";
  report["turn_join"]["ambiguity"] = 0.95;
  report["turn_join"]["alternative_deg"] = 23.0;
  report["turn_join"]["alternative_mm"] = 8.9;
  in.scan_report_json = report.dump();
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  for (const char* figure : {"badge bad\">refused_ambiguous", "23.0&deg;, 8.9 mm away) fits 95 %"})
    EXPECT_TRUE(Contains(html, figure)) << figure;
  // One turn: no section.
  in.scan_report_json = ScanReportJson(MakeScan());
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  EXPECT_FALSE(Contains(html, "id=\"turns\""));
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

// --- the 3D view ------------------------------------------------------------------

// The text of the element with id="<id>" (a <script> holding base64), or
// nullopt; its data-count in *count.
std::optional<std::string> ElementText(const std::string& html, const std::string& id,
                                       long* count = nullptr) {
  const std::size_t at = html.find("id=\"" + id + "\"");
  if (at == std::string::npos) return std::nullopt;
  const std::size_t begin = html.find('>', at) + 1;
  if (count) {
    const std::size_t c = html.find("data-count=\"", at);
    *count = c < begin ? std::stol(html.substr(c + 12)) : -1;
  }
  return html.substr(begin, html.find("</script>", begin) - begin);
}

std::string DecodeBase64(const std::string& text) {
  auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    return c == '+' ? 62 : c == '/' ? 63 : -1;
  };
  std::string out;
  std::uint32_t bits = 0;
  int n = 0;
  for (char c : text) {
    const int v = value(c);
    if (v < 0) continue;  // padding
    bits = bits << 6 | static_cast<std::uint32_t>(v);
    if ((n += 6) >= 8) out += static_cast<char>((bits >> (n -= 8)) & 0xff);
  }
  return out;
}

template <typename T>
std::vector<T> Decode(const std::string& html, const std::string& id, long* count) {
  const std::optional<std::string> text = ElementText(html, id, count);
  if (!text) return {};
  const std::string bytes = DecodeBase64(*text);
  std::vector<T> out(bytes.size() / sizeof(T));
  std::memcpy(out.data(), bytes.data(), out.size() * sizeof(T));  // little-endian host
  return out;
}

struct PageModel {
  long points = -1, vertices = -1, triangles = -1;
  std::vector<float> cloud, mesh;
  std::vector<std::uint8_t> cloud_colors, mesh_colors;
  std::vector<std::uint32_t> indices;
};

PageModel ReadModel(const std::string& html) {
  PageModel m;
  long ignored = 0;
  m.cloud = Decode<float>(html, "craftscan-cloud-positions", &m.points);
  m.cloud_colors = Decode<std::uint8_t>(html, "craftscan-cloud-colors", &ignored);
  m.mesh = Decode<float>(html, "craftscan-mesh-positions", &m.vertices);
  m.mesh_colors = Decode<std::uint8_t>(html, "craftscan-mesh-colors", &ignored);
  m.indices = Decode<std::uint32_t>(html, "craftscan-mesh-indices", &m.triangles);
  return m;
}

TEST(ReportViewer, ThePageCarriesTheViewerAndTheModel) {
  const ScanResult scan = MakeScan();  // 3000 coloured points, turntable frame
  const TriangleMesh mesh = SphereMesh(20, 40, {0, 0, 60}, 50);
  ReportInputs in;
  in.scan_report_json = ScanReportJson(scan);
  in.fused = &scan.fused;
  in.mesh = &mesh;
  ReportFiles files;
  std::string error;
  ASSERT_TRUE(MakeReportFiles(in, &files, &error)) << error;
  const std::string& html = files.files.back().bytes;

  // The section above the previews, the viewer script, the start-up script
  // with the turntable frame's up axis.
  const std::size_t model = html.find("<section id=\"model\">");
  ASSERT_NE(model, std::string::npos);
  EXPECT_LT(model, html.find("<section id=\"cloud\">"));
  EXPECT_TRUE(Contains(html, "<div id=\"craftscan-viewer\" class=\"viewer\">"));
  EXPECT_TRUE(Contains(html, "<a href=\"#model\">3D view</a>"));
  const std::optional<std::string> bundle = ElementText(html, "craftscan-viewer-bundle");
  ASSERT_TRUE(bundle);
  EXPECT_GT(bundle->size(), 100000u);  // three.js and the viewer, minified
  EXPECT_EQ(bundle->rfind("var CraftscanViewer=", 0), 0u) << bundle->substr(0, 80);
  const std::size_t start = html.find("<script>", html.find("id=\"craftscan-viewer-bundle\""));
  ASSERT_NE(start, std::string::npos);
  EXPECT_EQ(html.find("</script>", html.find("id=\"craftscan-viewer-bundle\"")) + 10, start)
      << "the bundle's script element ends before the start-up script";
  EXPECT_TRUE(Contains(html.substr(start),
                       "CraftscanViewer.create(box, {background: '#1d2125', "
                       "up: [0, 0, 1], front: [0, -1, 0]})"));
  EXPECT_TRUE(Contains(html, "Shown: 3000 of the 3000 fused points and the mesh's 1600 triangles"));

  // The cloud whole: positions and colours as given.
  const PageModel m = ReadModel(html);
  EXPECT_EQ(m.points, 3000);
  ASSERT_EQ(m.cloud.size(), 3u * 3000);
  ASSERT_EQ(m.cloud_colors.size(), 3u * 3000);
  for (std::size_t i : {std::size_t{0}, std::size_t{1234}, std::size_t{2999}})
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(m.cloud[3 * i + k], scan.fused.points_mm[i][k]) << i;
      EXPECT_EQ(m.cloud_colors[3 * i + k], scan.fused.colors_rgb[i][k]) << i;
    }
  // The mesh whole (under the triangle budget).
  EXPECT_EQ(m.triangles, 1600);
  EXPECT_EQ(m.vertices, static_cast<long>(mesh.vertices_mm.size()));
  ASSERT_EQ(m.mesh.size(), 3 * mesh.vertices_mm.size());
  EXPECT_EQ(m.mesh_colors.size(), 3 * mesh.vertices_mm.size());
  ASSERT_EQ(m.indices.size(), 3u * 1600);
  for (int k = 0; k < 3; ++k)
    EXPECT_EQ(m.indices[3 * 7 + k], static_cast<std::uint32_t>(mesh.faces[7][k]));
  EXPECT_EQ(m.mesh[3 * 5 + 2], mesh.vertices_mm[5][2]);
}

TEST(ReportViewer, BudgetsThinTheCloudAndSimplifyTheMesh) {
  PointCloud cloud = SpherePoints(5000, {0, 0, 40}, 40, true);
  cloud.points_mm[10] = {NAN, 0, 0};                             // left out
  const TriangleMesh mesh = SphereMesh(40, 80, {0, 0, 40}, 40);  // 6400 triangles
  ReportInputs in;
  in.fused = &cloud;
  in.mesh = &mesh;
  in.options.viewer_max_points = 1000;
  in.options.viewer_max_triangles = 1000;
  std::string html, error;
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  const PageModel m = ReadModel(html);

  // 1000 of the 4999 finite points, each one of the cloud's, spread over all of it.
  EXPECT_EQ(m.points, 1000);
  ASSERT_EQ(m.cloud.size(), 3000u);
  std::map<std::tuple<float, float, float>, std::size_t> index;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (i != 10) index[{cloud.points_mm[i][0], cloud.points_mm[i][1], cloud.points_mm[i][2]}] = i;
  std::size_t last = 0;
  for (std::size_t k = 0; k < 1000; ++k) {
    const auto it = index.find({m.cloud[3 * k], m.cloud[3 * k + 1], m.cloud[3 * k + 2]});
    ASSERT_NE(it, index.end()) << "point " << k << " is not one of the cloud's";
    EXPECT_NE(it->second, 10u);
    if (k > 0) {
      EXPECT_NEAR(double(it->second - last), 5.0, 1.0) << k;  // every 5th
    }
    last = it->second;
  }
  EXPECT_GE(last, 4990u);

  // The mesh simplified to at most 1000 triangles, still the sphere.
  EXPECT_LE(m.triangles, 1000);
  EXPECT_GE(m.triangles, 400);
  ASSERT_EQ(m.indices.size(), 3u * static_cast<std::size_t>(m.triangles));
  ASSERT_EQ(m.mesh.size(), 3u * static_cast<std::size_t>(m.vertices));
  EXPECT_EQ(m.mesh_colors.size(), m.mesh.size());
  for (std::uint32_t i : m.indices) ASSERT_LT(i, static_cast<std::uint32_t>(m.vertices));
  for (long v = 0; v < m.vertices; ++v) {
    const double r = std::hypot(m.mesh[3 * v], m.mesh[3 * v + 1], m.mesh[3 * v + 2] - 40);
    EXPECT_NEAR(r, 40, 3) << "vertex " << v;  // within about a cell (≈ 5 mm) of the sphere
  }
  EXPECT_TRUE(Contains(
      html, "the mesh simplified to " + std::to_string(m.triangles) + " of its 6400 triangles"));
}

TEST(ReportViewer, LeftOutWithoutAModelOrWhenTurnedOff) {
  const PointCloud cloud = SpherePoints(2000, {0, 0, 40}, 40, false);
  ReportInputs in;
  std::string html, error;
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  EXPECT_FALSE(Contains(html, "<script"));
  EXPECT_FALSE(Contains(html, "id=\"model\""));

  in.fused = &cloud;  // no colours: positions only
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  const PageModel m = ReadModel(html);
  EXPECT_EQ(m.points, 2000);
  EXPECT_EQ(m.cloud.size(), 6000u);
  EXPECT_TRUE(m.cloud_colors.empty());
  EXPECT_FALSE(Contains(html, "id=\"craftscan-mesh-"));
  EXPECT_TRUE(Contains(html, "CraftscanViewer.create(box, {background: '#1d2125'})"));

  in.options.viewer = false;
  ASSERT_TRUE(ReportHtml(in, {}, {}, &html, &error)) << error;
  EXPECT_FALSE(Contains(html, "<script"));

  in.options = ReportOptions();
  in.options.viewer_max_points = 10;
  ReportFiles files;
  EXPECT_FALSE(MakeReportFiles(in, &files, &error));
  EXPECT_TRUE(Contains(error, "viewer_max_points")) << error;
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
  std::string page, why;
  const double page_ms = ms([&] { ASSERT_TRUE(ReportHtml(in, files.pictures, {}, &page, &why)); });
  std::printf(
      "[ report ] report.html %.2f MB, %.0f ms CPU (the 3D view: at most %d points, %d "
      "triangles)\n",
      page.size() / 1e6, page_ms, in.options.viewer_max_points, in.options.viewer_max_triangles);
  RecordProperty("report_html_ms", std::to_string(page_ms));
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
