// Solids with relief: the carved box and the embroidery disc. Each is an
// implicit solid F(p) ≥ 0 (F is Lipschitz with a known bound) inside an
// axis-aligned bounding box; rays are marched with conservative steps
// (sphere tracing, never shorter than a minimum step) and the crossing is
// refined to 1e-7 mm. Images and ground truth use the same intersection, so
// the ground truth is exactly what is rendered. A shadow ray (Occludes) is
// marched the same way and not refined: it only asks whether it crosses.
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <vector>

#include "shapes.h"
#include "texture.h"

namespace craftscan::sim {
namespace {

constexpr double kPi = std::numbers::pi;

inline double Hypot(double a, double b) { return std::sqrt(a * a + b * b); }

class MarchedSolid : public Primitive {
 public:
  MarchedSolid(V3 lo, V3 hi, double lipschitz, double min_step_mm)
      : Primitive(SurfaceLabel::kObject),
        lo_(lo),
        hi_(hi),
        lipschitz_(lipschitz),
        min_step_mm_(min_step_mm) {}

  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    Crossing c;
    switch (March(o, d, t_min, t_max, &c)) {
      case Marched::kMiss:
        return false;
      case Marched::kAtEntry:
        hit->t = c.t_in;
        break;
      case Marched::kCrossed:
        hit->t = Refine(o, d, c.t_out, c.f_out, c.t_in, c.f_in, c.length);
        break;
    }
    hit->p = o + d * hit->t;
    return true;
  }

  // Whether the ray crosses the surface in (t_min, t_max): the same march
  // as Intersect, without refining where (a shadow ray needs no more).
  bool Occludes(const V3& o, const V3& d, double t_min, double t_max) const override {
    Crossing c;
    return March(o, d, t_min, t_max, &c) != Marched::kMiss;
  }

 protected:
  // ≥ 0 inside the solid; |∇F| ≤ lipschitz within the bounding box.
  virtual double Field(const V3& p) const = 0;
  // A bound on |dF/ds| along the unit direction u (≤ the isotropic one).
  virtual double RayLipschitz(const V3& /*u*/) const { return lipschitz_; }

  // Outward normal from the field's gradient.
  V3 FieldNormal(const V3& p) const {
    constexpr double h = 1e-4;  // mm
    const V3 g((Field(p + V3(h, 0, 0)) - Field(p - V3(h, 0, 0))),
               (Field(p + V3(0, h, 0)) - Field(p - V3(0, h, 0))),
               (Field(p + V3(0, 0, h)) - Field(p - V3(0, 0, h))));
    const double n = Norm(g);
    return n > 0 ? -g / n : V3(0, 0, 1);
  }

 private:
  static constexpr int kMaxSteps = 20000;

  enum class Marched { kMiss, kAtEntry, kCrossed };
  // kAtEntry: F ≥ 0 where the ray enters the bounding box, at t_in;
  // kCrossed: F < 0 at t_out and ≥ 0 at t_in (with the values f_out, f_in).
  struct Crossing {
    double t_out = 0, f_out = 0, t_in = 0, f_in = 0, length = 0;
  };

  Marched March(const V3& o, const V3& d, double t_min, double t_max, Crossing* c) const {
    double t0 = t_min, t1 = t_max;
    for (int a = 0; a < 3; ++a) {
      const double oa = o[a], da = d[a];
      if (da == 0) {
        if (oa < lo_[a] || oa > hi_[a]) return Marched::kMiss;
        continue;
      }
      double ta = (lo_[a] - oa) / da, tb = (hi_[a] - oa) / da;
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
      if (t0 > t1) return Marched::kMiss;
    }
    const double length = Norm(d);
    const double lipschitz = RayLipschitz(d / length);
    double t = t0;
    double f = Field(o + d * t);
    if (f >= 0) {  // on the bounding box's surface (an uncut face) or starting inside
      if (!(t > t_min)) return Marched::kMiss;
      c->t_in = t;
      return Marched::kAtEntry;
    }
    for (int step = 0; step < kMaxSteps; ++step) {
      double tn = t + std::max(-f / lipschitz, min_step_mm_) / length;
      const bool last = tn >= t1;
      if (last) tn = t1;
      const double fn = Field(o + d * tn);
      if (fn >= 0) {
        *c = {t, f, tn, fn, length};
        return Marched::kCrossed;
      }
      if (last) return Marched::kMiss;
      t = tn;
      f = fn;
    }
    return Marched::kMiss;
  }

