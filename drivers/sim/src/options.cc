// Option validation and enum names.
#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <numbers>
#include <string>

#include "craftscan/sim/station.h"

namespace craftscan::sim {
namespace {

bool Fail(std::string* why, std::string message) {
  if (why) *why = std::move(message);
  return false;
}

bool Finite(double v) { return std::isfinite(v); }

// The value among `values` whose ToString is `text`.
template <typename Enum>
bool FromName(std::string_view text, std::initializer_list<Enum> values, Enum* out) {
  for (Enum value : values) {
    if (text == ToString(value)) {
      *out = value;
      return true;
    }
  }
  return false;
}

}  // namespace

RigOptions::RigOptions() {
  // A mild 16 mm lens: barrel distortion, ~6 px at the image corners; the
  // two cameras differ slightly, as real ones do.
  left.distortion = {-0.08, 0.12, 0.0006, -0.0004, 0.0};
  left.principal_offset_px = {4.0, -3.0};
  right.distortion = {-0.075, 0.11, -0.0005, 0.0003, 0.0};
  right.principal_offset_px = {-5.0, 2.5};
  right.focal_px = 2407;
}

bool SimCameraOptions::IsValid(std::string* why) const {
  if (!(focal_px >= 50 && focal_px <= 1e5)) return Fail(why, "focal_px must be in [50, 1e5]");
  if (!(aspect >= 0.5 && aspect <= 2)) return Fail(why, "aspect must be in [0.5, 2]");
  if (!Finite(principal_offset_px.x) || !Finite(principal_offset_px.y)) {
    return Fail(why, "principal_offset_px must be finite");
  }
  for (int i = 0; i < 5; ++i) {
    if (!(std::abs(distortion[i]) <= 10)) {
      return Fail(why, "distortion[" + std::to_string(i) + "] must be finite and |value| ≤ 10");
    }
  }
  return true;
}

bool RigOptions::IsValid(std::string* why) const {
  if (image_size.width < 16 || image_size.height < 16 || image_size.width > 16384 ||
      image_size.height > 16384) {
    return Fail(why, "image_size must be between 16×16 and 16384×16384 px");
  }
  std::string reason;
  if (!left.IsValid(&reason)) return Fail(why, "left." + reason);
  if (!right.IsValid(&reason)) return Fail(why, "right." + reason);
  for (const SimCameraOptions* c : {&left, &right}) {
    if (std::abs(c->principal_offset_px.x) > image_size.width / 2.0 ||
        std::abs(c->principal_offset_px.y) > image_size.height / 2.0) {
      return Fail(why, std::string(c == &left ? "left" : "right") +
                           ".principal_offset_px puts the principal point outside the image");
    }
  }
  if (!(baseline_mm > 0 && baseline_mm <= 5000)) {
    return Fail(why, "baseline_mm must be in (0, 5000]");
  }
  if (!(vergence_deg >= 0 && vergence_deg < 90)) {
    return Fail(why, "vergence_deg must be in [0, 90)");
  }
  for (int i = 0; i < 3; ++i) {
    if (!(std::abs(right_misalignment_rad[i]) <= 0.2)) {
      return Fail(why, "right_misalignment_rad components must be within ±0.2 rad");
    }
  }
  if (!(distance_mm > 0 && distance_mm <= 1e5)) return Fail(why, "distance_mm must be in (0, 1e5]");
  if (!(elevation_deg > -89 && elevation_deg < 89)) {
    return Fail(why, "elevation_deg must be in (-89, 89)");
  }
  if (!Finite(target_height_mm)) return Fail(why, "target_height_mm must be finite");
  if (!(exposure > 0 && exposure <= 100)) return Fail(why, "exposure must be in (0, 100]");
  if (!(noise_sigma >= 0 && noise_sigma <= 100)) {
    return Fail(why, "noise_sigma must be in [0, 100] grey levels");
  }
  if (supersampling < 1 || supersampling > 4) return Fail(why, "supersampling must be in [1, 4]");
  if (num_threads < 1 || num_threads > 256) return Fail(why, "num_threads must be in [1, 256]");
  return true;
}

bool ProjectorOptions::IsValid(std::string* why) const {
  if (!enabled) return true;
  if (!Finite(position_mm[0]) || !Finite(position_mm[1]) || !Finite(position_mm[2]) ||
      !Finite(target_mm[0]) || !Finite(target_mm[1]) || !Finite(target_mm[2]))
    return Fail(why, "projector.position_mm and target_mm must be finite");
  if (!(cv::norm(target_mm - position_mm) > 1))
    return Fail(why, "projector.target_mm must be more than 1 mm from its position");
  if (!(fov_deg > 0 && fov_deg < 120)) return Fail(why, "projector.fov_deg must be in (0, 120)");
  if (pattern_px < 8 || pattern_px > 8192)
    return Fail(why, "projector.pattern_px must be in [8, 8192]");
  if (!(power >= 0 && power <= 10)) return Fail(why, "projector.power must be in [0, 10]");
  if (!(fill > 0 && fill < 1)) return Fail(why, "projector.fill must be in (0, 1)");
  return true;
}

ProjectorOptions ProjectorOnCameraHead(const RigOptions& rig) {
  // The head's geometry as SimStation::Create places it.
  const double elevation = rig.elevation_deg * std::numbers::pi / 180;
  ProjectorOptions p;
  p.enabled = true;
  p.target_mm = cv::Vec3d(0, 0, rig.target_height_mm);
  p.position_mm = p.target_mm +
                  cv::Vec3d(0, -std::cos(elevation), std::sin(elevation)) * rig.distance_mm +
                  cv::Vec3d(0, 0, 30);
  return p;
}

bool LightingOptions::IsValid(std::string* why) const {
  if (!(ambient >= 0 && ambient <= 10)) return Fail(why, "ambient must be in [0, 10]");
  if (!(directional >= 0 && directional <= 10)) return Fail(why, "directional must be in [0, 10]");
  const double n = cv::norm(direction_to_light);
  if (!(n > 1e-9) || !Finite(n)) return Fail(why, "direction_to_light must be non-zero and finite");
  return projector.IsValid(why);
}

bool BoardOptions::IsValid(std::string* why) const {
  if (!enabled) return true;
  const bool chess = spec.type == BoardSpec::Type::kChessboard;
  const int min_count = chess ? 2 : 3;
  if (spec.cols < min_count || spec.rows < min_count || spec.cols > 200 || spec.rows > 200) {
    return Fail(why, chess ? "spec.cols and spec.rows (inner corners) must be in [2, 200]"
                           : "spec.cols and spec.rows (squares) must be in [3, 200]");
  }
  if (!(spec.square_mm > 0 && spec.square_mm <= 1000)) {
    return Fail(why, "spec.square_mm must be in (0, 1000]");
  }
  if (!chess) {
    if (!(spec.marker_mm > 0 && spec.marker_mm < spec.square_mm)) {
      return Fail(why, "spec.marker_mm must be in (0, square_mm) for a ChArUco board");
    }
    if (spec.aruco_dictionary < 0 || spec.aruco_dictionary > 20) {
      return Fail(why,
                  "spec.aruco_dictionary must be a cv::aruco::PREDEFINED_DICTIONARY_NAME (0…20)");
    }
  }
  if (!(margin_mm >= 0 && margin_mm <= 1000)) return Fail(why, "margin_mm must be in [0, 1000]");
  if (!(thickness_mm >= 0 && thickness_mm <= 100)) {
    return Fail(why, "thickness_mm must be in [0, 100]");
  }
  if (placement == BoardPlacement::kOnPlatter) {
    if (!Finite(platter_position_mm.x) || !Finite(platter_position_mm.y) ||
        !Finite(platter_yaw_rad)) {
      return Fail(why, "platter_position_mm and platter_yaw_rad must be finite");
    }
  } else {
    for (int i = 0; i < 3; ++i) {
      if (!Finite(rotation_rad[i]) || !Finite(translation_mm[i])) {
        return Fail(why, "rotation_rad and translation_mm must be finite");
      }
    }
  }
  return true;
}

bool SceneOptions::IsValid(std::string* why) const {
  const ObjectOptions& o = object;
  switch (o.type) {
    case ObjectType::kNone:
      break;
    case ObjectType::kCarvedBox: {
      const CarvedBoxOptions& b = o.carved_box;
      if (!(b.width_mm > 0 && b.width_mm <= 1000) || !(b.depth_mm > 0 && b.depth_mm <= 1000) ||
          !(b.height_mm > 0 && b.height_mm <= 1000)) {
        return Fail(why, "object.carved_box: width_mm, depth_mm, height_mm must be in (0, 1000]");
      }
      const double smallest = std::min({b.width_mm, b.depth_mm, b.height_mm});
      if (!(b.relief_depth_mm >= 0 && b.relief_depth_mm <= smallest / 4)) {
        return Fail(why, "object.carved_box.relief_depth_mm must be in [0, smallest side / 4]");
      }
      break;
    }
    case ObjectType::kEgg:
      if (!(o.egg.diameter_mm > 0 && o.egg.diameter_mm <= 1000) ||
          !(o.egg.height_mm > 0 && o.egg.height_mm <= 1000)) {
        return Fail(why, "object.egg: diameter_mm and height_mm must be in (0, 1000]");
      }
      break;
    case ObjectType::kEmbroidery: {
      const EmbroideryOptions& e = o.embroidery;
      if (!(e.diameter_mm >= 10 && e.diameter_mm <= 1000)) {
        return Fail(why, "object.embroidery.diameter_mm must be in [10, 1000]");
      }
      if (!(e.thickness_mm > 0 && e.thickness_mm <= e.diameter_mm / 4)) {
        return Fail(why, "object.embroidery.thickness_mm must be in (0, diameter_mm / 4]");
      }
      if (!(e.relief_mm >= 0 && e.relief_mm <= 5)) {
        return Fail(why, "object.embroidery.relief_mm must be in [0, 5]");
      }
      if (!(std::abs(e.tilt_rad) <= 1.5707963267948966)) {
        return Fail(why, "object.embroidery.tilt_rad must be within ±π/2");
      }
      break;
    }
    case ObjectType::kMesh:
      if (o.mesh.path.empty()) return Fail(why, "object.mesh.path is empty");
      if (!(o.mesh.size_mm >= 0 && o.mesh.size_mm <= 1e4)) {
        return Fail(why, "object.mesh.size_mm must be in [0, 1e4] (0 = use scale)");
      }
      if (o.mesh.size_mm == 0 && !(o.mesh.scale > 0 && o.mesh.scale <= 1e6)) {
        return Fail(why, "object.mesh.scale must be in (0, 1e6]");
      }
      for (int i = 0; i < 3; ++i) {
        if (!Finite(o.mesh.rotation_rad[i])) {
          return Fail(why, "object.mesh.rotation_rad must be finite");
        }
      }
      if (ToString(o.mesh.surface) == "unknown") {
        return Fail(why, "object.mesh.surface is not a known MeshSurface");
      }
      break;
    default:
      return Fail(why, "object.type is not a known ObjectType");
  }
  if (!Finite(o.position_mm.x) || !Finite(o.position_mm.y) || !Finite(o.yaw_rad)) {
    return Fail(why, "object.position_mm and object.yaw_rad must be finite");
  }
  if (!Finite(o.rotation_rad[0]) || !Finite(o.rotation_rad[1]) || !Finite(o.rotation_rad[2]) ||
      cv::norm(o.rotation_rad) > 4 * std::numbers::pi) {
    return Fail(why, "object.rotation_rad must be finite, a rotation of at most 4π rad");
  }
  std::string reason;
  if (!board.IsValid(&reason)) return Fail(why, "board." + reason);
  if (!Finite(turntable_angle_rad)) return Fail(why, "turntable_angle_rad must be finite");
  if (!(platter_radius_mm >= 10 && platter_radius_mm <= 2000)) {
    return Fail(why, "platter_radius_mm must be in [10, 2000]");
  }
  if (!(platter_thickness_mm > 0 && platter_thickness_mm <= 500)) {
    return Fail(why, "platter_thickness_mm must be in (0, 500]");
  }
  if (!(backdrop_distance_mm > platter_radius_mm && backdrop_distance_mm <= 1e5)) {
    return Fail(why, "backdrop_distance_mm must be larger than platter_radius_mm (and ≤ 1e5)");
  }
  if (!lighting.IsValid(&reason)) return Fail(why, "lighting." + reason);
  return true;
}

std::string_view ToString(ObjectType type) {
  switch (type) {
    case ObjectType::kNone:
      return "none";
    case ObjectType::kCarvedBox:
      return "carved_box";
    case ObjectType::kEgg:
      return "egg";
    case ObjectType::kEmbroidery:
      return "embroidery";
    case ObjectType::kMesh:
      return "mesh";
  }
  return "unknown";
}

bool ObjectTypeFromString(std::string_view text, ObjectType* type) {
  return FromName(text,
                  {ObjectType::kNone, ObjectType::kCarvedBox, ObjectType::kEgg,
                   ObjectType::kEmbroidery, ObjectType::kMesh},
                  type);
}

std::string_view ToString(MeshSurface surface) {
  switch (surface) {
    case MeshSurface::kStone:
      return "stone";
    case MeshSurface::kWood:
      return "wood";
    case MeshSurface::kPainted:
      return "painted";
    case MeshSurface::kFabric:
      return "fabric";
  }
  return "unknown";
}

bool MeshSurfaceFromString(std::string_view text, MeshSurface* surface) {
  return FromName(
      text, {MeshSurface::kStone, MeshSurface::kWood, MeshSurface::kPainted, MeshSurface::kFabric},
      surface);
}

std::string_view ToString(BoardPlacement placement) {
  return placement == BoardPlacement::kOnPlatter ? "on_platter" : "in_world";
}
bool BoardPlacementFromString(std::string_view text, BoardPlacement* placement) {
  if (text == "on_platter") {
    *placement = BoardPlacement::kOnPlatter;
  } else if (text == "in_world") {
    *placement = BoardPlacement::kInWorld;
  } else {
    return false;
  }
  return true;
}

std::string_view ToString(PlatterTexture texture) {
  return texture == PlatterTexture::kPlain ? "plain" : "textured";
}
bool PlatterTextureFromString(std::string_view text, PlatterTexture* texture) {
  if (text == "plain") {
    *texture = PlatterTexture::kPlain;
  } else if (text == "textured") {
    *texture = PlatterTexture::kTextured;
  } else {
    return false;
  }
  return true;
}

std::string_view ToString(Background background) {
  return background == Background::kDarkCloth ? "dark_cloth" : "textured";
}
bool BackgroundFromString(std::string_view text, Background* background) {
  if (text == "dark_cloth") {
    *background = Background::kDarkCloth;
  } else if (text == "textured") {
    *background = Background::kTextured;
  } else {
    return false;
  }
  return true;
}

}  // namespace craftscan::sim
