// Joining two turns (turn_join.h) on synthetic turn clouds: an asymmetric
// solid seen standing and laid on its side, each turn without the face it
// rests on, with 0.1 mm noise along the normal. The join must find the true
// transform, refuse a symmetric egg, and refuse turns that share nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>
#include <random>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/registration/turn_join.h"

namespace craftscan {
namespace {

constexpr double kPi = std::numbers::pi;

struct Sphere {
  cv::Vec3d centre;
  double radius;
};

// A 60×40×30 box (base at z = 0, centred on the z axis) with two spherical
// bumps (no symmetry left), sampled every ~0.5 mm with outward normals.
PointCloud BumpyBox() {
  const double w = 60, d = 40, h = 30, step = 0.5;
  const std::vector<Sphere> bumps{{{30, 8, 18}, 7}, {{-12, -6, 30}, 9}};
  auto in_bump = [&](const cv::Vec3d& p) {
    for (const Sphere& s : bumps)
      if (cv::norm(p - s.centre) < s.radius) return true;
    return false;
  };
  auto in_box = [&](const cv::Vec3d& p) {
    return std::abs(p[0]) < w / 2 && std::abs(p[1]) < d / 2 && p[2] > 0 && p[2] < h;
  };
  PointCloud c;
  auto add = [&](const cv::Vec3d& p, const cv::Vec3d& n) {
    c.points_mm.emplace_back(p);
    c.normals.emplace_back(n);
  };
  for (int axis = 0; axis < 3; ++axis) {
    const cv::Vec3d size(w, d, h);
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (int side = -1; side <= 1; side += 2) {
      for (double a = step / 2; a < size[u]; a += step)
        for (double b = step / 2; b < size[v]; b += step) {
          cv::Vec3d p;
          p[axis] = side * size[axis] / 2;
          p[u] = a - size[u] / 2;
          p[v] = b - size[v] / 2;
          p[2] += h / 2;
          cv::Vec3d n(0, 0, 0);
          n[axis] = side;
          if (!in_bump(p)) add(p, n);
        }
    }
  }
  for (const Sphere& s : bumps) {  // Fibonacci lattice, ~0.5 mm apart
    const int n = static_cast<int>(4 * kPi * s.radius * s.radius / (step * step));
    for (int i = 0; i < n; ++i) {
      const double z = 1 - (2.0 * i + 1) / n, r = std::sqrt(1 - z * z);
      const double phi = i * kPi * (3 - std::sqrt(5.0));
      const cv::Vec3d dir(r * std::cos(phi), r * std::sin(phi), z);
      const cv::Vec3d p = s.centre + s.radius * dir;
      if (!in_box(p) && p[2] > 0) add(p, dir);
    }
  }
  return c;
}

// An egg (spheroid: 45 mm across, 60 mm tall, resting at z = 0).
PointCloud Egg() {
  const double a = 22.5, c = 30;
  PointCloud cloud;
  const int n = 30000;
  for (int i = 0; i < n; ++i) {
    const double z = 1 - (2.0 * i + 1) / n, r = std::sqrt(1 - z * z);
    const double phi = i * kPi * (3 - std::sqrt(5.0));
    const cv::Vec3d p(a * r * std::cos(phi), a * r * std::sin(phi), c + c * z);
    const cv::Vec3d g(p[0] / (a * a), p[1] / (a * a), (p[2] - c) / (c * c));
    cloud.points_mm.emplace_back(p);
    cloud.normals.emplace_back(g / cv::norm(g));
  }
  return cloud;
}

cv::Matx44d Rigid(const cv::Vec3d& rotation_rad, const cv::Vec3d& t) {
  cv::Matx33d R;
  cv::Rodrigues(rotation_rad, R);
  cv::Matx44d T = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) T(i, j) = R(i, j);
    T(i, 3) = t[i];
  }
  return T;
}

