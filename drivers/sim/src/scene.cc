#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include <opencv2/calib3d.hpp>

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "scene_impl.h"
#include "shapes.h"
#include "texture.h"

namespace craftscan::sim {
namespace {

Rigid Translation(const V3& t) {
  Rigid r;
  r.t = t;
  return r;
}

Rigid Rotation(const M3& R) {
  Rigid r;
  r.R = R;
  return r;
}

// Scales, rotates and seats the mesh: bounding box centred on the z axis,
// bottom at z = 0 (object frame, mm).
bool PlaceMesh(const MeshOptions& o, const TriangleMesh& mesh, std::vector<cv::Vec3d>* vertices_mm,
               std::string* error) {
  if (mesh.vertices_mm.empty() || mesh.faces.empty()) {
    *error = "object.mesh: '" + o.path + "' has no triangles";
    return false;
  }
  const M3 R = M3::Rodrigues(o.rotation_rad);
  V3 lo(1e300, 1e300, 1e300), hi(-1e300, -1e300, -1e300);
  vertices_mm->clear();
  vertices_mm->reserve(mesh.vertices_mm.size());
  for (const cv::Vec3f& file_vertex : mesh.vertices_mm) {
    const V3 p = R * FromCv(cv::Vec3d(file_vertex));
    vertices_mm->push_back(ToCv(p));
    lo = V3(std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z));
    hi = V3(std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z));
  }
  const V3 extent = hi - lo;
  const double largest = std::max({extent.x, extent.y, extent.z});
  if (!(largest > 0)) {
    *error = "object.mesh: '" + o.path + "' is degenerate (zero extent)";
    return false;
  }
  const double scale = o.size_mm > 0 ? o.size_mm / largest : o.scale;
  const V3 offset(-(lo.x + hi.x) / 2, -(lo.y + hi.y) / 2, -lo.z);
  for (cv::Vec3d& v : *vertices_mm) v = ToCv((FromCv(v) + offset) * scale);
  return true;
}

// The rotation R of the object frame, then the shift that centres the
// rotated object's axis-aligned bounding box on the z axis and puts its
// lowest point at z = 0: *seated_from_object. The extents come from the
// primitive's support (MinAlong) in its local frame.
bool SeatRotated(const Primitive& object, const M3& R, const Rigid& object_from_local,
                 Rigid* seated_from_object, std::string* why) {
  const Rigid rotated_from_local = Rotation(R) * object_from_local;
  // Lowest and highest coordinate of the rotated object along its axis i.
  auto extent = [&](int i, double sign) {
    const M3& Rl = rotated_from_local.R;
    const V3 axis_in_local = V3(Rl.m[3 * i], Rl.m[3 * i + 1], Rl.m[3 * i + 2]) * sign;  // row i
    return sign * (object.MinAlong(axis_in_local) + sign * rotated_from_local.t[i]);
  };
  const double x_lo = extent(0, 1), x_hi = extent(0, -1);
  const double y_lo = extent(1, 1), y_hi = extent(1, -1);
  const double z_lo = extent(2, 1);
  if (!std::isfinite(x_lo + x_hi + y_lo + y_hi + z_lo)) {
    *why = "this object cannot be rotated (its extent is unknown)";
    return false;
  }
  *seated_from_object =
      Translation(V3(-(x_lo + x_hi) / 2, -(y_lo + y_hi) / 2, -z_lo)) * Rotation(R);
  return true;
}

}  // namespace

void Scene::Impl::SetAngle(double angle) {
  angle_rad = angle;
  const Rigid world_from_turntable = Rotation(M3::RotZ(angle));
  for (auto& p : primitives) {
    p->world_from_local =
        p->on_turntable ? world_from_turntable * p->parent_from_local : p->parent_from_local;
    p->local_from_world = p->world_from_local.Inverse();
  }
}

Rigid Scene::Impl::WorldFromObject() const {
  if (object == nullptr) return Rigid{};
  return object->world_from_local * object_from_local.Inverse();
}

Rigid Scene::Impl::WorldFromBoard() const {
  if (board == nullptr) return Rigid{};
  return board->world_from_local;
}

bool Scene::Impl::Intersect(const V3& o, const V3& d, double t_min, double t_max, Hit* hit) const {
  bool found = false;
  for (const auto& p : primitives) {
    const V3 lo = p->local_from_world.Apply(o), ld = p->local_from_world.Rotate(d);
    LocalHit local;
    if (p->Intersect(lo, ld, t_min, t_max, &local)) {
      t_max = local.t;
      hit->primitive = p.get();
      hit->local = local;
      found = true;
    }
  }
  return found;
}

