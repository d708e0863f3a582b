// Triangle mesh object: a bounding volume hierarchy (median split, ≤ 4
// triangles per leaf) over the triangles, Möller–Trumbore intersection in
// double precision, smooth (area-weighted vertex) normals, and a seeded
// procedural surface (MeshSurface): solid textures of the point in the
// object frame (stone, wood), the egg's painted pattern about the z axis, or
// a woven tartan projected along the normal's main axis (fabric), so a mesh
// needs no texture coordinates.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <vector>

#include "shapes.h"
#include "texture.h"

namespace craftscan::sim {
namespace {

struct Box3 {
  V3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  void Grow(const V3& p) {
    lo = V3(std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z));
    hi = V3(std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z));
  }
  void Grow(const Box3& b) {
    Grow(b.lo);
    Grow(b.hi);
  }
};

struct Node {
  Box3 box;
  int first = 0;  // leaf: first index into order_; inner: index of the left child
  int count = 0;  // leaf: number of triangles (> 0); inner: 0 (right child = first + 1)
};

class MeshShape : public Primitive {
 public:
  MeshShape(const std::vector<cv::Vec3d>& vertices_mm, const std::vector<cv::Vec3i>& triangles,
            MeshSurface surface, std::uint64_t seed)
      : Primitive(SurfaceLabel::kObject), surface_(surface), seed_(seed) {
    vertices_.reserve(vertices_mm.size());
    Box3 bounds;
    for (const cv::Vec3d& v : vertices_mm) {
      vertices_.push_back(FromCv(v));
      bounds.Grow(vertices_.back());
    }
    triangles_.reserve(triangles.size());
    for (const cv::Vec3i& t : triangles) triangles_.push_back({t[0], t[1], t[2]});
    // Area-weighted vertex normals (the cross product's length is 2·area).
    normals_.assign(vertices_.size(), V3(0, 0, 0));
    for (const auto& t : triangles_) {
      const V3 n = Cross(vertices_[t[1]] - vertices_[t[0]], vertices_[t[2]] - vertices_[t[0]]);
      for (int k = 0; k < 3; ++k) normals_[t[k]] += n;
    }
    for (V3& n : normals_) {
      const double len = Norm(n);
      n = len > 0 ? n / len : V3(0, 0, 0);
    }
    const int base = static_cast<int>(ToUnit(Hash(seed, 300)) * 3);
    static constexpr V3 kStones[] = {
        {0.22, 0.36, 0.62},  // terracotta
        {0.50, 0.62, 0.72},  // sandstone
        {0.42, 0.52, 0.40},  // celadon
    };
    base_colour_ = kStones[base];
    // The other surfaces are laid out on the placed mesh's bounding box
    // (centred on the z axis, bottom at z = 0).
    const V3 extent = vertices_.empty() ? V3(1, 1, 1) : bounds.hi - bounds.lo;
    wood_.emplace(seed, V3(0, -1.3 * extent.y, -0.6 * extent.z));
    paint_.emplace(seed, 0.5 * std::max(extent.x, extent.y), 0.5 * extent.z);
    half_height_ = std::max(0.5 * extent.z, 1e-3);  // a flat mesh is its equator
    MakeSett(SubSeed(seed, 400));
    Build();
  }

  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    return Walk<false>(o, d, t_min, t_max, hit);
  }

  // Any triangle hit in (t_min, t_max) ends the walk (a shadow ray).
  bool Occludes(const V3& o, const V3& d, double t_min, double t_max) const override {
    LocalHit hit;
    return Walk<true>(o, d, t_min, t_max, &hit);
  }

  double MinAlong(const V3& n) const override {
    double lowest = std::numeric_limits<double>::infinity();
    for (const V3& v : vertices_) lowest = std::min(lowest, Dot(n, v));
    return lowest;
  }

  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    const auto& t = triangles_[static_cast<std::size_t>(hit.part)];
    const V3 n =
        normals_[t[0]] * (1 - hit.u - hit.v) + normals_[t[1]] * hit.u + normals_[t[2]] * hit.v;
    const double len = Norm(n);
    if (len > 1e-12) {
      *normal = n / len;
    } else {
      *normal =
          Normalized(Cross(vertices_[t[1]] - vertices_[t[0]], vertices_[t[2]] - vertices_[t[0]]));
    }
    const V3& p = hit.p;
    switch (surface_) {
      case MeshSurface::kStone:
        break;
      case MeshSurface::kWood:
        *albedo = wood_->Albedo(p);
        return;
      case MeshSurface::kPainted: {
        // Latitude from the height (as on an egg of the mesh's height),
        // longitude about the axis.
        const double lat = std::asin(std::clamp((p.z - half_height_) / half_height_, -1.0, 1.0));
        *albedo = paint_->Albedo(p, lat, std::atan2(p.y, p.x), std::hypot(p.x, p.y));
        return;
      }
      case MeshSurface::kFabric:
        *albedo = Fabric(p, *normal);
        return;
    }
    const double cloud = Fbm3(SubSeed(seed_, 301), p.x / 9, p.y / 9, p.z / 9, 4);
    const double grain =
        ToUnit(Hash(SubSeed(seed_, 302), static_cast<std::int64_t>(std::floor(p.x / 0.4)),
                    static_cast<std::int64_t>(std::floor(p.y / 0.4)),
                    static_cast<std::int64_t>(std::floor(p.z / 0.4))));
    *albedo = base_colour_ * (0.6 + 0.6 * cloud) * (0.85 + 0.3 * grain);
  }

  std::size_t triangle_count() const { return triangles_.size(); }

 private:
  static bool HitBox(const Box3& b, const V3& o, const V3& inv, double t_min, double t_max,
                     double* enter) {
    double t0 = t_min, t1 = t_max;
    for (int a = 0; a < 3; ++a) {
      double ta = (b.lo[a] - o[a]) * inv[a], tb = (b.hi[a] - o[a]) * inv[a];
      if (ta > tb) std::swap(ta, tb);
      // NaN (0·∞ for a ray in a slab plane) must not reject: compare so NaN passes.
      if (ta > t0) t0 = ta;
      if (tb < t1) t1 = tb;
      if (t0 > t1) return false;
    }
    *enter = t0;
    return true;
  }

  bool HitTriangle(int index, const V3& o, const V3& d, double* t, double* u, double* v) const {
    const auto& tri = triangles_[static_cast<std::size_t>(index)];
    const V3& v0 = vertices_[tri[0]];
    const V3 e1 = vertices_[tri[1]] - v0, e2 = vertices_[tri[2]] - v0;
    const V3 pvec = Cross(d, e2);
    const double det = Dot(e1, pvec);
    if (std::abs(det) < 1e-300) return false;
    const double inv_det = 1 / det;
    const V3 tvec = o - v0;
    *u = Dot(tvec, pvec) * inv_det;
    if (*u < 0 || *u > 1) return false;
    const V3 qvec = Cross(tvec, e1);
    *v = Dot(d, qvec) * inv_det;
    if (*v < 0 || *u + *v > 1) return false;
    *t = Dot(e2, qvec) * inv_det;
    return true;
  }

  void Build() {
    const std::size_t n = triangles_.size();
    order_.resize(n);
    std::iota(order_.begin(), order_.end(), 0);
    centroids_.resize(n);
    boxes_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      const auto& t = triangles_[i];
      Box3 b;
      for (int k = 0; k < 3; ++k) b.Grow(vertices_[t[k]]);
      boxes_[i] = b;
      centroids_[i] = (vertices_[t[0]] + vertices_[t[1]] + vertices_[t[2]]) / 3.0;
    }
    if (n == 0) return;
    nodes_.reserve(2 * n / 2 + 1);
    nodes_.emplace_back();
    BuildNode(0, 0, static_cast<int>(n), 0);
    centroids_.clear();
    centroids_.shrink_to_fit();
    boxes_.clear();
    boxes_.shrink_to_fit();
  }

  // The BVH walk, nearer child first: the nearest hit, or with kAnyHit the
  // first one found (*hit then holds only its t).
  template <bool kAnyHit>
  bool Walk(const V3& o, const V3& d, double t_min, double t_max, LocalHit* hit) const {
    if (nodes_.empty()) return false;
    const V3 inv(1 / d.x, 1 / d.y, 1 / d.z);
    int stack[128];
    int top = 0;
    stack[top++] = 0;
    bool found = false;
    while (top > 0) {
      const Node& node = nodes_[static_cast<std::size_t>(stack[--top])];
      double enter;
      if (!HitBox(node.box, o, inv, t_min, t_max, &enter)) continue;
      if (node.count > 0) {
        for (int i = node.first; i < node.first + node.count; ++i) {
          const int tri = order_[static_cast<std::size_t>(i)];
          double t, u, v;
          if (HitTriangle(tri, o, d, &t, &u, &v) && t > t_min && t < t_max) {
            t_max = t;
            hit->t = t;
            if constexpr (kAnyHit) return true;
            hit->part = tri;
            hit->u = u;
            hit->v = v;
            found = true;
          }
        }
        continue;
      }
      // Visit the nearer child first (pushed last).
      const int left = node.first, right = node.first + 1;
      double el = 1e300, er = 1e300;
      const bool hl = HitBox(nodes_[static_cast<std::size_t>(left)].box, o, inv, t_min, t_max, &el);
      const bool hr =
          HitBox(nodes_[static_cast<std::size_t>(right)].box, o, inv, t_min, t_max, &er);
      if (hl && hr) {
        if (el < er) {
          stack[top++] = right;
          stack[top++] = left;
        } else {
          stack[top++] = left;
          stack[top++] = right;
        }
      } else if (hl) {
        stack[top++] = left;
      } else if (hr) {
        stack[top++] = right;
      }
    }
    if (found) hit->p = o + d * hit->t;
    return found;
  }

  void BuildNode(int node_index, int begin, int end, int depth) {
    Box3 box, centre_box;
    for (int i = begin; i < end; ++i) {
      const int tri = order_[static_cast<std::size_t>(i)];
      box.Grow(boxes_[static_cast<std::size_t>(tri)]);
      centre_box.Grow(centroids_[static_cast<std::size_t>(tri)]);
    }
    nodes_[static_cast<std::size_t>(node_index)].box = box;
    const V3 extent = centre_box.hi - centre_box.lo;
    const int axis =
        extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
    if (end - begin <= kLeafSize || extent[axis] <= 0 || depth >= 60) {
      nodes_[static_cast<std::size_t>(node_index)].first = begin;
      nodes_[static_cast<std::size_t>(node_index)].count = end - begin;
      return;
    }
    const int mid = begin + (end - begin) / 2;
    std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                     [&](int a, int b) {
                       const double ca = centroids_[static_cast<std::size_t>(a)][axis];
                       const double cb = centroids_[static_cast<std::size_t>(b)][axis];
                       return ca < cb || (ca == cb && a < b);
                     });
    const int left = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    nodes_.emplace_back();
    nodes_[static_cast<std::size_t>(node_index)].first = left;
    nodes_[static_cast<std::size_t>(node_index)].count = 0;
    BuildNode(left, begin, mid, depth + 1);
    BuildNode(left + 1, mid, end, depth + 1);
  }

  // Fabric: a tartan sett (a repeating sequence of stripes, each a thread
  // colour and a number of threads), the same across the warp and the weft.
  void MakeSett(std::uint64_t seed) {
    const int stripes = 3 + static_cast<int>(ToUnit(Hash(seed, 1)) * 3);  // 3…5
    int colour = static_cast<int>(ToUnit(Hash(seed, 2)) * kNumThreadColours);
    for (int i = 0; i < stripes; ++i) {
      colour = (colour + 1 + static_cast<int>(ToUnit(Hash(seed, 10 + i)) * 3)) %
               kNumThreadColours;  // never the previous stripe's colour
      const int threads = 4 + static_cast<int>(ToUnit(Hash(seed, 20 + i)) * 21);  // 4…24
      sett_.insert(sett_.end(), static_cast<std::size_t>(threads), colour);
    }
  }

  V3 Thread(std::int64_t index) const {
    const auto n = static_cast<std::int64_t>(sett_.size());
    return kThreadColours[sett_[static_cast<std::size_t>(((index % n) + n) % n)]];
  }

  // Woven tartan in the plane across the normal's largest component
  // (a seam where that changes, as where cloth is cut and sewn).
  V3 Fabric(const V3& p, const V3& normal) const {
    const double ax = std::abs(normal.x), ay = std::abs(normal.y), az = std::abs(normal.z);
    double u = p.x, v = p.y;
    if (ax >= ay && ax >= az) {
      u = p.y;
      v = p.z;
    } else if (ay >= az) {
      v = p.z;
    }
    const WeaveSample w = PlainWeave(u, v, kFabricPitchMm);
    const V3 colour = w.warp_on_top ? Thread(w.warp) : Thread(w.weft);
    const double fold = Fbm3(SubSeed(seed_, 401), p.x / 12, p.y / 12, p.z / 12, 3);
    const double fibre = CellNoise2(SubSeed(seed_, 402), u / 0.15, v / 0.15);
    return colour * ((0.55 + 0.45 * w.crown) * (0.8 + 0.4 * fold) * (0.85 + 0.3 * fibre));
  }

  static constexpr int kLeafSize = 4;
  static constexpr double kFabricPitchMm = 0.5;

  MeshSurface surface_;
  std::uint64_t seed_;
  std::vector<V3> vertices_, normals_;
  std::vector<std::array<int, 3>> triangles_;
  std::vector<Node> nodes_;
  std::vector<int> order_;
  std::vector<V3> centroids_;  // build only
  std::vector<Box3> boxes_;    // build only
  V3 base_colour_;
  std::optional<WoodTexture> wood_;
  std::optional<PaintedPattern> paint_;
  double half_height_ = 1;
  std::vector<int> sett_;  // thread colour index per thread of one repeat
};

}  // namespace

std::unique_ptr<Primitive> MakeMesh(std::vector<cv::Vec3d> vertices_mm,
                                    std::vector<cv::Vec3i> triangles, MeshSurface surface,
                                    std::uint64_t seed) {
  return std::make_unique<MeshShape>(vertices_mm, triangles, surface, seed);
}

}  // namespace craftscan::sim