// One turn of `object` laid by `rotation_rad` (object frame → turn frame:
// rotated, seated at z = 0, centred, then yawed by the turntable's start):
// what the turn sees (everything above 1 mm: not the face it rests on),
// with 0.1 mm noise along the normal. *turn_from_object receives the pose.
PointCloud Turn(const PointCloud& object, const cv::Vec3d& rotation_rad, double yaw_rad,
                std::uint32_t seed, cv::Matx44d* turn_from_object) {
  PointCloud rotated = TransformCloud(Rigid(rotation_rad, {0, 0, 0}), object);
  cv::Vec3d lo(1e9, 1e9, 1e9), hi(-1e9, -1e9, -1e9);
  for (const cv::Vec3f& p : rotated.points_mm)
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], static_cast<double>(p[i]));
      hi[i] = std::max(hi[i], static_cast<double>(p[i]));
    }
  *turn_from_object = Rigid({0, 0, yaw_rad}, {0, 0, 0}) *
                      Rigid({0, 0, 0}, {-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]}) *
                      Rigid(rotation_rad, {0, 0, 0});
  const PointCloud placed = TransformCloud(*turn_from_object, object);
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.f, 0.1f);
  PointCloud seen;
  for (std::size_t i = 0; i < placed.size(); ++i) {
    if (placed.points_mm[i][2] < 1.0f) continue;
    seen.points_mm.push_back(placed.points_mm[i] + noise(rng) * placed.normals[i]);
    seen.normals.push_back(placed.normals[i]);
  }
  return seen;
}

// Lighter than the defaults (the synthetic clouds are clean): a few seconds.
TurnJoinOptions FastOptions() {
  TurnJoinOptions o;
  o.ransac_iterations = 20000;
  o.max_candidates = 4;
  o.hypothesis_source_points = 1500;
  o.fine.max_source_points = 6000;
  o.num_threads = 2;
  return o;
}

TEST(TurnJoin, FindsTheSecondTurnOfAnAsymmetricObjectLaidOnItsSide) {
  const PointCloud object = BumpyBox();
  cv::Matx44d a_from_object, b_from_object;
  const PointCloud a = Turn(object, {0, 0, 0}, 0.3, 1, &a_from_object);
  const PointCloud b = Turn(object, {kPi / 2, 0, 0}, -1.1, 2, &b_from_object);
  const TurnJoinResult j = JoinTurns(a, b, FastOptions());
  ASSERT_TRUE(j.IsUsable()) << j.message;
  const cv::Matx44d truth = a_from_object * InvertRigid(b_from_object);
  EXPECT_LT(RotationErrorDeg(j.a_from_b, truth), 0.1) << j.message;
  // The error where the object is: at its centre.
  const cv::Vec4d centre = b_from_object * cv::Vec4d(0, 0, 15, 1);
  const cv::Vec4d e = j.a_from_b * centre - truth * centre;
  EXPECT_LT(std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]), 0.2) << "mm";
  EXPECT_GT(j.overlap, 0.6);
  EXPECT_LT(j.rmse_mm, 0.2);
  EXPECT_LT(j.ambiguity, FastOptions().max_ambiguity);
  EXPECT_GE(j.hypotheses, 10);
  // Held by the whole shape: not weakly.
  std::cout << "bumpy box: constraint " << j.constraint << "\n";
  EXPECT_FALSE(j.held_weakly) << j.message;
  EXPECT_GE(j.constraint, FastOptions().weak_constraint);
  EXPECT_EQ(j.message.find("held weakly"), std::string::npos) << j.message;

  // Merged: turn A's platter contact goes where turn B sees the base's rim
  // region; everything else of both turns stays, in turn A's frame.
  std::size_t dropped_a = 0, dropped_b = 0;
  const PointCloud merged = MergeTurns(a, b, j.a_from_b, FastOptions(), &dropped_a, &dropped_b);
  EXPECT_EQ(merged.size() + dropped_a + dropped_b, a.size() + b.size());
  EXPECT_GT(dropped_a, 0u);
  EXPECT_TRUE(merged.HasNormals());
  // The base (object z = 0) is in the merged cloud: turn B saw it.
  const cv::Matx44d object_from_a = InvertRigid(a_from_object);
  std::size_t base = 0;
  for (const cv::Vec3f& p : merged.points_mm) {
    const cv::Vec4d q = object_from_a * cv::Vec4d(p[0], p[1], p[2], 1);
    if (std::abs(q[2]) < 0.5 && std::abs(q[0]) < 25 && std::abs(q[1]) < 15) ++base;
  }
  EXPECT_GT(base, 1000u);
}

