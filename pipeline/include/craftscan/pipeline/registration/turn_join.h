// Joining two turns of one object: the object scanned standing (turn A) and
// again laid in another pose (turn B: on its side, upside down), each turn
// registered within itself with the turntable prior and fused. Turn B's
// fused cloud is registered onto turn A's with no prior (FPFH + RANSAC,
// the distinct best hypotheses each refined by ICP, registration.h), with a
// verdict: refused when the turns overlap too little or when a clearly
// different placement fits about as well (a symmetric object: an egg laid on
// its side fits any turn about its long axis). Then each turn's
// platter-contact region goes where the other turn sees the surface, and
// the two clouds become one (MergeTurns) for one fusion, mesh and
// measurement (scan_reconstruction.h: JoinTurnScans).
//
//   TurnJoinResult j = JoinTurns(turn_a.fused, turn_b.fused, TurnJoinOptions{});
//   if (j.IsUsable()) merged = MergeTurns(turn_a.fused, turn_b.fused, j.a_from_b, options);
//   else std::cout << j.message;  // what to tell the operator
//
// Frames: each turn's cloud in its own turntable frame (origin on the axis
// at the platter surface, +Z up: the platter is z = 0); a_from_b maps turn
// B's points into turn A's frame. Units: millimetres, degrees in *_deg.
#pragma once

#include <cstdint>
#include <limits>
#include <string>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/registration/registration.h"

namespace craftscan {

struct TurnJoinOptions {
  // The clouds the join works on: turn clouds (with normals, as fusion
  // gives them) averaged in voxels of these edges, mm. coarse_voxel_mm 0:
  // turn A's bounding-box diagonal / 40 (2.8 mm for the 80×60×50 box), so
  // that features see the same share of any object.
  double fine_voxel_mm = 1.0;
  double coarse_voxel_mm = 0;
  // FPFH support radius and RANSAC inlier gate, in coarse voxels.
  double feature_radius_voxels = 5;
  double inlier_distance_voxels = 1.5;
  int ransac_iterations = 50000;
  std::uint64_t seed = 42;
  // ICP from each hypothesis on at most hypothesis_source_points of turn B
  // (an even stride, `fine`'s other settings); then the contenders (the
  // best and up to max_contenders − 1 others fitting at least
  // max_ambiguity × as well) again with `fine` in full, run to convergence,
  // so that a placement only half-way down a shallow valley (a jug's
  // rotation, held by its handle alone) is not taken for another solution
  // (registration.h FineOptions).
  int hypothesis_source_points = 3000;
  int max_contenders = 4;
  // Each contender is then polished by linearised point-to-plane ICP
  // (`fine`'s gates and stops, FineMethod::kPointToPlane), kept when it
  // still fits at least polish_min_fit × as well: weighted ICP creeps along
  // a shallow valley (a round body turning about itself), point-to-plane
  // reaches its bottom (README 11.11). polish_min_fit in (0, 1].
  bool polish = true;
  double polish_min_fit = 0.99;
  FineOptions fine = [] {
    FineOptions f;
    f.max_iterations = 200;
    f.max_correspondence_mm = 4;
    f.min_correspondence_mm = 0.5;
    f.stop_mean_distance_mm = 0;
    f.min_update_mm = 1e-4;
    f.max_source_points = 20000;
    return f;
  }();
  // Distinct RANSAC hypotheses refined (≥ 1); hypotheses whose rotations
  // are closer than 10° count as one. Besides them the best join turned by ±10°,
  // 90°, 180° and 270° about each principal axis of turn B is refined too:
  // a symmetry RANSAC did not sample still shows.
  int max_candidates = 8;
  // The quarter and half turns are also refined moved so that the middle of
  // turn B's extent along turn A's principal axes meets turn A's (a wrong
  // best is often off in translation too).
  bool recentre_turned = true;
  // Two joins differing by at least this rotation or translation are
  // different placements (deg, mm; > 0). A continuous symmetry (an egg
  // turning about its axis) leaves ICP wherever it starts along the valley:
  // the best join turned by ±10° about each principal axis of turn B is
  // refined too, so that it shows as a distinct placement fitting as well.
  double distinct_deg = 3;
  double distinct_mm = 3;
  // A point of turn B fits when turn A has a point within fit_distance_mm
  // and it lies within fit_plane_mm of that point's tangent plane (the
  // stereo noise is ~0.1–0.3 mm; a relief 2 mm deep that lands on a flat
  // face does not fit). fit = the fraction of turn B's fine points that fit.
  double fit_distance_mm = 1.0;
  double fit_plane_mm = 0.4;
  // Refused: the best join's fit below min_overlap (the turns share too
  // little surface), or a distinct join's fit at least max_ambiguity × the
  // best's (0..1]: the geometry does not tell the placements apart.
  // min_overlap: right joins of an object laid on its side fit 72–85 % of
  // the second turn (the box, the owl, the jug at 640×512); the wrong ones
  // seen fit 52–64 % (the box at 1280×1024 turned by 90° or 180°, when the
  // right placement was not among the hypotheses). A turn that fits less
  // is refused rather than joined on a guess.
  double min_overlap = 0.65;
  double max_ambiguity = 0.9;
  // A distinct placement is no rival when it moves more than
  // max_contradicted of turn B's points that fit the join farther than
  // contradiction_mm from turn A's surface (a feature landing where turn A
  // saw nothing). Turn A's own holes count too (the fused clouds know no
  // free space), so the limit sits above what they give: on the simulated
  // egg at 640×512 its rivals 6–23° away moved 0.7–2 % of the points off,
  // its wrong rivals 90° away 20–55 %. mm > fit_distance_mm; fraction 0..1.
  double contradiction_mm = 2.0;
  double max_contradicted = 0.02;
  // Nor is it a rival when the join fits a distinctive part of turn B that
  // the placement misplaces: a connected part (fine points within 1.6 fine
  // voxels of each other) that fits under the join and not under the
  // placement, of at least distinct_part_share of turn B's points and at
  // least distinct_part_ratio × the largest connected part the placement
  // fits and the join does not. A jug's handle seen by both turns is such a
  // part: turned 5° about its body the jug still fits 97 % as well, but
  // loses the handle whole (2–3.5 % of turn B in one piece, against at most
  // 0.4 % gained in one piece). Placements a symmetry makes equivalent (an
  // egg on its side turned about its axis) lose and gain scattered patches
  // of alike size (each ≤ 1 %, ratio 0.8–1.5): still rivals.
  // share 0..1 (1: off); ratio ≥ 1.
  double distinct_part_share = 0.015;
  double distinct_part_ratio = 3;
  // Refused too when the join's fit does not hold some motion: the smallest
  // eigenvalue of its point-to-plane information matrix (rotations scaled
  // by the object's size) over the largest below this (0..1). A surface of
  // revolution (an egg on its side, a plain vase) turns about its axis
  // without leaving itself: no rival placement need be found for that.
  double min_constraint = 0.005;
  // Joined, but held weakly, below this (min_constraint..1): the least held
  // motion rests on one small feature (a jug's handle, an owl's beak and
  // ears), and there each turn's reconstruction of that feature decides the
  // join: on the simulated station such joins (constraint 0.014–0.017) came
  // out 0.06–0.33° from the truth, those held by more of the shape (0.14–0.19:
  // the box, the bunny, a figurine) 0.03–0.07° (README 11.11, stop 64). The
  // result says so (TurnJoinResult::held_weakly), for the operator to lay
  // the object so that more of its distinctive shape is seen in both turns.
  double weak_constraint = 0.05;
  // Platter contact (MergeTurns): a turn's points lower than
  // contact_band_mm in its own frame go where the other turn has a point
  // within contact_cover_mm (it sees that surface, not at a grazing angle
  // beside the platter). mm, ≥ 0.
  double contact_band_mm = 3;
  double contact_cover_mm = 1.5;
  int num_threads = 1;  // ≥ 1; results are deterministic for a given count

