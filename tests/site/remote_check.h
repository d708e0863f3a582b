// What a test of remote reconstruction checks a stored model against: the
// fused cloud the station makes of the same stored views (ReconstructScan
// with the station's own pipeline settings), as fused.ply bytes.
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "../daemon/sessions/status_util.h"
#include "craftscan/daemon/config.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/surface/mesh.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"
#include "craftscan/pipeline/surface/visibility.h"
#include "file_util.h"

namespace craftscan::testing {

// `config_path`: the daemon's config file; `data_dir`: its data directory.
// The fused cloud the station makes from the session's stored views, with
// its own pipeline settings (the daemon's config file).
inline std::string LocalFusedPly(const std::string& config_path, const std::string& data_dir,
                                 const std::string& session_id, int threads,
                                 std::string* mesh_obj = nullptr) {
  std::string error;
  daemon::DaemonConfig config;
  EXPECT_TRUE(daemon::ParseDaemonConfig(ReadFile(config_path), {}, &config, &error)) << error;
  auto store = daemon::SessionStore::Open(data_dir, StatusInto(&error));
  EXPECT_TRUE(store) << error;
  if (!store) return {};
  auto session = store->OpenSession(session_id, StatusInto(&error));
  EXPECT_TRUE(session) << error;
  if (!session) return {};
  StereoCalibration calibration;
  EXPECT_TRUE(LoadCalibration(session->CalibrationPath(), &calibration, &error)) << error;
  std::vector<ScanView> views;
  for (const auto& [index, record] : session->manifest().views) {
    ScanView view;
    view.commanded_angle_rad = record.angle_deg * CV_PI / 180;
    EXPECT_TRUE(session->LoadCloud(index, &view.cloud_in_rig, &error)) << error;
    views.push_back(std::move(view));
  }
  ScanOptions scan = daemon::ReconstructionOptions(config.pipeline);
  scan.num_threads = threads;
  scan.camera = RectifiedLeftCamera(calibration);
  const ScanResult r = ReconstructScan(views, calibration.turntable, scan);
  EXPECT_TRUE(r.IsUsable()) << r.message;
  if (mesh_obj) *mesh_obj = EncodeMeshObj(r.mesh.mesh);
  return EncodePly(r.fused, true);
}

}  // namespace craftscan::testing