// An egg with one knob on its side (radius 9 mm at mid-height): round but
// for one feature, so that the join's rotation about the egg's axis is held
// by the knob alone, a shallow valley.
PointCloud KnobbedEgg() {
  const Sphere knob{{22.5, 0, 30}, 9};
  PointCloud cloud;
  const PointCloud egg = Egg();
  for (std::size_t i = 0; i < egg.size(); ++i) {
    if (cv::norm(cv::Vec3d(egg.points_mm[i]) - knob.centre) < knob.radius) continue;
    cloud.points_mm.push_back(egg.points_mm[i]);
    cloud.normals.push_back(egg.normals[i]);
  }
  const int n = static_cast<int>(4 * kPi * knob.radius * knob.radius / 0.25);
  for (int i = 0; i < n; ++i) {
    const double z = 1 - (2.0 * i + 1) / n, r = std::sqrt(1 - z * z);
    const double phi = i * kPi * (3 - std::sqrt(5.0));
    const cv::Vec3d dir(r * std::cos(phi), r * std::sin(phi), z);
    const cv::Vec3d p = knob.centre + knob.radius * dir;
    const cv::Vec3d q(p[0] / 22.5, p[1] / 22.5, (p[2] - 30) / 30);
    if (q.dot(q) < 1) continue;  // inside the egg
    cloud.points_mm.emplace_back(p);
    cloud.normals.emplace_back(dir);
  }
  return cloud;
}

TEST(TurnJoin, JoinsARoundBodyHeldByOneKnobPolishedNoWorse) {
  const PointCloud object = KnobbedEgg();
  cv::Matx44d a_from_object, b_from_object;
  const PointCloud a = Turn(object, {0, 0, 0}, 0.3, 1, &a_from_object);
  const PointCloud b = Turn(object, {kPi / 2, 0, 0.4}, -1.1, 2, &b_from_object);
  const cv::Matx44d truth = a_from_object * InvertRigid(b_from_object);
  TurnJoinOptions plain = FastOptions();
  plain.polish = false;
  const TurnJoinResult crept = JoinTurns(a, b, plain);
  const TurnJoinResult j = JoinTurns(a, b, FastOptions());
  ASSERT_TRUE(j.IsUsable()) << j.message;
  std::cout << "knobbed egg: " << RotationErrorDeg(crept.a_from_b, truth) << "° unpolished ("
            << ToString(crept.status) << "), " << RotationErrorDeg(j.a_from_b, truth)
            << "° polished\n";
  EXPECT_LT(RotationErrorDeg(j.a_from_b, truth), 0.05) << j.message;
  EXPECT_LE(RotationErrorDeg(j.a_from_b, truth), RotationErrorDeg(crept.a_from_b, truth));
}

// A jug: the egg's round body with a thin handle on its side above the
// middle (a half ring of 2.5 mm tube, 24 mm across, in the x–z plane): a
// few percent of the surface, the only thing that tells the body's turns
// apart (at mid-height a half turn about x would map it onto itself).
PointCloud Jug() {
  PointCloud cloud = Egg();
  const cv::Vec3d centre(21.7, 0, 38);  // on the body's surface
  const double ring = 12, tube = 2.5;
  const int around = 360, across = 48;
  for (int i = 0; i < around; ++i) {
    const double u = 2 * kPi * i / around;  // along the ring
    const cv::Vec3d axis_point = centre + ring * cv::Vec3d(std::cos(u), 0, std::sin(u));
    const cv::Vec3d radial(std::cos(u), 0, std::sin(u));
    for (int k = 0; k < across; ++k) {
      const double v = 2 * kPi * k / across;  // around the tube
      const cv::Vec3d n = std::cos(v) * radial + std::sin(v) * cv::Vec3d(0, 1, 0);
      const cv::Vec3d p = axis_point + tube * n;
      const cv::Vec3d q(p[0] / 22.5, p[1] / 22.5, (p[2] - 30) / 30);
      if (q.dot(q) < 1) continue;  // inside the body
      cloud.points_mm.emplace_back(p);
      cloud.normals.emplace_back(n);
    }
  }
  return cloud;
}

