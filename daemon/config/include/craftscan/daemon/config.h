// craftscand's configuration: the YAML file, environment overrides,
// validation that names the offending field, and a YAML dump
// (`craftscand --print-config`). Only the daemon parses this file; the
// settings map onto the pipeline's option structs (MatcherOptions() …).
//
// File format (version 1; systemd/craftscand.yaml is the annotated example).
// Every key is optional except `version`; unknown keys are refused, naming
// the key path. Ranges are checked at load.
//
//   version: 1                    required; other versions are refused
//   station: station1             [A-Za-z0-9_]{1,32}; in DDS topic names
//   site: default                 [A-Za-z0-9_-]{1,64}; the DDS partition of the site's
//                                 topics (stations and workers that share jobs)
//   data_dir: /var/lib/craftscan  absolute; sessions/ and calibration/ live here
//   log_level: info               debug | info | warning | error
//   dds:
//     domain: 0                   0..230 (Cyclone DDS's port mapping limit)
//     config_file: ""             absolute path of a Cyclone DDS XML file, or
//                                 "" (then CYCLONEDDS_URI or Cyclone's defaults)
//   auth:
//     tokens_file: /etc/craftscan/tokens.yaml   absolute (see auth.h)
//   plugins:
//     path: [<prefix>/lib/craftscan/drivers]       absolute directories, ≥ 1, no ':'
//   devices:                      omitted entirely: the simulated station
//     camera:    {driver: sim, config: {object: carved_box}}
//     turntable: {driver: sim, config: {object: carved_box}}
//                                 driver: [A-Za-z0-9_]{1,64} (the plugin
//                                 craftscan-driver-<driver>.so); config: a map of
//                                 scalars, passed as strings (drivers::DriverConfig).
//                                 When given, both devices are required. The same
//                                 driver with the same config map means one driver
//                                 instance serves both (the sim needs this: its
//                                 camera renders its turntable's angle).
//   calibration:
//     board:
//       type: chessboard          chessboard | charuco
//       cols: 9                   2..100 (chessboard: inner corners per row)
//       rows: 6                   2..100
//       square_mm: 25             (0, 1000]
//       marker_mm: 0              [0, 1000]; ChArUco only, < square_mm
//       dictionary: DICT_4X4_50   ChArUco only: an OpenCV ArUco dictionary name
//                                 (DICT_4X4_50 … DICT_APRILTAG_36h11) or its number
//                                 The board as a whole must satisfy BoardSpec::IsValid.
//     turntable_board: {...}      the board lying on the platter for
//                                 calibrate-turntable, same keys as board
//     turntable_board_thickness_mm: 3   [0, 100] its printed face above the platter
//     views: 15                   3..1000 board views per calibration
//     max_rms_px: 0.5             (0, 10] reprojection RMS accept threshold
//   scan:
//     views: 6                    2..360 views per scan
//     step_deg: 60                (0, 360] turntable step; views × step_deg ≤ 360
//     settle_ms: 200              0..60000 wait after a move before triggering
//     exposure_us: 10000          (0, 10000000]
//     gain_db: 0                  [0, 48] (as the camera command)
//     exposure_bracket: []        multiples of exposure_us also captured per
//                                 view and merged: each (1, 64], ascending,
//                                 ≤ 4 of them; [] = off (e.g. [8] for black paint)
//     auto_bracket: true          with exposure_bracket [], a view dark and without
//                                 texture on ≥ 1 % of the platter is also captured
//                                 at 8 × exposure_us (dark cloth); false = never
//   pipeline:
//     threads: 2                  1..256 worker threads per stage
//     min_disparity: 0            px, −4096..4096
//     num_disparities: 0          px, 0..4096; 0 = derive the band from the
//                                 calibration and the working volume
//     min_texture_std: 2.5        grey levels [0, 255]; 0 = off (ReprojectOptions);
//                                 not over the platter (ViewProcessorOptions)
//     match_gamma: 2.2            [1, 4] the matcher sees the pair gamma-encoded
//                                 as a bracketed merge is (1: as captured;
//                                 ViewProcessorOptions::match_gamma)
//     volume_radius_mm: 120       (0, 10000] working volume around the axis
//     volume_min_height_mm: 0.5   [−1000, 10000] above the platter
//     volume_max_height_mm: 200   (min, 10000]
//     platter_radius_mm: 150      [0, 10000] the band reaches its far edge
//     platter_band_mm: 1.5        [0, 1000] level points facing up below it are platter
//     platter_normal_deg: 60      [0, 90] level: a normal within this of straight up
//     free_space_tolerance_mm: 1  [0, 100]; 0 = no free-space check
//     depth_edge_radius_px: 1     0..5 erosion at depth edges; 0 = off
//     depth_edge_jump_px: 3       (0, 1000] what a depth edge is (px of disparity)
//     aggregation_iterations: 0   0..16 the matcher's cross-based aggregation
//                                 (the paper's 4 flatten slanted weak texture)
//     coarse_to_fine: true        per-pixel disparity ranges from a ~320 px wide
//                                 pass (CoarseToFineOptions) for bands over 192
//     speckle_max_area_pct: 0.004 [0, 1] % of the image: smaller patches go; 0 = off
//     speckle_range_px: 2         (0, 64] a patch's neighbours differ by at most this
//     mesh: true                  a mesh after fusion
//     mesh_method: implicit       implicit or poisson (MeshMethod)
//     measure_box: true           also measure the object as a box (edges, faces)
//   limits:
//     max_command_bytes: 65536    1024..16777216 (serialized DDS command)
//     queue_capacity: 2           1..16 items between capture, matching, registration
//   watchdog:
//     enabled: true               ping systemd's watchdog when it asks
//                                 (WATCHDOG_USEC); false never pings
//   reconstruction:
//     mode: local                 local | remote | auto: where a scan is reconstructed
//                                 (remote: a craftscan-worker of the site; auto: remote
//                                 when a worker is idle, else local)
//     offer_timeout_ms: 3000      100..600000: unclaimed this long → local
//     max_remote_s: 1800          10..86400: a granted job with no result this long → local
//   deliverables:
//     rights: ""                  rights statement and licence written into
//                                 every model (mesh.glb's asset.copyright and
//                                 provenance), e.g. "© 2026 Museum X, CC BY 4.0";
//                                 UTF-8, no control characters, ≤ 1024 bytes;
//                                 "" = none
//
// Booleans: true/false (also yes/no, on/off, 1/0). Numbers: plain decimal
// (no hex, no units, no trailing text).
//
// Environment overrides: every scalar field (and plugins.path) can be set by
// CRAFTSCAN_<PATH>, the path's segments upper-cased and joined by '_':
// CRAFTSCAN_STATION, CRAFTSCAN_DATA_DIR, CRAFTSCAN_LOG_LEVEL,
// CRAFTSCAN_DDS_DOMAIN, CRAFTSCAN_DDS_CONFIG_FILE, CRAFTSCAN_AUTH_TOKENS_FILE,
// CRAFTSCAN_PLUGINS_PATH (directories joined by ':'),
// CRAFTSCAN_DEVICES_CAMERA_DRIVER, CRAFTSCAN_CALIBRATION_BOARD_SQUARE_MM,
// CRAFTSCAN_SCAN_VIEWS, CRAFTSCAN_PIPELINE_THREADS, CRAFTSCAN_WATCHDOG_ENABLED,
// … (ConfigEnvironmentVariables() lists them all). Overrides apply after the
// file and are validated the same way; an error names the variable. Other
// CRAFTSCAN_* variables (e.g. the clients' CRAFTSCAN_TOKEN) are ignored.
#pragma once

