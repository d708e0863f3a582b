// Seeded procedural noise. Every value is a pure function of the seed and the
// coordinates (integer lattice points hashed with SplitMix64), so textures
// are identical whatever the thread count or evaluation order.
#pragma once

#include <cmath>
#include <cstdint>

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

}  // namespace craftscan::sim