bool Scene::Impl::Occluded(const V3& o, const V3& d, double t_min, double t_max) const {
  for (const auto& p : primitives) {
    if (p->label() == SurfaceLabel::kBackground) continue;  // nothing lies behind them
    const V3 lo = p->local_from_world.Apply(o), ld = p->local_from_world.Rotate(d);
    if (p->Occludes(lo, ld, t_min, t_max)) return true;
  }
  return false;
}

V3 Scene::Impl::Shade(const V3& d, const Hit& hit) const {
  V3 normal_local, albedo;
  hit.primitive->Surface(hit.local, &normal_local, &albedo);
  V3 n = hit.primitive->world_from_local.Rotate(normal_local);
  if (Dot(n, d) > 0) n = -n;  // two-sided
  const LightingOptions& light = options.lighting;
  double irradiance = light.ambient;
  const double cosine = Dot(n, to_light);
  if (cosine > 0 && light.directional > 0) {
    bool lit = true;
    if (light.shadows) {
      const V3 p = hit.primitive->world_from_local.Apply(hit.local.p);
      lit = !Occluded(p + n * 2e-3, to_light, 0, std::numeric_limits<double>::infinity());
    }
    if (lit) irradiance += light.directional * cosine;
  }
  if (light.projector.enabled && light.projector.power > 0) {
    const V3 p = hit.primitive->world_from_local.Apply(hit.local.p);
    const V3 to_projector = projector_centre - p;
    const double distance = Norm(to_projector);
    const V3 towards = to_projector / distance;
    const double cos_p = Dot(n, towards);
    if (cos_p > 0) {
      const double pattern = ProjectorPattern(p);
      if (pattern > 0 && !Occluded(p + n * 2e-3, towards, 0, distance))
        irradiance += light.projector.power * cos_p * pattern;
    }
  }
  return albedo * irradiance;
}

double Scene::Impl::ProjectorPattern(const V3& p) const {
  const ProjectorOptions& o = options.lighting.projector;
  const V3 d = p - projector_centre;
  const double z = Dot(d, projector_z);
  if (!(z > 0)) return 0;
  const double x = Dot(d, projector_x) / z / projector_tan_half;  // −1..1 across the field
  const double y = Dot(d, projector_y) / z / projector_tan_half;
  if (std::abs(x) >= 1 || std::abs(y) >= 1) return 0;
  // Pattern pixel coordinates; pixel (i, j) is lit or dark, bilinear between centres.
  const double u = (x + 1) / 2 * o.pattern_px - 0.5, v = (y + 1) / 2 * o.pattern_px - 0.5;
  const double i0 = std::floor(u), j0 = std::floor(v);
  const double fu = u - i0, fv = v - j0;
  auto lit = [&](double i, double j) {
    return ToUnit(Hash(o.seed, static_cast<std::int64_t>(i), static_cast<std::int64_t>(j))) < o.fill
               ? 1.0
               : 0.0;
  };
  return (1 - fv) * ((1 - fu) * lit(i0, j0) + fu * lit(i0 + 1, j0)) +
         fv * ((1 - fu) * lit(i0, j0 + 1) + fu * lit(i0 + 1, j0 + 1));
}

Scene::Scene() : impl_(std::make_unique<Impl>()) {}
Scene::~Scene() = default;