  bool IsValid(std::string* why) const;  // names the offending field
};

struct TurnJoinResult {
  enum class Status {
    kJoined,
    kRefusedOverlap,    // the turns share too little surface
    kRefusedAmbiguous,  // another placement fits about as well (symmetry)
    kFailed,            // invalid options or input, a registration failure
  };
  Status status = Status::kFailed;
  std::string message;  // the reason for a refusal, for the operator; notes otherwise

  cv::Matx44d a_from_b = cv::Matx44d::eye();  // turn B's frame → turn A's
  double overlap = 0;                         // the join's fit (fraction of B's points, 0..1)
  double rmse_mm = std::numeric_limits<double>::quiet_NaN();  // point-to-plane over the fits
  // The best distinct alternative placement that nothing contradicts: its
  // fit / the join's (0..1; 0 when every hypothesis converged to the join
  // or was contradicted) and how far it lies.
  double ambiguity = 0;
  double alternative_deg = std::numeric_limits<double>::quiet_NaN();
  double alternative_mm = std::numeric_limits<double>::quiet_NaN();
  double alternative_contradicted = 0;  // its contradicted share (see TurnJoinOptions)
  // How firmly the fit holds the join (see TurnJoinOptions::min_constraint)
  // and how much of its least held motion is a rotation (0..1).
  double constraint = 0;
  double weak_motion_rotation = 0;
  bool held_weakly = false;  // joined with constraint < TurnJoinOptions::weak_constraint
  int hypotheses = 0;        // refined by ICP, the join's included
  std::size_t points_a = 0, points_b = 0;  // fine points the fit is counted on
  double coarse_voxel_mm = 0;              // the one used
  double time_ms = 0;

  bool IsUsable() const { return status == Status::kJoined; }
};
const char* ToString(TurnJoinResult::Status status);  // "joined", "refused_overlap", ...

// Registers turn B onto turn A (see the top of this file). Both clouds need
// normals (outward, as FuseClouds gives them) and at least 100 points.
// Never throws; thread-safe (each call is independent).
TurnJoinResult JoinTurns(const PointCloud& turn_a, const PointCloud& turn_b,
                         const TurnJoinOptions& options);

// Turn A's points and turn B's mapped by a_from_b, each without its
// platter-contact points where the other turn sees the surface (see
// TurnJoinOptions), in turn A's frame: the input of one fusion. Normals and
// colours are kept when both clouds have them. *dropped_a, *dropped_b (may
// be null) receive the counts dropped. Never throws.
PointCloud MergeTurns(const PointCloud& turn_a, const PointCloud& turn_b,
                      const cv::Matx44d& a_from_b, const TurnJoinOptions& options,
                      std::size_t* dropped_a = nullptr, std::size_t* dropped_b = nullptr);

}  // namespace craftscan
