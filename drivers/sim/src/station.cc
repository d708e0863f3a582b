// The simulated rig: camera geometry, exact calibration, cached per-pixel
// rays and the multi-threaded renderer.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <opencv2/calib3d.hpp>

#include "craftscan/sim/station.h"
#include "math.h"
#include "scene_impl.h"
#include "texture.h"

namespace craftscan::sim {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// A raw camera: OpenCV pinhole with k1 k2 p1 p2 k3 distortion and its pose.
struct Camera {
  double fx = 1, fy = 1, cx = 0, cy = 0;
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;
  Rigid cam_from_world, world_from_cam;

  // Normalized undistorted (x, y) → normalized distorted, and the Jacobian.
  void Distort(double x, double y, double* xd, double* yd, double jac[4]) const {
    const double r2 = x * x + y * y;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    *xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
    *yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
    if (jac) {
      const double dr = k1 + r2 * (2 * k2 + 3 * k3 * r2);  // d radial / d r2
      jac[0] = radial + 2 * x * x * dr + 2 * p1 * y + 6 * p2 * x;
      jac[1] = 2 * x * y * dr + 2 * p1 * x + 2 * p2 * y;
      jac[2] = 2 * x * y * dr + 2 * p1 * x + 2 * p2 * y;
      jac[3] = radial + 2 * y * y * dr + 6 * p1 * y + 2 * p2 * x;
    }
  }

  // Pixel (u, v) → the normalized undistorted (x, y) that distorts onto it,
  // by Newton's method (residual < 1e-14, i.e. ~1e-11 px). False if it does
  // not converge (distortion not invertible there).
  bool Undistort(double u, double v, double* x, double* y) const {
    const double xd = (u - cx) / fx, yd = (v - cy) / fy;
    double X = xd, Y = yd;
    for (int i = 0; i < 60; ++i) {
      double dx, dy, j[4];
      Distort(X, Y, &dx, &dy, j);
      const double ex = dx - xd, ey = dy - yd;
      if (std::abs(ex) + std::abs(ey) < 1e-14) {
        *x = X;
        *y = Y;
        return true;
      }
      const double det = j[0] * j[3] - j[1] * j[2];
      if (!(std::abs(det) > 1e-9)) return false;
      X -= (j[3] * ex - j[1] * ey) / det;
      Y -= (-j[2] * ex + j[0] * ey) / det;
    }
    return false;
  }

  // World point → pixel (with distortion). False if behind the camera.
  bool Project(const V3& p_world, double* u, double* v) const {
    const V3 p = cam_from_world.Apply(p_world);
    if (!(p.z > 0)) return false;
    double xd, yd;
    Distort(p.x / p.z, p.y / p.z, &xd, &yd, nullptr);
    *u = fx * xd + cx;
    *v = fy * yd + cy;
    return true;
  }

  cv::Matx33d K() const { return {fx, 0, cx, 0, fy, cy, 0, 0, 1}; }
  cv::Vec<double, 5> D() const { return {k1, k2, p1, p2, k3}; }
};

Camera MakeCamera(const SimCameraOptions& o, cv::Size size) {
  Camera c;
  c.fx = o.focal_px;
  c.fy = o.focal_px * o.aspect;
  c.cx = (size.width - 1) / 2.0 + o.principal_offset_px.x;
  c.cy = (size.height - 1) / 2.0 + o.principal_offset_px.y;
  c.k1 = o.distortion[0];
  c.k2 = o.distortion[1];
  c.p1 = o.distortion[2];
  c.p2 = o.distortion[3];
  c.k3 = o.distortion[4];
  return c;
}

// cam_from_world from the camera's axes (in world) and its centre.
Rigid CameraPose(const V3& x, const V3& y, const V3& z, const V3& centre) {
  Rigid r;
  const double m[9] = {x.x, x.y, x.z, y.x, y.y, y.z, z.x, z.y, z.z};
  std::copy(m, m + 9, r.R.m);
  r.t = -(r.R * centre);
  return r;
}

// Runs fn(row) for every row in [0, rows); parallelism from the options.
template <class Fn>
void ForRows(tbb::task_arena* arena, int rows, Fn&& fn) {
  auto body = [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) fn(y);
  };
  if (arena == nullptr) {
    body(tbb::blocked_range<int>(0, rows));
    return;
  }
  arena->execute([&] { tbb::parallel_for(tbb::blocked_range<int>(0, rows, 1), body); });
}

