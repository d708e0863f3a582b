// Loop closure: a turntable-axis model, else a pose graph, both fitted by
// Levenberg–Marquardt over point residuals (Eigen; the problems have at most
// a few dozen parameters, so a numeric Jacobian is cheap and exact enough).
#include "craftscan/pipeline/registration/loop_closure.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include "common/eigen_cv.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace craftscan {
namespace {

using Mat4 = Eigen::Matrix4d;
using Vec = Eigen::VectorXd;

Mat4 InverseRigid(const Mat4& T) {
  Mat4 inv = Mat4::Identity();
  inv.topLeftCorner<3, 3>() = T.topLeftCorner<3, 3>().transpose();
  inv.topRightCorner<3, 1>() = -inv.topLeftCorner<3, 3>() * T.topRightCorner<3, 1>();
  return inv;
}

Mat4 AxisRotation(const Eigen::Vector3d& a, const Eigen::Vector3d& c, double angle) {
  Mat4 T = Mat4::Identity();
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle, a.normalized()).toRotationMatrix();
  T.topLeftCorner<3, 3>() = R;
  T.topRightCorner<3, 1>() = c - R * c;
  return T;
}

Mat4 Exp(const Eigen::Matrix<double, 6, 1>& x) {
  Mat4 T = Mat4::Identity();
  const Eigen::Vector3d w = x.head<3>();
  const double angle = w.norm();
  if (angle > 0) T.topLeftCorner<3, 3>() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
  T.topRightCorner<3, 1>() = x.tail<3>();
  return T;
}

double RotationDeg(const Mat4& T) {
  return Eigen::AngleAxisd(Eigen::Matrix3d(T.topLeftCorner<3, 3>())).angle() * 180.0 / M_PI;
}

struct Problem {
  int num_views = 0;
  std::vector<PoseEdge> edges;
  std::vector<Mat4> measured;  // target_from_source per edge
  std::vector<Eigen::Vector3d> samples;
};

// Where the poses put sample point `s` of edge e's source minus where the
// measured registration puts it (mm).
Eigen::Vector3d EdgeResidual(const Mat4& model_target_from_source, const Mat4& measured,
                             const Eigen::Vector3d& s) {
  return (model_target_from_source.topLeftCorner<3, 3>() - measured.topLeftCorner<3, 3>()) * s +
         (model_target_from_source.topRightCorner<3, 1>() - measured.topRightCorner<3, 1>());
}

// Residuals of poses view0_from_view over all edges and samples (mm),
// weighted by sqrt(edge weight).
Vec Residuals(const Problem& p, const std::vector<Mat4>& poses) {
  Vec r(static_cast<Eigen::Index>(p.edges.size() * p.samples.size() * 3));
  Eigen::Index k = 0;
  for (std::size_t e = 0; e < p.edges.size(); ++e) {
    const PoseEdge& edge = p.edges[e];
    const Mat4 model = InverseRigid(poses[edge.target]) * poses[edge.source];
    const double w = std::sqrt(edge.weight);
    for (const auto& s : p.samples) {
      r.segment<3>(k) = w * EdgeResidual(model, p.measured[e], s);
      k += 3;
    }
  }
  return r;
}

// RMS and max of the unweighted point residuals.
void Figures(const Problem& p, const std::vector<Mat4>& poses, double* rms, double* max) {
  double sum = 0, mx = 0;
  std::size_t n = 0;
  for (std::size_t e = 0; e < p.edges.size(); ++e) {
    const PoseEdge& edge = p.edges[e];
    const Mat4 model = InverseRigid(poses[edge.target]) * poses[edge.source];
    for (const auto& s : p.samples) {
      const double d = EdgeResidual(model, p.measured[e], s).norm();
      sum += d * d;
      mx = std::max(mx, d);
      ++n;
    }
  }
  *rms = n ? std::sqrt(sum / n) : 0;
  *max = mx;
}

