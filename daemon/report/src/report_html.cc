// The report page (report.h): one HTML file, inline CSS; JavaScript only for
// the 3D view (report_model.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/daemon/report.h"
#include "report_model.h"
#include "viewer_bundle.h"

namespace craftscan::daemon {
namespace {

using Json = nlohmann::json;

constexpr const char* kDash = "&mdash;";

constexpr const char* kStyle = R"css(
:root{--ink:#1f2328;--muted:#656d76;--line:#d8dee4;--bg:#f5f4f0;--ok:#1a7f37;--bad:#cf222e;--warn:#9a6700}
*{box-sizing:border-box}
body{margin:0;background:var(--bg);color:var(--ink);font:15px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif}
main{max-width:1180px;margin:0 auto;padding:28px 24px 48px}
header h1{font-size:30px;margin:0 0 2px}
header .sub{color:var(--muted);margin:0}
.headline{display:flex;flex-wrap:wrap;gap:14px;margin:18px 0 4px}
.kpi{background:#fff;border:1px solid var(--line);border-radius:8px;padding:10px 16px;min-width:150px}
.kpi .v{font-size:24px;font-weight:650;font-variant-numeric:tabular-nums}
.kpi .k{color:var(--muted);font-size:13px}
nav{margin:14px 0 0;font-size:14px}
nav a{color:var(--muted);margin-right:14px;text-decoration:none}
nav a:hover{text-decoration:underline}
section{background:#fff;border:1px solid var(--line);border-radius:8px;padding:16px 22px 20px;margin:18px 0}
h2{font-size:20px;margin:4px 0 12px}
h3{font-size:16px;margin:18px 0 8px}
table{border-collapse:collapse;font-variant-numeric:tabular-nums;margin:4px 0 8px}
th,td{padding:5px 12px;border-bottom:1px solid #eaeef2;text-align:left;vertical-align:top}
thead th{font-size:13px;color:var(--muted);font-weight:600;border-bottom:1px solid var(--line)}
table.kv th{font-weight:500;color:var(--muted);width:260px}
td.n{text-align:right}
.ok{color:var(--ok)}.bad{color:var(--bad)}.warn{color:var(--warn)}.muted{color:var(--muted)}
.badge{display:inline-block;padding:0 9px;border-radius:11px;font-size:13px;font-weight:600}
.badge.ok{background:#dafbe1}.badge.bad{background:#ffebe9}.badge.warn{background:#fff8c5}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(270px,1fr));gap:14px}
figure{margin:0}
figure img{display:block;width:100%;height:auto;border:1px solid var(--line);border-radius:6px;background:#f6f6f6}
figcaption{font-size:13px;color:var(--muted);margin-top:4px}
.notes{color:var(--warn);font-size:14px}
.viewer{position:relative;height:560px;max-height:75vh;border-radius:6px;overflow:hidden;background:#1d2125}
.viewer.failed{height:auto;padding:14px 16px;background:#fff8c5;color:var(--warn)}
.viewer.failed+p{display:none}
footer{color:var(--muted);font-size:13px;margin-top:24px}
@media print{body{background:#fff}section{break-inside:avoid;border:none}nav,#model{display:none}}
)css";

// --- formatting ----------------------------------------------------------------

std::string Fixed(double v, int decimals) {
  if (!std::isfinite(v)) return kDash;
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

const Json* Find(const Json& j, const char* key) {
  if (!j.is_object()) return nullptr;
  const auto it = j.find(key);
  return it == j.end() || it->is_null() ? nullptr : &*it;
}

std::string Number(const Json& j, const char* key, int decimals) {
  const Json* v = Find(j, key);
  return v && v->is_number() ? Fixed(v->get<double>(), decimals) : kDash;
}

std::string Count(const Json& j, const char* key) {
  const Json* v = Find(j, key);
  if (!v || !v->is_number()) return kDash;
  return std::to_string(static_cast<long long>(std::llround(v->get<double>())));
}

std::string Text(const Json& j, const char* key) {
  const Json* v = Find(j, key);
  return v && v->is_string() ? HtmlEscape(v->get<std::string>()) : "";
}

// true / false / absent
int Flag(const Json& j, const char* key) {
  const Json* v = Find(j, key);
  return v && v->is_boolean() ? (v->get<bool>() ? 1 : 0) : -1;
}

std::string YesNo(int flag) { return flag < 0 ? kDash : flag ? "yes" : "no"; }

std::string Badge(bool ok, const std::string& ok_text, const std::string& bad_text) {
  return std::string("<span class=\"badge ") + (ok ? "ok\">" : "bad\">") +
         HtmlEscape(ok ? ok_text : bad_text) + "</span>";
}

double Get(const Json& j, const char* key, double fallback) {
  const Json* v = Find(j, key);
  return v && v->is_number() ? v->get<double>() : fallback;
}

// A "[x, y, z]" array as "x × y × z".
std::string Triple(const Json* j, int decimals, const char* sep) {
  if (!j || !j->is_array() || j->size() != 3) return kDash;
  std::string out;
  for (int k = 0; k < 3; ++k) {
    if (k) out += sep;
    out += (*j)[k].is_number() ? Fixed((*j)[k].get<double>(), decimals) : kDash;
  }
  return out;
}

struct Page {
  std::string html;
  Page& operator<<(const std::string& s) {
    html += s;
    return *this;
  }
  void Row(const std::string& key, const std::string& value_html) {
    html += "<tr><th>" + HtmlEscape(key) + "</th><td>" + value_html + "</td></tr>\n";
  }
};

bool ValidPictureName(const std::string& name) {
  if (name.empty() || name.front() == '/' || name.size() > 200) return false;
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '.' || c == '_' || c == '-' || c == '/';
    if (!ok) return false;
  }
  return name.find("..") == std::string::npos && name.find("//") == std::string::npos;
}

// --- sections --------------------------------------------------------------------

void Headline(Page& p, const Json& scan) {
  const Json* measurement = Find(scan, "measurement");
  const Json* box = measurement ? Find(*measurement, "box") : nullptr;
  const Json* obb = measurement ? Find(*measurement, "oriented_box") : nullptr;
  p << "<div class=\"headline\">";
  if (box && Text(*box, "status") == "ok") {
    p << "<div class=\"kpi\"><div class=\"v\">" + Triple(Find(*box, "dims_mm"), 1, " &times; ") +
             " mm</div><div class=\"k\">box dimensions (edges)</div></div>";
  } else if (obb) {
    p << "<div class=\"kpi\"><div class=\"v\">" + Triple(Find(*obb, "extents_mm"), 1, " &times; ") +
             " mm</div><div class=\"k\">oriented bounding box</div></div>";
  }
  if (Find(scan, "fused_points"))
    p << "<div class=\"kpi\"><div class=\"v\">" + Count(scan, "fused_points") +
             "</div><div class=\"k\">fused points</div></div>";
  if (const Json* mesh = Find(scan, "mesh"); mesh && Flag(*mesh, "ok") == 1)
    p << "<div class=\"kpi\"><div class=\"v\">" + Count(*mesh, "faces") +
             "</div><div class=\"k\">mesh triangles</div></div>";
  if (const Json* views = Find(scan, "views"); views && views->is_array())
    p << "<div class=\"kpi\"><div class=\"v\">" + std::to_string(views->size()) +
             "</div><div class=\"k\">views</div></div>";
  p << "</div>\n";
}

void Measurements(Page& p, const Json& scan) {
  p << "<section id=\"measurements\"><h2>Measurements</h2>\n";
  const Json* measurement = Find(scan, "measurement");
  if (!measurement) {
    p << "<p class=\"muted\">No measurement (no fused cloud).</p></section>\n";
    return;
  }
  if (const Json* obb = Find(*measurement, "oriented_box")) {
    const Json* ext = Find(*obb, "extents_mm");
    const Json* height = Find(*obb, "height_mm");
    const bool upright = Flag(*obb, "upright") == 1 && height && height->is_number();
    p << (upright
              ? "<h3>Oriented bounding box, upright (as the object stands on the turntable)</h3>"
              : "<h3>Oriented bounding box</h3>")
      << "<table class=\"kv\">\n";
    const char* names[3] = {"Length (longest axis)", "Width", "Depth (shortest axis)"};
    for (int k = 0; k < 3; ++k) {
      const bool ok = ext && ext->is_array() && ext->size() == 3 && (*ext)[k].is_number();
      p.Row(names[k], (ok ? Fixed((*ext)[k].get<double>(), 2) : kDash) + std::string(" mm"));
    }
    if (upright)
      p.Row("Height (along the turntable's axis)", Fixed(height->get<double>(), 2) + " mm");
    p.Row("Centre", Triple(Find(*obb, "center_mm"), 2, ", ") + " mm");
    p.Row("Points", Count(*obb, "points"));
    p << "</table>\n";
  }
  if (const Json* box = Find(*measurement, "box")) {
    const bool ok = Text(*box, "status") == "ok";
    p << "<h3>Box measurement " + Badge(ok, "ok", "failed") + "</h3><table class=\"kv\">\n";
    if (!Text(*box, "message").empty()) p.Row(ok ? "Notes" : "Reason", Text(*box, "message"));
    p.Row("Dimensions (mean of 4 edges per axis)",
          Triple(Find(*box, "dims_mm"), 2, " &times; ") + " mm");
    p.Row("Vertex method", Text(*box, "vertex_method"));
    if (const Json* q = Find(*box, "quality")) {
      p.Row("Face fit RMS", Number(*q, "face_rms_mm", 3) + " mm");
      p.Row("Orthogonality error (before enforcing)",
            Number(*q, "max_orthogonality_error_deg", 2) + "&deg;");
      p.Row("Face points / input points",
            Count(*q, "face_points") + " / " + Count(*q, "input_points"));
    }
    p << "</table>\n";
    if (const Json* edges = Find(*box, "edges"); edges && edges->is_array() && !edges->empty()) {
      p << "<h3>Edges</h3><table><thead><tr><th>Edge</th><th>Along axis</th><th>Length (mm)</th>"
           "<th>Plane intersection (mm)</th><th>Point circle (mm)</th></tr></thead><tbody>\n";
      for (const Json& e : *edges) {
        p << "<tr><td>V" + Count(e, "a") + "&ndash;V" + Count(e, "b") + "</td><td>" +
                 Count(e, "axis") + "</td><td class=\"n\"><b>" + Number(e, "length_mm", 2) +
                 "</b></td><td class=\"n\">" + Number(e, "intersection_length_mm", 2) +
                 "</td><td class=\"n\">" + Number(e, "circle_length_mm", 2) + "</td></tr>\n";
      }
      p << "</tbody></table>\n";
    }
  }
  if (const std::string error = Text(scan, "box_measurement_error"); !error.empty())
    p << "<p class=\"notes\">Box measurement failed: " + error + "</p>\n";
  p << "</section>\n";
}

void Calibration(Page& p, const ReportInputs& in) {
  p << "<section id=\"calibration\"><h2>Calibration used</h2>\n<table class=\"kv\">\n";
  p.Row("Calibration", in.calibration_id.empty() ? kDash : HtmlEscape(in.calibration_id));
  if (!in.calibration) {
    p << "</table><p class=\"muted\">The calibration file was not available to the "
         "report.</p></section>\n";
    return;
  }
  const StereoCalibration& c = *in.calibration;
  const CalibrationReport& r = c.report;
  p.Row("Board", HtmlEscape(Describe(c.board)));
  p.Row("Image size", std::to_string(c.image_size.width) + " &times; " +
                          std::to_string(c.image_size.height) + " px");
  p.Row("Baseline", Fixed(c.baseline_mm(), 2) + " mm");
  p.Row("Rectified focal length", Fixed(c.rectified_focal_px(), 1) + " px");
  const bool accepted = r.verdict == CalibrationVerdict::kAccept;
  std::string verdict = r.verdict == CalibrationVerdict::kNotEvaluated
                            ? std::string("<span class=\"badge warn\">not evaluated</span>")
                            : Badge(accepted, "accepted", "rejected");
  if (!r.verdict_reason.empty()) verdict += " " + HtmlEscape(r.verdict_reason);
  p.Row("Verdict", verdict);
  p.Row("Reprojection RMS left / right",
        Fixed(r.rms_left_px, 3) + " / " + Fixed(r.rms_right_px, 3) + " px");
  p.Row("Reprojection RMS stereo", Fixed(r.rms_stereo_px, 3) + " px");
  p.Row("Epipolar error mean / max",
        Fixed(r.epipolar_mean_px, 3) + " / " + Fixed(r.epipolar_max_px, 3) + " px");
  p.Row("Coverage left / right", Fixed(100 * r.coverage_left, 0) + " % / " +
                                     Fixed(100 * r.coverage_right, 0) + " % of a " +
                                     std::to_string(r.coverage_grid) + "&times;" +
                                     std::to_string(r.coverage_grid) + " grid");
  p.Row("Board views used", std::to_string(r.views_used) + " of " + std::to_string(r.views.size()));
  if (c.turntable.valid) {
    const cv::Vec3d& d = c.turntable.direction_in_rig;
    const cv::Vec3d& q = c.turntable.point_in_rig_mm;
    p.Row("Turntable axis", "direction (" + Fixed(d[0], 4) + ", " + Fixed(d[1], 4) + ", " +
                                Fixed(d[2], 4) + "), through (" + Fixed(q[0], 1) + ", " +
                                Fixed(q[1], 1) + ", " + Fixed(q[2], 1) + ") mm in the rig frame");
    p.Row("Turntable axis residual", Fixed(r.turntable_residual_mm, 3) + " mm over " +
                                         std::to_string(r.turntable_steps) + " steps");
    p.Row("Turntable angle error (max)", Fixed(r.turntable_max_angle_error_deg, 3) + "&deg;");
  } else {
    p.Row("Turntable axis", "<span class=\"warn\">not calibrated</span>");
  }
  p << "</table></section>\n";
}

std::string RegistrationCells(const Json* reg) {
  if (!reg) return "<td colspan=\"7\" class=\"muted\">reference view</td>";
  const int ok = Flag(*reg, "ok");
  const double fitness = Get(*reg, "fitness", NAN);
  const char* fit_class = fitness < 0.3 ? " warn" : "";
  std::string status =
      ok == 1 ? "<span class=\"ok\">ok</span>" : "<span class=\"bad\">failed</span>";
  if (!Text(*reg, "message").empty())
    status += " <span class=\"muted\">" + Text(*reg, "message") + "</span>";
  return "<td class=\"n" + std::string(fit_class) + "\">" + Number(*reg, "fitness", 3) +
         "</td><td class=\"n\">" + Number(*reg, "rmse_mm", 3) + "</td><td class=\"n\">" +
         Count(*reg, "inliers") + "</td><td class=\"n\">" + Count(*reg, "iterations") +
         "</td><td>" + YesNo(Flag(*reg, "converged")) + "</td><td>" +
         YesNo(Flag(*reg, "prior_kept")) + "</td><td>" + status + "</td>";
}

void Registration(Page& p, const ReportInputs& in, const Json& scan) {
  p << "<section id=\"registration\"><h2>Registration</h2>\n";
  const Json* views = Find(scan, "views");
  if (!views || !views->is_array() || views->empty()) {
    p << "<p class=\"muted\">No per-view figures.</p></section>\n";
    return;
  }
  std::map<int, double> commanded;
  for (const DisparityView& d : in.disparities) commanded[d.index] = d.angle_deg;
  const Json* loop = Find(scan, "loop_closure");
  const Json* angles = loop ? Find(*loop, "angles_deg") : nullptr;
  p << "<p class=\"muted\">Each view is registered to the previous one (fitness: fraction of its "
       "points "
       "within the inlier gate; RMSE over those; prior kept: the turntable rotation won over "
       "feature matching).</p>\n";
  p << "<table><thead><tr><th>View</th><th>Angle (&deg;)</th><th>Loop angle (&deg;)</th><th>Points "
       "in</th>"
       "<th>Kept</th><th>Fitness</th><th>RMSE (mm)</th><th>Inliers</th><th>Iterations</th>"
       "<th>Converged</th><th>Prior kept</th><th>Status</th></tr></thead><tbody>\n";
  for (std::size_t k = 0; k < views->size(); ++k) {
    const Json& v = (*views)[k];
    const int index = static_cast<int>(Get(v, "index", static_cast<double>(k)));
    const auto a = commanded.find(index);
    const std::string angle = a == commanded.end() ? kDash : Fixed(a->second, 1);
    std::string loop_angle = kDash;
    if (angles && angles->is_array() && k < angles->size() && (*angles)[k].is_number())
      loop_angle = Fixed((*angles)[k].get<double>(), 2);
    p << "<tr><td>" + std::to_string(index) + "</td><td class=\"n\">" + angle +
             "</td><td class=\"n\">" + loop_angle + "</td><td class=\"n\">" +
             Count(v, "input_points") + "</td><td class=\"n\">" + Count(v, "fine_points") +
             "</td>" + RegistrationCells(Find(v, "registration_to_previous")) + "</tr>\n";
    if (!Text(v, "error").empty())
      p << "<tr><td></td><td colspan=\"11\" class=\"bad\">" + Text(v, "error") + "</td></tr>\n";
  }
  if (const Json* closing = Find(scan, "closing_registration"))
    p << "<tr><td colspan=\"5\">closing: 0 &rarr; last</td>" + RegistrationCells(closing) +
             "</tr>\n";
  p << "</tbody></table>\n";

  if (loop) {
    const bool ok = Flag(*loop, "ok") == 1;
    p << "<h3>Loop closure " + Badge(ok, "ok", "failed") + "</h3><table class=\"kv\">\n";
    p.Row("Model", Text(*loop, "model"));
    if (!Text(*loop, "message").empty()) p.Row(ok ? "Notes" : "Reason", Text(*loop, "message"));
    p.Row("Open-loop error (chained pairwise poses)",
          Number(*loop, "open_loop_rot_deg", 3) + "&deg;, " + Number(*loop, "open_loop_rms_mm", 3) +
              " mm RMS");
    p.Row("Turntable-axis model fit", Number(*loop, "axis_rms_mm", 3) + " mm RMS");
    if (!Text(*loop, "axis").empty()) {
      const std::string apart = Number(*loop, "axis_disagreement_deg", 3) + "&deg; and " +
                                Number(*loop, "axis_disagreement_mm", 2) + " mm";
      p.Row("Turntable axis",
            Text(*loop, "axis") == "calibrated"
                ? "the calibrated one (the views' own fit is " + apart + " from it)"
                : "<span class=\"bad\">fitted to the views: " + apart +
                      " from the calibrated one; the turntable or the cameras may have moved "
                      "since calibrate-turntable (run it again)</span>");
    }
    p.Row("Closed residual",
          Number(*loop, "rms_mm", 3) + " mm RMS, " + Number(*loop, "max_mm", 3) + " mm max");
    if (const Json* dir = Find(*loop, "axis_direction"))
      p.Row("Axis (view 0 frame)", "direction (" + Triple(dir, 4, ", ") + "), through (" +
                                       Triple(Find(*loop, "axis_point_mm"), 1, ", ") + ") mm");
    p << "</table>\n";
  } else {
    p << "<p class=\"muted\">No loop closure (the views do not cover a full turn).</p>\n";
  }
  p << "</section>\n";
}

void Reconstruction(Page& p, const Json& scan) {
  p << "<section id=\"reconstruction\"><h2>Reconstruction</h2><table class=\"kv\">\n";
  p.Row("Frame", Text(scan, "frame") == "turntable"
                     ? "turntable (origin on the axis at the platter, +Z up)"
                     : "view 0 (rectified left camera of the first view)");
  p.Row("Fused points", Count(scan, "fused_points"));
  if (const Json* fs = Find(scan, "free_space_check")) {
    std::string per_view;
    if (const Json* r = Find(*fs, "removed_per_view"); r && r->is_array())
      for (const Json& n : *r)
        per_view += (per_view.empty() ? "" : ", ") +
                    (n.is_number() ? std::to_string(n.get<long long>()) : kDash);
    p.Row("Free-space check",
          Count(*fs, "removed_points") + " of " + Count(*fs, "checked_points") +
              " view points removed (other views looked through them; per view: " + per_view + ")");
  }
  if (const Json* f = Find(scan, "fusion"))
    p.Row("Multi-view support",
          Count(*f, "unsupported_voxels_dropped") +
              " voxels no second view confirmed dropped; kept without one: " +
              Count(*f, "lone_view_voxels_kept") + " with no other view's points near, " +
              Count(*f, "sole_view_voxels_kept") + " that only their own camera faced, " +
              Count(*f, "hidden_view_voxels_kept") + " that every other camera saw from behind; " +
              Count(*f, "platter_shadow_voxels_dropped") +
              " one view saw facing down by the platter dropped; " +
              Count(*f, "small_cluster_voxels_dropped") + " in detached clusters dropped");
  if (const Json* q = Find(scan, "quality")) {
    p.Row("Estimated floaters", Number(*q, "far_from_mesh_pct", 2) +
                                    " % of the fused points lie more than " +
                                    Number(*q, "gate_mm", 1) + " mm from the mesh (median " +
                                    Number(*q, "median_to_mesh_mm", 3) + " mm, p95 " +
                                    Number(*q, "p95_to_mesh_mm", 3) + " mm)");
    p.Row("Holes", Count(*q, "holes") + " open boundaries besides the base (largest " +
                       Number(*q, "largest_hole_mm", 1) + " mm around; the base opening " +
                       Number(*q, "base_opening_mm", 1) + " mm)");
  }
  if (const Json* mesh = Find(scan, "mesh")) {
    const bool ok = Flag(*mesh, "ok") == 1;
    std::string value = Badge(ok, "ok", "not made") + " " + Count(*mesh, "vertices") +
                        " vertices, " + Count(*mesh, "faces") + " triangles";
    if (!Text(*mesh, "message").empty())
      value += " <span class=\"muted\">" + Text(*mesh, "message") + "</span>";
    p.Row("Mesh", value);
  }
  p << "</table>\n";
  if (const Json* times = Find(scan, "times")) {
    p << "<h3>Stage times</h3><table><thead><tr><th>Stage</th><th>Time "
         "(s)</th></tr></thead><tbody>\n";
    const std::pair<const char*, const char*> stages[] = {
        {"condition_ms", "Conditioning"}, {"register_ms", "Registration"},
        {"loop_ms", "Loop closure"},      {"fuse_ms", "Fusion"},
        {"mesh_ms", "Meshing"},           {"measure_ms", "Measurement"}};
    double total = 0;
    for (const auto& [key, label] : stages) {
      const double ms = Get(*times, key, NAN);
      if (std::isfinite(ms)) total += ms;
      p << "<tr><td>" + std::string(label) + "</td><td class=\"n\">" + Fixed(ms / 1000, 2) +
               "</td></tr>\n";
    }
    p << "<tr><td><b>Total</b></td><td class=\"n\"><b>" + Fixed(total / 1000, 2) +
             "</b></td></tr>\n";
    p << "</tbody></table>\n";
  }
  p << "</section>\n";
}

// Two turns (report.json "turns" and "turn_join"): the views of each, how
// the second was joined onto the first and how well. Nothing for one turn.
void Turns(Page& p, const Json& scan) {
  const Json* turns = Find(scan, "turns");
  if (!turns || !turns->is_array()) return;
  p << "<section id=\"turns\"><h2>Turns</h2>\n<p class=\"muted\">The object scanned standing "
       "(turn 1) and laid in another pose; each turn registered within itself, the later one "
       "joined onto turn 1 without a prior, then fused, meshed and measured as one, in turn 1's "
       "frame. A turn's points against the platter are dropped where the other turn sees that "
       "surface.</p>\n";
  p << "<table><thead><tr><th>Turn</th><th>Views</th><th>View numbers</th><th>Step "
       "(&deg;)</th><th>State</th><th>Platter-contact points dropped</th></tr></thead><tbody>\n";
  for (const Json& t : *turns) {
    const double first = Get(t, "first_view", 0), views = Get(t, "views", 0);
    p << "<tr><td>" + Count(t, "turn") + "</td><td class=\"n\">" + Count(t, "views") + "</td><td>" +
             Fixed(first, 0) + "&ndash;" + Fixed(first + views - 1, 0) + "</td><td class=\"n\">" +
             Number(t, "step_deg", 1) + "</td><td>" + Text(t, "state") + "</td><td class=\"n\">" +
             Count(t, "contact_dropped") + "</td></tr>\n";
  }
  p << "</tbody></table>\n";
  if (const Json* j = Find(scan, "turn_join")) {
    const bool ok = Text(*j, "status") == "joined";
    p << "<h3>Join " + Badge(ok, "joined", Text(*j, "status")) + "</h3><table class=\"kv\">\n";
    if (!Text(*j, "message").empty()) p.Row(ok ? "Notes" : "Reason", Text(*j, "message"));
    p.Row("Fit (overlap)", Number(*j, "overlap_pct", 1) +
                               " % of the later turn's surface lies on turn 1's (65 % needed)");
    p.Row("RMSE", Number(*j, "rmse_mm", 3) + " mm (point to plane, over the fitting points)");
    const double ambiguity = Get(*j, "ambiguity", 0);
    p.Row("Ambiguity", ambiguity > 0
                           ? "the best other placement (" + Number(*j, "alternative_deg", 1) +
                                 "&deg;, " + Number(*j, "alternative_mm", 1) + " mm away) fits " +
                                 Fixed(100 * ambiguity, 0) + " % as well (refused from 90 %)"
                           : std::string("no other placement fits nearly as well"));
    const bool weakly = Text(*j, "held") == "weakly";
    p.Row("Constraint", Number(*j, "constraint", 3) +
                            " (the least held motion over the best held; refused below 0.005)" +
                            (weakly ? std::string(" &mdash; held weakly, by one small feature: "
                                                  "the turns may be a few tenths of a degree "
                                                  "apart about it")
                                    : std::string()));
    p.Row("Hypotheses refined", Count(*j, "hypotheses"));
    p.Row("Points compared",
          Count(*j, "points_a") + " of turn 1, " + Count(*j, "points_b") + " of the later turn");
    p.Row("Time", Fixed(Get(*j, "time_ms", NAN) / 1000, 2) + " s");
    p << "</table>\n";
  }
  p << "</section>\n";
}

void Pictures(Page& p, const std::vector<ReportPicture>& pictures, const char* section,
              const char* id, const char* title, const char* empty_text) {
  p << "<section id=\"" + std::string(id) + "\"><h2>" + title + "</h2>\n";
  bool any = false;
  for (const ReportPicture& pic : pictures) {
    if (pic.section != section) continue;
    if (!any) p << "<div class=\"grid\">\n";
    any = true;
    p << "<figure><img src=\"" + HtmlEscape(pic.name) + "\" width=\"" +
             std::to_string(pic.size.width) + "\" height=\"" + std::to_string(pic.size.height) +
             "\" alt=\"" + HtmlEscape(pic.caption) + "\" loading=\"lazy\"><figcaption>" +
             HtmlEscape(pic.caption) + "</figcaption></figure>\n";
  }
  p << (any ? "</div>\n" : "<p class=\"muted\">" + std::string(empty_text) + "</p>\n");
  p << "</section>\n";
}

}  // namespace

std::string HtmlEscape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

bool ReportHtml(const ReportInputs& in, const std::vector<ReportPicture>& pictures,
                const std::vector<std::string>& notes, std::string* html, std::string* error) {
  try {
    Json scan = Json::object();
    if (!in.scan_report_json.empty()) {
      scan = Json::parse(in.scan_report_json, nullptr, false);
      if (!scan.is_object()) {
        if (error)
          *error = "report: scan_report_json is not a JSON object (expected ScanReportJson output)";
        return false;
      }
    }
    for (const ReportPicture& pic : pictures) {
      if (!ValidPictureName(pic.name)) {
        if (error)
          *error =
              "report: picture name '" + pic.name + "' is not a relative path of [A-Za-z0-9._/-]";
        return false;
      }
    }

    // The 3D view: when there is something to show and the library has the viewer.
    const std::string_view bundle = internal::ViewerBundle();
    internal::ViewerModel model;
    if (in.options.viewer && !bundle.empty()) {
      auto budget = [](int n) { return static_cast<std::size_t>(std::clamp(n, 1000, 5000000)); };
      model = internal::MakeViewerModel(in.fused, in.mesh, budget(in.options.viewer_max_points),
                                        budget(in.options.viewer_max_triangles));
    }

    const std::string object = in.object_name.empty() ? "Scan" : in.object_name;
    Page p;
    p << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
         "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
         "<meta name=\"generator\" content=\"craftscan\">\n<title>" +
             HtmlEscape(object) + " &mdash; craftscan session " + HtmlEscape(in.session_id) +
             "</title>\n<style>" + kStyle + "</style>\n</head>\n<body>\n<main>\n";
    p << "<header><h1>" + HtmlEscape(object) + "</h1>\n<p class=\"sub\">Session <code>" +
             HtmlEscape(in.session_id) + "</code>";
    if (!in.created_utc.empty()) p << " &middot; scanned " + HtmlEscape(in.created_utc);
    if (!in.calibration_id.empty()) p << " &middot; calibration " + HtmlEscape(in.calibration_id);
    p << "</p>\n";
    if (!in.scan_report_json.empty()) {
      const bool ok = Flag(scan, "ok") == 1;
      p << "<p>" + Badge(ok, "reconstruction ok", "reconstruction failed");
      if (!Text(scan, "message").empty())
        p << " <span class=\"muted\">" + Text(scan, "message") + "</span>";
      p << "</p>\n";
      Headline(p, scan);
    }
    p << "<nav><a href=\"#measurements\">Measurements</a>";
    if (!model.empty()) p << "<a href=\"#model\">3D view</a>";
    p << "<a href=\"#cloud\">Cloud</a><a "
         "href=\"#mesh\">Mesh</a>"
         "<a href=\"#calibration\">Calibration</a>";
    if (Find(scan, "turns")) p << "<a href=\"#turns\">Turns</a>";
    p << "<a href=\"#registration\">Registration</a>"
         "<a href=\"#reconstruction\">Reconstruction</a><a href=\"#disparity\">Disparity "
         "maps</a></nav>\n"
         "</header>\n";
    if (!notes.empty()) {
      p << "<section id=\"notes\"><h2>Left out</h2><ul class=\"notes\">\n";
      for (const std::string& note : notes) p << "<li>" + HtmlEscape(note) + "</li>\n";
      p << "</ul></section>\n";
    }

    Measurements(p, scan);
    if (!model.empty()) p << internal::ViewerSectionHtml(model);
    Pictures(p, pictures, "cloud", "cloud", "Fused point cloud", "No cloud previews.");
    Pictures(p, pictures, "mesh", "mesh", "Mesh", "No mesh previews.");
    Calibration(p, in);
    Turns(p, scan);
    Registration(p, in, scan);
    Reconstruction(p, scan);
    Pictures(p, pictures, "disparity", "disparity", "Disparity maps", "No disparity maps.");

    p << "<footer>Made by craftscan";
    if (!in.generated_utc.empty()) p << " on " + HtmlEscape(in.generated_utc);
    p << ". Units: millimetres and degrees. Files: fused.ply, mesh.ply, mesh.obj, "
         "report.json; mesh.glb (glTF: metres, +Y up).</footer>\n"
         "</main>\n";
    // Last: the page shows before the model's megabytes are read.
    if (!model.empty()) p << internal::ViewerScriptsHtml(model, bundle, Text(scan, "frame"));
    p << "</body>\n</html>\n";
    *html = std::move(p.html);
    return true;
  } catch (const std::exception& e) {
    if (error) *error = std::string("report: ") + e.what();
    return false;
  }
}

}  // namespace craftscan::daemon
