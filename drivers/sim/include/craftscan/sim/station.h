// The simulated station: a calibrated stereo rig looking down at a turntable,
// rendered by ray casting with exact ground truth.
//
//   std::string error;
//   auto station = sim::SimStation::Create(sim::RigOptions{}, &error);
//   auto scene = sim::Scene::Create(sim::SceneOptions{}, &error);  // carved box
//   sim::StereoRender frame = station->Render(*scene);
//   // frame.left / frame.right: raw 8-bit BGR images (distorted, noisy);
//   // frame.left_depth_mm, frame.rectified_disparity: ground truth;
//   // frame.calibration: the exact calibration of the simulated rig.
//
// Frames and units (DESIGN.md): millimetres, radians, pixels; degrees only in
// fields named *_deg. The world frame is the turntable frame: origin on the
// axis at the platter surface, +Z up along the axis; it does not turn. The
// platter and everything on it turn with the turntable angle. The rig frame
// is the rectified left camera. Camera frames follow OpenCV (x right, y down,
// z forward); pixel (u, v) has its centre at integer coordinates.
//
// Station geometry: the rig looks at the point `target_height_mm` above the
// platter on the turntable axis from `distance_mm` away, looking down by
// `elevation_deg`, from the world's −Y side (the rig's x axis is world +X at
// turntable angle 0). The optical centres sit ±baseline/2 along the rig's x
// axis from that viewpoint; each camera is toed in by vergence/2 about its
// own y axis (the defaults make the optical axes meet near the target), and
// the right camera may carry a small extra misalignment rotation.
//
// Rendering: per pixel, s×s supersamples (anti-aliasing), each an exact ray
// through the distorted pinhole model (OpenCV k1 k2 p1 p2 k3, undistorted by
// Newton iteration to < 1e-9 px, cached per camera); Lambertian shading with
// ambient + one directional light (optional cast shadows); exposure gain;
// Gaussian sensor noise seeded per pixel; 8-bit rounding and clamping.
// Textures are procedural and seeded: the same options, seed and frame index
// give bit-identical images for any thread count. Ground truth is traced
// along the ray through each pixel centre with the same intersection code as
// the images (relief surfaces to 1e-7 mm). A default 1280×1024 pair with
// ground truth takes ~2.5 s on 2 cores (carved box, 2×2 samples, shadows).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan::sim {

// ---------------------------------------------------------------- rig ------

// One raw camera of the rig (OpenCV pinhole + Brown–Conrady distortion).
struct SimCameraOptions {
  double focal_px = 2400;  // fx (px); fy = fx · aspect
  double aspect = 1.0;     // fy / fx
  // Principal point minus the image centre ((width − 1)/2, (height − 1)/2), px.
  cv::Point2d principal_offset_px{0, 0};
  cv::Vec<double, 5> distortion{0, 0, 0, 0, 0};  // k1 k2 p1 p2 k3 (OpenCV order)

  bool IsValid(std::string* why) const;
};

struct RigOptions {
  // Sets the defaults below and, per camera, a mild barrel distortion
  // (~6 px at the corners), a few px of principal point offset and (right)
  // a 0.3 % longer focal length: two slightly different real cameras.
  RigOptions();

  cv::Size image_size{1280, 1024};  // px, both cameras and the rectified images
  SimCameraOptions left, right;
  double baseline_mm = 100;     // distance between the two optical centres
  double vergence_deg = 14.25;  // angle between the optical axes; each camera toed in by half
                                // (14.25° = 2·atan(50/400): axes meet at the target)
  // Extra rotation of the right camera about its own axes (Rodrigues vector,
  // rad): the small misalignment every real rig has.
  cv::Vec3d right_misalignment_rad{0.0015, -0.001, 0.002};
  double distance_mm = 400;      // from the midpoint of the optical centres to the target
  double elevation_deg = 30;     // the rig looks down by this angle (0 = horizontal, < 90)
  double target_height_mm = 30;  // the target: on the turntable axis, above the platter

