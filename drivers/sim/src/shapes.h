// Scene primitives: analytic or marched ray intersection in a local frame,
// plus the surface normal and procedural albedo at a hit.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/matx.hpp>

#include "craftscan/sim/station.h"
#include "math.h"

namespace craftscan::sim {

struct LocalHit {
  double t = 0;         // ray parameter (same in every rigid frame)
  V3 p;                 // hit point, local frame
  int part = 0;         // primitive-specific (face, triangle, ...)
  double u = 0, v = 0;  // primitive-specific (barycentric coordinates for meshes)
};

class Primitive {
 public:
  explicit Primitive(SurfaceLabel label) : label_(label) {}
  virtual ~Primitive() = default;

  // Nearest hit with t in (t_min, t_max) of the local ray o + t·d.
  virtual bool Intersect(const V3& o, const V3& d, double t_min, double t_max,
                         LocalHit* hit) const = 0;
  // Whether some hit has t in (t_min, t_max): what Intersect returns, for a
  // shadow ray, which needs no nearest hit (overridden where that is less work).
  virtual bool Occludes(const V3& o, const V3& d, double t_min, double t_max) const {
    LocalHit hit;
    return Intersect(o, d, t_min, t_max, &hit);
  }
  // Outward unit normal (local frame) and albedo (BGR, [0, 1]) at a hit.
  virtual void Surface(const LocalHit& hit, V3* normal, V3* albedo) const = 0;

  // The smallest direction·p over the primitive's surface points p (local
  // frame; `direction` need not be unit): its support along −direction,
  // which seats a rotated object on the platter. NaN when the primitive
  // does not know it (only objects do).
  virtual double MinAlong(const V3& direction) const;

  SurfaceLabel label() const { return label_; }

  // Placement: parent_from_local, where the parent is the turntable frame
  // (turns with the platter) or the world frame.
  bool on_turntable = false;
  Rigid parent_from_local;
  // Current transforms, set by the scene for the turntable angle.
  Rigid world_from_local, local_from_world;

 private:
  SurfaceLabel label_;
};

std::unique_ptr<Primitive> MakeTable(double z_mm, Background background, std::uint64_t seed);
std::unique_ptr<Primitive> MakeBackdrop(double y_mm, Background background, std::uint64_t seed);
std::unique_ptr<Primitive> MakePlatter(double radius_mm, double thickness_mm,
                                       PlatterTexture texture, std::uint64_t seed);
// Local frame = object frame.
std::unique_ptr<Primitive> MakeEgg(const EggOptions& options, std::uint64_t seed);
std::unique_ptr<Primitive> MakeCarvedBox(const CarvedBoxOptions& options, std::uint64_t seed);
// Local frame = the disc's frame (base at z = 0, axis +z); *object_from_disc
// receives the tilt and lift that rest it on the platter.
std::unique_ptr<Primitive> MakeEmbroidery(const EmbroideryOptions& options, std::uint64_t seed,
                                          Rigid* object_from_disc);
// A triangle mesh (common/triangle_mesh.h faces) whose vertices were placed
// in the object frame (millimetres, double: placement keeps full precision),
// textured as `surface`.
std::unique_ptr<Primitive> MakeMesh(std::vector<cv::Vec3d> vertices_mm,
                                    std::vector<cv::Vec3i> triangles, MeshSurface surface,
                                    std::uint64_t seed);
// Local frame = board frame. Null with *error on failure (e.g. OpenCV).
std::unique_ptr<Primitive> MakeBoard(const BoardOptions& options, std::string* error);

}  // namespace craftscan::sim