// Standard normal from a per-pixel hash (Box–Muller): independent of the
// order in which pixels are rendered.
double GaussianNoise(std::uint64_t key) {
  const double u1 = 1.0 - ToUnit(Mix64(key));  // (0, 1]
  const double u2 = ToUnit(Mix64(key ^ 0x5851f42d4c957f2dULL));
  return std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
}

std::uint8_t Quantize(double value) {
  const double v = std::clamp(value, 0.0, 255.0);
  return static_cast<std::uint8_t>(v + 0.5);
}

}  // namespace

struct SimStation::Impl {
  RigOptions options;
  StereoCalibration calibration;
  Camera left, right;
  Rigid rig_from_world, world_from_rig;
  cv::Matx34d P1, P2;
  int samples = 1;                           // per pixel (s²)
  std::vector<float> left_rays, right_rays;  // (x, y) per supersample, normalized
  std::vector<double> left_centre_rays;      // (x, y) per pixel centre, normalized
  std::unique_ptr<tbb::task_arena> arena;    // null for one thread

  bool CacheRays(const Camera& camera, std::vector<float>* rays, std::vector<double>* centre,
                 std::string* error) const;
};

SimStation::SimStation() : impl_(std::make_unique<Impl>()) {}
SimStation::~SimStation() = default;

bool SimStation::Impl::CacheRays(const Camera& camera, std::vector<float>* rays,
                                 std::vector<double>* centre, std::string* error) const {
  const int w = options.image_size.width, h = options.image_size.height;
  const int s = options.supersampling;
  rays->assign(static_cast<std::size_t>(w) * h * samples * 2, 0.f);
  if (centre) centre->assign(static_cast<std::size_t>(w) * h * 2, 0.0);
  std::vector<char> row_ok(static_cast<std::size_t>(h), 1);
  ForRows(arena.get(), h, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const std::size_t pixel = static_cast<std::size_t>(y) * w + x;
      for (int k = 0; k < samples; ++k) {
        const double u = x + (k % s + 0.5) / s - 0.5, v = y + (k / s + 0.5) / s - 0.5;
        double rx, ry;
        if (!camera.Undistort(u, v, &rx, &ry)) {
          row_ok[static_cast<std::size_t>(y)] = 0;
          return;
        }
        (*rays)[(pixel * samples + k) * 2] = static_cast<float>(rx);
        (*rays)[(pixel * samples + k) * 2 + 1] = static_cast<float>(ry);
      }
      if (centre) {
        double rx, ry;
        if (!camera.Undistort(x, y, &rx, &ry)) {
          row_ok[static_cast<std::size_t>(y)] = 0;
          return;
        }
        (*centre)[pixel * 2] = rx;
        (*centre)[pixel * 2 + 1] = ry;
      }
    }
  });
  for (int y = 0; y < h; ++y) {
    if (!row_ok[static_cast<std::size_t>(y)]) {
      *error = "the distortion cannot be inverted at image row " + std::to_string(y) +
               " (is it monotonic over the image?)";
      return false;
    }
  }
  return true;
}

