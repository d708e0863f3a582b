// Analytic primitives: table, backdrop, platter, egg, calibration board.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/core.hpp>

#include "shapes.h"
#include "texture.h"

namespace craftscan::sim {
namespace {

constexpr double kPi = std::numbers::pi;

// Fabric and pattern albedo of the table and the backdrop at plane
// coordinates (u, v) in mm.
V3 BackgroundAlbedo(Background background, std::uint64_t seed, double u, double v) {
  if (background == Background::kDarkCloth) {
    // Plain weave, 0.6 mm pitch: warp and weft alternate over/under.
    const double thread = PlainWeave(u, v, 0.6).crown;  // bright crown, dark gaps
    const double fold = Fbm2(SubSeed(seed, 1), u / 40, v / 40, 3);
    const double fibre = CellNoise2(SubSeed(seed, 2), u / 0.2, v / 0.2);
    const double k = (0.55 + 0.45 * thread) * (0.7 + 0.6 * fold) * (0.85 + 0.3 * fibre);
    return V3(0.055, 0.045, 0.045) * k;
  }
  const double b = Fbm2(SubSeed(seed, 3), u / 18, v / 18, 4);
  const double g = Fbm2(SubSeed(seed, 4), u / 18, v / 18, 4);
  const double r = Fbm2(SubSeed(seed, 5), u / 18, v / 18, 4);
  const double speckle = CellNoise2(SubSeed(seed, 6), u / 1.2, v / 1.2);
  const V3 colour(0.1 + 0.75 * b, 0.1 + 0.75 * g, 0.1 + 0.75 * r);
  return colour * (0.7 + 0.45 * speckle);
}

// The table (horizontal, z = const) and the backdrop (vertical, y = const):
// one plane perpendicular to a world axis, facing the rig.
class AxisPlane : public Primitive {
 public:
  enum class Axis { kZ, kY };
  AxisPlane(Axis axis, double offset, Background background, std::uint64_t seed)
      : Primitive(SurfaceLabel::kBackground),
        axis_(axis),
        offset_(offset),
        background_(background),
        seed_(seed) {}
  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    const double dir = axis_ == Axis::kZ ? d.z : d.y;
    if (dir == 0) return false;
    const double t = (offset_ - (axis_ == Axis::kZ ? o.z : o.y)) / dir;
    if (!(t > t_min && t < t_max)) return false;
    hit->t = t;
    hit->p = o + d * t;
    return true;
  }
  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    if (axis_ == Axis::kZ) {
      *normal = V3(0, 0, 1);
      *albedo = BackgroundAlbedo(background_, seed_, hit.p.x, hit.p.y);
    } else {
      *normal = V3(0, -1, 0);
      *albedo = BackgroundAlbedo(background_, SubSeed(seed_, 99), hit.p.x, hit.p.z);
    }
  }

 private:
  Axis axis_;
  double offset_;
  Background background_;
  std::uint64_t seed_;
};