TEST(TurnJoin, JoinsAJugByItsHandleAlthoughItsBodyTurnedFitsNearlyAsWell) {
  const PointCloud object = Jug();
  cv::Matx44d a_from_object, b_from_object;
  const PointCloud a = Turn(object, {0, 0, 0}, 0.3, 7, &a_from_object);
  const PointCloud b = Turn(object, {kPi / 2, 0, 0.4}, -1.1, 8, &b_from_object);
  const cv::Matx44d truth = a_from_object * InvertRigid(b_from_object);
  // The synthetic handle holds the join more firmly than a real one does
  // (constraint 0.059 here, 0.014–0.016 for the simulated station's jug):
  // the limit for a weak hold is raised above it to see the join say so.
  TurnJoinOptions options = FastOptions();
  options.weak_constraint = 0.1;
  const TurnJoinResult j = JoinTurns(a, b, options);
  TurnJoinOptions no_parts = FastOptions();
  no_parts.distinct_part_share = 1;
  const TurnJoinResult without = JoinTurns(a, b, no_parts);
  std::cout << "jug: " << ToString(j.status) << " " << RotationErrorDeg(j.a_from_b, truth)
            << "°; without the part rule: " << without.message << "\n";
  // The premise: the body turned a few degrees fits at least 90 % as well.
  EXPECT_EQ(without.status, TurnJoinResult::Status::kRefusedAmbiguous) << without.message;
  EXPECT_LT(without.alternative_deg, 10);
  ASSERT_TRUE(j.IsUsable()) << j.message;
  EXPECT_LT(RotationErrorDeg(j.a_from_b, truth), 0.1) << j.message;
  EXPECT_NE(j.message.find("distinctive part"), std::string::npos) << j.message;
  // Joined, but only the handle holds the body's turn about its axis: the
  // result says it is held weakly, and what to do.
  std::cout << "jug: constraint " << j.constraint << ", rotation share of the least held motion "
            << j.weak_motion_rotation << "\n";
  EXPECT_TRUE(j.held_weakly) << j.message;
  EXPECT_LT(j.constraint, options.weak_constraint);
  EXPECT_GT(j.weak_motion_rotation, 0.9);
  EXPECT_NE(j.message.find("held weakly"), std::string::npos) << j.message;
  EXPECT_NE(j.message.find("about one axis"), std::string::npos) << j.message;
  EXPECT_NE(j.message.find("more of its distinctive shape"), std::string::npos) << j.message;
}

TEST(TurnJoin, RefusesAnEggLaidOnItsSide) {
  const PointCloud egg = Egg();
  cv::Matx44d a_from_object, b_from_object;
  const PointCloud a = Turn(egg, {0, 0, 0}, 0, 3, &a_from_object);
  const PointCloud b = Turn(egg, {kPi / 2, 0, 0}, 0.7, 4, &b_from_object);
  const TurnJoinResult j = JoinTurns(a, b, FastOptions());
  EXPECT_EQ(j.status, TurnJoinResult::Status::kRefusedAmbiguous) << j.message;
  EXPECT_FALSE(j.IsUsable());
  EXPECT_GE(j.ambiguity, FastOptions().max_ambiguity);
  EXPECT_GE(j.alternative_deg, FastOptions().distinct_deg);
  EXPECT_NE(j.message.find("symmetric"), std::string::npos) << j.message;
}

TEST(TurnJoin, RefusesTurnsThatShareTooLittle) {
  // The operator swapped the object: turn B shows the egg, turn A the box.
  // Nothing of one lies on the other.
  cv::Matx44d a_from_object, b_from_object;
  const PointCloud a = Turn(BumpyBox(), {0, 0, 0}, 0, 5, &a_from_object);
  const PointCloud b = Turn(Egg(), {kPi / 2, 0, 0}, 0, 6, &b_from_object);
  const TurnJoinResult j = JoinTurns(a, b, FastOptions());
  EXPECT_EQ(j.status, TurnJoinResult::Status::kRefusedOverlap) << j.message;
  EXPECT_FALSE(j.IsUsable());
  EXPECT_LT(j.overlap, FastOptions().min_overlap);
  EXPECT_NE(j.message.find("overlap too little"), std::string::npos) << j.message;
}

TEST(TurnJoin, InvalidInputIsAFailureWithAReason) {
  TurnJoinOptions o;
  o.max_ambiguity = 0;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("max_ambiguity"), std::string::npos);
  TurnJoinOptions weak;
  weak.weak_constraint = weak.min_constraint / 2;  // below the refusal's limit
  EXPECT_FALSE(weak.IsValid(&why));
  EXPECT_NE(why.find("weak_constraint"), std::string::npos) << why;
  const TurnJoinResult j = JoinTurns(PointCloud{}, PointCloud{}, TurnJoinOptions{});
  EXPECT_EQ(j.status, TurnJoinResult::Status::kFailed);
  EXPECT_NE(j.message.find("100 points"), std::string::npos) << j.message;
}

}  // namespace
}  // namespace craftscan
