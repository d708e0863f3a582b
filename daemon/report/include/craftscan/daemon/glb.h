// model.glb: a scan's mesh as glTF 2.0 binary (GLB) for the web and for
// archives (DESIGN.md "Deliverables"): vertex colours (COLOR_0), normals
// when the mesh has usable ones, metres and +Y up as glTF requires, and the
// model's provenance inside the file.
//
//   ModelProvenance p;
//   p.object_name = manifest.object_name;  p.session_id = session.id();
//   p.station = "station1";  p.captured_utc = first view's capture time;
//   p.client = manifest.params["client"];  p.calibration_id = manifest.calibration_id;
//   p.calibration_rms_px = calibration.report.rms_stereo_px;
//   p.software = "craftscan 0.1.0";  p.rights = config.deliverables.rights;
//   p.scan_report_json = ScanReportJson(result);
//   std::string glb;
//   if (!EncodeGlb(result.mesh.mesh, p, &glb, &error)) ...;
//
// Frames and units. The pipeline's model is in millimetres in the turntable
// frame (+Z up the axis, −Y towards the cameras) or, without a turntable
// axis, in the frame of view 0 (the rectified left camera: +Y down, +Z
// away from it). The GLB holds metres, +Y up, +Z towards the viewer:
//   turntable: (x, y, z)_gltf = 0.001 · ( x, z, −y)_turntable
//   view0:     (x, y, z)_gltf = 0.001 · ( x, −y, −z)_view0
// Vertices are converted (no node transform); the inverse, the source frame
// from glTF (mm from m, row-major 4×4), is recorded in the provenance.
//
// Where the provenance goes: asset.generator = software; asset.copyright =
// rights (when given); asset.extras.craftscan = {
//   "format": "craftscan-model-provenance", "format_version": 1,
//   "object_name", "session_id", "station", "captured_utc", "client",
//   "calibration": {"id", "rms_stereo_px", "epipolar_mean_px"},
//   "software", "rights",
//   "units": "m", "up": "+Y",
//   "source_frame": "turntable" | "view0", "source_units": "mm",
//   "source_from_gltf": [16 numbers, row-major],
//   "vertices", "triangles",
//   "accuracy": {"quality": report.json's quality (distances of the fused
//                points to the mesh, holes), "loop_closure": {rms_mm, max_mm,
//                axis_rms_mm, model}, "measurement": report.json's
//                measurement (oriented box, box edges)}}
// Empty strings and unknown (NaN) figures are left out.
#pragma once

#include <limits>
#include <string>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/triangle_mesh.h"

namespace craftscan::daemon {

// The frame a model's vertices are in (report.json's "frame").
enum class ModelFrame { kTurntable, kView0 };
const char* ToString(ModelFrame frame);  // "turntable", "view0"

// Who made the model, of what, with what, and how good it is. Strings are
// stored as given (UTF-8).
struct ModelProvenance {
  std::string object_name;     // as the operator gave it
  std::string session_id;      // the session folder's name
  std::string station;         // the station id
  std::string captured_utc;    // ISO 8601 UTC: when the first view was captured
  std::string client;          // the client that asked for the scan
  std::string calibration_id;  // as recorded in the manifest
  double calibration_rms_px = std::numeric_limits<double>::quiet_NaN();  // stereo reprojection
  double calibration_epipolar_mean_px = std::numeric_limits<double>::quiet_NaN();
  std::string software;  // "craftscan <version>"
  std::string rights;    // rights statement and licence (the config's deliverables.rights)
  // ScanResult's report (report.json): its frame and accuracy figures are
  // copied. "" or not a JSON object: the frame is the turntable's and no
  // accuracy figures are recorded.
  std::string scan_report_json;
};

// The transform from model coordinates (mm, `frame`) to glTF coordinates
// (m, +Y up): p_gltf = gltf_from_model · p_model. Its inverse is recorded.
cv::Matx44d GltfFromModel(ModelFrame frame);

// Encodes `mesh_mm` as a GLB with `provenance` (see above): one buffer,
// POSITION (float, with min/max), NORMAL (float, unit; left out when any
// normal is zero or not finite), COLOR_0 (normalized unsigned byte RGB) when
// the mesh has colours, and 32-bit indices; one node, one scene. Fails
// (false, *error naming what is wrong; *glb untouched) for an invalid or
// empty mesh or one too large for a GLB (4 GiB). Pure and thread-safe;
// never throws. About 40 bytes per vertex plus 12 per triangle.
bool EncodeGlb(const TriangleMesh& mesh_mm, const ModelProvenance& provenance, std::string* glb,
               std::string* error);

}  // namespace craftscan::daemon
