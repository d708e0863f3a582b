#include "craftscan/pipeline/surface/mesh.h"

#include <fcntl.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/surface/marching_cubes.h>
#include <pcl/surface/poisson.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <mutex>
#include <numbers>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

constexpr std::size_t kMinMeshPoints = 100;
// ImplicitMesh's grid: at most this many vertices (4 bytes each).
constexpr double kMaxGridVertices = 64e6;

template <typename V>
bool Finite3(const V& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

constexpr auto kFailed = MeshResult::Status::kFailed;
constexpr std::string_view kWhere = "PoissonMesh: ";

// Shortest round-trip text of a float.
void AppendFloat(std::string* out, float v) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), v);
  out->append(buffer, result.ptr);
}

}  // namespace

bool PoissonOptions::IsValid(std::string* why) const {
  if (depth < 4 || depth > 12) return Fail(why, "PoissonOptions.depth must be within 4..12");
  if (!(samples_per_node >= 1 && std::isfinite(samples_per_node)))
    return Fail(why, "PoissonOptions.samples_per_node must be finite and >= 1");
  if (!(point_weight >= 0 && std::isfinite(point_weight)))
    return Fail(why, "PoissonOptions.point_weight must be finite and >= 0");
  if (!(scale >= 1 && std::isfinite(scale)))
    return Fail(why, "PoissonOptions.scale must be finite and >= 1");
  if (!(trim_density_quantile >= 0 && trim_density_quantile < 1))
    return Fail(why, "PoissonOptions.trim_density_quantile must be within [0, 1)");
  if (!(support_radius_mm >= 0 && std::isfinite(support_radius_mm)))
    return Fail(why, "PoissonOptions.support_radius_mm must be finite and >= 0");
  if (!(min_component_fraction >= 0 && min_component_fraction <= 1))
    return Fail(why, "PoissonOptions.min_component_fraction must be within [0, 1]");
  if (num_threads < 1) return Fail(why, "PoissonOptions.num_threads must be >= 1");
  return true;
}

std::string_view ToString(MeshMethod method) {
  switch (method) {
    case MeshMethod::kPoisson:
      return "poisson";
    case MeshMethod::kImplicit:
      return "implicit";
  }
  return "unknown";
}

bool MeshMethodFromString(std::string_view text, MeshMethod* method) {
  if (text == "poisson") {
    *method = MeshMethod::kPoisson;
  } else if (text == "implicit") {
    *method = MeshMethod::kImplicit;
  } else {
    return false;
  }
  return true;
}

bool ImplicitMeshOptions::IsValid(std::string* why) const {
  if (!(voxel_spacings > 0 && voxel_spacings <= 10))
    return Fail(why, "ImplicitMeshOptions.voxel_spacings must be within (0, 10]");
  if (!(voxel_mm >= 0 && std::isfinite(voxel_mm)))
    return Fail(why, "ImplicitMeshOptions.voxel_mm must be finite and >= 0");
  if (!(radius_spacings >= 1 && radius_spacings <= 20))
    return Fail(why, "ImplicitMeshOptions.radius_spacings must be within [1, 20]");
  if (min_support < 1) return Fail(why, "ImplicitMeshOptions.min_support must be >= 1");
  if (!(fill_radii == 0 || (fill_radii > 1 && fill_radii <= 10)))
    return Fail(why, "ImplicitMeshOptions.fill_radii must be 0 or within (1, 10]");
  if (!(max_tangent_radii > 0 && max_tangent_radii <= 1))
    return Fail(why, "ImplicitMeshOptions.max_tangent_radii must be within (0, 1]");
  if (!(min_component_fraction >= 0 && min_component_fraction <= 1))
    return Fail(why, "ImplicitMeshOptions.min_component_fraction must be within [0, 1]");
  return true;
}

namespace {

// The cloud's points with finite, non-zero normals, as PCL wants them, with
// their positions alone (for the support tree) and their index in the cloud.
struct PoissonInput {
  pcl::PointCloud<pcl::PointNormal>::Ptr oriented =
      pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  pcl::PointCloud<pcl::PointXYZ>::Ptr positions =
      pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  std::vector<std::size_t> source_index;
};

PoissonInput OrientedPoints(const PointCloud& cloud) {
  PoissonInput in;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const cv::Vec3f& p = cloud.points_mm[i];
    const cv::Vec3f& n = cloud.normals[i];
    const double length = cv::norm(n);
    if (!Finite3(p) || !Finite3(n) || !(length > 1e-9)) continue;
    pcl::PointNormal q;
    q.x = p[0];
    q.y = p[1];
    q.z = p[2];
    q.normal_x = static_cast<float>(n[0] / length);
    q.normal_y = static_cast<float>(n[1] / length);
    q.normal_z = static_cast<float>(n[2] / length);
    in.oriented->push_back(q);
    in.positions->push_back(pcl::PointXYZ(p[0], p[1], p[2]));
    in.source_index.push_back(i);
  }
  return in;
}

// Keeps what is printed to stdout (fd 1) while it lives off stdout, and
// counts its lines. PCL's poisson4 printf()s a line for every edge its
// marching cubes cannot pair ("Vertex pair not in list", thousands on a
// scan's fused cloud), which would otherwise land in the output of whatever
// process meshes: a bench's JSON, a test's log, a daemon's journal. Only
// ReconstructPoisson uses it, under its lock, so two never nest; anything
// another thread of the process prints meanwhile is counted with PCL's
// lines, not shown (the daemon and the worker log to stderr). Without a
// memfd or a spare descriptor it leaves stdout alone.
class StdoutKeptOff {
 public:
  StdoutKeptOff() {
    std::fflush(stdout);
    sink_ = memfd_create("craftscan-library-stdout", MFD_CLOEXEC);
    saved_ = sink_ < 0 ? -1 : fcntl(STDOUT_FILENO, F_DUPFD_CLOEXEC, 3);
    if (saved_ < 0 || dup2(sink_, STDOUT_FILENO) < 0) Close();
  }
  StdoutKeptOff(const StdoutKeptOff&) = delete;
  StdoutKeptOff& operator=(const StdoutKeptOff&) = delete;
  ~StdoutKeptOff() { Restore(); }

