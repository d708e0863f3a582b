#include "texture.h"

namespace craftscan::sim {
namespace {

inline double Fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }

inline double Lattice2(std::uint64_t seed, std::int64_t x, std::int64_t y) {
  return ToUnit(Hash(seed, x, y));
}
inline double Lattice3(std::uint64_t seed, std::int64_t x, std::int64_t y, std::int64_t z) {
  return ToUnit(Hash(seed, x, y, z));
}

}  // namespace

double ValueNoise2(std::uint64_t seed, double x, double y) {
  const double fx = std::floor(x), fy = std::floor(y);
  const auto ix = static_cast<std::int64_t>(fx), iy = static_cast<std::int64_t>(fy);
  const double u = Fade(x - fx), v = Fade(y - fy);
  const double a = Lattice2(seed, ix, iy), b = Lattice2(seed, ix + 1, iy);
  const double c = Lattice2(seed, ix, iy + 1), d = Lattice2(seed, ix + 1, iy + 1);
  return (a + (b - a) * u) + ((c + (d - c) * u) - (a + (b - a) * u)) * v;
}

double ValueNoise3(std::uint64_t seed, double x, double y, double z) {
  const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
  const auto ix = static_cast<std::int64_t>(fx), iy = static_cast<std::int64_t>(fy),
             iz = static_cast<std::int64_t>(fz);
  const double u = Fade(x - fx), v = Fade(y - fy), w = Fade(z - fz);
  double plane[2];
  for (int k = 0; k < 2; ++k) {
    const double a = Lattice3(seed, ix, iy, iz + k), b = Lattice3(seed, ix + 1, iy, iz + k);
    const double c = Lattice3(seed, ix, iy + 1, iz + k), d = Lattice3(seed, ix + 1, iy + 1, iz + k);
    const double ab = a + (b - a) * u, cd = c + (d - c) * u;
    plane[k] = ab + (cd - ab) * v;
  }
  return plane[0] + (plane[1] - plane[0]) * w;
}

double Fbm2(std::uint64_t seed, double x, double y, int octaves) {
  double sum = 0, amplitude = 1, total = 0, scale = 1;
  for (int i = 0; i < octaves; ++i) {
    sum +=
        amplitude * ValueNoise2(Mix64(seed + static_cast<std::uint64_t>(i)), x * scale, y * scale);
    total += amplitude;
    amplitude *= 0.5;
    scale *= 2;
  }
  return sum / total;
}

double Fbm3(std::uint64_t seed, double x, double y, double z, int octaves) {
  double sum = 0, amplitude = 1, total = 0, scale = 1;
  for (int i = 0; i < octaves; ++i) {
    sum += amplitude * ValueNoise3(Mix64(seed + static_cast<std::uint64_t>(i)), x * scale,
                                   y * scale, z * scale);
    total += amplitude;
    amplitude *= 0.5;
    scale *= 2;
  }
  return sum / total;
}

}  // namespace craftscan::sim