// Platter: a cylinder of radius R from z = −thickness to its top at z = 0.
class Platter : public Primitive {
 public:
  Platter(double radius, double thickness, PlatterTexture texture, std::uint64_t seed)
      : Primitive(SurfaceLabel::kPlatter),
        radius_(radius),
        thickness_(thickness),
        texture_(texture),
        seed_(seed) {
    on_turntable = true;
  }
  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    bool found = false;
    if (d.z != 0) {  // top disc (seen from above only)
      const double t = -o.z / d.z;
      if (t > t_min && t < t_max && d.z < 0) {
        const V3 p = o + d * t;
        if (p.x * p.x + p.y * p.y <= radius_ * radius_) {
          hit->t = t_max = t;
          hit->p = p;
          hit->part = 0;
          found = true;
        }
      }
    }
    const double a = d.x * d.x + d.y * d.y;
    if (a > 0) {  // side wall, from outside
      const double b = o.x * d.x + o.y * d.y;
      const double c = o.x * o.x + o.y * o.y - radius_ * radius_;
      const double disc = b * b - a * c;
      if (disc >= 0) {
        const double t = (-b - std::sqrt(disc)) / a;
        if (t > t_min && t < t_max) {
          const V3 p = o + d * t;
          if (p.z <= 0 && p.z >= -thickness_) {
            hit->t = t;
            hit->p = p;
            hit->part = 1;
            found = true;
          }
        }
      }
    }
    return found;
  }
  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    const V3& p = hit.p;
    if (hit.part == 1) {
      *normal = Normalized(V3(p.x, p.y, 0));
      const double phi = std::atan2(p.y, p.x) * radius_;
      const double brushed = ValueNoise2(SubSeed(seed_, 20), phi / 0.15, p.z / 6);
      *albedo = V3(0.13, 0.13, 0.14) * (0.85 + 0.3 * brushed);
      return;
    }
    *normal = V3(0, 0, 1);
    if (texture_ == PlatterTexture::kPlain) {
      const double f = Fbm2(SubSeed(seed_, 21), p.x / 25, p.y / 25, 3);
      *albedo = V3(0.58, 0.6, 0.6) * (0.97 + 0.06 * f);
      return;
    }
    // Cork: granules of ~0.35 mm over a blotchy base, tan.
    const double grain = CellNoise2(SubSeed(seed_, 22), p.x / 0.35, p.y / 0.35);
    const double grain2 = CellNoise2(SubSeed(seed_, 23), p.x / 0.9 + 0.5, p.y / 0.9 + 0.5);
    const double blotch = Fbm2(SubSeed(seed_, 24), p.x / 4, p.y / 4, 3);
    V3 colour = V3(0.33, 0.47, 0.6) * (0.6 + 0.35 * grain + 0.2 * grain2 + 0.3 * blotch);
    // Degree marks at the rim: every 5°, longer every 30°, and a ring line.
    const double r = std::sqrt(p.x * p.x + p.y * p.y);
    if (r > radius_ - 16) {
      const double angle = std::atan2(p.y, p.x);
      const double step = kPi / 36;
      const double nearest = std::round(angle / step);
      const double dist_mm = std::abs(angle - nearest * step) * r;
      const bool major = static_cast<std::int64_t>(nearest) % 6 == 0;
      const double inner = major ? radius_ - 14 : radius_ - 8;
      const bool tick = r > inner && r < radius_ - 2 && dist_mm < 0.4;
      const bool ring = std::abs(r - (radius_ - 2.5)) < 0.3;
      if (tick || ring) colour = V3(0.05, 0.05, 0.05);
    }
    *albedo = colour;
  }

 private:
  double radius_, thickness_;
  PlatterTexture texture_;
  std::uint64_t seed_;
};

// --- egg ----------------------------------------------------------------

class Egg : public Primitive {
 public:
  Egg(const EggOptions& options, std::uint64_t seed)
      : Primitive(SurfaceLabel::kObject),
        a_(options.diameter_mm / 2),
        c_(options.height_mm / 2),
        paint_(seed, a_, c_) {}

  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    const V3 os(o.x / a_, o.y / a_, (o.z - c_) / c_);
    const V3 ds(d.x / a_, d.y / a_, d.z / c_);
    const double A = Dot(ds, ds), B = Dot(os, ds), C = Dot(os, os) - 1;
    const double disc = B * B - A * C;
    if (disc < 0) return false;
    const double sq = std::sqrt(disc);
    // Stable roots.
    const double q = B > 0 ? -(B + sq) : -(B - sq);
    double t0 = q / A, t1 = q != 0 ? C / q : t0;
    if (t0 > t1) std::swap(t0, t1);
    double t = t0;
    if (!(t > t_min)) t = t1;
    if (!(t > t_min && t < t_max)) return false;
    hit->t = t;
    hit->p = o + d * t;
    return true;
  }

  // The ellipsoid's support: centre (0, 0, c), semi-axes a, a, c.
  double MinAlong(const V3& n) const override {
    return c_ * n.z - std::sqrt(a_ * a_ * (n.x * n.x + n.y * n.y) + c_ * c_ * n.z * n.z);
  }

  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    const V3& p = hit.p;
    *normal = Normalized(V3(p.x / (a_ * a_), p.y / (a_ * a_), (p.z - c_) / (c_ * c_)));
    const V3 q(p.x / a_, p.y / a_, (p.z - c_) / c_);
    const double lat = std::asin(std::clamp(q.z, -1.0, 1.0));
    const double lon = std::atan2(q.y, q.x);
    *albedo = paint_.Albedo(p, lat, lon, a_ * std::cos(lat));
  }

 private:
  double a_, c_;
  PaintedPattern paint_;
};

// --- board --------------------------------------------------------------

// A ChArUco marker on the board: its corners (OpenCV order: left-top,
// right-top, right-bottom, left-bottom as drawn) and bits (1 = white).
struct Marker {
  V3 corner0, right, down;  // corner0 and the unit edge vectors × (1 / edge length)
  cv::Mat bits;             // CV_8UC1, marker_size × marker_size
};