  // Puts stdout back; the number of lines printed meanwhile.
  std::size_t Restore() {
    if (saved_ < 0) return 0;
    std::fflush(stdout);
    dup2(saved_, STDOUT_FILENO);
    std::size_t lines = 0;
    char buffer[4096];
    ssize_t n;
    if (lseek(sink_, 0, SEEK_SET) == 0)
      while ((n = read(sink_, buffer, sizeof buffer)) > 0)
        lines += static_cast<std::size_t>(std::count(buffer, buffer + n, '\n'));
    Close();
    return lines;
  }

 private:
  void Close() {
    if (sink_ >= 0) close(sink_);
    if (saved_ >= 0) close(saved_);
    sink_ = saved_ = -1;
  }
  int sink_ = -1;
  int saved_ = -1;
};

// PCL's Poisson surface (triangles, manifold). Throws what PCL throws. What
// PCL prints to stdout meanwhile is kept off it (StdoutKeptOff); the number
// of lines goes to *stdout_lines.
// One at a time per process: PCL's poisson4 keeps its octree's node
// allocator and flags in static members (TreeOctNode::SetAllocator,
// TreeNodeData::UseIndex), which reconstruct() resets, so two reconstructions
// at once corrupt each other (a worker holding two jobs segfaulted in
// libpcl_surface). Each reconstruction still uses its own threads.
void ReconstructPoisson(const PoissonInput& in, const PoissonOptions& options,
                        pcl::PointCloud<pcl::PointNormal>* vertices,
                        std::vector<pcl::Vertices>* polygons, std::size_t* stdout_lines) {
  static std::mutex one_at_a_time;
  std::lock_guard lock(one_at_a_time);
  StdoutKeptOff kept_off;
  pcl::Poisson<pcl::PointNormal> poisson;
  poisson.setDepth(options.depth);
  poisson.setSamplesPerNode(static_cast<float>(options.samples_per_node));
  poisson.setPointWeight(static_cast<float>(options.point_weight));
  poisson.setScale(static_cast<float>(options.scale));
  poisson.setOutputPolygons(false);  // triangles
  poisson.setManifold(true);
  poisson.setThreads(options.num_threads);
  poisson.setInputCloud(in.oriented);
  poisson.reconstruct(*vertices, *polygons);
  *stdout_lines = kept_off.Restore();
}

// The support radius: 2.5 × the median nearest-neighbour spacing of a
// sample of the input; 0 when it cannot be estimated.
double EstimateSupportRadius(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree,
                             const pcl::PointCloud<pcl::PointXYZ>& positions) {
  std::vector<float> spacing;
  std::vector<int> index(2);
  std::vector<float> d2(2);
  const std::size_t step = std::max<std::size_t>(1, positions.size() / 2000);
  for (std::size_t i = 0; i < positions.size(); i += step)
    if (tree.nearestKSearch(positions[i], 2, index, d2) == 2) spacing.push_back(std::sqrt(d2[1]));
  if (spacing.empty()) return 0;
  std::nth_element(spacing.begin(),
                   spacing.begin() + static_cast<std::ptrdiff_t>(spacing.size() / 2),
                   spacing.end());
  return 2.5 * std::max(1e-6f, spacing[spacing.size() / 2]);
}

// Drops the vertices no face uses (before normals and colours exist);
// returns how many.
std::size_t DropUnusedVertices(TriangleMesh* mesh) {
  std::vector<int> used(mesh->vertices_mm.size(), -1);
  std::vector<cv::Vec3f> kept;
  for (cv::Vec3i& f : mesh->faces)
    for (int k = 0; k < 3; ++k) {
      int& u = used[static_cast<std::size_t>(f[k])];
      if (u < 0) {
        u = static_cast<int>(kept.size());
        kept.push_back(mesh->vertices_mm[static_cast<std::size_t>(f[k])]);
      }
      f[k] = u;
    }
  const std::size_t dropped = mesh->vertices_mm.size() - kept.size();
  if (!mesh->colors_rgb.empty()) {
    std::vector<cv::Vec3b> colors(kept.size());
    for (std::size_t v = 0; v < used.size(); ++v)
      if (used[v] >= 0) colors[static_cast<std::size_t>(used[v])] = mesh->colors_rgb[v];
    mesh->colors_rgb.swap(colors);
  }
  mesh->vertices_mm.swap(kept);
  return dropped;
}

// The component (union-find root) of each face; faces sharing a vertex are
// connected.
std::vector<int> FaceComponents(const TriangleMesh& mesh) {
  std::vector<int> parent(mesh.vertices_mm.size());
  for (std::size_t v = 0; v < parent.size(); ++v) parent[v] = static_cast<int>(v);
  const auto find = [&](int v) {
    while (parent[static_cast<std::size_t>(v)] != v)
      v = parent[static_cast<std::size_t>(v)] =
          parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(v)])];
    return v;
  };
  for (const cv::Vec3i& f : mesh.faces) {
    parent[static_cast<std::size_t>(find(f[1]))] = find(f[0]);
    parent[static_cast<std::size_t>(find(f[2]))] = find(f[0]);
  }
  std::vector<int> component(mesh.faces.size());
  for (std::size_t f = 0; f < mesh.faces.size(); ++f) component[f] = find(mesh.faces[f][0]);
  return component;
}

// Removes the components with fewer faces than `fraction` × the largest
// one's (then the unused vertices); counts what is left and what went.
void DropSmallComponents(double fraction, MeshResult* r) {
  TriangleMesh& mesh = r->mesh;
  const std::vector<int> component = FaceComponents(mesh);
  std::vector<std::size_t> faces_in(mesh.vertices_mm.size(), 0);
  for (int c : component) ++faces_in[static_cast<std::size_t>(c)];
  const std::size_t largest = *std::max_element(faces_in.begin(), faces_in.end());
  const double min_faces = fraction * static_cast<double>(largest);
  std::vector<cv::Vec3i> kept;
  for (std::size_t f = 0; f < mesh.faces.size(); ++f)
    if (static_cast<double>(faces_in[static_cast<std::size_t>(component[f])]) >= min_faces)
      kept.push_back(mesh.faces[f]);
  for (std::size_t n : faces_in) {
    if (n == 0) continue;
    if (static_cast<double>(n) >= min_faces)
      ++r->components;
    else
      ++r->removed_components;
  }
  mesh.faces.swap(kept);
  r->trimmed_vertices += DropUnusedVertices(&mesh);
}