#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/drivers/host.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/working_volume.h"
#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/stereo/reproject.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::daemon {

// The config file version this build reads.
inline constexpr int kConfigVersion = 1;

// The driver plugin directory of this build's install prefix
// (<prefix>/lib/craftscan/drivers), the default plugins.path.
std::string DefaultPluginDirectory();

// The log level: the drivers' enum, so the daemon's logger and the drivers'
// host log share one scale. drivers::ToString gives "debug", "info",
// "warning", "error"; LogLevelFromString reads them back.
using LogLevel = drivers::LogLevel;
bool LogLevelFromString(std::string_view text, LogLevel* level);

struct DdsSettings {
  int domain = 0;           // DDS domain id, 0..230
  std::string config_file;  // absolute path of a Cyclone DDS XML file, or empty
};

struct AuthSettings {
  std::string tokens_file = "/etc/craftscan/tokens.yaml";  // absolute; see auth.h
};

struct PluginSettings {
  std::vector<std::string> path = {DefaultPluginDirectory()};  // absolute dirs, searched in order
  // The directories joined by ':' (drivers::PluginLoader's search path).
  std::string SearchPath() const;
};

struct DeviceSettings {
  std::string driver = "sim";    // plugin name: craftscan-driver-<driver>.so
  drivers::DriverConfig config;  // passed to the driver as is
  // Whether `other` is served by the same driver instance (same driver and config).
  bool SharesInstanceWith(const DeviceSettings& other) const {
    return driver == other.driver && config == other.config;
  }
};

