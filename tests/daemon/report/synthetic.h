// Synthetic geometry with known projections for the report tests: points on
// a sphere and on a cube's surface, a closed cube mesh and a UV-sphere mesh.
#pragma once

#include <cmath>
#include <cstddef>
#include <random>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::testing {

// `n` points evenly spread over a sphere (Fibonacci lattice) with outward
// normals; colours when `colors`.
inline PointCloud SpherePoints(std::size_t n, const cv::Vec3f& center, float radius, bool colors) {
  PointCloud cloud;
  const double golden = M_PI * (3 - std::sqrt(5.0));
  for (std::size_t i = 0; i < n; ++i) {
    const double z = 1 - 2 * (i + 0.5) / n;
    const double r = std::sqrt(1 - z * z);
    const double phi = golden * i;
    const cv::Vec3f nrm(static_cast<float>(r * std::cos(phi)),
                        static_cast<float>(r * std::sin(phi)), static_cast<float>(z));
    cloud.points_mm.push_back(center + radius * nrm);
    cloud.normals.push_back(nrm);
    if (colors)
      cloud.colors_rgb.push_back(cv::Vec3b(static_cast<uchar>(128 + 120 * nrm[0]),
                                           static_cast<uchar>(128 + 120 * nrm[1]), 90));
  }
  return cloud;
}

// Points uniformly (seeded random) on the surface of an axis-aligned cube of
// side `side` centred at `center`, with outward normals.
inline PointCloud CubePoints(std::size_t n, const cv::Vec3f& center, float side,
                             unsigned seed = 7) {
  PointCloud cloud;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  std::uniform_int_distribution<int> face(0, 5);
  for (std::size_t i = 0; i < n; ++i) {
    const int f = face(rng);
    const int axis = f / 2;
    const float sign = f % 2 ? 0.5f : -0.5f;
    cv::Vec3f p(u(rng), u(rng), u(rng)), nrm(0, 0, 0);
    p[axis] = sign;
    nrm[axis] = sign * 2;
    cloud.points_mm.push_back(center + side * p);
    cloud.normals.push_back(nrm);
  }
  return cloud;
}

// A closed cube mesh (8 vertices, 12 triangles, counter-clockwise seen from
// outside), no normals or colours.
inline TriangleMesh CubeMesh(const cv::Vec3f& center, float side) {
  TriangleMesh mesh;
  for (int i = 0; i < 8; ++i) {
    const cv::Vec3f corner((i & 1) ? 0.5f : -0.5f, (i & 2) ? 0.5f : -0.5f, (i & 4) ? 0.5f : -0.5f);
    mesh.vertices_mm.push_back(center + side * corner);
  }
  // Quads (outward, counter-clockwise) split into two triangles each.
  const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5},   // −x, +x
                           {0, 1, 5, 4}, {2, 6, 7, 3},   // −y, +y
                           {0, 2, 3, 1}, {4, 5, 7, 6}};  // −z, +z
  for (const auto& q : quads) {
    mesh.faces.push_back({q[0], q[1], q[2]});
    mesh.faces.push_back({q[0], q[2], q[3]});
  }
  return mesh;
}

// A UV sphere with `rings` × `segments` quads (2 triangles each), vertex
// normals and colours.
inline TriangleMesh SphereMesh(int rings, int segments, const cv::Vec3f& center, float radius) {
  TriangleMesh mesh;
  for (int r = 0; r <= rings; ++r) {
    const double theta = M_PI * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * M_PI * s / segments;
      const cv::Vec3f n(static_cast<float>(std::sin(theta) * std::cos(phi)),
                        static_cast<float>(std::sin(theta) * std::sin(phi)),
                        static_cast<float>(std::cos(theta)));
      mesh.vertices_mm.push_back(center + radius * n);
      mesh.normals.push_back(n);
      mesh.colors_rgb.push_back(cv::Vec3b(static_cast<uchar>(140 + 100 * n[2]), 150,
                                          static_cast<uchar>(140 - 100 * n[2])));
    }
  }
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const int a = r * segments + s, b = r * segments + (s + 1) % segments;
      const int c = a + segments, d = b + segments;
      mesh.faces.push_back({a, c, d});
      mesh.faces.push_back({a, d, b});
    }
  }
  return mesh;
}

}  // namespace craftscan::testing
