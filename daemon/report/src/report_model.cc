// report.html's 3D view: the model's data and the page's parts (report_model.h).
#include "report_model.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <unordered_map>
#include <unordered_set>

namespace craftscan::daemon::internal {
namespace {

bool Finite(const cv::Vec3f& p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

// The arrays' bytes as the browser's typed arrays read them (little-endian).
template <typename T>
std::string LittleEndianBytes(const std::vector<T>& values) {
  std::string out(values.size() * sizeof(T), '\0');
  if (!values.empty()) std::memcpy(out.data(), values.data(), out.size());
  if constexpr (std::endian::native == std::endian::big && sizeof(T) > 1) {
    for (std::size_t at = 0; at < out.size(); at += sizeof(T))
      std::reverse(out.begin() + static_cast<std::ptrdiff_t>(at),
                   out.begin() + static_cast<std::ptrdiff_t>(at + sizeof(T)));
  }
  return out;
}

struct TripleHash {
  std::size_t operator()(const std::array<std::uint32_t, 3>& t) const {
    std::uint64_t h = 0x9e3779b97f4a7c15ull;
    for (std::uint32_t v : t) h = (h ^ v) * 0x100000001b3ull;
    return static_cast<std::size_t>(h ^ (h >> 29));
  }
};

// One clustering pass with cells of `cell` mm from `origin`.
TriangleMesh Cluster(const TriangleMesh& mesh, const cv::Vec3d& origin, double cell) {
  const bool colors = mesh.colors_rgb.size() == mesh.vertices_mm.size();
  constexpr std::int64_t kMaxCell = (1 << 21) - 1;
  auto cell_of = [&](const cv::Vec3f& p) {
    std::uint64_t key = 0;
    for (int k = 0; k < 3; ++k) {
      const auto i = static_cast<std::int64_t>(std::floor((p[k] - origin[k]) / cell));
      key = (key << 21) | static_cast<std::uint64_t>(std::clamp<std::int64_t>(i, 0, kMaxCell));
    }
    return key;
  };
  std::unordered_map<std::uint64_t, std::uint32_t> cluster_of_key;
  cluster_of_key.reserve(mesh.vertices_mm.size() / 2);
  std::vector<std::uint32_t> cluster(mesh.vertices_mm.size());
  std::vector<cv::Vec3d> sum;
  std::vector<cv::Vec3i> color_sum;
  std::vector<int> members;
  for (std::size_t v = 0; v < mesh.vertices_mm.size(); ++v) {
    const auto [it, added] = cluster_of_key.try_emplace(cell_of(mesh.vertices_mm[v]),
                                                        static_cast<std::uint32_t>(sum.size()));
    if (added) {
      sum.emplace_back(0, 0, 0);
      color_sum.emplace_back(0, 0, 0);
      members.push_back(0);
    }
    const std::uint32_t c = cluster[v] = it->second;
    sum[c] += cv::Vec3d(mesh.vertices_mm[v]);
    if (colors) color_sum[c] += cv::Vec3i(mesh.colors_rgb[v]);
    ++members[c];
  }
  // Faces over clusters: collapsed ones (two corners in one cell) and
  // repeats (the same three cells in the same turn) dropped.
  std::vector<cv::Vec3i> faces;
  std::unordered_set<std::array<std::uint32_t, 3>, TripleHash> seen;
  std::vector<std::int32_t> new_index(sum.size(), -1);
  std::int32_t used = 0;
  for (const cv::Vec3i& f : mesh.faces) {
    std::array<std::uint32_t, 3> t = {cluster[f[0]], cluster[f[1]], cluster[f[2]]};
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    std::rotate(t.begin(), std::min_element(t.begin(), t.end()), t.end());  // keeps the turn
    if (!seen.insert(t).second) continue;
    cv::Vec3i out;
    for (int k = 0; k < 3; ++k) {
      if (new_index[t[k]] < 0) new_index[t[k]] = used++;
      out[k] = new_index[t[k]];
    }
    faces.push_back(out);
  }
  TriangleMesh out;
  out.vertices_mm.resize(static_cast<std::size_t>(used));
  if (colors) out.colors_rgb.resize(static_cast<std::size_t>(used));
  for (std::size_t c = 0; c < sum.size(); ++c) {
    if (new_index[c] < 0) continue;
    const auto i = static_cast<std::size_t>(new_index[c]);
    out.vertices_mm[i] = cv::Vec3f(sum[c] / members[c]);
    if (colors) {
      for (int k = 0; k < 3; ++k)
        out.colors_rgb[i][k] = static_cast<uchar>((color_sum[c][k] + members[c] / 2) / members[c]);
    }
  }
  out.faces = std::move(faces);
  return out;
}

std::string FormatCount(std::size_t n) { return std::to_string(n); }

void DataElement(std::string& html, const char* id, std::size_t count, const std::string& bytes) {
  html += "<script type=\"application/octet-stream\" id=\"";
  html += id;
  html += "\" data-count=\"" + std::to_string(count) + "\">";
  html += Base64(bytes);
  html += "</script>\n";
}

// Starts the viewer on the data elements; without WebGL (or the bundle) it
// says so in the view's place, and the pictures below remain.
constexpr const char* kStartScript = R"js(
(function () {
  var box = document.getElementById('craftscan-viewer');
  function bytes(id) {
    var e = document.getElementById(id);
    return e ? CraftscanViewer.base64ToBytes(e.textContent) : null;
  }
  function words(id, Type) {
    var b = bytes(id);
    return b ? new Type(b.buffer, 0, b.length / Type.BYTES_PER_ELEMENT) : null;
  }
  try {
    if (typeof CraftscanViewer === 'undefined') throw new Error('the viewer script did not run');
    var data = {};
    var cloud = words('craftscan-cloud-positions', Float32Array);
    if (cloud) data.cloud = {positions: cloud, colors: bytes('craftscan-cloud-colors')};
    var mesh = words('craftscan-mesh-positions', Float32Array);
    if (mesh) data.mesh = {positions: mesh, colors: bytes('craftscan-mesh-colors'),
                           indices: words('craftscan-mesh-indices', Uint32Array)};
    var viewer = CraftscanViewer.create(box, OPTIONS);
    viewer.setData(data);
    window.craftscanViewer = viewer;
  } catch (e) {
    box.className += ' failed';
    box.textContent = 'The 3D view is not available in this browser (' + (e && e.message || e) +
        '). The pictures below show the model.';
  }
})();
)js";

}  // namespace

ViewerModel MakeViewerModel(const PointCloud* cloud, const TriangleMesh* mesh,
                            std::size_t max_points, std::size_t max_triangles) {
  ViewerModel model;
  max_points = std::max<std::size_t>(max_points, 1);
  max_triangles = std::max<std::size_t>(max_triangles, 1);
  if (cloud && !cloud->empty()) {
    model.cloud_source_points = cloud->size();
    const bool colors = cloud->colors_rgb.size() == cloud->size();
    std::vector<std::size_t> finite;
    finite.reserve(cloud->size());
    for (std::size_t i = 0; i < cloud->size(); ++i)
      if (Finite(cloud->points_mm[i])) finite.push_back(i);
    const std::size_t n = finite.size();
    const std::size_t m = std::min(n, max_points);
    model.cloud_positions_mm.reserve(3 * m);
    if (colors) model.cloud_colors.reserve(3 * m);
    for (std::size_t k = 0; k < m; ++k) {
      // Every (n / m)-th: the fused cloud is in voxel order, so this is even in space.
      const std::size_t i = finite[static_cast<std::size_t>(std::uint64_t{k} * n / m)];
      const cv::Vec3f& p = cloud->points_mm[i];
      model.cloud_positions_mm.insert(model.cloud_positions_mm.end(), {p[0], p[1], p[2]});
      if (colors) {
        const cv::Vec3b& c = cloud->colors_rgb[i];
        model.cloud_colors.insert(model.cloud_colors.end(), {c[0], c[1], c[2]});
      }
    }
  }
  if (mesh && !mesh->empty()) {
    model.mesh_source_triangles = mesh->faces.size();
    std::string why;
    if (!mesh->IsValid(&why)) {
      model.mesh_left_out = "the mesh is invalid: " + why;
    } else {
      const TriangleMesh simple = SimplifyMesh(*mesh, max_triangles);
      const bool colors = simple.colors_rgb.size() == simple.vertices_mm.size();
      model.mesh_positions_mm.reserve(3 * simple.vertices_mm.size());
      for (std::size_t v = 0; v < simple.vertices_mm.size(); ++v) {
        const cv::Vec3f& p = simple.vertices_mm[v];
        model.mesh_positions_mm.insert(model.mesh_positions_mm.end(), {p[0], p[1], p[2]});
        if (colors) {
          const cv::Vec3b& c = simple.colors_rgb[v];
          model.mesh_colors.insert(model.mesh_colors.end(), {c[0], c[1], c[2]});
        }
      }
      model.mesh_indices.reserve(3 * simple.faces.size());
      for (const cv::Vec3i& f : simple.faces)
        for (int k = 0; k < 3; ++k) model.mesh_indices.push_back(static_cast<std::uint32_t>(f[k]));
    }
  }
  return model;
}

TriangleMesh SimplifyMesh(const TriangleMesh& mesh, std::size_t max_triangles, double* cell_mm) {
  if (cell_mm) *cell_mm = 0;
  max_triangles = std::max<std::size_t>(max_triangles, 1);
  if (mesh.faces.size() <= max_triangles || !mesh.IsValid(nullptr)) return mesh;
  cv::Vec3d lo(INFINITY, INFINITY, INFINITY), hi(-INFINITY, -INFINITY, -INFINITY);
  for (const cv::Vec3f& p : mesh.vertices_mm)
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], double(p[k]));
      hi[k] = std::max(hi[k], double(p[k]));
    }
  double area = 0;
  for (const cv::Vec3i& f : mesh.faces) {
    const cv::Vec3d a(mesh.vertices_mm[f[0]]), b(mesh.vertices_mm[f[1]]), c(mesh.vertices_mm[f[2]]);
    area += 0.5 * cv::norm((b - a).cross(c - a));
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-9});
  // A surface cut into cells of side s keeps about 2 triangles per cell it
  // crosses: start a little finer than that, grow the cell while there are
  // too many, then bisect between the last too fine and the first that fits
  // to come close to the budget.
  double cell = 0.8 * std::sqrt(2 * area / static_cast<double>(max_triangles));
  if (!(cell > 0)) cell = extent / std::sqrt(static_cast<double>(max_triangles));
  cell = std::max(cell, extent * 1e-6);  // keeps cell indices within 21 bits
  TriangleMesh out;
  double too_fine = 0;
  for (int attempt = 0; attempt < 24; ++attempt) {
    out = Cluster(mesh, lo, cell);
    if (out.faces.size() <= max_triangles) break;
    too_fine = cell;
    cell *= std::max(1.05, std::sqrt(static_cast<double>(out.faces.size()) /
                                     static_cast<double>(max_triangles)));
  }
  if (out.faces.size() > max_triangles) {
    out.faces.resize(max_triangles);  // not seen; a bound
  } else if (too_fine > 0) {
    for (int k = 0; k < 4; ++k) {
      const double mid = std::sqrt(too_fine * cell);
      TriangleMesh finer = Cluster(mesh, lo, mid);
      if (finer.faces.size() <= max_triangles) {
        cell = mid;
        out = std::move(finer);
      } else {
        too_fine = mid;
      }
    }
  }
  if (cell_mm) *cell_mm = cell;
  return out;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 3 <= bytes.size(); i += 3) {
    const std::uint32_t v = std::uint32_t(std::uint8_t(bytes[i])) << 16 |
                            std::uint32_t(std::uint8_t(bytes[i + 1])) << 8 |
                            std::uint8_t(bytes[i + 2]);
    out += kAlphabet[v >> 18];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (const std::size_t rest = bytes.size() - i; rest > 0) {
    std::uint32_t v = std::uint32_t(std::uint8_t(bytes[i])) << 16;
    if (rest == 2) v |= std::uint32_t(std::uint8_t(bytes[i + 1])) << 8;
    out += kAlphabet[v >> 18];
    out += kAlphabet[(v >> 12) & 63];
    out += rest == 2 ? kAlphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string ViewerSectionHtml(const ViewerModel& model) {
  std::string shown;
  if (model.points() > 0) {
    shown = FormatCount(model.points()) + " of the " + FormatCount(model.cloud_source_points) +
            " fused points";
  }
  if (model.triangles() > 0) {
    if (!shown.empty()) shown += " and ";
    shown += model.triangles() == model.mesh_source_triangles
                 ? "the mesh's " + FormatCount(model.triangles()) + " triangles"
                 : "the mesh simplified to " + FormatCount(model.triangles()) + " of its " +
                       FormatCount(model.mesh_source_triangles) + " triangles";
  }
  std::string html =
      "<section id=\"model\"><h2>3D view</h2>\n"
      "<div id=\"craftscan-viewer\" class=\"viewer\"><noscript><p>The 3D view needs JavaScript; "
      "the pictures below show the model.</p></noscript></div>\n"
      "<p class=\"muted\">Drag to turn, right-drag or shift-drag to move, wheel to zoom; "
      "millimetres. Shown: " +
      shown + ".";
  if (!model.mesh_left_out.empty()) html += " Mesh left out: " + model.mesh_left_out + ".";
  html += " The files fused.ply and mesh.ply hold the full model.</p>\n</section>\n";
  return html;
}

std::string ViewerScriptsHtml(const ViewerModel& model, std::string_view bundle,
                              const std::string& frame) {
  std::string html =
      "<!-- The 3D view's model: base64 of little-endian float32 x, y, z (mm), uint8 r, g, b "
      "(sRGB) and uint32 vertex indices (three per triangle); data-count: points, vertices or "
      "triangles. The viewer: craftscan's CraftscanViewer with three.js (MIT). -->\n";
  if (model.points() > 0) {
    DataElement(html, "craftscan-cloud-positions", model.points(),
                LittleEndianBytes(model.cloud_positions_mm));
    if (!model.cloud_colors.empty())
      DataElement(html, "craftscan-cloud-colors", model.points(),
                  LittleEndianBytes(model.cloud_colors));
  }
  if (model.triangles() > 0) {
    const std::size_t vertices = model.mesh_positions_mm.size() / 3;
    DataElement(html, "craftscan-mesh-positions", vertices,
                LittleEndianBytes(model.mesh_positions_mm));
    if (!model.mesh_colors.empty())
      DataElement(html, "craftscan-mesh-colors", vertices, LittleEndianBytes(model.mesh_colors));
    DataElement(html, "craftscan-mesh-indices", model.triangles(),
                LittleEndianBytes(model.mesh_indices));
  }
  html += "<script id=\"craftscan-viewer-bundle\">";
  html += bundle;
  html += "</script>\n<script>";
  // The scan's frame sets which way is up and where the front view looks from.
  std::string options = "{background: '#1d2125'";
  if (frame == "turntable") options += ", up: [0, 0, 1], front: [0, -1, 0]";
  if (frame == "view0") options += ", up: [0, -1, 0], front: [0, 0, -1]";
  options += "}";
  std::string start = kStartScript;
  start.replace(start.find("OPTIONS"), 7, options);
  html += start;
  html += "</script>\n";
  return html;
}

}  // namespace craftscan::daemon::internal
