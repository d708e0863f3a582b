// report.html for a finished scan session (DESIGN.md "Sessions on disk"):
// one self-contained page (inline CSS) with the measurements, the
// calibration used and its quality, per-view registration quality, loop
// closure, stage times, and pictures — colour-mapped disparity maps and
// previews of the fused cloud and mesh from several angles (preview.h) —
// stored beside it as previews/*.png. Above the previews an interactive 3D
// view of the cloud and mesh (clients/web/API.md "The 3D viewer"): the
// viewer's script and the model are inlined, so it works from file://
// without network; the previews stay for browsers without WebGL.
//
//   ReportInputs in;
//   in.session_id = session.id();  in.object_name = manifest.object_name;
//   in.created_utc = manifest.created_utc;  in.calibration_id = manifest.calibration_id;
//   in.scan_report_json = ScanReportJson(result);      // or the stored report.json
//   in.fused = &result.fused;
//   if (result.mesh.IsUsable()) in.mesh = &result.mesh.mesh;
//   in.calibration = &calibration;
//   in.disparities.push_back({k, angle_deg, disparity_px, min_d, max_d});
//   ReportFiles files;
//   if (!MakeReportFiles(in, &files, &error)) ...;
//   for (const ReportFile& f : files.files) Status stored = session.StoreOutput(f.name, f.bytes);
//
// The files come pictures first and report.html last, so storing them in
// order lists the page only once every picture it shows is durable.
// Every function is pure and thread-safe and never throws.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "craftscan/daemon/preview.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::daemon {

// One view's disparity map as stored (views/NNN/disparity.pfm).
struct DisparityView {
  int index = 0;                                                // view index, 0..999
  double angle_deg = std::numeric_limits<double>::quiet_NaN();  // commanded angle; NaN: unknown
  cv::Mat disparity_px;                                         // CV_32FC1, NaN = invalid
  // The matcher's search range, used as the colour-map range; NaN: the
  // range of the finite values.
  double min_disparity_px = std::numeric_limits<double>::quiet_NaN();
  double max_disparity_px = std::numeric_limits<double>::quiet_NaN();
};

struct ReportOptions {
  PreviewOptions preview;  // size, projection, light...; up/azimuth_zero are set from the frame
  std::vector<PreviewView> views = DefaultPreviewViews();  // cloud and mesh previews
  // Disparity pictures are downscaled (nearest neighbour) to at most this
  // width: full-size maps of a 5 MP camera would make a 100 MB report. 64..8192.
  int disparity_max_width_px = 640;
  // The 3D view (needs a fused cloud or a mesh; its script adds ≈ 0.6 MB).
  // The cloud is thinned evenly to at most viewer_max_points, a mesh with
  // more than viewer_max_triangles is simplified (vertex clustering) to at
  // most that many: the page grows by ≈ 20 bytes per point and ≈ 26 per
  // triangle. Each 1000..5000000.
  bool viewer = true;
  int viewer_max_points = 200000;
  int viewer_max_triangles = 100000;

  bool IsValid(std::string* why) const;  // names the offending field
};

// What a report is made from. Pointers are non-owning, may be null (that part
// is left out, with a note), and must stay valid during the call. Strings are
// shown as given (HTML-escaped).
struct ReportInputs {
  std::string session_id;
  std::string object_name;     // as the operator gave it
  std::string created_utc;     // when the session was created (ISO 8601)
  std::string generated_utc;   // when the report is made; "" leaves it out
  std::string calibration_id;  // as recorded in the manifest
  // ScanReportJson(result) or the session's report.json: measurements,
  // registration, loop closure, stage times, sizes, and "frame" (turntable
  // or view0, which sets the previews' up axis). "" leaves those out.
  std::string scan_report_json;
  const StereoCalibration* calibration = nullptr;
  const PointCloud* fused = nullptr;
  const TriangleMesh* mesh = nullptr;
  std::vector<DisparityView> disparities;  // any order; shown by index
  ReportOptions options;
};

// A picture the page shows.
struct ReportPicture {
  std::string name;     // relative to the session folder, e.g. "previews/cloud_az000.png"
  std::string section;  // "cloud", "mesh" or "disparity"
  std::string caption;  // plain text (escaped when written)
  cv::Size size;        // px
};

// The page for `inputs` showing `pictures` (in the order given within each
// section) and listing `notes` (parts left out) near the top. Every
// user-supplied string (object name, ids, messages, notes) is HTML-escaped.
// Of inputs.options only the viewer fields are used (out-of-range budgets
// are clamped to 1000..5000000); the page has scripts only when it has the
// 3D view. Fails (false, *error; *html untouched) only
// when scan_report_json is not empty and not a JSON object, or a picture name
// is not a relative path of [A-Za-z0-9._/-] without "..".
bool ReportHtml(const ReportInputs& inputs, const std::vector<ReportPicture>& pictures,
                const std::vector<std::string>& notes, std::string* html, std::string* error);

// Escapes & < > " ' for HTML text and attribute values.
std::string HtmlEscape(const std::string& text);

struct ReportFile {
  std::string name;   // relative to the session folder: "previews/…png", "report.html"
  std::string bytes;  // PNG or UTF-8 HTML
};

struct ReportFiles {
  std::vector<ReportFile> files;  // pictures, then report.html (last)
  std::vector<ReportPicture> pictures;
  // Parts left out and why ("mesh previews: no mesh", "view 3 disparity: …").
  std::vector<std::string> notes;
  double render_ms = 0;  // wall time of rendering and encoding
};

// Renders the pictures (disparity_NNN.png per view, cloud_<view>.png and
// mesh_<view>.png per ReportOptions::views) as PNG and writes the page that
// shows them. A picture that cannot be made is left out with a note (the
// page says so too); that is not a failure. Fails (false, *error naming the
// field) for invalid options, an invalid scan_report_json, or a PNG
// encoder failure. One thread; about 1.3 s of CPU for a 200k-point cloud, a
// 300k-triangle mesh (5 views each) and 24 disparity maps of 1280×960 at the
// default sizes (≈ 5 MB of PNG), of which ≈ 0.25 s for the 3D view (its mesh
// simplified to 100k triangles; report.html ≈ 7 MB).
bool MakeReportFiles(const ReportInputs& inputs, ReportFiles* files, std::string* error);

}  // namespace craftscan::daemon