struct DevicesSettings {  // defaults: the simulated station (one sim instance)
  DeviceSettings camera;
  DeviceSettings turntable;
};

// Default boards: the ones the simulated station's rig (100 mm baseline,
// ~400 mm to the axis) is made for; a real station sets its printed boards.
inline BoardSpec DefaultBoard(double square_mm) {
  BoardSpec board;
  board.cols = 9;
  board.rows = 6;
  board.square_mm = square_mm;
  return board;
}

struct CalibrationSettings {
  // Held in front of the cameras (calibrate); craftscan::BoardSpec.
  BoardSpec board = DefaultBoard(8);
  // Lying on the platter (calibrate-turntable); its printed face is
  // turntable_board_thickness_mm above the platter. Not 180°-symmetric
  // (a chessboard's cols + rows odd): the axis fit needs its corner order.
  BoardSpec turntable_board = DefaultBoard(12);
  double turntable_board_thickness_mm = 3;  // [0, 100]
  int views = 15;                           // board views captured per calibration, 3..1000
  double max_rms_px = 0.5;  // accept threshold on the reprojection RMS (px), (0, 10]
  // Guided: the calibrate job watches the live stream, takes a view when the
  // board is held still in a new pose and tells the person what to do next
  // (calibration_guide.h); `views` are then the views needed. Off: it takes
  // `views` frames as they come (the simulator's posed board). Guided,
  // calibrate-turntable waits for the board to lie still in view before it
  // turns and measures a still board at each angle (PlatterGuide).
  bool guided = false;
  double guided_max_s = 600;  // give up after this long, [10, 3600]
};

struct ScanSettings {
  int views = 6;               // views per scan, 2..360
  double step_deg = 60;        // turntable step between views (°), (0, 360]
  int settle_ms = 200;         // wait after a move before triggering (ms), 0..60000
  double exposure_us = 10000;  // µs, (0, 10000000]
  double gain_db = 0;          // dB, [0, 48]
  // Exposure bracketing: each view is also captured at these multiples of
  // exposure_us and the pairs merged (MergeExposures) before matching, for
  // dark, weakly textured paint. Each in (1, 64], ascending, at most 4;
  // exposure_us × the largest ≤ 10000000. Empty (the default) = off.
  std::vector<double> exposure_bracket;
  // With exposure_bracket empty: each view whose platter is dark without
  // texture on enough of its pixels (dark cloth, black paint; AutoBracketOptions)
  // is also captured at 8 × exposure_us and merged; the others once. Its
  // meta.json says which. exposure_us × 8 ≤ 10000000 when on.
  bool auto_bracket = true;
};