  double exposure = 1.0;     // linear gain: radiance 1 (white, fully lit) → grey 255·exposure
  double noise_sigma = 1.0;  // Gaussian sensor noise, grey levels (0 = none)
  std::uint64_t seed = 1;    // sensor noise; frames differ through Render's frame_index
  int supersampling = 2;     // s: s×s samples per pixel, 1…4
  int num_threads = 1;       // render threads, 1…256; results do not depend on it

  bool IsValid(std::string* why) const;  // names the offending field
};

// ---------------------------------------------------------------- scene ----

enum class ObjectType {
  kNone,        // empty turntable (e.g. for calibration boards)
  kCarvedBox,   // box with chip-carved relief on every visible face, wood texture
  kEgg,         // ellipsoid with a painted (pysanka-style) pattern
  kEmbroidery,  // thin disc with coloured satin stitching in low relief
  kMesh,        // a PLY triangle mesh, scaled and placed, with a MeshSurface
};
std::string_view ToString(ObjectType type);  // "none", "carved_box", "egg", "embroidery", "mesh"
bool ObjectTypeFromString(std::string_view text, ObjectType* type);

// Object frames: the object's base rests on the platter (z = 0 in the object
// frame) centred on the object frame's z axis.
struct CarvedBoxOptions {
  double width_mm = 80;   // along object x
  double depth_mm = 60;   // along object y
  double height_mm = 50;  // along object z; the base sits at z = 0
  // Depth of the deepest cuts below each face (top and four sides; the base
  // is flat). Cuts keep ≥ 4 mm away from the edges.
  double relief_depth_mm = 2.0;
};

struct EggOptions {         // ellipsoid, touching the platter at its lowest point
  double diameter_mm = 45;  // along object x and y
  double height_mm = 60;    // along object z
};

struct EmbroideryOptions {
  double diameter_mm = 110;
  double thickness_mm = 2;  // fabric on its stiff backing
  double relief_mm = 0.6;   // height of the stitches above the fabric
  // Tilt of the disc about the object x axis (0 = lying flat); the disc is
  // lifted so its lowest point touches the platter.
  double tilt_rad = 0;
};

// The texture of a mesh object: seeded and procedural like the built-in
// objects' (the file's colours, if any, are not used), with colour variation
// down to ~0.2 mm for the stereo matcher.
enum class MeshSurface {
  kStone,    // terracotta, sandstone or celadon, cloudy, with a 0.4 mm grain
  kWood,     // the carved box's wood: growth rings at a seeded slant, fibres, pores
  kPainted,  // the egg's painted pattern in dye colours, wrapped about the z axis by height
  kFabric,   // plain weave (0.5 mm threads) in a seeded tartan of the embroidery's thread
             // colours, projected along the normal's main axis
};
std::string_view ToString(MeshSurface surface);  // "stone", "wood", "painted", "fabric"
bool MeshSurfaceFromString(std::string_view text, MeshSurface* surface);

struct MeshOptions {
  std::string path;    // PLY file (see ply.h)
  double scale = 1.0;  // mm per file unit (ignored when size_mm > 0)
  double size_mm = 0;  // > 0: scale so the largest bounding-box extent is this
  // Rotation applied to the file's coordinates before scaling (Rodrigues, rad);
  // e.g. {π/2, 0, 0} turns a +Y-up mesh +Z-up. Then the mesh is moved so its
  // bounding box is centred on the object z axis with its bottom at z = 0.
  cv::Vec3d rotation_rad{0, 0, 0};
  MeshSurface surface = MeshSurface::kStone;
};