  // Illinois regula falsi between t_out (F < 0) and t_in (F ≥ 0); returns a
  // point with F ≥ 0 within 1e-7 mm of the crossing.
  double Refine(const V3& o, const V3& d, double t_out, double f_out, double t_in, double f_in,
                double length) const {
    int side = 0;
    for (int i = 0; i < 100 && (t_in - t_out) * length > 1e-7; ++i) {
      double tm = t_out - f_out * (t_in - t_out) / (f_in - f_out);
      if (!(tm > t_out && tm < t_in)) tm = 0.5 * (t_out + t_in);
      const double fm = Field(o + d * tm);
      if (fm >= 0) {
        t_in = tm;
        f_in = fm;
        if (side == 1) f_out *= 0.5;
        side = 1;
      } else {
        t_out = tm;
        f_out = fm;
        if (side == -1) f_in *= 0.5;
        side = -1;
      }
    }
    return t_in;
  }

  V3 lo_, hi_;
  double lipschitz_, min_step_mm_;
};

// --- carved box ---------------------------------------------------------

// A chip-carved rosette: two circular V-grooves joined by radial spokes,
// a triangular chip in every sector between the spokes, a dimple inside.
struct Rosette {
  double ca = 0, cb = 0;  // centre in face coordinates (mm)
  double r_out = 10, r_in = 5;
  int spokes = 8;
  double phase = 0;
  double dimple_r = 3;
  // Precomputed: spoke directions, and per sector the chip's three edge
  // lines as inward unit normal (nx, ny) and offset c (inside: n·p − c > 0).
  std::vector<double> spoke_cos, spoke_sin;
  std::vector<std::array<double, 9>> chip_edges;

  void Precompute(double groove_w) {
    const double sector = 2 * kPi / spokes;
    const double gap = groove_w + 0.6;
    const double delta = gap / r_out;
    spoke_cos.clear();
    spoke_sin.clear();
    chip_edges.clear();
    for (int k = 0; k < spokes; ++k) {
      const double a = phase + k * sector;
      spoke_cos.push_back(std::cos(a));
      spoke_sin.push_back(std::sin(a));
      // Counter-clockwise triangle: inner middle, outer start, outer end.
      const double ta = a + 0.5 * sector, tb = a + delta, tc = a + sector - delta;
      const double ra = r_in + gap, rb = r_out - gap;
      const double px[3] = {ra * std::cos(ta), rb * std::cos(tb), rb * std::cos(tc)};
      const double py[3] = {ra * std::sin(ta), rb * std::sin(tb), rb * std::sin(tc)};
      std::array<double, 9> edges;
      for (int e = 0; e < 3; ++e) {
        const int f = (e + 1) % 3;
        const double ex = px[f] - px[e], ey = py[f] - py[e];
        const double len = std::sqrt(ex * ex + ey * ey);
        const double nx = -ey / len, ny = ex / len;  // left of the edge = inside
        edges[static_cast<std::size_t>(3 * e)] = nx;
        edges[static_cast<std::size_t>(3 * e + 1)] = ny;
        edges[static_cast<std::size_t>(3 * e + 2)] = nx * px[e] + ny * py[e];
      }
      chip_edges.push_back(edges);
    }
  }
  int Wrap(double k) const {
    const int i = static_cast<int>(k) % spokes;
    return i < 0 ? i + spokes : i;
  }
};

// Everything about one face's carving; H(a, b) ∈ [0, 1] is the cut depth as
// a fraction of the relief depth at face coordinates (a, b) from the centre.
struct CarvedFace {
  V3 n, u, v, centre;     // outward normal, in-plane axes, centre (box frame)
  double hu = 0, hv = 0;  // half extents along u, v
  double depth = 0;       // relief depth; 0 = not carved
  double inset = 5;       // border groove inset from the edges
  double groove_w = 1.2;  // V-groove half-width (cut to full depth on its centre line)
  double chip_w = 1.5;    // chips reach full depth this far inside their outline
  std::vector<Rosette> rosettes;