// Density trimming: keeps the vertices with at least the quantile's number
// of input points within the radius (and at least one), the faces whose
// three vertices are kept, and then only the vertices a face uses. Fills
// r->mesh, trimmed_vertices and support_threshold.
void TrimBySupport(const pcl::PointCloud<pcl::PointNormal>& vertices,
                   const std::vector<pcl::Vertices>& polygons,
                   const pcl::KdTreeFLANN<pcl::PointXYZ>& tree, double radius,
                   double trim_density_quantile, int threads, MeshResult* r) {
  std::vector<int> support(vertices.size(), 0);
  const auto n = static_cast<long>(vertices.size());
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<int> index;
    std::vector<float> d2;
#pragma omp for schedule(dynamic, 1024)
    for (long v = 0; v < n; ++v) {
      const pcl::PointNormal& q = vertices[static_cast<std::size_t>(v)];
      if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z)) continue;
      support[static_cast<std::size_t>(v)] =
          tree.radiusSearch(pcl::PointXYZ(q.x, q.y, q.z), radius, index, d2);
    }
  }
  double threshold = 1;
  if (trim_density_quantile > 0) {
    std::vector<int> sorted = support;
    const auto k =
        static_cast<std::size_t>(trim_density_quantile * static_cast<double>(sorted.size() - 1));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
    threshold = std::max<double>(threshold, sorted[k]);
  }
  r->support_threshold = threshold;
  std::vector<int> remap(vertices.size(), -1);
  TriangleMesh& mesh = r->mesh;
  for (std::size_t v = 0; v < vertices.size(); ++v) {
    if (support[v] < threshold) {
      ++r->trimmed_vertices;
      continue;
    }
    remap[v] = static_cast<int>(mesh.vertices_mm.size());
    mesh.vertices_mm.emplace_back(vertices[v].x, vertices[v].y, vertices[v].z);
  }
  for (const pcl::Vertices& poly : polygons) {
    if (poly.vertices.size() != 3) continue;
    cv::Vec3i face;
    bool keep = true;
    for (int k = 0; k < 3 && keep; ++k) {
      const std::uint32_t v = poly.vertices[static_cast<std::size_t>(k)];
      keep = v < remap.size() && remap[v] >= 0;
      if (keep) face[k] = remap[v];
    }
    if (keep && face[0] != face[1] && face[1] != face[2] && face[0] != face[2])
      mesh.faces.push_back(face);
  }
  r->trimmed_vertices += DropUnusedVertices(&mesh);
}

// Turns the faces to agree with the input normals (outwards, by a vote over
// a sample of faces) and gives each vertex the area-weighted normal of its
// faces.
void OrientAndShade(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree,
                    const pcl::PointCloud<pcl::PointNormal>& oriented, TriangleMesh* mesh) {
  const auto vertex = [&](std::size_t f, int k) -> const cv::Vec3f& {
    return mesh->vertices_mm[static_cast<std::size_t>(mesh->faces[f][k])];
  };
  std::vector<cv::Vec3d> face_normals(mesh->faces.size());
  for (std::size_t f = 0; f < mesh->faces.size(); ++f) {
    const cv::Vec3d a(vertex(f, 0)), b(vertex(f, 1)), c(vertex(f, 2));
    face_normals[f] = (b - a).cross(c - a);
  }
  double agreement = 0;
  std::vector<int> index(1);
  std::vector<float> d2(1);
  const std::size_t step = std::max<std::size_t>(1, mesh->faces.size() / 2000);
  for (std::size_t f = 0; f < mesh->faces.size(); f += step) {
    const cv::Vec3f& a = vertex(f, 0);
    if (tree.nearestKSearch(pcl::PointXYZ(a[0], a[1], a[2]), 1, index, d2) != 1) continue;
    const pcl::PointNormal& q = oriented[static_cast<std::size_t>(index[0])];
    const double dot = face_normals[f].dot(cv::Vec3d(q.normal_x, q.normal_y, q.normal_z));
    agreement += dot > 0 ? 1 : (dot < 0 ? -1 : 0);
  }
  if (agreement < 0) {
    for (cv::Vec3i& face : mesh->faces) std::swap(face[1], face[2]);
    for (cv::Vec3d& n : face_normals) n = -n;
  }
  std::vector<cv::Vec3d> sums(mesh->vertices_mm.size(), cv::Vec3d(0, 0, 0));
  for (std::size_t f = 0; f < mesh->faces.size(); ++f)
    for (int k = 0; k < 3; ++k)
      sums[static_cast<std::size_t>(mesh->faces[f][k])] += face_normals[f];
  mesh->normals.resize(mesh->vertices_mm.size());
  for (std::size_t v = 0; v < sums.size(); ++v) {
    const double length = cv::norm(sums[v]);
    const cv::Vec3d n = length > 0 ? sums[v] / length : cv::Vec3d(0, 0, 1);
    mesh->normals[v] =
        cv::Vec3f(static_cast<float>(n[0]), static_cast<float>(n[1]), static_cast<float>(n[2]));
  }
}

// Each vertex takes the colour of its nearest input point.
void ColorFromCloud(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree, const PointCloud& cloud,
                    const std::vector<std::size_t>& source_index, int threads, TriangleMesh* mesh) {
  mesh->colors_rgb.resize(mesh->vertices_mm.size());
  const auto n = static_cast<long>(mesh->vertices_mm.size());
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<int> index(1);
    std::vector<float> d2(1);
#pragma omp for schedule(static)
    for (long v = 0; v < n; ++v) {
      const cv::Vec3f& p = mesh->vertices_mm[static_cast<std::size_t>(v)];
      if (tree.nearestKSearch(pcl::PointXYZ(p[0], p[1], p[2]), 1, index, d2) == 1)
        mesh->colors_rgb[static_cast<std::size_t>(v)] =
            cloud.colors_rgb[source_index[static_cast<std::size_t>(index[0])]];
    }
  }
}