// Levenberg–Marquardt on a model with a local parametrisation: `poses_of(x)`
// gives the poses for an update x about the current state; `rebase(x)`
// makes x the new current state.
bool Solve(const Problem& p, int num_params, int max_iterations,
           const std::function<std::vector<Mat4>(const Vec&)>& poses_of,
           const std::function<void(const Vec&)>& rebase) {
  double lambda = 1e-3;
  Vec zero = Vec::Zero(num_params);
  Vec r = Residuals(p, poses_of(zero));
  double cost = r.squaredNorm();
  for (int it = 0; it < max_iterations; ++it) {
    Eigen::MatrixXd J(r.size(), num_params);
    for (int j = 0; j < num_params; ++j) {
      Vec x = zero;
      const double h = 1e-6;
      x[j] = h;
      const Vec rp = Residuals(p, poses_of(x));
      x[j] = -h;
      const Vec rm = Residuals(p, poses_of(x));
      J.col(j) = (rp - rm) / (2 * h);
    }
    const Eigen::MatrixXd H = J.transpose() * J;
    const Vec g = J.transpose() * r;
    bool improved = false;
    for (int attempt = 0; attempt < 10; ++attempt) {
      Eigen::MatrixXd A = H;
      A.diagonal() += lambda * H.diagonal().cwiseMax(1e-9);
      const Vec dx = A.ldlt().solve(-g);
      if (!dx.allFinite()) return false;
      const Vec r2 = Residuals(p, poses_of(dx));
      const double cost2 = r2.squaredNorm();
      if (cost2 < cost) {
        rebase(dx);
        r = r2;
        const double gain = cost - cost2;
        cost = cost2;
        lambda = std::max(1e-9, lambda / 3);
        improved = true;
        if (gain < 1e-12 * std::max(1.0, cost)) return true;
        break;
      }
      lambda *= 4;
    }
    if (!improved) return true;  // at a minimum (to numerical precision)
  }
  return true;
}

}  // namespace

bool LoopClosureOptions::IsValid(std::string* why) const {
  if (!(max_axis_rms_mm > 0)) return Fail(why, "max_axis_rms_mm must be > 0");
  if (max_iterations < 1) return Fail(why, "max_iterations must be ≥ 1");
  if (!(max_axis_disagreement_deg > 0) || !(max_axis_disagreement_mm > 0))
    return Fail(why, "max_axis_disagreement_deg and max_axis_disagreement_mm must be > 0");
  return true;
}

const char* ToString(LoopClosureResult::Model model) {
  switch (model) {
    case LoopClosureResult::Model::kNone:
      return "none";
    case LoopClosureResult::Model::kTurntableAxis:
      return "turntable_axis";
    case LoopClosureResult::Model::kPoseGraph:
      return "pose_graph";
  }
  return "none";
}