std::unique_ptr<SimStation> SimStation::Create(const RigOptions& options, std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) {
    if (error) *error = "invalid rig options: " + why;
    return nullptr;
  }
  std::unique_ptr<SimStation> station(new SimStation());
  Impl& s = *station->impl_;
  s.options = options;
  s.samples = options.supersampling * options.supersampling;
  if (options.num_threads > 1) s.arena = std::make_unique<tbb::task_arena>(options.num_threads);
  const cv::Size size = options.image_size;
  s.left = MakeCamera(options.left, size);
  s.right = MakeCamera(options.right, size);

  // Head: looks at the target on the axis from the world's −Y side, down by
  // the elevation; x right (world +X), y down, z forward.
  const double elevation = options.elevation_deg * kPi / 180;
  const V3 target(0, 0, options.target_height_mm);
  const V3 forward(0, std::cos(elevation), -std::sin(elevation));
  const V3 mid = target - forward * options.distance_mm;
  const V3 down = Normalized(V3(0, 0, -1) - forward * Dot(V3(0, 0, -1), forward));
  const V3 right_axis = Cross(down, forward);
  const V3 centre_left = mid - right_axis * (options.baseline_mm / 2);
  const V3 centre_right = mid + right_axis * (options.baseline_mm / 2);
  // Toe-in: each camera turns about its y axis towards the other by half
  // the vergence.
  const double half = options.vergence_deg * kPi / 360;
  const V3 z_left = forward * std::cos(half) + right_axis * std::sin(half);
  const V3 x_left = right_axis * std::cos(half) - forward * std::sin(half);
  const V3 z_right = forward * std::cos(half) - right_axis * std::sin(half);
  const V3 x_right = right_axis * std::cos(half) + forward * std::sin(half);
  s.left.cam_from_world = CameraPose(x_left, down, z_left, centre_left);
  Rigid right_nominal = CameraPose(x_right, down, z_right, centre_right);
  Rigid misalign;
  misalign.R = M3::Rodrigues(options.right_misalignment_rad);
  s.right.cam_from_world = misalign * right_nominal;  // rotation about the right centre
  s.left.world_from_cam = s.left.cam_from_world.Inverse();
  s.right.world_from_cam = s.right.cam_from_world.Inverse();

  // right_from_left.
  const Rigid right_from_left = s.right.cam_from_world * s.left.world_from_cam;
  StereoCalibration& c = s.calibration;
  c.image_size = size;
  c.left.camera_matrix = s.left.K();
  c.left.distortion = s.left.D();
  c.right.camera_matrix = s.right.K();
  c.right.distortion = s.right.D();
  c.R = right_from_left.R.ToCv();
  c.T = ToCv(right_from_left.t);
  try {
    cv::Mat R1, R2, P1, P2, Q;
    cv::stereoRectify(cv::Mat(c.left.camera_matrix), cv::Mat(c.left.distortion),
                      cv::Mat(c.right.camera_matrix), cv::Mat(c.right.distortion), size,
                      cv::Mat(c.R), cv::Mat(c.T), R1, R2, P1, P2, Q, /*flags=*/0, /*alpha=*/0,
                      size);
    c.R1 = cv::Matx33d(R1);
    c.R2 = cv::Matx33d(R2);
    c.P1 = cv::Matx34d(P1);
    c.P2 = cv::Matx34d(P2);
    c.Q = cv::Matx44d(Q);
  } catch (const cv::Exception& e) {
    if (error) *error = std::string("cv::stereoRectify failed: ") + e.what();
    return nullptr;
  }
  s.P1 = c.P1;
  s.P2 = c.P2;
  Rigid rig_from_left;
  rig_from_left.R = M3::FromCv(c.R1);
  s.rig_from_world = rig_from_left * s.left.cam_from_world;
  s.world_from_rig = s.rig_from_world.Inverse();
  c.turntable.valid = true;
  c.turntable.direction_in_rig = ToCv(s.rig_from_world.Rotate(V3(0, 0, 1)));
  c.turntable.point_in_rig_mm = ToCv(s.rig_from_world.t);

  std::string ray_error;
  if (!s.CacheRays(s.left, &s.left_rays, &s.left_centre_rays, &ray_error)) {
    if (error) *error = "left camera: " + ray_error;
    return nullptr;
  }
  if (!s.CacheRays(s.right, &s.right_rays, nullptr, &ray_error)) {
    if (error) *error = "right camera: " + ray_error;
    return nullptr;
  }
  return station;
}

const RigOptions& SimStation::options() const { return impl_->options; }
const StereoCalibration& SimStation::calibration() const { return impl_->calibration; }
cv::Matx44d SimStation::rig_from_world() const { return impl_->rig_from_world.ToCv(); }
cv::Matx44d SimStation::world_from_rig() const { return impl_->world_from_rig.ToCv(); }
cv::Matx44d SimStation::left_from_world() const { return impl_->left.cam_from_world.ToCv(); }
cv::Matx44d SimStation::right_from_world() const { return impl_->right.cam_from_world.ToCv(); }

