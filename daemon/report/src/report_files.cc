// The report's files: pictures rendered and PNG-encoded, then the page (report.h).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/report.h"

namespace craftscan::daemon {
namespace {

bool EncodePng(const cv::Mat& image, std::string* bytes, std::string* error) {
  try {
    std::vector<uchar> buffer;
    // Level 3: a third of level 9's time for ~5 % larger files.
    if (!cv::imencode(".png", image, buffer, {cv::IMWRITE_PNG_COMPRESSION, 3})) {
      if (error) *error = "PNG encoder refused the image";
      return false;
    }
    bytes->assign(buffer.begin(), buffer.end());
    return true;
  } catch (const cv::Exception& e) {
    if (error) *error = std::string("PNG encoder: ") + e.what();
    return false;
  }
}

std::string Format(const char* format, double a, double b = 0, double c = 0) {
  char buf[160];
  std::snprintf(buf, sizeof buf, format, a, b, c);
  return buf;
}

std::string ViewCaption(const std::string& what, const PreviewView& view) {
  if (view.elevation_deg >= 89.5) return what + " · from above";
  if (view.elevation_deg <= -89.5) return what + " · from below";
  return what + Format(" · azimuth %.0f°, elevation %.0f°", view.azimuth_deg, view.elevation_deg);
}

struct Work {
  ReportFiles* files;
  std::string* error;