struct ObjectOptions {
  ObjectType type = ObjectType::kCarvedBox;
  CarvedBoxOptions carved_box;
  EggOptions egg;
  EmbroideryOptions embroidery;
  MeshOptions mesh;
  // The pose an operator lays the object in (on its side, upside down, any
  // tilt): a rotation of the object frame (Rodrigues, rad) applied first;
  // the rotated object is then moved so its axis-aligned bounding box is
  // centred on the turntable axis and its lowest point rests on the platter
  // (the carved box's corners, the egg's ellipsoid, the mesh's vertices
  // exactly; the embroidery by its disc's bounds). Zero (the default) leaves
  // the object standing on its base as built, untouched.
  // Scene::world_from_object includes the rotation and the seating exactly.
  cv::Vec3d rotation_rad{0, 0, 0};
  // Placement on the platter at turntable angle 0 (world x, y of the object
  // frame origin, or with a rotation of the seated bounding box's centre, mm)
  // and rotation about the axis (rad), both after `rotation_rad`.
  cv::Point2d position_mm{0, 0};
  double yaw_rad = 0;
};

// Calibration boards, in the board frame of craftscan's calibration
// (BoardCornersInBoard in calibration.h): x along the `cols` direction, y
// along the `rows` direction, both in the printed face, which looks towards
// −z (seen from the front x runs right and y down; z points into the
// board). Chessboard: origin at inner corner 0, corner (i, j) at
// (i·s, j·s, 0); the grid is (cols + 1) × (rows + 1) squares from (−s, −s),
// the square there black. ChArUco: corners and markers as OpenCV's
// cv::aruco::CharucoBoard::create(cols, rows, square_mm, marker_mm,
// dictionary) (chessboardCorners, objPoints), origin at the grid's corner,
// cols × rows squares, the square at the origin black. Patterns are drawn
// exactly (vector, no texture resampling). A white margin surrounds the
// grid; the board is a slab from z = 0 back to z = thickness_mm, grey behind
// and on its edges.
enum class BoardPlacement {
  kOnPlatter,  // printed face up (board z down), `thickness_mm` above the platter; turns with it
  kInWorld,    // world_from_board = (rotation_rad, translation_mm); does not turn
};
std::string_view ToString(BoardPlacement placement);  // "on_platter", "in_world"
bool BoardPlacementFromString(std::string_view text, BoardPlacement* placement);

struct BoardOptions {
  bool enabled = false;
  BoardSpec spec;         // type, cols, rows, square_mm, marker_mm, aruco_dictionary
  double margin_mm = 10;  // white border around the square grid
  BoardPlacement placement = BoardPlacement::kOnPlatter;
  double thickness_mm = 3;  // slab from the printed face (z = 0) back to z = thickness_mm
  // kOnPlatter: board frame origin at world (x, y) at turntable angle 0 (mm),
  // printed face `thickness_mm` above the platter, yaw about the axis (rad).
  cv::Point2d platter_position_mm{-60, -45};
  double platter_yaw_rad = 0;
  // kInWorld: world_from_board as a Rodrigues vector (rad) and translation (mm).
  // To place a board relative to the cameras use SimStation::world_from_rig().
  cv::Vec3d rotation_rad{0, 0, 0};
  cv::Vec3d translation_mm{0, 0, 0};

  bool IsValid(std::string* why) const;
};

enum class PlatterTexture {
  kPlain,     // light grey, almost uniform
  kTextured,  // cork-like speckle with degree marks at the rim
};
std::string_view ToString(PlatterTexture texture);  // "plain", "textured"
bool PlatterTextureFromString(std::string_view text, PlatterTexture* texture);

enum class Background {
  kDarkCloth,  // near-black woven cloth on the table and the backdrop
  kTextured,   // colourful seeded pattern (gives matchers texture everywhere)
};
std::string_view ToString(Background background);  // "dark_cloth", "textured"
bool BackgroundFromString(std::string_view text, Background* background);

// A pattern projector beside the cameras (what real stations add for
// surfaces without texture: flat paint, dark fabric): a pinhole projector at
// `position_mm` aimed at `target_mm` (world frame) casting a fixed random
// pattern of square pixels (each lit with probability `fill`, bilinearly
// blurred into its neighbours as a slightly defocused projector blurs
// them) over a square field of `fov_deg`; its light adds `power` × cos θ ×
// pattern to a surface's irradiance, and objects cast its shadows.
struct ProjectorOptions {
  bool enabled = false;
  cv::Vec3d position_mm{0, -346, 260};  // world; the sim driver sets it from the rig
  cv::Vec3d target_mm{0, 0, 30};
  double fov_deg = 30;      // (0, 120)
  int pattern_px = 400;     // pattern pixels across the field, 8..8192
  double power = 0.6;       // [0, 10]
  double fill = 0.5;        // (0, 1)
  std::uint64_t seed = 11;  // the pattern