// The cloud's usable oriented points into *in; false with r->message (and
// r->input_points) when the cloud cannot be meshed.
bool UsableInput(const PointCloud& cloud, std::string_view where, MeshResult* r, PoissonInput* in) {
  std::string why;
  if (!cloud.IsValid(&why)) {
    *r = Failed(std::move(*r), kFailed, std::string(where) + "invalid cloud: " + why);
    return false;
  }
  if (!cloud.HasNormals()) {
    *r = Failed(std::move(*r), kFailed,
                std::string(where) + "the cloud has no normals (meshing needs them)");
    return false;
  }
  *in = OrientedPoints(cloud);
  r->input_points = in->oriented->size();
  if (r->input_points < kMinMeshPoints) {
    *r = Failed(std::move(*r), kFailed,
                std::string(where) + "need at least " + std::to_string(kMinMeshPoints) +
                    " points with finite normals, got " + std::to_string(r->input_points) +
                    " (of " + std::to_string(cloud.size()) + ")");
    return false;
  }
  return true;
}

// What every mesh gets after its surface: small components dropped, faces
// turned outwards, vertex normals, and colours from the nearest input point.
void FinishMesh(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree, const PoissonInput& input,
                const PointCloud& cloud, double min_component_fraction, bool colors, int threads,
                MeshResult* r) {
  DropSmallComponents(min_component_fraction, r);
  OrientAndShade(tree, *input.oriented, &r->mesh);
  if (colors && cloud.HasColors())
    ColorFromCloud(tree, cloud, input.source_index, threads, &r->mesh);
}

// ---------------------------------------------------------------------------
// Implicit surface (ImplicitMesh)

// A grid over the cloud's bounding box (widened by two cells): the vertices
// near the input points have a slot, and a slot a value (NaN where the
// surface is undefined) and a colour. Index (x, y, z), x fastest.
struct Grid {
  cv::Vec3d origin;
  double h = 0;
  int nx = 0, ny = 0, nz = 0;
  std::vector<std::int32_t> slot;  // per vertex, −1: none
  std::vector<float> value;        // per slot
  std::vector<cv::Vec3f> color;    // per slot, RGB 0..255
  std::size_t Index(int x, int y, int z) const {
    return (static_cast<std::size_t>(z) * ny + y) * nx + x;
  }
  cv::Vec3f Position(int x, int y, int z) const {
    return cv::Vec3f(static_cast<float>(origin[0] + x * h), static_cast<float>(origin[1] + y * h),
                     static_cast<float>(origin[2] + z * h));
  }
  float Value(int x, int y, int z) const {
    const std::int32_t k = slot[Index(x, y, z)];
    return k < 0 ? std::numeric_limits<float>::quiet_NaN() : value[static_cast<std::size_t>(k)];
  }
};

// Whether the points index[0, found) surround q in the plane normal to
// `normal`: seen from q, no empty sector of 135° or more among 16 (a hole's
// inside is surrounded; the far side of the data's edge sees a half plane,
// 180°, empty).
bool Surrounded(const PoissonInput& in, const cv::Vec3f& q, const cv::Vec3f& normal,
                const std::vector<int>& index, int found) {
  constexpr int kSectors = 16, kMaxEmpty = 6;  // 6 × 22.5° = 135°
  const double length = cv::norm(normal);
  if (!(length > 0)) return false;
  const cv::Vec3f n = normal / length;
  const cv::Vec3f seed = std::abs(n[0]) < 0.9f ? cv::Vec3f(1, 0, 0) : cv::Vec3f(0, 1, 0);
  const cv::Vec3f u = cv::normalize(seed - seed.dot(n) * n), v = n.cross(u);
  bool occupied[kSectors] = {};
  for (int j = 0; j < found; ++j) {
    const pcl::PointXYZ& p =
        (*in.positions)[static_cast<std::size_t>(index[static_cast<std::size_t>(j)])];
    const cv::Vec3f t = cv::Vec3f(p.x, p.y, p.z) - q;
    const double angle = std::atan2(t.dot(v), t.dot(u));  // (−π, π]
    const int sector =
        static_cast<int>((angle + std::numbers::pi) / (2 * std::numbers::pi) * kSectors);
    occupied[std::clamp(sector, 0, kSectors - 1)] = true;
  }
  int run = 0, longest = 0;
  for (int k = 0; k < 2 * kSectors; ++k) {  // twice round: runs that wrap
    run = occupied[k % kSectors] ? 0 : run + 1;
    longest = std::max(longest, run);
  }
  return longest < kMaxEmpty;
}

// Running sums of one grid vertex's IMLS value (see EvaluateImls).
struct ImlsSum {
  float w = 0, f = 0;
  cv::Vec3f offset{0, 0, 0}, normal{0, 0, 0}, color{0, 0, 0};
  int count = 0;
  void Add(float weight, float distance, const cv::Vec3f& d, const cv::Vec3f& n,
           const cv::Vec3f& c) {
    w += weight;
    f += weight * distance;
    offset += weight * d;
    normal += weight * n;
    color += weight * c;
    ++count;
  }
  // The value and colour, false where undefined: fewer than `min_support`
  // points, or the weighted centroid more than `max_tangent` from x along
  // the surface.
  bool Value(int min_support, double max_tangent, float* value, cv::Vec3f* colour) const {
    if (count < min_support || !(w > 0)) return false;
    const cv::Vec3f to_x = offset / w;  // x − the weighted centroid
    const double length = cv::norm(normal);
    const cv::Vec3f n = length > 0 ? normal / length : cv::Vec3f(0, 0, 0);
    if (cv::norm(to_x - to_x.dot(n) * n) > max_tangent) return false;
    *value = f / w;
    *colour = color / w;
    return true;
  }
};