class Board : public Primitive {
 public:
  Board(const BoardOptions& options, std::vector<Marker> markers, std::vector<int> square_marker,
        int black_parity)
      : Primitive(SurfaceLabel::kBoard),
        spec_(options.spec),
        markers_(std::move(markers)),
        square_marker_(std::move(square_marker)),
        black_parity_(black_parity) {
    nx_ = spec_.type == BoardSpec::Type::kChessboard ? spec_.cols + 1 : spec_.cols;
    ny_ = spec_.type == BoardSpec::Type::kChessboard ? spec_.rows + 1 : spec_.rows;
    width_ = nx_ * spec_.square_mm;
    height_ = ny_ * spec_.square_mm;
    // Chessboard frame origin at inner corner 0 (as craftscan's
    // BoardCornersInBoard); ChArUco at the grid's corner (as OpenCV's).
    origin_ = spec_.type == BoardSpec::Type::kChessboard ? -spec_.square_mm : 0.0;
    margin_ = options.margin_mm;
    thickness_ = options.thickness_mm;
  }

  // The board is a slab: printed face at z = 0 facing −z, back at
  // z = +thickness (OpenCV's board convention: x right, y down on the print).
  bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                 LocalHit* hit) const override {
    const V3 lo(origin_ - margin_, origin_ - margin_, 0);
    const V3 hi(origin_ + width_ + margin_, origin_ + height_ + margin_, thickness_);
    if (thickness_ <= 0) {
      if (d.z == 0) return false;
      const double t = -o.z / d.z;
      if (!(t > t_min && t < t_max)) return false;
      const V3 p = o + d * t;
      if (p.x < lo.x || p.x > hi.x || p.y < lo.y || p.y > hi.y) return false;
      hit->t = t;
      hit->p = p;
      hit->part = d.z > 0 ? 0 : 1 + 2 * 2 + 1;  // front, or back (+z)
      return true;
    }
    double t0 = t_min, t1 = t_max;
    int entry_axis = -1;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0) {
        if (o[a] < lo[a] || o[a] > hi[a]) return false;
        continue;
      }
      double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        entry_axis = a;
      }
      t1 = std::min(t1, tb);
      if (t0 > t1) return false;
    }
    if (entry_axis < 0) return false;  // starts inside the board
    hit->t = t0;
    hit->p = o + d * t0;
    // part: 0 = printed face; else 1 + 2·axis + (outward normal positive ? 1 : 0).
    const bool positive = d[entry_axis] < 0;
    hit->part = (entry_axis == 2 && !positive) ? 0 : 1 + 2 * entry_axis + (positive ? 1 : 0);
    return true;
  }

  void Surface(const LocalHit& hit, V3* normal, V3* albedo) const override {
    if (hit.part != 0) {
      const int axis = (hit.part - 1) / 2;
      const double sign = ((hit.part - 1) % 2) == 1 ? 1 : -1;
      *normal = V3(axis == 0 ? sign : 0, axis == 1 ? sign : 0, axis == 2 ? sign : 0);
      *albedo = V3(0.3, 0.3, 0.3);
      return;
    }
    *normal = V3(0, 0, -1);
    const double g = Reflectance(hit.p.x - origin_, hit.p.y - origin_);
    *albedo = V3(g, g, g);
  }

 private:
  static constexpr double kBlack = 0.04, kWhite = 0.85;

  // Exact (vector) pattern: no texture resampling, so corners are where the
  // board's object points say. (x, y) from the grid's corner.
  double Reflectance(double x, double y) const {
    if (x < 0 || y < 0 || x >= width_ || y >= height_) return kWhite;
    const int i = std::min(static_cast<int>(std::floor(x / spec_.square_mm)), nx_ - 1);
    const int j = std::min(static_cast<int>(std::floor(y / spec_.square_mm)), ny_ - 1);
    if (((i + j) & 1) == black_parity_) return kBlack;
    if (spec_.type == BoardSpec::Type::kChessboard) return kWhite;
    const int m = square_marker_[static_cast<std::size_t>(j * nx_ + i)];
    if (m < 0) return kWhite;
    const Marker& marker = markers_[static_cast<std::size_t>(m)];
    const V3 rel = V3(x, y, 0) - marker.corner0;
    const double a = Dot(rel, marker.right), b = Dot(rel, marker.down);  // 0…1 inside
    if (a < 0 || a >= 1 || b < 0 || b >= 1) return kWhite;
    const int cells = marker.bits.rows + 2;  // one border bit on each side
    const int c = static_cast<int>(a * cells), r = static_cast<int>(b * cells);
    if (r == 0 || c == 0 || r == cells - 1 || c == cells - 1) return kBlack;
    return marker.bits.at<std::uint8_t>(r - 1, c - 1) != 0 ? kWhite : kBlack;
  }

  BoardSpec spec_;
  std::vector<Marker> markers_;
  std::vector<int> square_marker_;  // per square (j·nx + i): marker index or −1
  int black_parity_ = 0;            // squares with (i + j) % 2 == this are black
  int nx_ = 0, ny_ = 0;
  double width_ = 0, height_ = 0, margin_ = 0, thickness_ = 0;
  double origin_ = 0;  // the grid's corner in the board frame (x = y = origin_)
};

}  // namespace