  double Offset() const { return Dot(n, centre); }

  double Carve(double a, double b) const {
    if (depth <= 0) return 0;
    // Border groove along a rectangle inset from the face edges.
    const double ex = std::abs(a) - (hu - inset), ey = std::abs(b) - (hv - inset);
    const double outside = Hypot(std::max(ex, 0.0), std::max(ey, 0.0));
    const double sd = outside + std::min(std::max(ex, ey), 0.0);
    double h = 1 - std::abs(sd) / groove_w;
    for (const Rosette& r : rosettes) {
      const double dx = a - r.ca, dy = b - r.cb;
      const double rad = Hypot(dx, dy);
      if (rad > r.r_out + groove_w) continue;
      h = std::max(h, 1 - std::abs(rad - r.r_out) / groove_w);
      h = std::max(h, 1 - std::abs(rad - r.r_in) / groove_w);
      h = std::max(h, 1 - (rad / r.dimple_r) * (rad / r.dimple_r));
      if (rad < r.r_in - groove_w) continue;
      const double sector = 2 * kPi / r.spokes;
      const double phi = std::atan2(dy, dx) - r.phase;
      // Nearest spoke (a radial segment from r_in to r_out).
      const int ks = r.Wrap(std::round(phi / sector));
      const double cs = r.spoke_cos[static_cast<std::size_t>(ks)];
      const double ss = r.spoke_sin[static_cast<std::size_t>(ks)];
      const double along = dx * cs + dy * ss, across = -dx * ss + dy * cs;
      const double clamped = std::clamp(along, r.r_in, r.r_out);
      h = std::max(h, 1 - Hypot(along - clamped, across) / groove_w);
      // Chip: a triangle in this sector (convex: the inside distance is the
      // smallest distance to its edge lines).
      const auto& e = r.chip_edges[static_cast<std::size_t>(r.Wrap(std::floor(phi / sector)))];
      const double inside = std::min({e[0] * dx + e[1] * dy - e[2], e[3] * dx + e[4] * dy - e[5],
                                      e[6] * dx + e[7] * dy - e[8]});
      h = std::max(h, std::min(inside / chip_w, 1.0));
    }
    return std::clamp(h, 0.0, 1.0);
  }
  // Lipschitz constant of Carve (per mm).
  double CarveSlope() const {
    double s = std::max(1 / groove_w, 1 / chip_w);
    for (const Rosette& r : rosettes) s = std::max(s, 2 / r.dimple_r);
    return s;
  }
};

class CarvedBox : public MarchedSolid {
 public:
  CarvedBox(const CarvedBoxOptions& o, std::array<CarvedFace, 6> faces, double slope,
            double lipschitz, std::uint64_t seed)
      : MarchedSolid(V3(-o.width_mm / 2, -o.depth_mm / 2, 0),
                     V3(o.width_mm / 2, o.depth_mm / 2, o.height_mm), lipschitz, 0.05),
        faces_(faces),
        slope_(slope),
        wood_(seed, V3(0, -1.3 * o.depth_mm, -0.6 * o.height_mm)),
        half_w_(o.width_mm / 2),
        half_d_(o.depth_mm / 2),
        height_(o.height_mm) {}

  // The cuts lie inside the faces, away from the edges: the corners are the box's.
  double MinAlong(const V3& n) const override {
    return -half_w_ * std::abs(n.x) - half_d_ * std::abs(n.y) + std::min(0.0, height_ * n.z);
  }

  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    const V3& p = hit.p;
    *normal = FieldNormal(p);
    // Cut depth at the hit: the deepest cut of the faces within reach.
    double cut = 0;
    for (const CarvedFace& f : faces_) {
      const double s = f.Offset() - Dot(f.n, p);
      if (f.depth > 0 && s < f.depth + 1e-6) {
        const V3 rel = p - f.centre;
        cut = std::max(cut, f.Carve(Dot(rel, f.u), Dot(rel, f.v)));
      }
    }
    // Wood (the log axis below and behind the box); fresh cuts are lighter.
    V3 colour = wood_.Albedo(p);
    colour = Lerp(colour, WoodTexture::kFreshCut, 0.55 * SmoothStep(0.02, 0.35, cut));
    *albedo = colour;
  }