// Running sums of an algebraic sphere fitted to the points and normals
// around x (Guennebaud and Gross, "Algebraic point set surfaces", SIGGRAPH
// 2007, the normal-constrained fit with β = 1), in coordinates centred on x.
// Across a hole it carries the curvature of the surface around it, where
// Kolluri's value blends the tangent planes of the rim (over a convex cap
// they meet in a cone above the surface).
struct ApssSum {
  double w = 0, pn = 0, pp = 0;
  cv::Vec3d p{0, 0, 0}, n{0, 0, 0};
  // d = x − p_i (p_i relative to x is −d).
  void Add(double weight, const cv::Vec3f& d, const cv::Vec3f& normal) {
    const cv::Vec3d q(-d[0], -d[1], -d[2]), m(normal[0], normal[1], normal[2]);
    w += weight;
    p += weight * q;
    n += weight * m;
    pn += weight * q.dot(m);
    pp += weight * q.dot(q);
  }
  // The signed distance from x to the fitted sphere (or plane), positive
  // on the side the normals face; false when the fit is degenerate.
  bool Distance(double scale, float* value) const {
    if (!(w > 0)) return false;
    const cv::Vec3d P = p / w, N = n / w;
    const double spread = pp / w - P.dot(P);
    if (!(spread > 1e-12 * scale * scale)) return false;
    const double u4 = 0.5 * (pn / w - P.dot(N)) / spread;
    const cv::Vec3d u = N - 2 * u4 * P;
    const double u0 = -u.dot(P) - u4 * pp / w;
    const double gradient = cv::norm(u);
    double distance;
    if (std::abs(u4) * scale < 1e-6 * gradient) {  // a plane
      if (!(gradient > 0)) return false;
      distance = u0 / gradient;
    } else {
      const cv::Vec3d c = -u / (2 * u4);
      const double r2 = c.dot(c) - u0 / u4;
      if (!(r2 > 0)) return false;
      distance = (u4 > 0 ? 1 : -1) * (cv::norm(c) - std::sqrt(r2));
    }
    if (!std::isfinite(distance)) return false;
    *value = static_cast<float>(distance);
    return true;
  }
};