namespace {

// The problem of CloseLoop's inputs: edges that join views, connected to
// view 0, finite positive weights, at least three finite sample points not
// on one line. Returns what is wrong, empty when the problem is sound.
std::string BuildProblem(int num_views, const std::vector<PoseEdge>& edges,
                         const std::vector<cv::Vec3d>& sample_points_mm, Problem* p) {
  if (edges.empty()) return "no edges";
  p->num_views = num_views;
  std::vector<int> parent(num_views);  // connectivity: union-find over views
  for (int i = 0; i < num_views; ++i) parent[i] = i;
  std::function<int(int)> find = [&](int i) {
    return parent[i] == i ? i : parent[i] = find(parent[i]);
  };
  for (const PoseEdge& e : edges) {
    if (e.source < 0 || e.source >= num_views || e.target < 0 || e.target >= num_views ||
        e.source == e.target)
      return "edge " + std::to_string(e.source) + " → " + std::to_string(e.target) +
             " does not join two of the " + std::to_string(num_views) + " views";
    if (!(e.weight > 0) || !std::isfinite(e.weight)) return "edge weights must be finite and > 0";
    parent[find(e.source)] = find(e.target);
    p->edges.push_back(e);
    p->measured.push_back(ToEigen(e.target_from_source));
  }
  for (int i = 1; i < num_views; ++i)
    if (find(i) != find(0))
      return "view " + std::to_string(i) + " is not connected to view 0 by any edge";
  for (const auto& s : sample_points_mm) {
    if (!std::isfinite(s[0]) || !std::isfinite(s[1]) || !std::isfinite(s[2]))
      return "sample points must be finite";
    p->samples.emplace_back(s[0], s[1], s[2]);
  }
  if (p->samples.size() < 3) return "need at least 3 sample points";
  const Eigen::Vector3d a = p->samples[1] - p->samples[0];
  for (std::size_t i = 2; i < p->samples.size(); ++i)
    if (a.cross(p->samples[i] - p->samples[0]).norm() > 1e-6 * std::max(1.0, a.squaredNorm()))
      return {};
  return "sample points lie on one line";
}

// The turntable-axis model: every view a rotation about one axis. Starts
// from the mean of the views' rotation axes (sign-aligned, weighted by their
// angle up to 90°) and the least-squares point of t_k = (I − R_k)·c, then
// fits axis, point and one angle per view k ≥ 1; with `fixed`, the axis is
// that one and only the angles are fitted. Fills the result's axis figures;
// returns the poses, empty when no axis could be fitted.
std::vector<Mat4> FitTurntableAxis(const Problem& p, const std::vector<Mat4>& initial,
                                   const LoopClosureOptions& options, LoopClosureResult* result,
                                   const CalibratedAxis* fixed = nullptr) {
  const int num_views = p.num_views;
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  for (int k = 1; k < num_views; ++k) {
    const Eigen::AngleAxisd aa(Eigen::Matrix3d(initial[k].topLeftCorner<3, 3>()));
    Eigen::Vector3d a = aa.axis() * std::min(aa.angle(), M_PI / 2);  // small angles: ill-defined
    if (axis.norm() > 0 && a.dot(axis) < 0) a = -a;
    axis += a;
  }
  if (!(axis.norm() > 1e-9)) return {};
  axis.normalize();
  Eigen::MatrixXd A(3 * (num_views - 1) + 1, 3);
  Eigen::VectorXd b(3 * (num_views - 1) + 1);
  std::vector<double> angles(num_views, 0.0);
  for (int k = 1; k < num_views; ++k) {
    const Eigen::Matrix3d R = initial[k].topLeftCorner<3, 3>();
    A.block<3, 3>(3 * (k - 1), 0) = Eigen::Matrix3d::Identity() - R;
    b.segment<3>(3 * (k - 1)) = initial[k].topRightCorner<3, 1>();
    const Eigen::AngleAxisd aa(R);
    angles[k] = aa.axis().dot(axis) >= 0 ? aa.angle() : -aa.angle();
  }
  A.row(A.rows() - 1) = axis.transpose();
  b[b.size() - 1] = 0;
  Eigen::Vector3d center = A.colPivHouseholderQr().solve(b);
  if (fixed) {
    Eigen::Vector3d d(fixed->direction[0], fixed->direction[1], fixed->direction[2]);
    if (!(d.norm() > 0)) return {};
    d.normalize();
    axis = d.dot(axis) >= 0 ? d : Eigen::Vector3d(-d);
    center = Eigen::Vector3d(fixed->point_mm[0], fixed->point_mm[1], fixed->point_mm[2]);
    for (int k = 1; k < num_views; ++k) {
      const Eigen::AngleAxisd aa(Eigen::Matrix3d(initial[k].topLeftCorner<3, 3>()));
      angles[k] = aa.axis().dot(axis) >= 0 ? aa.angle() : -aa.angle();
    }
  }
  // Local parametrisation: [u v] tilt the axis in its normal plane, [cu cv]
  // move the point in that plane (neither with a fixed axis), then one
  // angle per view k ≥ 1.
  Eigen::Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
  const int axis_params = fixed ? 0 : 4;
  const int n = axis_params + (num_views - 1);
  auto state_of = [&](const Vec& x, Eigen::Vector3d* a, Eigen::Vector3d* c,
                      std::vector<double>* th) {
    *a = fixed ? axis : (axis + x[0] * e1 + x[1] * e2).normalized();
    *c = fixed ? center : Eigen::Vector3d(center + x[2] * e1 + x[3] * e2);
    *th = angles;
    for (int k = 1; k < num_views; ++k) (*th)[k] += x[axis_params - 1 + k];
  };
  auto poses_of = [&](const Vec& x) {
    Eigen::Vector3d a, c;
    std::vector<double> th;
    state_of(x, &a, &c, &th);
    std::vector<Mat4> poses(num_views);
    for (int k = 0; k < num_views; ++k) poses[k] = AxisRotation(a, c, th[k]);
    return poses;
  };
  auto rebase = [&](const Vec& x) {
    Eigen::Vector3d a, c;
    std::vector<double> th;
    state_of(x, &a, &c, &th);
    axis = a;
    center = c - a * a.dot(c);  // the point nearest the origin of view 0
    angles = th;
    e1 = axis.unitOrthogonal();
    e2 = axis.cross(e1);
  };
  if (!Solve(p, n, options.max_iterations, poses_of, rebase)) return {};
  std::vector<Mat4> poses = poses_of(Vec::Zero(n));
  double mx;
  Figures(p, poses, &result->axis_rms_mm, &mx);
  result->axis_direction = cv::Vec3d(axis[0], axis[1], axis[2]);
  result->axis_point_mm = cv::Vec3d(center[0], center[1], center[2]);
  result->angles_rad = angles;
  return poses;
}

// The result's fitted axis against `calibrated`: the angle between their
// directions (deg, either sign) and the distance between the points of the
// two lines nearest the samples' centroid (mm).
void Disagreement(const LoopClosureResult& result, const CalibratedAxis& calibrated,
                  const std::vector<Eigen::Vector3d>& samples, double* deg, double* mm) {
  const auto vec = [](const cv::Vec3d& v) { return Eigen::Vector3d(v[0], v[1], v[2]); };
  const Eigen::Vector3d a = vec(result.axis_direction).normalized();
  const Eigen::Vector3d b = vec(calibrated.direction).normalized();
  *deg = std::atan2(a.cross(b).norm(), std::abs(a.dot(b))) * 180 / M_PI;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& s : samples) centroid += s;
  centroid /= static_cast<double>(std::max<std::size_t>(1, samples.size()));
  const auto foot = [&](const Eigen::Vector3d& point, const Eigen::Vector3d& direction) {
    return Eigen::Vector3d(point + direction * direction.dot(centroid - point));
  };
  *mm = (foot(vec(result.axis_point_mm), a) - foot(vec(calibrated.point_mm), b)).norm();
}

