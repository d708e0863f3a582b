// craftscan_browser_report_demo --out DIR [--points N]
// Writes report.html and its previews (MakeReportFiles, daemon/report) for a
// synthetic 80 × 60 × 50 mm box on the turntable — a fused cloud of N points
// (default 60000) on its sides and top and a closed mesh, each face its own
// colour, so that turning the view changes the picture — into DIR. The
// browser tests open the page from file://. Exit 0 when written, 1 otherwise.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "craftscan/daemon/report.h"

namespace {

using craftscan::PointCloud;
using craftscan::TriangleMesh;

constexpr float kSize[3] = {80, 60, 50};  // mm along x, y, z; the base at z = 0

// Face f: axis f / 2, side − (even) or + (odd).
const cv::Vec3b kFaceRgb[6] = {{60, 160, 90},  {200, 70, 60}, {220, 180, 60},
                               {70, 110, 200}, {90, 90, 90},  {185, 185, 190}};

cv::Vec3f OnFace(int f, float u, float v) {  // u, v in 0..1
  const int axis = f / 2, a = (axis + 1) % 3, b = (axis + 2) % 3;
  cv::Vec3f p;
  p[axis] = (f % 2 ? 0.5f : -0.5f) * kSize[axis];
  p[a] = (u - 0.5f) * kSize[a];
  p[b] = (v - 0.5f) * kSize[b];
  p[2] += kSize[2] / 2;
  return p;
}

TriangleMesh BoxMesh(int cells) {
  TriangleMesh mesh;
  for (int f = 0; f < 6; ++f) {
    const int first = static_cast<int>(mesh.vertices_mm.size());
    for (int j = 0; j <= cells; ++j)
      for (int i = 0; i <= cells; ++i) {
        mesh.vertices_mm.push_back(OnFace(f, float(i) / cells, float(j) / cells));
        mesh.colors_rgb.push_back(kFaceRgb[f]);
      }
    for (int j = 0; j < cells; ++j)
      for (int i = 0; i < cells; ++i) {
        const int a = first + j * (cells + 1) + i, b = a + 1, c = a + cells + 1, d = c + 1;
        // Outward (counter-clockwise from outside): the u×v order flips on − faces.
        if (f % 2) {
          mesh.faces.push_back({a, b, d});
          mesh.faces.push_back({a, d, c});
        } else {
          mesh.faces.push_back({a, d, b});
          mesh.faces.push_back({a, c, d});
        }
      }
  }
  return mesh;
}

PointCloud BoxPoints(int n) {
  PointCloud cloud;
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> u(0, 1);
  std::normal_distribution<float> noise(0, 0.15f);
  std::uniform_int_distribution<int> shade(-12, 12);
  for (int k = 0; k < n; ++k) {
    int f = k % 5;
    if (f == 4) f = 5;  // no base: the turntable hides it
    cv::Vec3f p = OnFace(f, u(rng), u(rng));
    p[f / 2] += noise(rng);
    cloud.points_mm.push_back(p);
    cv::Vec3b c = kFaceRgb[f];
    const int s = shade(rng);
    for (int i = 0; i < 3; ++i) c[i] = cv::saturate_cast<uchar>(c[i] + s);
    cloud.colors_rgb.push_back(c);
  }
  return cloud;
}

}  // namespace

int main(int argc, char** argv) {
  std::string out;
  int points = 60000;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--out") out = argv[i + 1];
    if (key == "--points") points = std::atoi(argv[i + 1]);
  }
  if (out.empty() || points < 1) {
    std::fprintf(stderr, "usage: %s --out DIR [--points N]\n", argv[0]);
    return 1;
  }
  const PointCloud cloud = BoxPoints(points);
  const TriangleMesh mesh = BoxMesh(40);
  craftscan::daemon::ReportInputs in;
  in.session_id = "20260101-120000-browser";
  in.object_name = "Synthetic box";
  in.created_utc = "2026-01-01T12:00:00.000Z";
  in.scan_report_json =
      "{\"ok\": true, \"frame\": \"turntable\", \"fused_points\": " + std::to_string(points) + "}";
  in.fused = &cloud;
  in.mesh = &mesh;
  craftscan::daemon::ReportFiles files;
  std::string error;
  if (!craftscan::daemon::MakeReportFiles(in, &files, &error)) {
    std::fprintf(stderr, "report: %s\n", error.c_str());
    return 1;
  }
  for (const craftscan::daemon::ReportFile& f : files.files) {
    const std::filesystem::path path = std::filesystem::path(out) / f.name;
    std::error_code ec;
    std::filesystem::create_directories(path.parent_path(), ec);
    std::ofstream file(path, std::ios::binary);
    file.write(f.bytes.data(), static_cast<std::streamsize>(f.bytes.size()));
    if (!file) {
      std::fprintf(stderr, "cannot write %s\n", path.c_str());
      return 1;
    }
  }
  std::printf("%s/report.html: %zu bytes, %zu points, %zu triangles\n", out.c_str(),
              files.files.back().bytes.size(), cloud.size(), mesh.faces.size());
  return 0;
}