 protected:
  // Face term s − depth·H changes by ≤ |n·u| + depth·slope·|u − (n·u)n|.
  double RayLipschitz(const V3& u) const override {
    double bound = 1;
    for (const CarvedFace& face : faces_) {
      const double normal = std::abs(Dot(face.n, u));
      const double tangential = std::sqrt(std::max(0.0, 1 - normal * normal));
      bound = std::max(bound, normal + face.depth * slope_ * tangential);
    }
    return 1.1 * bound;
  }

  double Field(const V3& p) const override {
    double f = 1e9;
    for (const CarvedFace& face : faces_) {
      const double s = face.Offset() - Dot(face.n, p);
      if (face.depth > 0 && s < face.depth) {
        const V3 rel = p - face.centre;
        f = std::min(f, s - face.depth * face.Carve(Dot(rel, face.u), Dot(rel, face.v)));
      } else {
        // Beyond the cuts' reach: s − depth ≤ the true term, and ≥ 0 here.
        f = std::min(f, s - face.depth);
      }
    }
    return f;
  }

 private:
  std::array<CarvedFace, 6> faces_;
  double slope_;  // the largest CarveSlope of the faces
  WoodTexture wood_;
  double half_w_, half_d_, height_;
};

// Rosettes for a face of half extents hu × hv inside its border groove.
std::vector<Rosette> LayOutRosettes(double hu, double hv, double inset, double groove_w,
                                    std::uint64_t seed) {
  std::vector<Rosette> out;
  const double free_u = hu - inset - groove_w - 1.5, free_v = hv - inset - groove_w - 1.5;
  if (free_u < 6 || free_v < 6) return out;
  const bool along_u = free_u >= free_v;
  const double longer = along_u ? free_u : free_v, shorter = along_u ? free_v : free_u;
  const int count = std::max(1, static_cast<int>(std::floor(longer / shorter + 0.35)));
  const double radius = std::min(shorter, longer / count);
  for (int i = 0; i < count; ++i) {
    Rosette r;
    const double offset = -longer + radius * (2 * i + 1);
    r.ca = along_u ? offset : 0;
    r.cb = along_u ? 0 : offset;
    r.r_out = radius - groove_w - 0.3;
    r.r_in = r.r_out * (0.4 + 0.15 * ToUnit(Hash(seed, 10 * i + 1)));
    r.spokes = 6 + 2 * static_cast<int>(ToUnit(Hash(seed, 10 * i + 2)) * 4);  // 6…12
    r.phase = 2 * kPi * ToUnit(Hash(seed, 10 * i + 3));
    r.dimple_r = std::max(2.0, r.r_in - groove_w - 0.8);
    r.Precompute(groove_w);
    if (r.r_out > r.r_in + 2 * groove_w + 1.5) out.push_back(r);
  }
  return out;
}

// --- embroidery ---------------------------------------------------------

struct Stitch {
  double height = 0;  // H ∈ [0, 1]
  V3 colour;
};

class Embroidery : public MarchedSolid {
 public:
  Embroidery(const EmbroideryOptions& o, std::uint64_t seed, double lipschitz)
      : MarchedSolid(V3(-o.diameter_mm / 2, -o.diameter_mm / 2, 0),
                     V3(o.diameter_mm / 2, o.diameter_mm / 2, o.thickness_mm + o.relief_mm),
                     lipschitz, 0.05),
        radius_(o.diameter_mm / 2),
        thickness_(o.thickness_mm),
        relief_(o.relief_mm),
        seed_(seed) {
    petals_ = 5 + static_cast<int>(ToUnit(Hash(seed, 200)) * 4);  // 5…8
    phase_ = 2 * kPi * ToUnit(Hash(seed, 201));
    const int base = static_cast<int>(ToUnit(Hash(seed, 202)) * kNumThreadColours);
    for (int i = 0; i < 5; ++i) colours_[i] = kThreadColours[(base + 3 * i) % kNumThreadColours];
    dark_fabric_ = ToUnit(Hash(seed, 203)) < 0.35;
    if (dark_fabric_) {  // light threads show on dark cloth
      for (V3& c : colours_) {
        if (c.x + c.y + c.z < 0.3) c = kThreadColours[kWhiteThread];
      }
    }
    flower_r_ = 0.52 * radius_;
    centre_r_ = 0.2 * flower_r_;
    const double sector = 2 * kPi / petals_;
    petal_a_ = 0.5 * (flower_r_ - centre_r_);
    // Petal half-width: 90 % of the sector's at its middle, at most 0.85·a.
    petal_b_ = std::min(0.9 * (centre_r_ + petal_a_) * std::tan(0.5 * sector), 0.85 * petal_a_);
    ring_threads_ = std::round(2 * kPi * 0.85 * radius_ / kThreadW);
    ring_knots_ = std::round(2 * kPi * 0.73 * radius_ / 2.2);
    for (int k = 0; k < petals_; ++k) {
      petal_cos_.push_back(std::cos(phase_ + k * sector));
      petal_sin_.push_back(std::sin(phase_ + k * sector));
      leaf_cos_.push_back(std::cos(phase_ + (k + 0.5) * sector));
      leaf_sin_.push_back(std::sin(phase_ + (k + 0.5) * sector));
    }
  }