std::unique_ptr<Scene> Scene::Create(const SceneOptions& options, std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) {
    if (error) *error = "invalid scene options: " + why;
    return nullptr;
  }
  std::unique_ptr<Scene> scene(new Scene());
  Impl& s = *scene->impl_;
  s.options = options;
  s.to_light = Normalized(FromCv(options.lighting.direction_to_light));
  if (const ProjectorOptions& p = options.lighting.projector; p.enabled) {
    s.has_projector = true;
    s.projector_centre = FromCv(p.position_mm);
    s.projector_z = Normalized(FromCv(p.target_mm) - s.projector_centre);
    V3 x = Cross(V3(0, 0, -1), s.projector_z);  // horizontal, as the rig's x
    if (Norm(x) < 1e-6) x = V3(1, 0, 0);        // looking straight down
    s.projector_x = Normalized(x);
    s.projector_y = Cross(s.projector_z, s.projector_x);
    s.projector_tan_half = std::tan(p.fov_deg * std::numbers::pi / 360);
  }
  const std::uint64_t seed = options.seed;

  s.primitives.push_back(
      MakeTable(-options.platter_thickness_mm, options.background, SubSeed(seed, 1)));
  s.primitives.push_back(
      MakeBackdrop(options.backdrop_distance_mm, options.background, SubSeed(seed, 2)));
  s.primitives.push_back(MakePlatter(options.platter_radius_mm, options.platter_thickness_mm,
                                     options.platter_texture, SubSeed(seed, 3)));

  const ObjectOptions& o = options.object;
  std::unique_ptr<Primitive> object;
  const std::uint64_t object_seed = SubSeed(seed, 4);
  switch (o.type) {
    case ObjectType::kNone:
      break;
    case ObjectType::kCarvedBox:
      object = MakeCarvedBox(o.carved_box, object_seed);
      break;
    case ObjectType::kEgg:
      object = MakeEgg(o.egg, object_seed);
      break;
    case ObjectType::kEmbroidery:
      object = MakeEmbroidery(o.embroidery, object_seed, &s.object_from_local);
      break;
    case ObjectType::kMesh: {
      TriangleMesh mesh;  // file units
      std::string load_error;
      if (!ReadMeshPly(o.mesh.path, &mesh, &load_error)) {
        if (error) *error = "object.mesh: " + load_error;
        return nullptr;
      }
      std::vector<cv::Vec3d> vertices_mm;
      if (!PlaceMesh(o.mesh, mesh, &vertices_mm, &load_error)) {
        if (error) *error = load_error;
        return nullptr;
      }
      s.mesh_triangles = mesh.faces.size();
      object = MakeMesh(std::move(vertices_mm), std::move(mesh.faces), o.mesh.surface, object_seed);
      break;
    }
  }
  if (object) {
    object->on_turntable = true;
    object->parent_from_local = Translation(V3(o.position_mm.x, o.position_mm.y, 0)) *
                                Rotation(M3::RotZ(o.yaw_rad)) * s.object_from_local;
    if (o.rotation_rad != cv::Vec3d(0, 0, 0)) {
      // The operator's pose: the rotated object seated on the platter, centred.
      // (Only then: without a rotation the object stays exactly as built.)
      Rigid seated_from_object;
      std::string why;
      if (!SeatRotated(*object, M3::Rodrigues(o.rotation_rad), s.object_from_local,
                       &seated_from_object, &why)) {
        if (error) *error = "object.rotation_rad: " + why;
        return nullptr;
      }
      object->parent_from_local = Translation(V3(o.position_mm.x, o.position_mm.y, 0)) *
                                  Rotation(M3::RotZ(o.yaw_rad)) * seated_from_object *
                                  s.object_from_local;
    }
    s.object = object.get();
    s.primitives.push_back(std::move(object));
  }

  const BoardOptions& b = options.board;
  if (b.enabled) {
    std::string board_error;
    std::unique_ptr<Primitive> board = MakeBoard(b, &board_error);
    if (!board) {
      if (error) *error = board_error;
      return nullptr;
    }
    if (b.placement == BoardPlacement::kOnPlatter) {
      board->on_turntable = true;
      // Printed face up: the board's z (into the board) points down.
      M3 face_up;
      face_up.m[4] = -1;
      face_up.m[8] = -1;
      board->parent_from_local =
          Translation(V3(b.platter_position_mm.x, b.platter_position_mm.y, b.thickness_mm)) *
          Rotation(M3::RotZ(b.platter_yaw_rad) * face_up);
    } else {
      board->on_turntable = false;
      board->parent_from_local.R = M3::Rodrigues(b.rotation_rad);
      board->parent_from_local.t = FromCv(b.translation_mm);
    }
    s.board = board.get();
    s.primitives.push_back(std::move(board));
  }
  s.SetAngle(options.turntable_angle_rad);
  return scene;
}

const SceneOptions& Scene::options() const { return impl_->options; }
void Scene::SetTurntableAngle(double angle_rad) { impl_->SetAngle(angle_rad); }
bool Scene::SetProjectorOn(bool on) {
  if (!impl_->has_projector) return false;
  impl_->options.lighting.projector.enabled = on;
  return true;
}
bool Scene::projector_on() const { return impl_->options.lighting.projector.enabled; }
double Scene::turntable_angle_rad() const { return impl_->angle_rad; }
cv::Matx44d Scene::world_from_object() const { return impl_->WorldFromObject().ToCv(); }
cv::Matx44d Scene::world_from_board() const { return impl_->WorldFromBoard().ToCv(); }
std::size_t Scene::mesh_triangle_count() const { return impl_->mesh_triangles; }

bool Scene::Intersect(const cv::Vec3d& origin_in_world, const cv::Vec3d& direction_in_world,
                      double* t, SurfaceLabel* label) const {
  Impl::Hit hit;
  if (!impl_->Intersect(FromCv(origin_in_world), FromCv(direction_in_world), 0,
                        std::numeric_limits<double>::infinity(), &hit)) {
    return false;
  }
  if (t) *t = hit.local.t;
  if (label) *label = hit.primitive->label();
  return true;
}

}  // namespace craftscan::sim