// The signed distance of Kolluri's implicit moving least squares at the
// grid vertices near the surface: f(x) = Σ w_i n_i·(x − p_i) / Σ w_i over the
// points within the radius r, w_i = exp(−|x − p_i|² / (r/2)²), and the
// points' colours weighted alike. A value is undefined (NaN) with fewer than
// `min_support` points, or where the weighted centroid of the neighbours lies
// more than `max_tangent_radii` × r from x along the surface: x is beyond the
// edge of the data, and the surface is not extended past what the cameras
// saw. (At the straight edge of evenly spread points the centroid lies 0.28 r
// inside, the mean of a Gaussian of deviation r/√8 cut in half; in a hole
// the points around x pull it back towards x.) With `sphere_fit` a defined
// vertex takes instead its distance to the sphere fitted with the same
// weights (ApssSum), where the fit is not degenerate.
//
// First the vertices within 1.75 cells of a point, at `radius`: each point
// adds itself to the vertices around it (a scatter). Then, with
// `fill_radius` > radius, holes close from their edges: undefined and new
// vertices next to defined ones within 1.5 cells of the surface are
// evaluated at the fill radius (a search in `tree`), ring after ring, as far
// as the fill radius reaches.
void EvaluateImls(const PoissonInput& in, const PointCloud& cloud,
                  const pcl::KdTreeFLANN<pcl::PointXYZ>& tree, double radius, double fill_radius,
                  int min_support, double max_tangent_radii, bool sphere_fit, Grid* g) {
  const double h = g->h;
  const int n[3] = {g->nx, g->ny, g->nz};
  // The vertex range [lo, hi] within `reach` cells of p along each axis.
  const auto range = [&](const pcl::PointXYZ& p, double reach, int* lo, int* hi) {
    for (int a = 0; a < 3; ++a) {
      const double c = (p.data[a] - g->origin[a]) / h;
      lo[a] = std::max(0, static_cast<int>(std::ceil(c - reach)));
      hi[a] = std::min(n[a] - 1, static_cast<int>(std::floor(c + reach)));
    }
  };
  g->slot.assign(static_cast<std::size_t>(g->nx) * g->ny * g->nz, -1);
  std::int32_t slots = 0;
  int lo[3], hi[3];
  for (const pcl::PointXYZ& p : *in.positions) {
    range(p, 1.75, lo, hi);
    for (int z = lo[2]; z <= hi[2]; ++z)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int x = lo[0]; x <= hi[0]; ++x) {
          g->slot[g->Index(x, y, z)] = 0;
        }
  }
  // Numbered in the grid's order, so that neighbouring vertices' sums lie
  // near each other in memory.
  for (std::int32_t& k : g->slot)
    if (k == 0) k = slots++;
  std::vector<ImlsSum> sums(static_cast<std::size_t>(slots));
  std::vector<ApssSum> spheres(sphere_fit ? static_cast<std::size_t>(slots) : 0);
  const bool colors = cloud.HasColors();
  const auto colour = [&](std::size_t i) {
    return colors ? cv::Vec3f(cloud.colors_rgb[in.source_index[i]]) : cv::Vec3f();
  };
  const double r2 = radius * radius, inv_sigma2 = 4.0 / r2;
  const double reach = radius / h;
  // The scatter on OpenMP's threads: the points in slabs across the grid's
  // longest axis, each more than twice the reach thick, so that two slabs
  // of one parity touch no vertex in common; the even slabs at once, then
  // the odd ones. Each vertex adds its points in the same order whatever
  // the number of threads.
  const int slab = 2 * static_cast<int>(std::ceil(reach)) + 1;
  const int axis = static_cast<int>(std::max_element(n, n + 3) - n);
  std::vector<std::vector<std::uint32_t>> by_slab(static_cast<std::size_t>(n[axis] / slab + 1));
  for (std::size_t i = 0; i < in.positions->size(); ++i) {
    const double c = ((*in.positions)[i].data[axis] - g->origin[axis]) / h;
    const int s =
        std::clamp(static_cast<int>(std::floor(c / slab)), 0, static_cast<int>(by_slab.size()) - 1);
    by_slab[static_cast<std::size_t>(s)].push_back(static_cast<std::uint32_t>(i));
  }
  // Within a slab in the grid's order too: consecutive points update
  // mostly the same vertices.
  const auto cell = [&](std::uint32_t i) {
    const pcl::PointXYZ& p = (*in.positions)[i];
    return g->Index(static_cast<int>((p.x - g->origin[0]) / h),
                    static_cast<int>((p.y - g->origin[1]) / h),
                    static_cast<int>((p.z - g->origin[2]) / h));
  };
  for (std::vector<std::uint32_t>& points : by_slab)
    std::stable_sort(points.begin(), points.end(),
                     [&](std::uint32_t a, std::uint32_t b) { return cell(a) < cell(b); });
  const auto scatter = [&](std::size_t i) {
    const pcl::PointNormal& p = (*in.oriented)[i];
    const cv::Vec3f pn(p.normal_x, p.normal_y, p.normal_z), pc = colour(i);
    int lo[3], hi[3];
    range((*in.positions)[i], reach, lo, hi);
    // Only the vertices within the radius: per row, the x range of the
    // sphere's chord.
    for (int z = lo[2]; z <= hi[2]; ++z) {
      const float dz = g->Position(0, 0, z)[2] - p.z;
      for (int y = lo[1]; y <= hi[1]; ++y) {
        const float dy = g->Position(0, y, 0)[1] - p.y;
        const double rest = r2 - (static_cast<double>(dy) * dy + static_cast<double>(dz) * dz);
        if (rest < 0) continue;
        const double chord = std::sqrt(rest), c = (p.x - g->origin[0]) / h;
        const int x0 = std::max(lo[0], static_cast<int>(std::ceil(c - chord / h)) - 1);
        const int x1 = std::min(hi[0], static_cast<int>(std::floor(c + chord / h)) + 1);
        const std::int32_t* row = &g->slot[g->Index(0, y, z)];
        for (int x = x0; x <= x1; ++x) {
          const std::int32_t k = row[x];
          if (k < 0) continue;
          const cv::Vec3f d(g->Position(x, 0, 0)[0] - p.x, dy, dz);
          const double d2 = d.dot(d);
          if (d2 <= r2) {
            const float weight = std::exp(static_cast<float>(-d2 * inv_sigma2));
            sums[static_cast<std::size_t>(k)].Add(weight, pn.dot(d), d, pn, pc);
            if (sphere_fit) spheres[static_cast<std::size_t>(k)].Add(weight, d, pn);
          }
        }
      }
    }
  };
  const auto slabs = static_cast<long>(by_slab.size());
  for (long parity = 0; parity < 2; ++parity) {
#pragma omp parallel for schedule(dynamic, 1)
    for (long s = parity; s < slabs; s += 2)
      for (std::uint32_t i : by_slab[static_cast<std::size_t>(s)]) scatter(i);
  }
  g->value.assign(sums.size(), std::numeric_limits<float>::quiet_NaN());
  g->color.assign(sums.size(), cv::Vec3f(0, 0, 0));
  for (std::size_t k = 0; k < sums.size(); ++k)
    if (sums[k].Value(min_support, max_tangent_radii * radius, &g->value[k], &g->color[k]) &&
        sphere_fit)
      spheres[k].Distance(radius, &g->value[k]);
  if (!(fill_radius > radius)) return;

  // The fill, ring by ring from the defined vertices near the surface (each
  // ring's values on OpenMP's threads; the grid does not depend on them).
  const double near_surface = 1.5 * h;
  const double fill_inv_sigma2 = 4.0 / (fill_radius * fill_radius);
  std::vector<std::uint8_t> tried(g->slot.size(), 0);
  std::vector<std::size_t> ring;
  for (std::size_t v = 0; v < g->slot.size(); ++v) {
    const std::int32_t k = g->slot[v];
    if (k >= 0 && std::abs(g->value[static_cast<std::size_t>(k)]) < near_surface) {
      ring.push_back(v);
      tried[v] = 1;
    }
  }
  const std::size_t stride[3] = {1, static_cast<std::size_t>(g->nx),
                                 static_cast<std::size_t>(g->nx) * g->ny};
  const int rings = static_cast<int>(std::ceil(fill_radius / h));
  // Each ring: its candidates in order, then their values (from the input
  // points alone, so on any number of threads), then written in order: the
  // grid is the same as one candidate after the other would make it.
  struct Candidate {
    std::size_t u = 0;
    bool defined = false;
    float value = 0;
    cv::Vec3f color;
  };
  std::vector<Candidate> candidates;
  for (int step = 0; step < rings && !ring.empty(); ++step) {
    candidates.clear();
    for (std::size_t v : ring) {
      const int c[3] = {static_cast<int>(v % g->nx), static_cast<int>((v / g->nx) % g->ny),
                        static_cast<int>(v / stride[2])};
      for (int a = 0; a < 3; ++a)
        for (int dir : {-1, 1}) {
          if (c[a] + dir < 0 || c[a] + dir >= n[a]) continue;
          const std::size_t u = dir < 0 ? v - stride[a] : v + stride[a];
          if (tried[u]) continue;
          // Not where the value, extrapolated from v and the vertex behind
          // it, is more than two cells from the surface: such a vertex is
          // no corner of a cell the surface crosses (those lie within √3
          // cells of it) and would not carry the fill on. Another
          // neighbour may still make it a candidate.
          if (c[a] - dir >= 0 && c[a] - dir < n[a]) {
            const std::int32_t kv = g->slot[v];
            const std::int32_t kw = g->slot[dir < 0 ? v + stride[a] : v - stride[a]];
            if (kw >= 0) {
              const float behind = g->value[static_cast<std::size_t>(kw)];
              if (!std::isnan(behind) &&
                  std::abs(2 * g->value[static_cast<std::size_t>(kv)] - behind) > 2 * h)
                continue;
            }
          }
          tried[u] = 1;
          const std::int32_t k = g->slot[u];
          if (k >= 0 && !std::isnan(g->value[static_cast<std::size_t>(k)])) continue;
          candidates.push_back({u});
        }
    }
    const auto count = static_cast<long>(candidates.size());
#pragma omp parallel
    {
      std::vector<int> index;
      std::vector<float> d2;
#pragma omp for schedule(dynamic, 64)
      for (long ci = 0; ci < count; ++ci) {
        Candidate& cand = candidates[static_cast<std::size_t>(ci)];
        const std::size_t u = cand.u;
        const int x = static_cast<int>(u % g->nx), y = static_cast<int>((u / g->nx) % g->ny);
        const cv::Vec3f q = g->Position(x, y, static_cast<int>(u / stride[2]));
        const int found =
            tree.radiusSearch(pcl::PointXYZ(q[0], q[1], q[2]), fill_radius, index, d2);
        ImlsSum sum;
        ApssSum sphere;
        for (int j = 0; j < found; ++j) {
          const std::size_t i = static_cast<std::size_t>(index[static_cast<std::size_t>(j)]);
          const pcl::PointNormal& p = (*in.oriented)[i];
          const cv::Vec3f pn(p.normal_x, p.normal_y, p.normal_z);
          const cv::Vec3f d = q - cv::Vec3f(p.x, p.y, p.z);
          const float weight =
              static_cast<float>(std::exp(-d2[static_cast<std::size_t>(j)] * fill_inv_sigma2));
          sum.Add(weight, pn.dot(d), d, pn, colour(i));
          if (sphere_fit) sphere.Add(weight, d, pn);
        }
        // No tangent test here (at a hole's edge the points lie on one side
        // of x as at the data's edge): the points must surround x instead.
        cand.defined = sum.Value(min_support, 1e30, &cand.value, &cand.color) &&
                       Surrounded(in, q, sum.normal, index, found);
        if (cand.defined && sphere_fit) sphere.Distance(fill_radius, &cand.value);
      }
    }
    std::vector<std::size_t> next;
    for (const Candidate& cand : candidates) {
      if (!cand.defined) continue;
      std::int32_t k = g->slot[cand.u];
      if (k < 0) {
        k = g->slot[cand.u] = static_cast<std::int32_t>(g->value.size());
        g->value.push_back(cand.value);
        g->color.push_back(cand.color);
      } else {
        g->value[static_cast<std::size_t>(k)] = cand.value;
        g->color[static_cast<std::size_t>(k)] = cand.color;
      }
      if (std::abs(cand.value) < near_surface) next.push_back(cand.u);
    }
    ring.swap(next);
  }
}