  // The disc's cylinder from z = 0 to the stitches' highest (a bound where
  // the stitches do not reach the rim: within relief_mm).
  double MinAlong(const V3& n) const override {
    return std::min(0.0, (thickness_ + relief_) * n.z) - radius_ * std::hypot(n.x, n.y);
  }

  // Satin ridges are at most this steep, per mm of H (see Pattern).
  // Lipschitz constant of the stitch height H (per mm), the steepest region:
  // satin ridges (1 − s², slope ≤ 4/thread width, ×1.15 for the ring's arc
  // scaling, weight 0.8) rising over kEdge at their outline; knots (slope
  // ≤ 2/radius) also rise over kEdge in the flower centre.
  static double PatternSlope() {
    return std::max(1 / kEdge + 0.8 * 1.15 * 4 / kThreadW, 1 / kEdge + 2 / kKnotR);
  }

  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    const V3& p = hit.p;
    *normal = FieldNormal(p);
    const double rho = Hypot(p.x, p.y);
    if (p.z < thickness_ - 1e-6 || rho > radius_ - 1e-6) {  // side of the disc
      *albedo = dark_fabric_ ? V3(0.05, 0.05, 0.12) : V3(0.55, 0.66, 0.7);
      return;
    }
    *albedo = Pattern(p.x, p.y, true).colour;
  }

 protected:
  // The top term changes by ≤ |u_z| + relief·slope·|u_xy| along u; the
  // others by ≤ 1.
  double RayLipschitz(const V3& u) const override {
    const double horizontal = std::sqrt(std::max(0.0, 1 - u.z * u.z));
    return 1.1 * std::max(1.0, std::abs(u.z) + relief_ * PatternSlope() * horizontal);
  }

  double Field(const V3& p) const override {
    const double rho = Hypot(p.x, p.y);
    const double top = thickness_ + relief_ * Pattern(p.x, p.y, false).height;
    return std::min({radius_ - rho, p.z, top - p.z});
  }

 private:
  static constexpr double kThreadW = 0.7;   // satin thread spacing (mm)
  static constexpr double kEdge = 0.35;     // stitches rise to full height over this (mm)
  static constexpr double kKnotR = 0.45;    // French knot radius (mm)
  static constexpr double kFabricH = 0.12;  // weave relief as a fraction of relief_mm

  // Satin: threads along `along`, side by side across; `across` in mm.
  static double SatinRidge(double across) {
    const double q = across / kThreadW;
    const double s = 2 * (q - std::floor(q)) - 1;
    return 1 - s * s;
  }
  static double ThreadShade(double along, double across, double ridge) {
    const double turn = along / 0.3 + across / kThreadW;
    const double f = turn - std::floor(turn);
    const double twist = 16 * f * f * (1 - f) * (1 - f);  // fibre twist, one bump per turn
    return (0.78 + 0.22 * ridge) * (0.92 + 0.08 * twist);
  }

  Stitch Pattern(double x, double y, bool want_colour) const {
    Stitch out;
    // Linen weave everywhere.
    const double weave = PlainWeave(x, y, 0.4).crown;  // thread cross-section
    out.height = kFabricH * (0.5 + 0.5 * weave);
    if (want_colour) {
      const V3 cloth = dark_fabric_ ? V3(0.05, 0.04, 0.16) : V3(0.68, 0.80, 0.85);
      out.colour =
          cloth * (0.8 + 0.2 * weave) * (0.93 + 0.14 * Fbm2(SubSeed(seed_, 210), x / 6, y / 6, 2));
    }
    const double rho = Hypot(x, y);
    auto take = [&](double h, const V3& colour) {
      if (h > out.height) {
        out.height = h;
        if (want_colour) out.colour = colour;
      }
    };

    // Border ring: satin across the ring (threads radial).
    const double b0 = 0.80 * radius_, b1 = 0.90 * radius_;
    if (rho > b0 && rho < b1) {
      const double edge = std::min(1.0, std::min(rho - b0, b1 - rho) / kEdge);
      // A whole number of threads around the ring: no seam.
      const double across = std::atan2(y, x) * ring_threads_ * kThreadW / (2 * kPi);
      const double ridge = SatinRidge(across);
      take(edge * (0.25 + 0.75 * ridge), colours_[0] * ThreadShade(rho, across, ridge));
      return out;
    }
    // Ring of French knots.
    const double dots_r = 0.73 * radius_;
    if (std::abs(rho - dots_r) < kKnotR) {
      const double phi = std::atan2(y, x);
      const double spacing = 2 * kPi / ring_knots_;
      const double k = std::round(phi / spacing);
      const double du = (phi - k * spacing) * dots_r, dv = rho - dots_r;
      const double d2 = (du * du + dv * dv) / (kKnotR * kKnotR);
      if (d2 < 1) take(1 - d2, colours_[3] * (0.8 + 0.2 * (1 - d2)));
      return out;
    }
    // Flower centre: French knots on a hexagonal lattice.
    const double centre_r = centre_r_;
    if (rho < centre_r) {
      const double edge = std::min(1.0, (centre_r - rho) / kEdge);
      const double sx = 1.0, sy = 0.866;
      const double j = std::round(y / sy);
      const double i = std::round(x / sx - 0.5 * (static_cast<std::int64_t>(j) & 1));
      const double du = x - (i + 0.5 * (static_cast<std::int64_t>(j) & 1)) * sx;
      const double dv = y - j * sy;
      const double d2 = (du * du + dv * dv) / (kKnotR * kKnotR);
      take(edge * std::max(0.0, 1 - d2), colours_[2] * (0.75 + 0.25 * std::max(0.0, 1 - d2)));
      return out;
    }
    if (rho < flower_r_ + 1) {
      // Petal k: an ellipse along its axis, satin across it, shaded from
      // base to tip (long-and-short look).
      const int petal = Nearest(petal_cos_, petal_sin_, x, y);
      const double ca = petal_cos_[petal], sa = petal_sin_[petal];
      const double along = x * ca + y * sa, side = -x * sa + y * ca;
      const double a = petal_a_, bb = petal_b_;
      const double xi = along - (centre_r + a), q = Hypot(xi / a, side / bb);
      const double inside = (1 - q) * bb;  // ≈ distance inside the outline
      if (inside > 0) {
        const double edge = std::min(1.0, inside / kEdge);
        const double ridge = SatinRidge(along);
        const V3 base = (petal & 1) ? colours_[1] : colours_[4];
        const V3 tip = Lerp(base, V3(0.9, 0.9, 0.9), 0.35);
        const V3 colour = Lerp(base, tip, Clamp01((along - centre_r) / (2 * a)));
        take(edge * (0.2 + 0.8 * ridge), colour * ThreadShade(side, along, ridge));
      }
      return out;
    }
    // Leaves between the petals, satin at 45° to the leaf axis.
    const int leaf = Nearest(leaf_cos_, leaf_sin_, x, y);
    const double cl = leaf_cos_[leaf], sl = leaf_sin_[leaf];
    const double along = x * cl + y * sl - 0.64 * radius_, side = -x * sl + y * cl;
    const double la = 0.07 * radius_, lb = 0.035 * radius_;
    const double q = Hypot(along / la, side / lb);
    const double inside = (1 - q) * lb;
    if (inside > 0) {
      const double edge = std::min(1.0, inside / kEdge);
      const double across = (along + side) * 0.7071;
      const double ridge = SatinRidge(across);
      take(edge * (0.2 + 0.8 * ridge),
           V3(0.18, 0.45, 0.12) * ThreadShade(along - side, across, ridge));
    }
    return out;
  }

  // Index of the axis (unit vectors cos, sin) closest in angle to (x, y).
  static int Nearest(const std::vector<double>& cos, const std::vector<double>& sin, double x,
                     double y) {
    int best = 0;
    double best_dot = -1e300;
    for (std::size_t k = 0; k < cos.size(); ++k) {
      const double dot = x * cos[k] + y * sin[k];
      if (dot > best_dot) {
        best_dot = dot;
        best = static_cast<int>(k);
      }
    }
    return best;
  }

  double radius_, thickness_, relief_;
  std::uint64_t seed_;
  int petals_ = 6;
  std::vector<double> petal_cos_, petal_sin_, leaf_cos_, leaf_sin_;
  double phase_ = 0, flower_r_ = 0, centre_r_ = 0, petal_a_ = 1, petal_b_ = 1;
  double ring_threads_ = 1, ring_knots_ = 1;
  V3 colours_[5];
  bool dark_fabric_ = false;
};

}  // namespace