StereoRender SimStation::Render(const Scene& scene, std::uint64_t frame_index,
                                RenderOutputs outputs) const {
  const auto start = std::chrono::steady_clock::now();
  const Impl& s = *impl_;
  const Scene::Impl& world = *scene.impl_;
  const int w = s.options.image_size.width, h = s.options.image_size.height;
  const int samples = s.samples;
  const double gain = 255.0 * s.options.exposure / samples;
  const double sigma = s.options.noise_sigma;
  const std::uint64_t noise_seed =
      Hash(Mix64(s.options.seed), static_cast<std::int64_t>(frame_index));

  StereoRender out;
  out.left.create(h, w, CV_8UC3);
  out.right.create(h, w, CV_8UC3);
  const V3 centre_left = s.left.world_from_cam.t, centre_right = s.right.world_from_cam.t;
  const double rf_x = s.P1(0, 0), rf_y = s.P1(1, 1), rc_x = s.P1(0, 2), rc_y = s.P1(1, 2);
  const cv::Matx34d& P2 = s.P2;

  // One camera's colour for pixel (x, y): the average radiance of its
  // supersamples, exposed, with noise, quantized.
  auto shade_pixel = [&](const Camera& camera, const std::vector<float>& rays, int cam, int x,
                         int y, std::uint8_t* bgr) {
    const V3 origin = camera.world_from_cam.t;
    V3 sum(0, 0, 0);
    const std::size_t base = (static_cast<std::size_t>(y) * w + x) * samples * 2;
    for (int k = 0; k < samples; ++k) {
      const V3 d =
          camera.world_from_cam.Rotate(V3(rays[base + 2 * k], rays[base + 2 * k + 1], 1.0));
      Scene::Impl::Hit hit;
      if (world.Intersect(origin, d, 0, kInf, &hit)) sum += world.Shade(d, hit);
    }
    const double value[3] = {sum.x * gain, sum.y * gain, sum.z * gain};
    for (int ch = 0; ch < 3; ++ch) {
      double v = value[ch];
      if (sigma > 0) {
        const std::uint64_t key = Hash(noise_seed, cam, y, static_cast<std::int64_t>(x) * 4 + ch);
        v += sigma * GaussianNoise(key);
      }
      bgr[ch] = Quantize(v);
    }
  };

  // The poses, calibration and timing every render reports.
  auto finish = [&] {
    out.turntable_angle_rad = world.angle_rad;
    out.world_from_object = world.WorldFromObject().ToCv();
    out.world_from_board = world.WorldFromBoard().ToCv();
    out.rig_from_world = s.rig_from_world.ToCv();
    out.calibration = s.calibration;
    if (world.options.board.enabled) out.calibration.board = world.options.board.spec;
    out.status = StereoRender::Status::kOk;
    out.render_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return out;
  };

  if (outputs != RenderOutputs::kImagesAndGroundTruth) {
    const bool right = outputs == RenderOutputs::kImagesOnly;
    if (!right) out.right.release();
    ForRows(s.arena.get(), h, [&](int y) {
      auto* left_row = out.left.ptr<std::uint8_t>(y);
      for (int x = 0; x < w; ++x) shade_pixel(s.left, s.left_rays, 0, x, y, left_row + 3 * x);
      if (!right) return;
      auto* right_row = out.right.ptr<std::uint8_t>(y);
      for (int x = 0; x < w; ++x) shade_pixel(s.right, s.right_rays, 1, x, y, right_row + 3 * x);
    });
    return finish();
  }

  out.left_depth_mm.create(h, w, CV_32FC1);
  out.left_labels.create(h, w, CV_8UC1);
  out.left_object_mask.create(h, w, CV_8UC1);
  out.rectified_disparity.create(h, w, CV_32FC1);
  out.rectified_depth_mm.create(h, w, CV_32FC1);
  out.rectified_labels.create(h, w, CV_8UC1);
  out.rectified_object_mask.create(h, w, CV_8UC1);
  out.rectified_visible_right.create(h, w, CV_8UC1);

  ForRows(s.arena.get(), h, [&](int y) {
    auto* left_row = out.left.ptr<std::uint8_t>(y);
    auto* right_row = out.right.ptr<std::uint8_t>(y);
    auto* depth_row = out.left_depth_mm.ptr<float>(y);
    auto* label_row = out.left_labels.ptr<std::uint8_t>(y);
    auto* mask_row = out.left_object_mask.ptr<std::uint8_t>(y);
    auto* disp_row = out.rectified_disparity.ptr<float>(y);
    auto* rdepth_row = out.rectified_depth_mm.ptr<float>(y);
    auto* rlabel_row = out.rectified_labels.ptr<std::uint8_t>(y);
    auto* rmask_row = out.rectified_object_mask.ptr<std::uint8_t>(y);
    auto* visible_row = out.rectified_visible_right.ptr<std::uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      shade_pixel(s.left, s.left_rays, 0, x, y, left_row + 3 * x);
      shade_pixel(s.right, s.right_rays, 1, x, y, right_row + 3 * x);

      // Left ground truth along the ray through the pixel centre: the ray
      // is (x, y, 1) in camera coordinates, so t is the depth z.
      {
        const std::size_t pixel = static_cast<std::size_t>(y) * w + x;
        const V3 d = s.left.world_from_cam.Rotate(
            V3(s.left_centre_rays[2 * pixel], s.left_centre_rays[2 * pixel + 1], 1.0));
        Scene::Impl::Hit hit;
        if (world.Intersect(centre_left, d, 0, kInf, &hit)) {
          depth_row[x] = static_cast<float>(hit.local.t);
          label_row[x] = static_cast<std::uint8_t>(hit.primitive->label());
        } else {
          depth_row[x] = kNaN;
          label_row[x] = static_cast<std::uint8_t>(SurfaceLabel::kNothing);
        }
        mask_row[x] = label_row[x] == static_cast<std::uint8_t>(SurfaceLabel::kObject) ? 255 : 0;
      }

      // Rectified ground truth: the ray of rectified pixel (x, y) in the rig
      // frame is ((x − cx)/f, (y − cy)/f, 1); project its surface point with P2.
      {
        const V3 d_rig((x - rc_x) / rf_x, (y - rc_y) / rf_y, 1.0);
        const V3 d = s.world_from_rig.Rotate(d_rig);
        Scene::Impl::Hit hit;
        visible_row[x] = 0;
        if (world.Intersect(centre_left, d, 0, kInf, &hit)) {
          const double t = hit.local.t;
          const V3 p_rig = d_rig * t;
          const double xr =
              (P2(0, 0) * p_rig.x + P2(0, 1) * p_rig.y + P2(0, 2) * p_rig.z + P2(0, 3)) /
              (P2(2, 0) * p_rig.x + P2(2, 1) * p_rig.y + P2(2, 2) * p_rig.z + P2(2, 3));
          disp_row[x] = static_cast<float>(x - xr);
          rdepth_row[x] = static_cast<float>(t);
          rlabel_row[x] = static_cast<std::uint8_t>(hit.primitive->label());
          // Seen by the right camera: inside its raw image, nothing in between.
          const V3 p_world = centre_left + d * t;
          double u, v;
          if (s.right.Project(p_world, &u, &v) && u >= -0.5 && u < w - 0.5 && v >= -0.5 &&
              v < h - 0.5) {
            const V3 to_point = p_world - centre_right;
            const double length = Norm(to_point);
            const bool blocked = world.Occluded(centre_right, to_point, 0, 1 - 0.05 / length);
            visible_row[x] = blocked ? 0 : 255;
          }
        } else {
          disp_row[x] = kNaN;
          rdepth_row[x] = kNaN;
          rlabel_row[x] = static_cast<std::uint8_t>(SurfaceLabel::kNothing);
        }
        rmask_row[x] = rlabel_row[x] == static_cast<std::uint8_t>(SurfaceLabel::kObject) ? 255 : 0;
      }
    }
  });

  return finish();
}

}  // namespace craftscan::sim