// The pose graph: a free rigid update per view k ≥ 1. Returns false when it
// does not converge.
bool FitPoseGraph(const Problem& p, const LoopClosureOptions& options, std::vector<Mat4>* poses) {
  const int n = 6 * (p.num_views - 1);
  auto poses_of = [&](const Vec& x) {
    std::vector<Mat4> out = *poses;
    for (int k = 1; k < p.num_views; ++k) out[k] = Exp(x.segment<6>(6 * (k - 1))) * (*poses)[k];
    return out;
  };
  auto rebase = [&](const Vec& x) { *poses = poses_of(x); };
  return Solve(p, n, options.max_iterations, poses_of, rebase);
}

}  // namespace

LoopClosureResult CloseLoop(int num_views, const std::vector<PoseEdge>& edges,
                            const std::vector<cv::Matx44d>& initial_view0_from_view,
                            const std::vector<cv::Vec3d>& sample_points_mm,
                            const LoopClosureOptions& options,
                            const std::optional<CalibratedAxis>& calibrated) {
  return NoThrow<LoopClosureResult>(
      "CloseLoop", LoopClosureResult::Status::kFailed, [&]() -> LoopClosureResult {
        LoopClosureResult result;
        std::string why;
        if (!options.IsValid(&why)) {
          result.message = "invalid options: " + why;
          return result;
        }
        if (num_views < 2) {
          result.message = "need at least 2 views";
          return result;
        }
        if (static_cast<int>(initial_view0_from_view.size()) != num_views) {
          result.message = "initial poses: " + std::to_string(initial_view0_from_view.size()) +
                           " given for " + std::to_string(num_views) + " views";
          return result;
        }
        Problem p;
        result.message = BuildProblem(num_views, edges, sample_points_mm, &p);
        if (!result.message.empty()) return result;
        std::vector<Mat4> initial(num_views);
        for (int k = 0; k < num_views; ++k) initial[k] = ToEigen(initial_view0_from_view[k]);
        // Everything relative to view 0.
        const Mat4 inv0 = InverseRigid(initial[0]);
        for (auto& T : initial) T = inv0 * T;

        // Open loop: how far the starting poses are from the edges.
        double worst = 0;
        for (std::size_t e = 0; e < p.edges.size(); ++e) {
          const Mat4 model = InverseRigid(initial[p.edges[e].target]) * initial[p.edges[e].source];
          worst = std::max(worst, RotationDeg(InverseRigid(p.measured[e]) * model));
        }
        result.open_loop_rot_deg = worst;
        double mx;
        Figures(p, initial, &result.open_loop_rms_mm, &mx);

        std::vector<Mat4> axis_poses = FitTurntableAxis(p, initial, options, &result);
        const bool axis_ok = !axis_poses.empty();
        if (axis_ok && result.axis_rms_mm <= options.max_axis_rms_mm) {
          const Problem* solved = &p;
          // The registrations' own motions where a slid registration kept the
          // turntable's (the calibration's) motion instead.
          Problem own;
          LoopClosureResult own_fit = result;
          std::vector<Mat4> own_poses;
          if (calibrated) {
            std::vector<PoseEdge> registered = edges;
            bool slid = false;
            for (PoseEdge& e : registered)
              if (e.registered_target_from_source) {
                e.target_from_source = *e.registered_target_from_source;
                slid = true;
              }
            if (slid && BuildProblem(num_views, registered, sample_points_mm, &own).empty()) {
              own_poses = FitTurntableAxis(own, initial, options, &own_fit);
              if (own_fit.axis_rms_mm > options.max_axis_rms_mm) own_poses.clear();
            }
          }
          if (calibrated) {
            // The fitted axis against the calibrated one; where they agree,
            // the calibrated one (known far more precisely) and the angles.
            Disagreement(own_poses.empty() ? result : own_fit, *calibrated, p.samples,
                         &result.axis_disagreement_deg, &result.axis_disagreement_mm);
            if (result.axis_disagreement_deg <= options.max_axis_disagreement_deg &&
                result.axis_disagreement_mm <= options.max_axis_disagreement_mm) {
              LoopClosureResult about = result;
              std::vector<Mat4> poses = FitTurntableAxis(p, initial, options, &about, &*calibrated);
              if (!poses.empty() && about.axis_rms_mm <= options.max_axis_rms_mm) {
                result = about;
                result.calibrated_axis = true;
                axis_poses = std::move(poses);
              }
            } else if (!own_poses.empty()) {
              // The kept turntable motions are the contradicted calibration's.
              own_fit.axis_disagreement_deg = result.axis_disagreement_deg;
              own_fit.axis_disagreement_mm = result.axis_disagreement_mm;
              result = own_fit;
              axis_poses = std::move(own_poses);
              solved = &own;
            }
          }
          result.status = LoopClosureResult::Status::kOk;
          result.model = LoopClosureResult::Model::kTurntableAxis;
          for (const auto& T : axis_poses) result.view0_from_view.push_back(ToCv(T));
          Figures(*solved, axis_poses, &result.rms_mm, &result.max_mm);
          return result;
        }
        if (!options.allow_pose_graph) {
          result.message = axis_ok ? "the turntable-axis model fits poorly (RMS " +
                                         std::to_string(result.axis_rms_mm) +
                                         " mm) and the pose graph is off"
                                   : "no turntable axis could be fitted and the pose graph is off";
          return result;
        }

        std::vector<Mat4> poses = initial;
        if (!FitPoseGraph(p, options, &poses)) {
          result.message = "the pose graph did not converge";
          return result;
        }
        result.status = LoopClosureResult::Status::kOk;
        result.model = LoopClosureResult::Model::kPoseGraph;
        result.angles_rad.clear();
        for (const auto& T : poses) result.view0_from_view.push_back(ToCv(T));
        Figures(p, poses, &result.rms_mm, &result.max_mm);
        result.message = axis_ok ? "turntable-axis model rejected (RMS " +
                                       std::to_string(result.axis_rms_mm) + " mm): pose graph used"
                                 : "no turntable axis could be fitted: pose graph used";
        return result;
      });
}

}  // namespace craftscan
