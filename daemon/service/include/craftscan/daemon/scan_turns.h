// The turns of a scan session (issue 20, README 4.6): a scan's session may
// take further turns, each captured with the object laid in another pose
// (craftscanctl scan --add-to SESSION), each reconstructed within itself and
// joined onto turn 1 (JoinTurnScans, scan_reconstruction.h) so the model
// has the base the first turn stood on.
//
// They are recorded in the manifest's params as "turns", a list in turn
// order:
//   {"turn": 2, "first_view": 6, "views": 6, "step_deg": 60,
//    "exposure_bracket": [], "client": "ctl", "state": "joined",
//    "message": "...", "join": {TurnJoinJson}}
// Turn t's views are views/NNN with NNN in [first_view, first_view + views),
// numbered after the turns before it, at commanded angles 0, step_deg, ….
// A turn's state: "done" (turn 1, its own model), "capturing" (the turn in
// progress: the session's state says whether a job runs it or it is
// interrupted), "joined", "refused" (the join was refused: the operator lays
// the object differently and adds another turn; its views stay on disk) or
// "failed" (its reconstruction failed). A session without "turns" (made
// before turns, or never added to) has one turn: params views and step_deg.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/daemon/session_manifest.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::daemon {

struct TurnRecord {
  int turn = 1;        // 1-based
  int first_view = 0;  // its first view's index
  int views = 0;
  double step_deg = 0;
  std::string state = "done";
  nlohmann::json extra = nlohmann::json::object();  // exposure_bracket, client, message, join
};

// The turns of `manifest` (see above); false with *error naming the field
// when params.turns is malformed (not a list of objects with the fields
// above, turns not numbered 1, 2, …, views overlapping or beyond 999).
bool SessionTurns(const Manifest& manifest, std::vector<TurnRecord>* turns, std::string* error);
// params.turns as written.
nlohmann::json TurnsJson(const std::vector<TurnRecord>& turns);
// The figures of a join (ScanResult::turn_join and the platter-contact
// points dropped): status, message, overlap (0..1) and overlap_pct, rmse_mm,
// ambiguity, alternative_deg/_mm, constraint, held ("firmly", "weakly":
// TurnJoinResult::held_weakly, or "not joined"), hypotheses, points_a/_b,
// coarse_voxel_mm, time_ms, a_from_b (row-major 4×4), contact_dropped_a/_b.
// Null without a join.
nlohmann::json TurnJoinJson(const ScanResult& result);
// One line for people: "joined (fit 72.6 %, RMSE 0.21 mm, no rival)",
// "joined (…, no rival, held weakly)" or "refused_overlap: <message>".
std::string TurnJoinSummary(const nlohmann::json& join);

}  // namespace craftscan::daemon
