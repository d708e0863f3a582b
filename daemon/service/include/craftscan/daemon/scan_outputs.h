// A finished scan's outputs as bytes: fused.ply, mesh.ply, mesh.obj,
// mesh.glb, report.json, then report.html and its pictures. One function
// for the station (ReconstructStage) and for a reconstruction worker
// (craftscan-worker), so a model made on another host is the same model,
// byte for byte, as the station would have made from the same views.
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "craftscan/daemon/session_store.h"
#include "craftscan/daemon/stages.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::daemon {

// Everything the outputs are made from besides the ScanResult: the session's
// provenance and where to find its disparity maps.
struct ScanOutputContext {
  std::string session_id;
  std::string object_name;
  std::string created_utc;
  std::string captured_utc;  // of the first view
  std::string client;        // who asked for the scan ("" = unknown)
  std::string calibration_id;
  const StereoCalibration* calibration = nullptr;  // not owned; required
  std::string station, software, rights;           // as ReconstructStage::Options
  // The views the report shows: (index, commanded angle °).
  std::vector<std::pair<int, double>> report_views;
  int min_disparity = 0, num_disparities = 0;  // the band searched, px
  // A view's disparity map (px), for the report's pictures; may be empty.
  std::function<bool(int view, cv::Mat* disparity_px)> load_disparity;
  ReportWriter report;  // may be empty: no report pages
  // false: mesh.obj is left out. A worker sends its outputs without it (the
  // text OBJ is about half of a job's bytes) and the station writes it from
  // the mesh.ply it received (StoreMeshObjFromPly), the same bytes as its
  // own would be: PLY holds the mesh's floats and colours exactly.
  bool mesh_obj = true;
  ProgressFn progress;  // may be empty
  LogFn log;            // may be empty
};

struct ScanOutputFile {
  std::string name;  // session output name
  std::string bytes;
  bool required = true;  // false: the report's pages (one that cannot be stored is logged)
};

struct ScanOutputs {
  std::vector<ScanOutputFile> files;  // in the order they are stored
  // fused_points, mesh_vertices, stage_ms, box_mm, measurement (when
  // measured), report_ms.
  nlohmann::json result;
};

// The context of a station's session (manifest, disparity maps on disk).
ScanOutputContext SessionOutputContext(const Session& session,
                                       const StereoCalibration* calibration);

// The outputs of usable scan `r` whose report.json is `report_json`
// (ScanReportJson(r), with a joined turn's additions). A mesh.glb that
// cannot be encoded and report pages that cannot be made are logged and
// left out. Never throws.
ScanOutputs MakeScanOutputs(const ScanResult& r, const std::string& report_json,
                            const ScanOutputContext& context);

// When `session` has a mesh.ply output and no mesh.obj: reads mesh.ply back
// and stores the OBJ that MakeScanOutputs would have made of the same mesh
// (atomically; a failure is a Storage outcome, resumable). Otherwise does
// nothing.
StageOutcome StoreMeshObjFromPly(Session& session);

// Stores `outputs` in `session`, each atomically: a required file that
// cannot be stored → Storage outcome (resumable); a report page is logged.
StageOutcome StoreScanOutputs(Session& session, const ScanOutputs& outputs, const LogFn& log);

}  // namespace craftscan::daemon