struct PipelineSettings {
  int threads = 2;               // worker threads per stage, 1..256
  int min_disparity = 0;         // px, −4096..4096
  int num_disparities = 0;       // px, 0..4096; 0 = derive from calibration + volume
  double min_texture_std = 2.5;  // grey levels, [0, 255]; 0 = off (ViewProcessorOptions)
  // The matcher's copy of each pair gamma-encoded with this, [1, 4]; 1 =
  // as the cameras deliver it (ViewProcessorOptions::match_gamma).
  double match_gamma = 2.2;
  // pipeline.volume_radius_mm (0, 10000], pipeline.volume_min_height_mm
  // [−1000, 10000], pipeline.volume_max_height_mm (min, 10000]; mm. The
  // bottom is 0.5 mm, below the pipeline's own 1.5: with the platter band
  // below (level and gently sloped points under 1.5 mm go) the walls'
  // lowest millimetre stays (README 11.9: box height error 1.44 -> 0.4 mm).
  WorkingVolume volume{.radius_mm = 120, .min_height_mm = 0.5, .max_height_mm = 200};
  // The turntable platter's radius (mm, [0, 10000]; 0 = not used): the
  // matcher's band reaches the platter's far edge, seen above low objects
  // (ViewProcessorOptions::platter_radius_mm).
  double platter_radius_mm = 150;
  // Points lower than this above the platter whose normal is within
  // platter_normal_deg of straight up are the platter itself, lifted by
  // matching noise, and dropped (mm, [0, 1000]; at or below
  // volume_min_height_mm: off): VolumeCrop::platter_band_mm. Walls (steeper
  // than 90° - platter_normal_deg), feet facing down and relief below it are
  // kept.
  double platter_band_mm = 1.5;
  // Degrees, [0, 90]: VolumeCrop::platter_normal_deg. 60 also takes sloped
  // platter noise and keeps a vertical wall and a base that meets the
  // platter at up to 30° from vertical. The noise under an overhang (an
  // egg's underside, where the matcher lifts the shadowed platter) faces
  // down: fusion's platter_shadow_mm (3 mm) takes it unless two views saw it.
  double platter_normal_deg = 60;
  // Erosion at depth discontinuities (EraseNearDepthEdges): pixels within
  // depth_edge_radius_px (0..5; 0 = off) of a nearer surface, its disparity
  // more than depth_edge_jump_px ((0, 1000]) above theirs, are dropped.
  int depth_edge_radius_px = 1;
  double depth_edge_jump_px = 3;
  // The matcher's cross-based aggregation iterations (0..16):
  // ViewProcessorOptions::aggregation_iterations.
  int aggregation_iterations = 0;
  // ViewProcessorOptions::coarse_to_fine (CoarseToFineOptions::enabled).
  bool coarse_to_fine = true;
  // Speckles (RemoveDisparitySpeckles): connected disparity patches of at
  // most speckle_max_area_pct % of the image ([0, 1]; 0 = off), neighbours
  // within speckle_range_px ((0, 64]), are dropped before reprojection:
  // ViewProcessorOptions::speckle_max_area_pct, speckle_range_px.
  double speckle_max_area_pct = 0.004;
  double speckle_range_px = 2.0;
  // Drop fused points other views look straight through (mm of depth
  // agreement, [0, 100]; 0 = off): VisibilityOptions::tolerance_mm.
  double free_space_tolerance_mm = 1.0;
  bool mesh = true;  // a mesh after fusion
  // The implicit surface (algebraic spheres fitted over a grid, marching
  // cubes, only where the points are) or Poisson's (trimmed by support):
  // ScanOptions::mesh_method.
  MeshMethod mesh_method = MeshMethod::kImplicit;
  // Measure the object as a box (faces, edges, vertices) besides its
  // oriented bounding box; objects that are not boxes report why not.
  bool measure_box = true;
};

struct LimitSettings {
  int max_command_bytes = 65536;  // largest accepted command (bytes), 1024..16777216
  // Items in flight between capture, matching and registration (each a
  // stereo pair or a cloud of tens of MB): 2 lets capture run one view ahead
  // of matching without holding more than a few hundred MB. 1..16.
  int queue_capacity = 2;
};

struct WatchdogSettings {
  bool enabled = true;  // ping when systemd sets WATCHDOG_USEC; false: never ping
};