  bool IsValid(std::string* why) const;
};

// The projector a station mounts on its camera head (the sim driver's
// `projector: 1`): 30 mm above the middle of the camera bar, aimed at the
// rig's target, the other fields at their defaults; enabled.
ProjectorOptions ProjectorOnCameraHead(const RigOptions& rig);

struct LightingOptions {
  double ambient = 0.3;       // radiance factor of the ambient light (≥ 0)
  double directional = 0.75;  // radiance factor of the directional light at normal incidence
  // Direction towards the light in the world frame (any length > 0). The
  // default lights from above, in front and to the left of the rig.
  cv::Vec3d direction_to_light{-0.35, -0.6, 0.72};
  bool shadows = true;  // cast shadows from the directional light
  ProjectorOptions projector;

  bool IsValid(std::string* why) const;
};

struct SceneOptions {
  ObjectOptions object;
  BoardOptions board;
  double turntable_angle_rad = 0;  // initial; see Scene::SetTurntableAngle
  double platter_radius_mm = 150;
  double platter_thickness_mm = 20;  // the table surface is this far below the platter top
  PlatterTexture platter_texture = PlatterTexture::kTextured;
  Background background = Background::kDarkCloth;
  double backdrop_distance_mm = 300;  // the vertical backdrop at world y = +this
  LightingOptions lighting;
  std::uint64_t seed = 1;  // every procedural texture and carving pattern

  bool IsValid(std::string* why) const;  // names the offending field; does not open files
};

// What a pixel sees.
enum class SurfaceLabel : std::uint8_t {
  kNothing = 0,     // the ray hit no surface
  kBackground = 1,  // table or backdrop
  kPlatter = 2,
  kObject = 3,
  kBoard = 4,
};

// A scene: the turntable with its object and board, the table and backdrop.
// Immutable apart from the turntable angle. Rendering reads it from many
// threads; SetTurntableAngle must not run concurrently with a render.
class Scene {
 public:
  // Builds the scene (loads the mesh and builds its BVH, lays out the
  // ChArUco markers).
  // Returns null and sets *error (naming the option or the file) on failure.
  static std::unique_ptr<Scene> Create(const SceneOptions& options, std::string* error);
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  const SceneOptions& options() const;
  // Switches the pattern projector (LightingOptions::projector) off and on
  // again, as a station does for a texture frame between pattern frames.
  // False (nothing changes) when the scene was created without one.
  bool SetProjectorOn(bool on);
  bool projector_on() const;
  void SetTurntableAngle(double angle_rad);
  double turntable_angle_rad() const;

  // Object frame → world at the current angle (identity with no object).
  cv::Matx44d world_from_object() const;
  // Board frame (see BoardOptions) → world at the current angle (identity
  // with no board).
  cv::Matx44d world_from_board() const;
  // Number of triangles of a mesh object (0 for other objects).
  std::size_t mesh_triangle_count() const;

  // First surface along the ray origin + t·direction, t > 0 (world frame,
  // any non-zero direction length; t in units of that length). Returns false
  // when nothing is hit. Thread-safe.
  bool Intersect(const cv::Vec3d& origin_in_world, const cv::Vec3d& direction_in_world, double* t,
                 SurfaceLabel* label) const;

 private:
  friend class SimStation;
  struct Impl;
  Scene();
  std::unique_ptr<Impl> impl_;
};

// ---------------------------------------------------------------- render ---

