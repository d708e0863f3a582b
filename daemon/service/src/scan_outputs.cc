// A finished scan's outputs as bytes (scan_outputs.h).
#include "craftscan/daemon/scan_outputs.h"

#include <exception>

#include "craftscan/daemon/glb.h"
#include "craftscan/daemon/report.h"
#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::daemon {
namespace {

void Log(const ScanOutputContext& context, drivers::LogLevel level, const std::string& message) {
  if (context.log) context.log(level, "session " + context.session_id + ": " + message);
}

// mesh.glb with the session's provenance; "" (logged) when it cannot be
// encoded: the PLY and OBJ still hold the model.
std::string EncodeModel(const std::string& report_json, const ScanResult& r,
                        const ScanOutputContext& context) {
  ModelProvenance p;
  p.object_name = context.object_name;
  p.session_id = context.session_id;
  p.station = context.station;
  p.captured_utc = context.captured_utc;
  p.client = context.client;
  p.calibration_id = context.calibration_id;
  p.calibration_rms_px = context.calibration->report.rms_stereo_px;
  p.calibration_epipolar_mean_px = context.calibration->report.epipolar_mean_px;
  p.software = context.software;
  p.rights = context.rights;
  p.scan_report_json = report_json;
  std::string glb, why;
  if (!EncodeGlb(r.mesh.mesh, p, &glb, &why)) {
    Log(context, drivers::LogLevel::kWarning, "mesh.glb: " + why);
    return {};
  }
  return glb;
}

// The page people look at: measurements, calibration, registration and
// pictures. A report that cannot be made is noted, not a failed scan.
void AddReport(const std::string& report_json, const ScanResult& r,
               const ScanOutputContext& context, ScanOutputs* out) {
  if (!context.report) return;
  if (context.progress) context.progress("report", 0, 1, "rendering previews and report.html");
  ReportInputs inputs;
  inputs.session_id = context.session_id;
  inputs.object_name = context.object_name;
  inputs.created_utc = context.created_utc;
  inputs.calibration_id = context.calibration_id;
  inputs.scan_report_json = report_json;
  inputs.calibration = context.calibration;
  inputs.fused = &r.fused;
  if (r.mesh.status == MeshResult::Status::kOk) inputs.mesh = &r.mesh.mesh;
  for (const auto& [k, angle] : context.report_views) {
    DisparityView view;
    view.index = k;
    view.angle_deg = angle;
    view.min_disparity_px = context.min_disparity;
    view.max_disparity_px = context.min_disparity + context.num_disparities - 1;
    if (context.load_disparity && context.load_disparity(k, &view.disparity_px)) {
      inputs.disparities.push_back(std::move(view));
    }
  }
  ReportFiles files;
  std::string why;
  if (!context.report(inputs, &files, &why)) {
    Log(context, drivers::LogLevel::kWarning, "report: " + why);
    return;
  }
  for (ReportFile& file : files.files)
    out->files.push_back({file.name, std::move(file.bytes), false});
  out->result["report_ms"] = files.render_ms;
}

}  // namespace

ScanOutputContext SessionOutputContext(const Session& session,
                                       const StereoCalibration* calibration) {
  const Manifest manifest = session.manifest();
  ScanOutputContext c;
  c.session_id = session.id();
  c.object_name = manifest.object_name;
  c.created_utc = manifest.created_utc;
  c.captured_utc =
      manifest.views.empty() ? manifest.created_utc : manifest.views.begin()->second.captured_utc;
  if (const auto client = manifest.params.find("client");
      client != manifest.params.end() && client->is_string())
    c.client = client->get<std::string>();
  c.calibration_id = manifest.calibration_id;
  c.calibration = calibration;
  c.load_disparity = [&session](int view, cv::Mat* disparity) {
    return session.LoadDisparity(view, disparity, nullptr);
  };
  return c;
}

ScanOutputs MakeScanOutputs(const ScanResult& r, const std::string& report_json,
                            const ScanOutputContext& context) {
  ScanOutputs out;
  const bool mesh = r.mesh.status == MeshResult::Status::kOk;
  out.files.push_back({"fused.ply", EncodePly(r.fused, true), true});
  if (mesh) {
    out.files.push_back({"mesh.ply", EncodeMeshPly(r.mesh.mesh, true), true});
    if (context.mesh_obj) out.files.push_back({"mesh.obj", EncodeMeshObj(r.mesh.mesh), true});
    if (std::string glb = EncodeModel(report_json, r, context); !glb.empty())
      out.files.push_back({"mesh.glb", std::move(glb), true});
  }
  out.files.push_back({"report.json", report_json, true});
  AddReport(report_json, r, context, &out);

  out.result["fused_points"] = r.fused.size();
  out.result["mesh_vertices"] = r.mesh.mesh.vertices_mm.size();
  out.result["stage_ms"] = {{"condition", r.condition_ms}, {"register", r.register_ms},
                            {"loop", r.loop_ms},           {"fuse", r.fuse_ms},
                            {"mesh", r.mesh_ms},           {"measure", r.measure_ms}};
  out.result["box_mm"] = {r.box.extents_mm[0], r.box.extents_mm[1], r.box.extents_mm[2]};
  const nlohmann::json report = nlohmann::json::parse(report_json, nullptr, false);
  if (report.is_object() && report.contains("measurement"))
    out.result["measurement"] = report["measurement"];
  return out;
}

StageOutcome StoreMeshObjFromPly(Session& session) {
  const Manifest manifest = session.manifest();
  if (!manifest.outputs.count("mesh.ply") || manifest.outputs.count("mesh.obj"))
    return StageOutcome::Ok();
  TriangleMesh mesh;
  std::string why;
  // Unreadable as stored (a disk error, or a worker's mesh.ply that passed
  // its checksum but is no mesh): resumable, as a resume makes the model again.
  if (!ReadMeshPly(session.dir() + "/mesh.ply", &mesh, &why))
    return StageOutcome::Error(ErrorCode::kIoError, "mesh.obj from mesh.ply: " + why, true);
  const std::string obj = EncodeMeshObj(mesh);
  const Status stored = session.StoreOutputWith(
      "mesh.obj", [&obj](const std::string& path) { return WriteFileAtomically(path, obj); });
  if (!stored.ok()) return StageOutcome::Storage(stored, "outputs: ");
  return StageOutcome::Ok();
}

StageOutcome StoreScanOutputs(Session& session, const ScanOutputs& outputs, const LogFn& log) {
  for (const ScanOutputFile& file : outputs.files) {
    // Written with the Status-returning WriteFileAtomically, so a full or
    // read-only disk reaches the job as its code.
    const Status stored = session.StoreOutputWith(file.name, [&file](const std::string& path) {
      return WriteFileAtomically(path, file.bytes);
    });
    if (stored.ok()) continue;
    // Storage, not the pipeline: resumable like a capture that failed.
    if (file.required) return StageOutcome::Storage(stored, "outputs: ");
    if (log)
      log(drivers::LogLevel::kWarning, "session " + session.id() + ": report: " + stored.message());
  }
  return StageOutcome::Ok();
}

}  // namespace craftscan::daemon