struct DeliverableSettings {
  // Rights statement and licence of the station's models (mesh.glb's
  // asset.copyright and provenance): valid UTF-8 without control
  // characters, at most 1024 bytes; "" = none recorded.
  std::string rights;
};

// Where a scan's reconstruction runs (after its views are matched):
// kLocal on this station; kRemote on a worker of the site (craftscan-worker),
// this station taking over when no worker claims the job within
// offer_timeout_ms; kAuto remote when a worker is idle now, else local.
enum class ReconstructionMode { kLocal, kRemote, kAuto };
std::string_view ToString(ReconstructionMode mode);  // "local", "remote", "auto"
bool ReconstructionModeFromString(std::string_view text, ReconstructionMode* mode);

struct ReconstructionSettings {
  ReconstructionMode mode = ReconstructionMode::kLocal;
  // An offer nobody claims (or a job whose worker was lost and that nobody
  // claims again) is reconstructed here after this long (ms), 100..600000.
  int offer_timeout_ms = 3000;
  // A granted job whose result has not come this long after the grant (s,
  // 10..86400) is taken back and reconstructed here.
  int max_remote_s = 1800;
};

struct DaemonConfig {
  std::string station = "station1";  // [A-Za-z0-9_]{1,32}
  // The site the station belongs to: its stations and workers share jobs
  // and see each other in this DDS partition (craftscan/dds/site.h).
  std::string site = "default";                 // [A-Za-z0-9_-]{1,64}
  std::string data_dir = "/var/lib/craftscan";  // absolute
  LogLevel log_level = LogLevel::kInfo;
  DdsSettings dds;
  AuthSettings auth;
  PluginSettings plugins;
  DevicesSettings devices;
  CalibrationSettings calibration;
  ScanSettings scan;
  PipelineSettings pipeline;
  LimitSettings limits;
  WatchdogSettings watchdog;
  DeliverableSettings deliverables;
  ReconstructionSettings reconstruction;

  // Checks every field's range and the cross-field rules (board validity,
  // views × step_deg ≤ 360, volume heights ordered, matcher options). On
  // failure *why (may be null) starts with the field path, e.g.
  // "scan.views: must be an integer in 1..360, got '0'".
  bool IsValid(std::string* why) const;
};

// Parses a config from YAML text, then applies the CRAFTSCAN_* entries of
// `env` (name → value; other entries ignored), then validates. On failure
// returns false, leaves *config unchanged and sets *error to one message
// naming the field path (and the YAML line, or the environment variable).
// Never throws. Thread-safe.
bool ParseDaemonConfig(const std::string& yaml_text, const std::map<std::string, std::string>& env,
                       DaemonConfig* config, std::string* error);

// Reads `path` and parses it with the process environment's CRAFTSCAN_*
// overrides. Errors are prefixed with the path. Never throws. Thread-safe as
// long as no other thread modifies the environment.
bool LoadDaemonConfig(const std::string& path, DaemonConfig* config, std::string* error);

// The config as a version-1 YAML document with every field, in schema
// order. ParseDaemonConfig(DumpDaemonConfig(c), {}, …) yields c again.
std::string DumpDaemonConfig(const DaemonConfig& config);

// The environment variables ParseDaemonConfig reads, in schema order.
std::vector<std::string> ConfigEnvironmentVariables();

// The process environment's variables that start with "CRAFTSCAN_".
std::map<std::string, std::string> CraftscanEnvironment();

// The settings as pipeline options. MatcherOptions: threads, the
// aggregation iterations, and the disparity band when num_disparities > 0
// (otherwise the caller sets the band it derived). ReconstructionOptions: threads, working volume,
// mesh.
ADCensusOptions MatcherOptions(const PipelineSettings& settings);
ReprojectOptions ReprojectionOptions(const PipelineSettings& settings);
ScanOptions ReconstructionOptions(const PipelineSettings& settings);
// The per-view processing of a scan (ViewProcessor): working volume, texture
// threshold, a fixed band when num_disparities > 0, threads. The daemon and
// `craftscan-bench scan` both take it from here.
ViewProcessorOptions ViewOptions(const PipelineSettings& settings);

}  // namespace craftscan::daemon
