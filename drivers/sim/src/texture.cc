#include "texture.h"

#include <algorithm>
#include <numbers>

namespace craftscan::sim {
namespace {

constexpr double kPi = std::numbers::pi;

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

// ---------------------------------------------------------------- wood -----

WoodTexture::WoodTexture(std::uint64_t seed, const V3& log_point)
    : seed_(seed), log_point_(log_point) {
  const double slant = (12 + 20 * ToUnit(Hash(seed, 33))) * kPi / 180;
  log_axis_ = V3(std::cos(slant), 0, std::sin(slant));
}

V3 WoodTexture::Albedo(const V3& p) const {
  const V3 rel = p - log_point_;
  const double along = Dot(rel, log_axis_);
  const V3 radial = rel - log_axis_ * along;
  const double wobble = Fbm3(SubSeed(seed_, 30), p.x / 25, p.y / 25, p.z / 25, 3);
  const double ring = Norm(radial) / 2.4 + 3.0 * wobble;
  const double late = SmoothStep(0.55, 0.9, ring - std::floor(ring));
  const V3 across = Cross(log_axis_, V3(0, 1, 0));
  const double fibre =
      ValueNoise3(SubSeed(seed_, 31), along / 4, Dot(rel, across) / 0.25, p.y / 0.25);
  const std::uint64_t cell =
      Hash(SubSeed(seed_, 32), static_cast<std::int64_t>(std::floor(p.x / 0.3)),
           static_cast<std::int64_t>(std::floor(p.y / 0.3)),
           static_cast<std::int64_t>(std::floor(p.z / 0.3)));
  const double pore = ToUnit(cell) > 0.9 ? 0.65 : 1.0;
  const V3 early(0.30, 0.47, 0.66), late_wood(0.13, 0.24, 0.40);
  return Lerp(early, late_wood, 0.85 * late) * ((0.85 + 0.25 * fibre) * pore);
}

// ---------------------------------------------------------------- painted --

PaintedPattern::PaintedPattern(std::uint64_t seed, double a_mm, double c_mm)
    : a_(a_mm), c_(c_mm), seed_(seed) {
  auto pick = [&](int k, int avoid) {
    int i = static_cast<int>(ToUnit(Hash(seed, 100 + k)) * kNumDyeColours) % kNumDyeColours;
    if (i == avoid) i = (i + 1) % kNumDyeColours;
    return i;
  };
  const int bg = pick(0, -1);
  const int line = (bg == 1) ? 3 : 1;  // black lines, white on black
  palette_ = {kDyeColours[bg], kDyeColours[line], kDyeColours[pick(1, bg)],
              kDyeColours[pick(2, bg)], kDyeColours[pick(3, bg)]};
  meridians_ = 4 + 2 * static_cast<int>(ToUnit(Hash(seed, 110)) * 3);  // 4, 6, 8
  zigzag_teeth_ = 2 * meridians_;
  petals_ = 6 + 2 * static_cast<int>(ToUnit(Hash(seed, 111)) * 2);  // 6 or 8
  band_lat_ = 0.38 + 0.12 * ToUnit(Hash(seed, 112));
}

V3 PaintedPattern::Albedo(const V3& p, double lat, double lon, double ring_radius_mm) const {
  return Pattern(lat, lon, ring_radius_mm) *
         (0.9 + 0.2 * Fbm3(SubSeed(seed_, 120), p.x / 1.5, p.y / 1.5, p.z / 1.5, 2));
}

V3 PaintedPattern::Pattern(double lat, double lon, double ring) const {
  auto wrap = [](double angle) { return angle - 2 * kPi * std::round(angle / (2 * kPi)); };
  const double w = 0.45;  // line half-width, mm
  const double band = band_lat_;
  // Equator band edges and the tropic lines.
  for (double edge : {-band, band, -band - 0.12, band + 0.12}) {
    if (std::abs(LatMm(lat - edge)) < w) return palette_.line;
  }
  if (std::abs(lat) < band) {
    // Zigzag across the band, filled above in accent1.
    const double phase = lon * zigzag_teeth_ / (2 * kPi);
    const double tri = 2 * std::abs(phase - std::floor(phase) - 0.5);  // 0…1
    const double zig = -band + 2 * band * tri;
    if (std::abs(LatMm(lat - zig)) < w * 1.2) return palette_.line;
    return lat > zig ? palette_.accent1 : palette_.background;
  }
  if (std::abs(lat) < band + 0.12) {
    // Row of dots between the band and the tropic line.
    const double mid = (lat > 0 ? 1 : -1) * (band + 0.06);
    const double spacing = 2 * kPi / (zigzag_teeth_ * 2);
    const double k = std::round(lon / spacing);
    const double du = ring * (lon - k * spacing), dv = LatMm(lat - mid);
    if (du * du + dv * dv < 1.1 * 1.1) return palette_.dot;
    return palette_.background;
  }
  // Hemispheres: meridians split them into segments, each with a rosette.
  const double seg = 2 * kPi / meridians_;
  const double k = std::round(lon / seg);
  if (std::abs(std::abs(lat) - kPi / 2) > 0.25 && std::abs(ring * (lon - k * seg)) < w) {
    return palette_.line;
  }
  const double sign = lat > 0 ? 1 : -1;
  if (std::abs(lat) > 1.25) {  // polar star
    const double rays = 8;
    const double phase = lon * rays / (2 * kPi);
    const double tri = 2 * std::abs(phase - std::floor(phase) - 0.5);
    const double reach = 1.25 + 0.3 * (1 - tri);
    return std::abs(lat) > reach ? palette_.accent2 : palette_.background;
  }
  const double centre_lat = sign * (band + 0.12 + 1.25) / 2;
  const double centre_lon = (k + 0.5) * seg;  // between meridians
  const double cl = wrap(lon - centre_lon);
  const double du = ring * cl, dv = LatMm(lat - centre_lat);
  const double r = std::sqrt(du * du + dv * dv);
  const double phi = std::atan2(dv, du);
  const double radius = 0.42 * std::min(a_ * std::cos(centre_lat) * seg, LatMm(1.25 - band - 0.12));
  const double petal = radius * (0.45 + 0.55 * std::abs(std::cos(petals_ * phi / 2)));
  if (r < 0.22 * radius) return palette_.dot;
  if (std::abs(r - petal) < w) return palette_.line;
  if (r < petal) return palette_.accent2;
  return palette_.background;
}

}  // namespace craftscan::sim