  bool Add(const std::string& name, const std::string& section, const std::string& caption,
           const cv::Mat& image) {
    ReportFile file{name, {}};
    std::string why;
    if (!EncodePng(image, &file.bytes, &why)) {
      if (error) *error = "report: " + name + ": " + why;
      return false;
    }
    files->files.push_back(std::move(file));
    files->pictures.push_back({name, section, caption, image.size()});
    return true;
  }
};

bool DisparityPictures(const ReportInputs& in, Work& work) {
  std::vector<const DisparityView*> order;
  for (const DisparityView& d : in.disparities) order.push_back(&d);
  std::stable_sort(order.begin(), order.end(), [](const DisparityView* a, const DisparityView* b) {
    return a->index < b->index;
  });
  std::set<int> seen;
  for (const DisparityView* d : order) {
    const std::string what = "view " + std::to_string(d->index) + " disparity";
    if (d->index < 0 || d->index > 999) {
      work.files->notes.push_back(what + ": view index out of range 0..999");
      continue;
    }
    if (!seen.insert(d->index).second) {
      work.files->notes.push_back(what + ": given twice, the second left out");
      continue;
    }
    const cv::Mat& full = d->disparity_px;
    cv::Mat shown = full;
    if (!full.empty() && full.cols > in.options.disparity_max_width_px) {
      const int w = in.options.disparity_max_width_px;
      const int h = std::max(1, static_cast<int>(std::lround(double(full.rows) * w / full.cols)));
      cv::resize(full, shown, {w, h}, 0, 0, cv::INTER_NEAREST);  // keeps NaN holes as holes
    }
    std::string why;
    const cv::Mat colored =
        ColorizeDisparity(shown, d->min_disparity_px, d->max_disparity_px, &why);
    if (colored.empty()) {
      work.files->notes.push_back(what + ": " + why);
      continue;
    }
    int valid = 0;
    for (int y = 0; y < full.rows; ++y) {
      const float* row = full.ptr<float>(y);
      for (int x = 0; x < full.cols; ++x) valid += std::isfinite(row[x]);
    }
    std::string caption = "View " + std::to_string(d->index);
    if (std::isfinite(d->angle_deg)) caption += Format(" · %.1f°", d->angle_deg);
    if (std::isfinite(d->min_disparity_px) && std::isfinite(d->max_disparity_px))
      caption += Format(" · %.1f–%.1f px", d->min_disparity_px, d->max_disparity_px);
    caption += Format(" · %.0f %% valid", 100.0 * valid / std::max(1, full.rows * full.cols));
    char name[48];
    std::snprintf(name, sizeof name, "previews/disparity_%03d.png", d->index);
    if (!work.Add(name, "disparity", caption, colored)) return false;
  }
  return true;
}

}  // namespace

bool ReportOptions::IsValid(std::string* why) const {
  std::string sub;
  if (!preview.IsValid(&sub)) {
    if (why) *why = "preview: " + sub;
    return false;
  }
  std::set<std::string> names;
  for (const PreviewView& v : views) {
    if (!v.IsValid(&sub)) {
      if (why) *why = "views: " + sub;
      return false;
    }
    if (!names.insert(v.name).second) {
      if (why) *why = "views: name '" + v.name + "' used twice";
      return false;
    }
  }
  if (disparity_max_width_px < 64 || disparity_max_width_px > 8192) {
    if (why) *why = "disparity_max_width_px must be 64..8192";
    return false;
  }
  if (viewer_max_points < 1000 || viewer_max_points > 5000000) {
    if (why) *why = "viewer_max_points must be 1000..5000000";
    return false;
  }
  if (viewer_max_triangles < 1000 || viewer_max_triangles > 5000000) {
    if (why) *why = "viewer_max_triangles must be 1000..5000000";
    return false;
  }
  return true;
}

bool MakeReportFiles(const ReportInputs& in, ReportFiles* files, std::string* error) {
  const auto start = std::chrono::steady_clock::now();
  std::string why;
  if (!in.options.IsValid(&why)) {
    if (error) *error = "report options: " + why;
    return false;
  }
  nlohmann::json scan = nlohmann::json::object();
  if (!in.scan_report_json.empty()) {
    scan = nlohmann::json::parse(in.scan_report_json, nullptr, false);
    if (!scan.is_object()) {
      if (error)
        *error = "report: scan_report_json is not a JSON object (expected ScanReportJson output)";
      return false;
    }
  }

  ReportFiles out;
  Work work{&out, error};
  if (!DisparityPictures(in, work)) return false;

  // The previews' up axis and front follow the frame the scan is in.
  PreviewOptions preview = in.options.preview;
  const auto frame = scan.find("frame");
  if (frame != scan.end() && *frame == "turntable") {
    preview.up = {0, 0, 1};             // the turntable axis
    preview.azimuth_zero = {0, -1, 0};  // towards the cameras (turntable −y ≈ rig −z)
  } else if (frame != scan.end() && *frame == "view0") {
    preview.up = {0, -1, 0};            // the rig's y points down
    preview.azimuth_zero = {0, 0, -1};  // where the left camera was
  }

  const bool have_cloud = in.fused && !in.fused->empty();
  const bool have_mesh = in.mesh && !in.mesh->empty();
  if (!have_cloud) out.notes.push_back("cloud previews: no fused cloud");
  if (!have_mesh) out.notes.push_back("mesh previews: no mesh");
  for (const PreviewView& view : in.options.views) {
    if (have_cloud) {
      const PreviewImage image = RenderCloudPreview(*in.fused, view, preview);
      if (!image.ok())
        out.notes.push_back(image.error);
      else if (!work.Add("previews/cloud_" + view.name + ".png", "cloud",
                         ViewCaption(std::to_string(in.fused->size()) + " points", view),
                         image.image_bgr))
        return false;
    }
    if (have_mesh) {
      const PreviewImage image = RenderMeshPreview(*in.mesh, view, preview);
      if (!image.ok())
        out.notes.push_back(image.error);
      else if (!work.Add("previews/mesh_" + view.name + ".png", "mesh",
                         ViewCaption(std::to_string(in.mesh->faces.size()) + " triangles", view),
                         image.image_bgr))
        return false;
    }
  }

  ReportFile page{"report.html", {}};
  if (!ReportHtml(in, out.pictures, out.notes, &page.bytes, error)) return false;
  out.files.push_back(std::move(page));
  out.render_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  *files = std::move(out);
  return true;
}

}  // namespace craftscan::daemon
