// The turns of a scan session (scan_turns.h).
#include "craftscan/daemon/scan_turns.h"

#include <cmath>
#include <cstdio>

namespace craftscan::daemon {
namespace {

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

nlohmann::json Finite(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

}  // namespace

bool SessionTurns(const Manifest& manifest, std::vector<TurnRecord>* turns, std::string* error) {
  turns->clear();
  const nlohmann::json& params = manifest.params;
  const auto list = params.find("turns");
  if (list == params.end()) {
    TurnRecord one;
    one.views = params.value("views", 0);
    one.step_deg = params.value("step_deg", 0.0);
    one.state = manifest.state == SessionState::kDone ? "done" : "capturing";
    turns->push_back(one);
    return true;
  }
  const std::string prefix = "session " + manifest.id + ": manifest params.turns";
  if (!list->is_array() || list->empty()) return Fail(error, prefix + " must be a non-empty list");
  int next_view = 0;
  for (std::size_t i = 0; i < list->size(); ++i) {
    const nlohmann::json& t = (*list)[i];
    const std::string at = prefix + "[" + std::to_string(i) + "]";
    if (!t.is_object()) return Fail(error, at + " must be an object");
    TurnRecord r;
    const auto integer = [&](const char* key, int* value) {
      const auto it = t.find(key);
      if (it == t.end() || !it->is_number_integer()) return false;
      *value = it->get<int>();
      return true;
    };
    if (!integer("turn", &r.turn) || r.turn != static_cast<int>(i) + 1)
      return Fail(error, at + ".turn must be " + std::to_string(i + 1));
    if (!integer("first_view", &r.first_view) || !integer("views", &r.views) || r.views < 1 ||
        r.first_view < next_view || r.first_view + r.views - 1 > kMaxViewIndex) {
      return Fail(error, at + ": first_view and views must be integers, views after the turn " +
                             "before, within view 999");
    }
    const auto step = t.find("step_deg");
    const auto state = t.find("state");
    if (step == t.end() || !step->is_number() || state == t.end() || !state->is_string())
      return Fail(error, at + ": step_deg (number) and state (string) are required");
    r.step_deg = step->get<double>();
    r.state = state->get<std::string>();
    for (const auto& [key, value] : t.items()) {
      if (key != "turn" && key != "first_view" && key != "views" && key != "step_deg" &&
          key != "state")
        r.extra[key] = value;
    }
    next_view = r.first_view + r.views;
    turns->push_back(std::move(r));
  }
  return true;
}

nlohmann::json TurnsJson(const std::vector<TurnRecord>& turns) {
  nlohmann::json out = nlohmann::json::array();
  for (const TurnRecord& r : turns) {
    nlohmann::json t = {{"turn", r.turn},
                        {"first_view", r.first_view},
                        {"views", r.views},
                        {"step_deg", r.step_deg},
                        {"state", r.state}};
    t.update(r.extra);
    out.push_back(std::move(t));
  }
  return out;
}

nlohmann::json TurnJoinJson(const ScanResult& r) {
  if (!r.turn_join) return nullptr;
  const TurnJoinResult& j = *r.turn_join;
  nlohmann::json a_from_b = nlohmann::json::array();
  for (int i = 0; i < 16; ++i) a_from_b.push_back(j.a_from_b.val[i]);
  return {{"status", ToString(j.status)},
          {"message", j.message},
          {"overlap", j.overlap},
          {"overlap_pct", 100 * j.overlap},
          {"rmse_mm", Finite(j.rmse_mm)},
          {"ambiguity", j.ambiguity},
          {"alternative_deg", Finite(j.alternative_deg)},
          {"alternative_mm", Finite(j.alternative_mm)},
          {"constraint", j.constraint},
          {"held", j.IsUsable() ? (j.held_weakly ? "weakly" : "firmly") : "not joined"},
          {"hypotheses", j.hypotheses},
          {"points_a", j.points_a},
          {"points_b", j.points_b},
          {"coarse_voxel_mm", j.coarse_voxel_mm},
          {"time_ms", j.time_ms},
          {"a_from_b", a_from_b},
          {"contact_dropped_a", r.contact_dropped_a},
          {"contact_dropped_b", r.contact_dropped_b}};
}

std::string TurnJoinSummary(const nlohmann::json& join) {
  if (!join.is_object()) return "not joined";
  const std::string status = join.value("status", std::string("failed"));
  if (status != "joined") return status + ": " + join.value("message", std::string());
  char text[160];
  const nlohmann::json rmse = join.value("rmse_mm", nlohmann::json());
  const double ambiguity = join.value("ambiguity", 0.0);
  std::snprintf(text, sizeof text, "joined (fit %.1f %%, RMSE %.2f mm, %s)",
                join.value("overlap_pct", 0.0), rmse.is_number() ? rmse.get<double>() : NAN,
                ambiguity > 0 ? "rival" : "no rival");
  std::string out = text;
  if (ambiguity > 0) {
    std::snprintf(text, sizeof text, " fits %.0f %% as well)", 100 * ambiguity);
    out.pop_back();
    out += text;
  }
  if (join.value("held", std::string()) == "weakly") {
    out.pop_back();
    out += ", held weakly)";
  }
  return out;
}

}  // namespace craftscan::daemon