// Marching cubes (PCL's tables and corner order) over the cells whose eight
// corners are all defined; one vertex per grid edge, shared by the cells
// around it, so the mesh comes out connected rather than as triangle soup
// (pcl::MarchingCubes makes soup over a dense grid it fills itself).
void MarchingCubesOnGrid(const Grid& g, bool colors, TriangleMesh* mesh) {
  static constexpr int kCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1},
                                        {0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}};
  static constexpr int kEdge[12][2] = {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {4, 5}, {5, 6},
                                       {6, 7}, {7, 4}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};
  std::unordered_map<std::uint64_t, int> edge_vertex;
  for (int z = 0; z + 1 < g.nz; ++z)
    for (int y = 0; y + 1 < g.ny; ++y)
      for (int x = 0; x + 1 < g.nx; ++x) {
        float f[8];
        int cube = 0;
        bool defined = true;
        for (int c = 0; c < 8 && defined; ++c) {
          f[c] = g.Value(x + kCorner[c][0], y + kCorner[c][1], z + kCorner[c][2]);
          defined = !std::isnan(f[c]);
          if (f[c] < 0) cube |= 1 << c;
        }
        if (!defined || pcl::edgeTable[cube] == 0) continue;
        int vertex[12];
        for (int e = 0; e < 12; ++e) {
          if (!(pcl::edgeTable[cube] & (1u << e))) continue;
          const int* a = kCorner[kEdge[e][0]];
          const int* b = kCorner[kEdge[e][1]];
          int lo[3], axis = 0;
          for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(a[k], b[k]);
            if (a[k] != b[k]) axis = k;
          }
          const std::uint64_t key = g.Index(x + lo[0], y + lo[1], z + lo[2]) * 3 + axis;
          const auto [it, added] =
              edge_vertex.emplace(key, static_cast<int>(mesh->vertices_mm.size()));
          if (added) {
            const float fa = f[kEdge[e][0]], fb = f[kEdge[e][1]];
            const float t = fa / (fa - fb);
            const cv::Vec3f pa = g.Position(x + a[0], y + a[1], z + a[2]);
            const cv::Vec3f pb = g.Position(x + b[0], y + b[1], z + b[2]);
            mesh->vertices_mm.push_back(pa + t * (pb - pa));
            if (colors) {
              const cv::Vec3f ca =
                  g.color[static_cast<std::size_t>(g.slot[g.Index(x + a[0], y + a[1], z + a[2])])];
              const cv::Vec3f cb =
                  g.color[static_cast<std::size_t>(g.slot[g.Index(x + b[0], y + b[1], z + b[2])])];
              const cv::Vec3f c = ca + t * (cb - ca);
              mesh->colors_rgb.emplace_back(cv::saturate_cast<std::uint8_t>(c[0]),
                                            cv::saturate_cast<std::uint8_t>(c[1]),
                                            cv::saturate_cast<std::uint8_t>(c[2]));
            }
          }
          vertex[e] = it->second;
        }
        for (int k = 0; pcl::triTable[cube][k] != -1; k += 3) {
          const cv::Vec3i face(vertex[pcl::triTable[cube][k]], vertex[pcl::triTable[cube][k + 1]],
                               vertex[pcl::triTable[cube][k + 2]]);
          if (face[0] != face[1] && face[1] != face[2] && face[0] != face[2])
            mesh->faces.push_back(face);
        }
      }
}

}  // namespace