double Primitive::MinAlong(const V3&) const { return std::numeric_limits<double>::quiet_NaN(); }

std::unique_ptr<Primitive> MakeTable(double z_mm, Background background, std::uint64_t seed) {
  return std::make_unique<AxisPlane>(AxisPlane::Axis::kZ, z_mm, background, seed);
}
std::unique_ptr<Primitive> MakeBackdrop(double y_mm, Background background, std::uint64_t seed) {
  return std::make_unique<AxisPlane>(AxisPlane::Axis::kY, y_mm, background, seed);
}
std::unique_ptr<Primitive> MakePlatter(double radius_mm, double thickness_mm,
                                       PlatterTexture texture, std::uint64_t seed) {
  return std::make_unique<Platter>(radius_mm, thickness_mm, texture, seed);
}
std::unique_ptr<Primitive> MakeEgg(const EggOptions& options, std::uint64_t seed) {
  return std::make_unique<Egg>(options, seed);
}

std::unique_ptr<Primitive> MakeBoard(const BoardOptions& options, std::string* error) {
  const BoardSpec& s = options.spec;
  if (s.type == BoardSpec::Type::kChessboard) {
    return std::make_unique<Board>(options, std::vector<Marker>{}, std::vector<int>{}, 0);
  }
  std::vector<Marker> markers;
  std::vector<int> square_marker(static_cast<std::size_t>(s.cols * s.rows), -1);
  int white_parity = 1;
  try {
    cv::Ptr<cv::aruco::Dictionary> dictionary =
        cv::aruco::getPredefinedDictionary(s.aruco_dictionary);
    cv::Ptr<cv::aruco::CharucoBoard> board =
        cv::aruco::CharucoBoard::create(s.cols, s.rows, static_cast<float>(s.square_mm),
                                        static_cast<float>(s.marker_mm), dictionary);
    for (std::size_t m = 0; m < board->objPoints.size(); ++m) {
      const std::vector<cv::Point3f>& c = board->objPoints[m];
      const int id = board->ids[m];
      if (c.size() != 4 || id < 0 || id >= dictionary->bytesList.rows) {
        if (error) *error = "board: unexpected ChArUco marker layout from OpenCV";
        return nullptr;
      }
      Marker marker;
      marker.corner0 = V3(c[0].x, c[0].y, 0);
      const V3 right = V3(c[1].x, c[1].y, 0) - marker.corner0;
      const V3 down = V3(c[3].x, c[3].y, 0) - marker.corner0;
      // OpenCV 4.6 draws the board with y down (marker corners clockwise in
      // x-right, y-down axes); the printed face then faces −z. Other
      // layouts would need the face flipped: refuse rather than render a
      // mirror image.
      if (Cross(right, down).z <= 0) {
        if (error) *error = "board: this OpenCV's ChArUco layout has y up; unsupported";
        return nullptr;
      }
      marker.right = right / Dot(right, right);
      marker.down = down / Dot(down, down);
      marker.bits = cv::aruco::Dictionary::getBitsFromByteList(
          dictionary->bytesList.rowRange(id, id + 1), dictionary->markerSize);
      const double cx = 0.25 * (c[0].x + c[1].x + c[2].x + c[3].x);
      const double cy = 0.25 * (c[0].y + c[1].y + c[2].y + c[3].y);
      const int i = static_cast<int>(std::floor(cx / s.square_mm));
      const int j = static_cast<int>(std::floor(cy / s.square_mm));
      if (i < 0 || j < 0 || i >= s.cols || j >= s.rows) {
        if (error) *error = "board: ChArUco marker outside the square grid";
        return nullptr;
      }
      white_parity = (i + j) & 1;  // markers sit in the white squares
      square_marker[static_cast<std::size_t>(j * s.cols + i)] = static_cast<int>(markers.size());
      markers.push_back(std::move(marker));
    }
  } catch (const cv::Exception& e) {
    if (error) *error = std::string("board: cannot build the ChArUco board: ") + e.what();
    return nullptr;
  }
  return std::make_unique<Board>(options, std::move(markers), std::move(square_marker),
                                 1 - white_parity);
}

}  // namespace craftscan::sim
