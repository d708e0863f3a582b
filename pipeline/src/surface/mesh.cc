#include "craftscan/pipeline/surface/mesh.h"

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/surface/poisson.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <string_view>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

constexpr std::size_t kMinMeshPoints = 100;

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

// PCL's Poisson surface (triangles, manifold). Throws what PCL throws.
void ReconstructPoisson(const PoissonInput& in, const PoissonOptions& options,
                        pcl::PointCloud<pcl::PointNormal>* vertices,
                        std::vector<pcl::Vertices>* polygons) {
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
                   double trim_density_quantile, MeshResult* r) {
  std::vector<int> support(vertices.size(), 0);
  std::vector<int> index;
  std::vector<float> d2;
  for (std::size_t v = 0; v < vertices.size(); ++v) {
    const pcl::PointNormal& q = vertices[v];
    if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z)) continue;
    support[v] = tree.radiusSearch(pcl::PointXYZ(q.x, q.y, q.z), radius, index, d2);
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
                    const std::vector<std::size_t>& source_index, TriangleMesh* mesh) {
  mesh->colors_rgb.resize(mesh->vertices_mm.size());
  std::vector<int> index(1);
  std::vector<float> d2(1);
  for (std::size_t v = 0; v < mesh->vertices_mm.size(); ++v) {
    const cv::Vec3f& p = mesh->vertices_mm[v];
    if (tree.nearestKSearch(pcl::PointXYZ(p[0], p[1], p[2]), 1, index, d2) == 1)
      mesh->colors_rgb[v] = cloud.colors_rgb[source_index[static_cast<std::size_t>(index[0])]];
  }
}

}  // namespace

MeshResult PoissonMesh(const PointCloud& cloud, const PoissonOptions& options) {
  return NoThrow<MeshResult>("PoissonMesh", MeshResult::Status::kFailed, [&]() -> MeshResult {
    const auto start = std::chrono::steady_clock::now();
    MeshResult r;
    std::string why;
    if (!options.IsValid(&why)) return Failed(r, kFailed, std::string(kWhere) + why);
    if (!cloud.IsValid(&why))
      return Failed(r, kFailed, std::string(kWhere) + "invalid cloud: " + why);
    if (!cloud.HasNormals())
      return Failed(r, kFailed,
                    std::string(kWhere) + "the cloud has no normals (Poisson needs them)");

    const PoissonInput input = OrientedPoints(cloud);
    r.input_points = input.oriented->size();
    if (input.oriented->size() < kMinMeshPoints)
      return Failed(r, kFailed,
                    std::string(kWhere) + "need at least " + std::to_string(kMinMeshPoints) +
                        " points with finite normals, got " + std::to_string(r.input_points) +
                        " (of " + std::to_string(cloud.size()) + ")");

    pcl::PointCloud<pcl::PointNormal> vertices;
    std::vector<pcl::Vertices> polygons;
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    try {
      ReconstructPoisson(input, options, &vertices, &polygons);
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

    TrimBySupport(vertices, polygons, tree, radius, options.trim_density_quantile, &r);
    if (r.mesh.faces.empty()) {
      r.mesh = TriangleMesh{};  // a failed result holds no mesh
      return Failed(r, kFailed, std::string(kWhere) + "density trimming removed every triangle");
    }
    DropSmallComponents(options.min_component_fraction, &r);
    OrientAndShade(tree, *input.oriented, &r.mesh);
    if (options.colors && cloud.HasColors())
      ColorFromCloud(tree, cloud, input.source_index, &r.mesh);
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
