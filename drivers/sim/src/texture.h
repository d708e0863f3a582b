// Seeded procedural noise, and the materials made of it that several
// objects share (weave, wood, painted pattern). Every value is a pure
// function of the seed and the coordinates (integer lattice points hashed
// with SplitMix64), so textures are identical whatever the thread count or
// evaluation order.
#pragma once

#include <cmath>
#include <cstdint>

#include "math.h"

namespace craftscan::sim {

inline std::uint64_t Mix64(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}
// One SplitMix64 round over a linear combination of the coordinates with odd
// 64-bit constants: cheap, and ample for texture noise.
inline std::uint64_t Hash(std::uint64_t seed, std::int64_t a) {
  return Mix64(seed ^ (static_cast<std::uint64_t>(a) * 0xd6e8feb86659fd93ULL));
}
inline std::uint64_t Hash(std::uint64_t seed, std::int64_t a, std::int64_t b) {
  return Mix64(seed ^ (static_cast<std::uint64_t>(a) * 0xd6e8feb86659fd93ULL +
                       static_cast<std::uint64_t>(b) * 0xa0761d6478bd642fULL));
}
inline std::uint64_t Hash(std::uint64_t seed, std::int64_t a, std::int64_t b, std::int64_t c) {
  return Mix64(seed ^ (static_cast<std::uint64_t>(a) * 0xd6e8feb86659fd93ULL +
                       static_cast<std::uint64_t>(b) * 0xa0761d6478bd642fULL +
                       static_cast<std::uint64_t>(c) * 0xe7037ed1a0b428dbULL));
}
// [0, 1) from the top 53 bits.
inline double ToUnit(std::uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

// Value noise on the unit lattice with quintic interpolation, in [0, 1].
double ValueNoise2(std::uint64_t seed, double x, double y);
double ValueNoise3(std::uint64_t seed, double x, double y, double z);
// Fractal sums of value noise (gain 0.5, lacunarity 2), normalized to [0, 1].
double Fbm2(std::uint64_t seed, double x, double y, int octaves);
double Fbm3(std::uint64_t seed, double x, double y, double z, int octaves);
// Uniform [0, 1) constant over each unit cell (speckle).
inline double CellNoise2(std::uint64_t seed, double x, double y) {
  return ToUnit(Hash(seed, static_cast<std::int64_t>(std::floor(x)),
                     static_cast<std::int64_t>(std::floor(y))));
}

// A sub-seed for one use (texture layer, face, ...) of a scene seed.
inline std::uint64_t SubSeed(std::uint64_t seed, std::uint64_t purpose) {
  return Mix64(seed * 0x100000001b3ULL ^ Mix64(purpose));
}

// ---------------------------------------------------------------- materials

// Colours are BGR albedos in [0, 1].

// Traditional egg dyes (the egg's and the painted mesh's palette).
inline constexpr V3 kDyeColours[] = {
    {0.08, 0.09, 0.55},  // madder red
    {0.04, 0.04, 0.05},  // black
    {0.10, 0.62, 0.85},  // yellow
    {0.80, 0.82, 0.82},  // white
    {0.08, 0.35, 0.80},  // orange
    {0.15, 0.45, 0.12},  // green
    {0.55, 0.25, 0.08},  // blue
};
inline constexpr int kNumDyeColours = 7;

// Embroidery threads (the embroidery's and the fabric mesh's colours).
inline constexpr V3 kThreadColours[] = {
    {0.10, 0.10, 0.70},  // red
    {0.08, 0.05, 0.38},  // deep red
    {0.15, 0.65, 0.85},  // gold
    {0.65, 0.35, 0.12},  // blue
    {0.20, 0.50, 0.15},  // green
    {0.04, 0.04, 0.04},  // black
    {0.85, 0.86, 0.86},  // white
    {0.55, 0.25, 0.55},  // purple
};
inline constexpr int kNumThreadColours = 8;
inline constexpr int kWhiteThread = 6;

// Plain weave at plane coordinates (u, v), mm: threads `pitch_mm` apart,
// warp threads along v (index floor(u / pitch)), weft along u (index
// floor(v / pitch)), each passing over and under the other alternately.
struct WeaveSample {
  bool warp_on_top = true;
  std::int64_t warp = 0, weft = 0;  // thread indices
  double crown = 0;  // 4·a·(1 − a) across the top thread: 1 on its middle, 0 at gaps
};
inline WeaveSample PlainWeave(double u, double v, double pitch_mm) {
  const double fu = u / pitch_mm, fv = v / pitch_mm;
  const double iu = std::floor(fu), iv = std::floor(fv);
  WeaveSample s;
  s.warp_on_top = (static_cast<std::int64_t>(iu + iv) & 1) == 0;
  s.warp = static_cast<std::int64_t>(iu);
  s.weft = static_cast<std::int64_t>(iv);
  const double across = s.warp_on_top ? fu - iu : fv - iv;
  s.crown = 4 * across * (1 - across);
  return s;
}

// Wood: growth rings around a log axis, at a seeded slant of 12…32° to the
// x axis in the x–z plane (boards are rarely cut exactly along the grain)
// through `log_point` (mm; below and behind the piece, so the rings sweep
// across it), wobbling with noise; fibres along the axis; open pores as
// dark flecks. Solid: a function of the point (mm) alone.
class WoodTexture {
 public:
  WoodTexture(std::uint64_t seed, const V3& log_point);
  V3 Albedo(const V3& p) const;
  // A fresh cut (the carved box's chips) is lighter than the aged surface.
  static constexpr V3 kFreshCut{0.42, 0.62, 0.80};

 private:
  std::uint64_t seed_;
  V3 log_axis_, log_point_;
};

// The pysanka-style painted pattern of the egg, on a body of revolution
// about the z axis with semi-axes a (horizontal) and c (vertical), centred
// at z = c: latitude bands with a zigzag and rows of dots, meridians, a
// rosette in each segment and a star at each pole, in dye colours picked by
// the seed.
class PaintedPattern {
 public:
  PaintedPattern(std::uint64_t seed, double a_mm, double c_mm);
  // At latitude `lat` ∈ [−π/2, π/2] and longitude `lon` (rad) of a surface
  // point p (mm), `ring_radius_mm` from the axis (line widths in mm along
  // the parallels use it; on the egg a·cos(lat)); mottled by noise at p.
  V3 Albedo(const V3& p, double lat, double lon, double ring_radius_mm) const;

 private:
  struct Palette {
    V3 background, line, accent1, accent2, dot;
  };
  V3 Pattern(double lat, double lon, double ring_radius_mm) const;
  // Arc length (mm) along a meridian for a latitude difference.
  double LatMm(double dlat) const { return 0.5 * (a_ + c_) * dlat; }

  double a_, c_;
  std::uint64_t seed_;
  Palette palette_;
  int meridians_, zigzag_teeth_, petals_;
  double band_lat_;
};

}  // namespace craftscan::sim