MeshResult PoissonMesh(const PointCloud& cloud, const PoissonOptions& options) {
  return NoThrow<MeshResult>("PoissonMesh", MeshResult::Status::kFailed, [&]() -> MeshResult {
    const auto start = std::chrono::steady_clock::now();
    MeshResult r;
    std::string why;
    if (!options.IsValid(&why)) return Failed(r, kFailed, std::string(kWhere) + why);
    PoissonInput input;
    if (!UsableInput(cloud, kWhere, &r, &input)) return r;

    pcl::PointCloud<pcl::PointNormal> vertices;
    std::vector<pcl::Vertices> polygons;
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    try {
      ReconstructPoisson(input, options, &vertices, &polygons, &r.library_stdout_lines);
      tree.setInputCloud(input.positions);
    } catch (const std::exception& e) {
      return Failed(r, kFailed,
                    std::string(kWhere) + std::string("reconstruction failed: ") + e.what());
    }
    r.raw_vertices = vertices.size();
    r.raw_faces = polygons.size();
    if (vertices.empty() || polygons.empty())
      return Failed(r, kFailed, std::string(kWhere) + "reconstruction produced no triangle");

    double radius = options.support_radius_mm;
    if (radius == 0) radius = EstimateSupportRadius(tree, *input.positions);
    if (!(radius > 0))
      return Failed(r, kFailed, std::string(kWhere) + "could not estimate the point spacing");
    r.support_radius_mm = radius;

    TrimBySupport(vertices, polygons, tree, radius, options.trim_density_quantile,
                  options.num_threads, &r);
    if (r.mesh.faces.empty()) {
      r.mesh = TriangleMesh{};  // a failed result holds no mesh
      return Failed(r, kFailed, std::string(kWhere) + "density trimming removed every triangle");
    }
    FinishMesh(tree, input, cloud, options.min_component_fraction, options.colors,
               options.num_threads, &r);
    r.status = MeshResult::Status::kOk;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return r;
  });
}

MeshResult ImplicitMesh(const PointCloud& cloud, const ImplicitMeshOptions& options) {
  return NoThrow<MeshResult>("ImplicitMesh", MeshResult::Status::kFailed, [&]() -> MeshResult {
    constexpr std::string_view where = "ImplicitMesh: ";
    const auto start = std::chrono::steady_clock::now();
    MeshResult r;
    std::string why;
    if (!options.IsValid(&why)) return Failed(r, kFailed, std::string(where) + why);
    const ImplicitMeshOptions& opt = options;
    PoissonInput input;
    if (!UsableInput(cloud, where, &r, &input)) return r;
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(input.positions);
    const double spacing = EstimateSupportRadius(tree, *input.positions) / 2.5;
    if (!(spacing > 0))
      return Failed(r, kFailed, std::string(where) + "could not estimate the point spacing");
    Grid g;
    g.h = opt.voxel_mm > 0 ? opt.voxel_mm : opt.voxel_spacings * spacing;
    const double radius = opt.radius_spacings * spacing;
    r.support_radius_mm = radius;
    cv::Vec3d lo(1e300, 1e300, 1e300), hi(-1e300, -1e300, -1e300);
    for (const pcl::PointXYZ& p : *input.positions)
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], static_cast<double>(p.data[a]));
        hi[a] = std::max(hi[a], static_cast<double>(p.data[a]));
      }
    // A coarser grid rather than more memory than kMaxGridVertices floats.
    for (;;) {
      g.origin = lo - cv::Vec3d::all(2 * g.h);
      g.nx = static_cast<int>(std::ceil((hi[0] - lo[0]) / g.h)) + 5;
      g.ny = static_cast<int>(std::ceil((hi[1] - lo[1]) / g.h)) + 5;
      g.nz = static_cast<int>(std::ceil((hi[2] - lo[2]) / g.h)) + 5;
      if (static_cast<double>(g.nx) * g.ny * g.nz <= kMaxGridVertices) break;
      g.h *= 1.25;
    }
    EvaluateImls(input, cloud, tree, radius, opt.fill_radii * radius, opt.min_support,
                 opt.max_tangent_radii, opt.sphere_fit, &g);
    const bool colors = options.colors && cloud.HasColors();
    MarchingCubesOnGrid(g, colors, &r.mesh);
    r.raw_vertices = r.mesh.vertices_mm.size();
    r.raw_faces = r.mesh.faces.size();
    if (r.mesh.faces.empty()) {
      r.mesh = TriangleMesh{};
      return Failed(r, kFailed, std::string(where) + "no surface: the cloud is too sparse or flat");
    }
    // Colours came from the grid.
    FinishMesh(tree, input, cloud, options.min_component_fraction, /*colors=*/false,
               /*threads=*/1, &r);
    r.status = MeshResult::Status::kOk;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return r;
  });
}

std::string EncodeMeshObj(const TriangleMesh& mesh) {
  if (!mesh.IsValid(nullptr)) return {};
  const bool normals = !mesh.normals.empty(), colors = !mesh.colors_rgb.empty();
  std::string out = "# craftscan mesh, units mm\n";
  out += "# " + std::to_string(mesh.vertices_mm.size()) + " vertices, " +
         std::to_string(mesh.faces.size()) + " faces\n";
  for (std::size_t v = 0; v < mesh.vertices_mm.size(); ++v) {
    out += 'v';
    for (int k = 0; k < 3; ++k) {
      out += ' ';
      AppendFloat(&out, mesh.vertices_mm[v][k]);
    }
    if (colors)
      for (int k = 0; k < 3; ++k) {
        out += ' ';
        AppendFloat(&out, static_cast<float>(mesh.colors_rgb[v][k]) / 255.0f);
      }
    out += '\n';
  }
  if (normals)
    for (const cv::Vec3f& n : mesh.normals) {
      out += "vn";
      for (int k = 0; k < 3; ++k) {
        out += ' ';
        AppendFloat(&out, n[k]);
      }
      out += '\n';
    }
  for (const cv::Vec3i& f : mesh.faces) {
    out += 'f';
    for (int k = 0; k < 3; ++k) {
      const std::string i = std::to_string(f[k] + 1);
      out += ' ' + i;
      if (normals) out += "//" + i;
    }
    out += '\n';
  }
  return out;
}

bool WriteMeshObj(const std::string& path, const TriangleMesh& mesh, std::string* error) {
  return NoThrowBool("WriteMeshObj", error, [&]() -> bool {
    std::string why;
    if (!mesh.IsValid(&why)) return Fail(error, "WriteMeshObj '" + path + "': " + why);
    return WriteFileAtomically(path, EncodeMeshObj(mesh), error);
  });
}

}  // namespace craftscan
