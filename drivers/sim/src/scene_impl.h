// The scene's internals, shared with the renderer (station.cc).
#pragma once

#include <memory>
#include <vector>

#include "craftscan/sim/station.h"
#include "math.h"
#include "shapes.h"

namespace craftscan::sim {

struct Scene::Impl {
  SceneOptions options;
  std::vector<std::unique_ptr<Primitive>> primitives;
  const Primitive* object = nullptr;  // also in primitives
  const Primitive* board = nullptr;   // also in primitives
  Rigid object_from_local;            // object frame ← the object primitive's frame
  Rigid board_parent_from_board;      // turntable (on platter) or world ← board frame
  double angle_rad = 0;
  std::size_t mesh_triangles = 0;
  V3 to_light;  // unit, world frame
  // The projector's frame (world): centre, unit axes (x right, y down, z
  // forward), tan of half its field.
  V3 projector_centre, projector_x, projector_y, projector_z;
  double projector_tan_half = 0;
  bool has_projector = false;  // created with one (it may be switched off)
  // Its pattern's brightness at world point p (0..1), 0 outside its field.
  double ProjectorPattern(const V3& p) const;

  struct Hit {
    const Primitive* primitive = nullptr;
    LocalHit local;
  };

  void SetAngle(double angle_rad);
  // Nearest surface along o + t·d, t in (t_min, t_max) (world frame).
  bool Intersect(const V3& o, const V3& d, double t_min, double t_max, Hit* hit) const;
  // Whether any surface lies along o + t·d for t in (t_min, t_max).
  bool Occluded(const V3& o, const V3& d, double t_min, double t_max) const;
  // Radiance (BGR, before exposure) leaving `hit` towards the ray's origin.
  V3 Shade(const V3& d, const Hit& hit) const;
  Rigid WorldFromObject() const;
  Rigid WorldFromBoard() const;
};

}  // namespace craftscan::sim