std::unique_ptr<Primitive> MakeCarvedBox(const CarvedBoxOptions& o, std::uint64_t seed) {
  const double w = o.width_mm, d = o.depth_mm, h = o.height_mm;
  std::array<CarvedFace, 6> faces;
  // +x, −x, +y, −y, top, bottom. Side faces: u horizontal, v up.
  faces[0] = {V3(1, 0, 0), V3(0, 1, 0), V3(0, 0, 1), V3(w / 2, 0, h / 2), d / 2, h / 2};
  faces[1] = {V3(-1, 0, 0), V3(0, -1, 0), V3(0, 0, 1), V3(-w / 2, 0, h / 2), d / 2, h / 2};
  faces[2] = {V3(0, 1, 0), V3(-1, 0, 0), V3(0, 0, 1), V3(0, d / 2, h / 2), w / 2, h / 2};
  faces[3] = {V3(0, -1, 0), V3(1, 0, 0), V3(0, 0, 1), V3(0, -d / 2, h / 2), w / 2, h / 2};
  faces[4] = {V3(0, 0, 1), V3(1, 0, 0), V3(0, 1, 0), V3(0, 0, h), w / 2, d / 2};
  faces[5] = {V3(0, 0, -1), V3(1, 0, 0), V3(0, -1, 0), V3(0, 0, 0), w / 2, d / 2};
  double slope = 0;
  for (int i = 0; i < 5; ++i) {
    CarvedFace& f = faces[static_cast<std::size_t>(i)];
    const std::uint64_t face_seed = SubSeed(seed, 40 + static_cast<std::uint64_t>(i));
    f.depth = o.relief_depth_mm;
    f.inset = 4.5 + 1.5 * ToUnit(Hash(face_seed, 1));
    f.groove_w = 1.0 + 0.4 * ToUnit(Hash(face_seed, 2));
    f.rosettes = LayOutRosettes(f.hu, f.hv, f.inset, f.groove_w, face_seed);
    slope = std::max(slope, f.CarveSlope());
  }
  // |∇(s − depth·H)| ≤ √(1 + (depth·slope)²); 10 % margin.
  const double lipschitz = 1.1 * std::sqrt(1 + std::pow(o.relief_depth_mm * slope, 2));
  return std::make_unique<CarvedBox>(o, faces, slope, lipschitz, seed);
}

std::unique_ptr<Primitive> MakeEmbroidery(const EmbroideryOptions& o, std::uint64_t seed,
                                          Rigid* object_from_disc) {
  const double lift = 0.5 * o.diameter_mm * std::abs(std::sin(o.tilt_rad));
  object_from_disc->R = M3::RotX(o.tilt_rad);
  object_from_disc->t = V3(0, 0, lift);
  const double lipschitz =
      1.1 * std::sqrt(1 + std::pow(o.relief_mm * Embroidery::PatternSlope(), 2));
  return std::make_unique<Embroidery>(o, seed, lipschitz);
}

}  // namespace craftscan::sim