// What SimStation::Render computes. The ground truth (two more rays and an
// occlusion test per pixel) takes about a third of a point-sampled render
// (a board scene on the default rig: 0.96 → 0.66 CPU-s per pair); drivers
// that only show images skip it. The images do not depend on it.
enum class RenderOutputs {
  kImagesAndGroundTruth,
  kImagesOnly,     // the depth, label, mask and rectified maps of StereoRender stay empty
  kLeftImageOnly,  // as kImagesOnly without the right image (a texture frame)
};

struct StereoRender {
  enum class Status { kOk, kFailed };
  Status status = Status::kFailed;
  std::string message;

  // Raw images (distorted, with noise), CV_8UC3 BGR, image_size.
  cv::Mat left, right;

  // Ground truth at the raw left pixel centres (image_size):
  cv::Mat left_depth_mm;  // CV_32FC1, z of the surface in the left camera frame; NaN = no surface
  cv::Mat left_labels;    // CV_8UC1, SurfaceLabel
  cv::Mat left_object_mask;  // CV_8UC1, 255 where the object is seen

  // Ground truth on the rectified left grid (calibration R1/P1, image_size):
  // for each rectified left pixel, the surface point on its ray, projected
  // into the rectified right image with P2: d = x_left − x_right (px). It
  // agrees with Q: Q·(x, y, d, 1) gives that point in the rig frame.
  cv::Mat rectified_disparity;    // CV_32FC1; NaN = no surface
  cv::Mat rectified_depth_mm;     // CV_32FC1, z of that point in the rig frame
  cv::Mat rectified_labels;       // CV_8UC1, SurfaceLabel
  cv::Mat rectified_object_mask;  // CV_8UC1, 255 where the object is seen
  // 255 where the point is also seen by the right camera (inside its raw
  // image and not occluded): Middlebury's "non-occluded".
  cv::Mat rectified_visible_right;

  double turntable_angle_rad = 0;
  cv::Matx44d world_from_object = cv::Matx44d::eye();
  cv::Matx44d world_from_board = cv::Matx44d::eye();
  cv::Matx44d rig_from_world = cv::Matx44d::eye();
  StereoCalibration calibration;  // the rig's exact calibration (board = the scene's board)

  double render_ms = 0;  // wall clock of Render

  bool IsUsable() const { return status == Status::kOk; }
};

// The rig: cameras, their exact calibration and cached per-pixel rays.
// Render is const and thread-safe (several renders may run at once).
class SimStation {
 public:
  // Validates the options, computes the calibration (cv::stereoRectify with
  // flags 0 and alpha 0: each rectified image keeps its own principal point,
  // so the point where the optical axes meet has a disparity near 0 (within
  // ~20 px with the default rig, where f·B/Z is ~600 px), nearer points
  // positive, farther ones negative: an object at the target needs a search
  // band of about ±(f·B·Δz/z²) around 0 (the default carved box: −61…+69 px);
  // Q accounts for the offset. alpha 0 crops the rectified images to valid
  // pixels.) Then the per-pixel ray caches.
  // Returns null and sets *error on invalid options.
  static std::unique_ptr<SimStation> Create(const RigOptions& options, std::string* error);
  ~SimStation();
  SimStation(const SimStation&) = delete;
  SimStation& operator=(const SimStation&) = delete;

  const RigOptions& options() const;
  // image_size, intrinsics, distortion, R/T (right_from_left), R1 R2 P1 P2 Q,
  // and the turntable axis in the rig frame. board is the default BoardSpec.
  const StereoCalibration& calibration() const;
  cv::Matx44d rig_from_world() const;
  cv::Matx44d world_from_rig() const;
  cv::Matx44d left_from_world() const;   // raw left camera
  cv::Matx44d right_from_world() const;  // raw right camera

  // Renders both cameras and (unless kImagesOnly) the ground truth at the
  // scene's current angle. frame_index varies the sensor noise between
  // frames. Uses options().num_threads threads; results do not depend on the
  // count.
  StereoRender Render(const Scene& scene, std::uint64_t frame_index = 0,
                      RenderOutputs outputs = RenderOutputs::kImagesAndGroundTruth) const;

 private:
  SimStation();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::sim
