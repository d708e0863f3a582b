// craftscand's config file: parsing, per-field validation messages, unknown
// keys, the version key, environment overrides, the dump round trip and the
// shipped example (systemd/craftscand.yaml).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "../../unit/test_util.h"
#include "craftscan/daemon/config.h"
#include "fake_notify_socket.h"
#include "test_paths.h"

namespace craftscan::daemon {
namespace {

using ::testing::HasSubstr;

const std::map<std::string, std::string> kNoEnv;

bool Parse(const std::string& yaml, DaemonConfig* config, std::string* error,
           const std::map<std::string, std::string>& env = kNoEnv) {
  return ParseDaemonConfig(yaml, env, config, error);
}

TEST(DaemonConfig, DefaultsAreValid) {
  DaemonConfig config;
  std::string why;
  EXPECT_TRUE(config.IsValid(&why)) << why;
  EXPECT_EQ(config.devices.camera.driver, "sim");
  EXPECT_TRUE(config.devices.camera.SharesInstanceWith(config.devices.turntable));
  ASSERT_EQ(config.plugins.path.size(), 1u);
  EXPECT_EQ(config.plugins.path[0], DefaultPluginDirectory());
}

TEST(DaemonConfig, MinimalFileGivesDefaults) {
  DaemonConfig config;
  config.station = "changed";
  std::string error;
  ASSERT_TRUE(Parse("version: 1\n", &config, &error)) << error;
  EXPECT_EQ(DumpDaemonConfig(config), DumpDaemonConfig(DaemonConfig{}));
}

TEST(DaemonConfig, ReadsEveryField) {
  const std::string yaml = R"(version: 1
station: lab_2
data_dir: /srv/craftscan
log_level: debug
dds: {domain: 7, config_file: /etc/craftscan/cyclonedds.xml}
auth: {tokens_file: /srv/tokens.yaml}
plugins: {path: [/opt/a, /opt/b]}
devices:
  camera: {driver: aravis, config: {left: "192.168.1.10", right: "192.168.1.11", packet_size: 9000}}
  turntable: {driver: serial_turntable, config: {port: /dev/ttyACM0}}
calibration:
  board: {type: charuco, cols: 7, rows: 5, square_mm: 30, marker_mm: 22, dictionary: DICT_5X5_100}
  views: 20
  max_rms_px: 0.3
scan: {views: 8, step_deg: 45, settle_ms: 500, exposure_us: 2500.5, gain_db: 6,
       exposure_bracket: [4, 16.5]}
pipeline:
  threads: 4
  min_disparity: -32
  num_disparities: 192
  min_texture_std: 0
  aggregation_iterations: 4
  coarse_to_fine: false
  speckle_max_area_pct: 0.01
  speckle_range_px: 1.5
  volume_radius_mm: 90
  volume_min_height_mm: 2
  volume_max_height_mm: 150
  platter_band_mm: 3
  platter_normal_deg: 45
  mesh: false
  mesh_method: implicit
limits: {max_command_bytes: 4096, queue_capacity: 3}
watchdog: {enabled: no}
deliverables: {rights: "© 2026 Musée d'Orsay: CC BY-NC 4.0"}
)";
  DaemonConfig c;
  std::string error;
  ASSERT_TRUE(Parse(yaml, &c, &error)) << error;
  EXPECT_EQ(c.station, "lab_2");
  EXPECT_EQ(c.data_dir, "/srv/craftscan");
  EXPECT_EQ(c.log_level, LogLevel::kDebug);
  EXPECT_EQ(c.dds.domain, 7);
  EXPECT_EQ(c.dds.config_file, "/etc/craftscan/cyclonedds.xml");
  EXPECT_EQ(c.auth.tokens_file, "/srv/tokens.yaml");
  EXPECT_EQ(c.plugins.path, (std::vector<std::string>{"/opt/a", "/opt/b"}));
  EXPECT_EQ(c.plugins.SearchPath(), "/opt/a:/opt/b");
  EXPECT_EQ(c.devices.camera.driver, "aravis");
  EXPECT_EQ(c.devices.camera.config.at("left"), "192.168.1.10");
  EXPECT_EQ(c.devices.camera.config.at("packet_size"), "9000");
  EXPECT_EQ(c.devices.turntable.driver, "serial_turntable");
  EXPECT_EQ(c.devices.turntable.config.at("port"), "/dev/ttyACM0");
  EXPECT_FALSE(c.devices.camera.SharesInstanceWith(c.devices.turntable));
  EXPECT_EQ(c.calibration.board.type, BoardSpec::Type::kCharuco);
  EXPECT_EQ(c.calibration.board.cols, 7);
  EXPECT_EQ(c.calibration.board.rows, 5);
  EXPECT_DOUBLE_EQ(c.calibration.board.square_mm, 30);
  EXPECT_DOUBLE_EQ(c.calibration.board.marker_mm, 22);
  EXPECT_EQ(c.calibration.board.aruco_dictionary, 5);  // DICT_5X5_100
  EXPECT_EQ(c.calibration.views, 20);
  EXPECT_DOUBLE_EQ(c.calibration.max_rms_px, 0.3);
  EXPECT_EQ(c.scan.views, 8);
  EXPECT_DOUBLE_EQ(c.scan.step_deg, 45);
  EXPECT_EQ(c.scan.settle_ms, 500);
  EXPECT_DOUBLE_EQ(c.scan.exposure_us, 2500.5);
  EXPECT_DOUBLE_EQ(c.scan.gain_db, 6);
  EXPECT_EQ(c.scan.exposure_bracket, (std::vector<double>{4, 16.5}));
  EXPECT_EQ(c.pipeline.threads, 4);
  EXPECT_EQ(c.pipeline.min_disparity, -32);
  EXPECT_EQ(c.pipeline.num_disparities, 192);
  EXPECT_DOUBLE_EQ(c.pipeline.min_texture_std, 0);
  EXPECT_EQ(c.pipeline.aggregation_iterations, 4);
  EXPECT_DOUBLE_EQ(c.pipeline.volume.radius_mm, 90);
  EXPECT_DOUBLE_EQ(c.pipeline.volume.min_height_mm, 2);
  EXPECT_DOUBLE_EQ(c.pipeline.volume.max_height_mm, 150);
  EXPECT_FALSE(c.pipeline.mesh);
  EXPECT_EQ(c.pipeline.mesh_method, MeshMethod::kImplicit);
  EXPECT_EQ(c.limits.max_command_bytes, 4096);
  EXPECT_EQ(c.limits.queue_capacity, 3);
  EXPECT_FALSE(c.watchdog.enabled);
  EXPECT_EQ(c.deliverables.rights, "© 2026 Musée d'Orsay: CC BY-NC 4.0");

  const ADCensusOptions matcher = MatcherOptions(c.pipeline);
  EXPECT_EQ(matcher.num_threads, 4);
  EXPECT_EQ(matcher.min_disparity, -32);
  EXPECT_EQ(matcher.num_disparities, 192);
  EXPECT_EQ(matcher.aggregation_iterations, 4);
  EXPECT_EQ(ViewOptions(c.pipeline).aggregation_iterations, 4);
  EXPECT_FALSE(ViewOptions(c.pipeline).coarse_to_fine);
  EXPECT_FALSE(matcher.coarse_to_fine.enabled);
  EXPECT_TRUE(ViewOptions(PipelineSettings{}).coarse_to_fine);  // the default
  EXPECT_DOUBLE_EQ(ViewOptions(c.pipeline).speckle_max_area_pct, 0.01);
  EXPECT_DOUBLE_EQ(ViewOptions(c.pipeline).speckle_range_px, 1.5);
  const ScanOptions scan = ReconstructionOptions(c.pipeline);
  EXPECT_EQ(scan.num_threads, 4);
  EXPECT_DOUBLE_EQ(scan.volume.radius_mm, 90);
  EXPECT_DOUBLE_EQ(scan.conditioning.crop.platter_band_mm, 3);
  EXPECT_DOUBLE_EQ(scan.conditioning.crop.platter_normal_deg, 45);
  EXPECT_FALSE(scan.mesh);
  // The defaults: a 0.5 mm bottom with the band above it active.
  const ScanOptions defaults = ReconstructionOptions(PipelineSettings{});
  EXPECT_DOUBLE_EQ(defaults.volume.min_height_mm, 0.5);
  EXPECT_DOUBLE_EQ(defaults.conditioning.crop.platter_band_mm, 1.5);
  EXPECT_DOUBLE_EQ(defaults.conditioning.crop.platter_normal_deg, 60);
  EXPECT_DOUBLE_EQ(ReprojectionOptions(c.pipeline).min_texture_std, 0);

  // The dump reads back to the same config.
  DaemonConfig again;
  ASSERT_TRUE(Parse(DumpDaemonConfig(c), &again, &error)) << error << "\n" << DumpDaemonConfig(c);
  EXPECT_EQ(DumpDaemonConfig(again), DumpDaemonConfig(c));
  EXPECT_EQ(again.devices.camera.config, c.devices.camera.config);
  EXPECT_EQ(again.calibration.board.aruco_dictionary, 5);
  EXPECT_EQ(again.deliverables.rights, c.deliverables.rights);
}

// One bad value per field: the load fails and the message names the field
// path and the offending text.
struct BadValueCase {
  std::string yaml;      // after "version: 1\n"
  std::string expected;  // substring of the error
};

class BadValue : public ::testing::TestWithParam<BadValueCase> {};

TEST_P(BadValue, ErrorNamesTheField) {
  DaemonConfig config;
  const DaemonConfig before = config;
  std::string error;
  EXPECT_FALSE(Parse("version: 1\n" + GetParam().yaml, &config, &error));
  EXPECT_THAT(error, HasSubstr(GetParam().expected)) << GetParam().yaml;
  EXPECT_EQ(DumpDaemonConfig(config), DumpDaemonConfig(before)) << "config changed on failure";
}

INSTANTIATE_TEST_SUITE_P(
    EveryField, BadValue,
    ::testing::Values(
        BadValueCase{
            "station: st-1\n",
            "station: must be 1 to 32 characters of A-Z, a-z, 0-9, _, starting with a letter, got "
            "'st-1'"},
        BadValueCase{"station: 2nd_floor\n",
                     "station: must be 1 to 32 characters of A-Z, a-z, 0-9, "
                     "_, starting with a letter, got '2nd_floor'"},
        BadValueCase{"station: abcdefghijklmnopqrstuvwxyz0123456\n", "station: must be 1 to 32"},
        BadValueCase{
            "station: \"\"\n",
            "station: must be 1 to 32 characters of A-Z, a-z, 0-9, _, starting with a letter, "
            "got nothing"},
        BadValueCase{"data_dir: relative/dir\n",
                     "data_dir: must be an absolute path, got 'relative/dir'"},
        BadValueCase{"log_level: verbose\n",
                     "log_level: must be one of debug, info, warning, error; got 'verbose'"},
        BadValueCase{"dds: {domain: 231}\n", "dds.domain: must be an integer in 0..230, got '231'"},
        BadValueCase{"dds: {domain: -1}\n", "dds.domain: must be an integer in 0..230, got '-1'"},
        BadValueCase{"dds: {domain: 1.5}\n", "dds.domain: must be an integer in 0..230, got '1.5'"},
        BadValueCase{"dds: {config_file: cyclone.xml}\n",
                     "dds.config_file: must be an absolute path or \"\", got 'cyclone.xml'"},
        BadValueCase{"auth: {tokens_file: \"\"}\n",
                     "auth.tokens_file: must be an absolute path, got nothing"},
        BadValueCase{"plugins: {path: []}\n", "plugins.path: must list at least one directory"},
        BadValueCase{"plugins: {path: [/a, b]}\n",
                     "plugins.path: entry 2 must be an absolute directory without ':', got 'b'"},
        BadValueCase{"plugins: {path: /a}\n", "plugins.path: must be a list"},
        BadValueCase{"plugins: {path: [[/a]]}\n", "plugins.path: entries must be plain values"},
        BadValueCase{"devices: {camera: {driver: my-cam}, turntable: {driver: sim}}\n",
                     "devices.camera.driver: must be a driver name"},
        BadValueCase{
            "devices: {camera: {driver: sim}, turntable: {driver: \"\"}}\n",
            "devices.turntable.driver: must be a driver name of 1 to 64 characters of A-Z, "
            "a-z, 0-9, _, got nothing"},
        BadValueCase{"devices: {camera: {driver: sim, config: [a]}, turntable: {driver: sim}}\n",
                     "devices.camera.config: must be a mapping of driver settings"},
        BadValueCase{
            "devices: {camera: {driver: sim, config: {object: [egg]}}, turntable: {driver: sim}}\n",
            "devices.camera.config.object: must be a single value"},
        BadValueCase{"devices: {camera: {driver: sim}}\n", "devices.turntable: missing"},
        BadValueCase{"devices: {camera: {config: {}}, turntable: {driver: sim}}\n",
                     "devices.camera.driver: missing"},
        BadValueCase{"devices:\n", "devices.camera: missing"},
        BadValueCase{"calibration: {board: {type: circles}}\n",
                     "calibration.board.type: must be one of chessboard, charuco; got 'circles'"},
        BadValueCase{"calibration: {board: {cols: 101}}\n",
                     "calibration.board.cols: must be an integer in 2..100, got '101'"},
        BadValueCase{"calibration: {board: {rows: six}}\n",
                     "calibration.board.rows: must be an integer in 2..100, got 'six'"},
        BadValueCase{"calibration: {board: {square_mm: 0}}\n",
                     "calibration.board.square_mm: must be a number in (0, 1000], got '0'"},
        BadValueCase{"calibration: {board: {marker_mm: -1}}\n",
                     "calibration.board.marker_mm: must be a number in [0, 1000], got '-1'"},
        BadValueCase{"calibration: {board: {dictionary: DICT_9X9_50}}\n",
                     "calibration.board.dictionary: must be an ArUco dictionary name"},
        BadValueCase{
            "calibration: {board: {dictionary: 21}}\n",
            "calibration.board.dictionary: must be an ArUco dictionary name (DICT_4X4_50 … "
            "DICT_APRILTAG_36h11) or its number 0..20, got '21'"},
        BadValueCase{"calibration: {board: {cols: 2}}\n",
                     "calibration.board: a chessboard needs at least 3x3 inner corners"},
        BadValueCase{"calibration: {board: {type: charuco, cols: 5, rows: 5, marker_mm: 0}}\n",
                     "calibration.board: ChArUco marker_mm must be > 0 and < square_mm"},
        BadValueCase{"calibration: {board: {type: charuco, cols: 20, rows: 20, square_mm: 10, "
                     "marker_mm: 7, dictionary: DICT_4X4_50}}\n",
                     "calibration.board: 20x20 ChArUco squares need 200 markers"},
        BadValueCase{"calibration: {views: 2}\n",
                     "calibration.views: must be an integer in 3..1000, got '2'"},
        BadValueCase{"calibration: {max_rms_px: 0}\n",
                     "calibration.max_rms_px: must be a number in (0, 10], got '0'"},
        BadValueCase{"calibration: {max_rms_px: nan}\n",
                     "calibration.max_rms_px: must be a number in (0, 10], got 'nan'"},
        BadValueCase{"scan: {views: abc}\n", "scan.views: must be an integer in 2..360, got 'abc'"},
        BadValueCase{"scan: {views: 1}\n", "scan.views: must be an integer in 2..360, got '1'"},
        BadValueCase{"scan: {views: 12}\n",
                     "scan.step_deg: 12 views × 60° = 720° is more than a full turn"},
        BadValueCase{"scan: {step_deg: 0}\n",
                     "scan.step_deg: must be a number in (0, 360], got '0'"},
        BadValueCase{"scan: {step_deg: 60deg}\n",
                     "scan.step_deg: must be a number in (0, 360], got '60deg'"},
        BadValueCase{"scan: {settle_ms: 60001}\n",
                     "scan.settle_ms: must be an integer in 0..60000, got '60001'"},
        BadValueCase{"scan: {exposure_us: 0}\n",
                     "scan.exposure_us: must be a number in (0, 10000000], got '0'"},
        BadValueCase{"scan: {gain_db: -3}\n",
                     "scan.gain_db: must be a number in [0, 48], got '-3'"},
        BadValueCase{
            "scan: {exposure_bracket: [8, 4]}\n",
            "scan.exposure_bracket: entry 2 must be a multiple of the exposure in (1, 64], "
            "larger than the one before, got '4'"},
        BadValueCase{
            "scan: {exposure_bracket: [1]}\n",
            "scan.exposure_bracket: entry 1 must be a multiple of the exposure in (1, 64], "
            "larger than the one before, got '1'"},
        BadValueCase{"scan: {exposure_bracket: [2, bright]}\n",
                     "scan.exposure_bracket: entry 2 must be a number, got 'bright'"},
        BadValueCase{"scan: {exposure_bracket: [2, 3, 4, 5, 6]}\n",
                     "scan.exposure_bracket: must list at most 4 multiples, got 5"},
        BadValueCase{"scan: {exposure_bracket: 8}\n", "scan.exposure_bracket: must be a list"},
        BadValueCase{"scan: {exposure_us: 1000000, exposure_bracket: [16]}\n",
                     "scan.exposure_bracket: exposure_us × 16 = 16000000 µs is more than 10000000"},
        BadValueCase{"scan: {exposure_us: 2000000}\n",
                     "scan.auto_bracket: a dark view is also exposed × 8, and exposure_us × 8 = "
                     "16000000 µs is more than 10000000: set auto_bracket: false or a shorter "
                     "exposure"},
        BadValueCase{"scan: {auto_bracket: maybe}\n", "scan.auto_bracket"},
        BadValueCase{"pipeline: {threads: 0}\n",
                     "pipeline.threads: must be an integer in 1..256, got '0'"},
        BadValueCase{"pipeline: {min_disparity: 5000}\n",
                     "pipeline.min_disparity: must be an integer in -4096..4096, got '5000'"},
        BadValueCase{"pipeline: {num_disparities: 0x40}\n",
                     "pipeline.num_disparities: must be an integer in 0..4096, got '0x40'"},
        BadValueCase{"pipeline: {aggregation_iterations: 17}\n",
                     "pipeline.aggregation_iterations: must be an integer in 0..16, got '17'"},
        BadValueCase{"pipeline: {speckle_max_area_pct: 2}\n",
                     "pipeline.speckle_max_area_pct: must be a number in [0, 1], got '2'"},
        BadValueCase{"pipeline: {speckle_range_px: 0}\n",
                     "pipeline.speckle_range_px: must be a number in (0, 64], got '0'"},
        BadValueCase{"pipeline: {min_texture_std: 256}\n",
                     "pipeline.min_texture_std: must be a number in [0, 255], got '256'"},
        BadValueCase{"pipeline: {volume_radius_mm: 0}\n",
                     "pipeline.volume_radius_mm: must be a number in (0, 10000], got '0'"},
        BadValueCase{
            "pipeline: {volume_min_height_mm: -2000}\n",
            "pipeline.volume_min_height_mm: must be a number in [-1000, 10000], got '-2000'"},
        BadValueCase{"pipeline: {volume_max_height_mm: 0.2}\n",
                     "pipeline.volume_max_height_mm: must be above volume_min_height_mm (0.5)"},
        BadValueCase{"pipeline: {platter_normal_deg: 91}\n",
                     "pipeline.platter_normal_deg: must be a number in [0, 90], got '91'"},
        BadValueCase{"pipeline: {mesh: maybe}\n",
                     "pipeline.mesh: must be true or false, got 'maybe'"},
        BadValueCase{"pipeline: {mesh_method: marching}\n",
                     "pipeline.mesh_method: must be one of poisson, implicit; got 'marching'"},
        BadValueCase{"limits: {max_command_bytes: 100}\n",
                     "limits.max_command_bytes: must be an integer in 1024..16777216, got '100'"},
        BadValueCase{"limits: {queue_capacity: 17}\n",
                     "limits.queue_capacity: must be an integer in 1..16, got '17'"},
        BadValueCase{"watchdog: {enabled: 2}\n",
                     "watchdog.enabled: must be true or false, got '2'"},
        BadValueCase{"deliverables: {rights: \"a\\tb\"}\n",
                     "deliverables.rights: must be UTF-8 text without control characters, at "
                     "most 1024 bytes"},
        BadValueCase{"deliverables: {rights: \"\\x85\"}\n",  // C1 control NEL
                     "deliverables.rights: must be UTF-8 text without control characters"},
        BadValueCase{"deliverables: {rights: " + std::string(1025, 'x') + "}\n",
                     "deliverables.rights: must be UTF-8 text without control characters"},
        BadValueCase{"scan: {views: [6]}\n", "scan.views: must be a single value, not a list"},
        BadValueCase{"scan: {views: {n: 6}}\n",
                     "scan.views: must be a single value, not a mapping"},
        BadValueCase{"scan: {views: }\n", "scan.views: must be an integer in 2..360, got nothing"},
        BadValueCase{"scan: 6\n", "scan: must be a mapping of keys"},
        BadValueCase{"scan: {views: 6, views: 8}\n", "scan.views: given more than once"}));

TEST(DaemonConfig, ErrorGivesTheLine) {
  DaemonConfig config;
  std::string error;
  EXPECT_FALSE(Parse("version: 1\nstation: s\n\nscan:\n  views: abc\n", &config, &error));
  EXPECT_EQ(error, "scan.views: must be an integer in 2..360, got 'abc' (line 5)");
}

TEST(DaemonConfig, UnknownKeysAreRefusedWithTheirPath) {
  DaemonConfig config;
  std::string error;
  EXPECT_FALSE(Parse("version: 1\ndds:\n  domian: 3\n", &config, &error));
  EXPECT_EQ(error, "dds.domian: unknown key (did you mean 'dds.domain'?) (line 3)");

  EXPECT_FALSE(Parse("version: 1\nviews: 6\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("views: unknown key (did you mean 'calibration.views' or "
                               "'scan.views'?)"));

  EXPECT_FALSE(Parse("version: 1\ncalibration: {board: {colour: red}}\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("calibration.board.colour: unknown key"));

  EXPECT_FALSE(Parse("version: 1\nfrobnicate: true\n", &config, &error));
  EXPECT_EQ(error, "frobnicate: unknown key (line 2)");

  EXPECT_FALSE(
      Parse("version: 1\ndevices: {camera: {driver: sim, settings: {}}, "
            "turntable: {driver: sim}}\n",
            &config, &error));
  EXPECT_THAT(error, HasSubstr("devices.camera.settings: unknown key"));
}

TEST(DaemonConfig, VersionIsRequiredAndChecked) {
  DaemonConfig config;
  std::string error;
  EXPECT_FALSE(Parse("station: s\n", &config, &error));
  EXPECT_EQ(error, "version: missing; add 'version: 1' (this craftscand reads config version 1)");
  EXPECT_FALSE(Parse("version: 2\nstation: s\n", &config, &error));
  EXPECT_EQ(error, "version: 2 is not supported; this craftscand reads config version 1 (line 1)");
  EXPECT_FALSE(Parse("version: one\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("version: must be an integer (this craftscand reads config "
                               "version 1), got 'one'"));
}

TEST(DaemonConfig, MalformedDocumentsAreRefused) {
  DaemonConfig config;
  std::string error;
  EXPECT_FALSE(Parse("", &config, &error));
  EXPECT_THAT(error, HasSubstr("empty configuration"));
  EXPECT_FALSE(Parse("- version: 1\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("must be a mapping"));
  EXPECT_FALSE(Parse("version: 1\nscan: {views: 6\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("YAML syntax error at line"));
  EXPECT_FALSE(Parse("version: 1\n---\nversion: 1\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("one YAML document, found 2"));
  EXPECT_FALSE(Parse("version: 1\n? [a, b]\n: 3\n", &config, &error));
  EXPECT_THAT(error, HasSubstr("keys must be plain names"));
}

TEST(DaemonConfig, EnvironmentOverridesScalars) {
  const std::map<std::string, std::string> env = {
      {"CRAFTSCAN_STATION", "envstation"},
      {"CRAFTSCAN_DATA_DIR", "/data"},
      {"CRAFTSCAN_DDS_DOMAIN", "42"},
      {"CRAFTSCAN_LOG_LEVEL", "warning"},
      {"CRAFTSCAN_SCAN_VIEWS", "4"},
      {"CRAFTSCAN_SCAN_STEP_DEG", "90"},
      {"CRAFTSCAN_PLUGINS_PATH", "/x:/y::"},
      {"CRAFTSCAN_SCAN_EXPOSURE_BRACKET", "2:8"},
      {"CRAFTSCAN_CALIBRATION_BOARD_SQUARE_MM", "12.5"},
      {"CRAFTSCAN_WATCHDOG_ENABLED", "false"},
      {"CRAFTSCAN_TOKEN", "not a config variable: ignored"},
      {"PATH", "/usr/bin"},
  };
  DaemonConfig c;
  std::string error;
  ASSERT_TRUE(Parse("version: 1\nstation: filestation\nscan: {views: 6}\n", &c, &error, env))
      << error;
  EXPECT_EQ(c.station, "envstation");
  EXPECT_EQ(c.data_dir, "/data");
  EXPECT_EQ(c.dds.domain, 42);
  EXPECT_EQ(c.log_level, LogLevel::kWarning);
  EXPECT_EQ(c.scan.views, 4);
  EXPECT_DOUBLE_EQ(c.scan.step_deg, 90);
  EXPECT_EQ(c.plugins.path, (std::vector<std::string>{"/x", "/y"}));
  EXPECT_EQ(c.scan.exposure_bracket, (std::vector<double>{2, 8}));
  EXPECT_DOUBLE_EQ(c.calibration.board.square_mm, 12.5);
  EXPECT_FALSE(c.watchdog.enabled);
}

TEST(DaemonConfig, BadOverrideNamesTheVariable) {
  DaemonConfig c;
  std::string error;
  EXPECT_FALSE(Parse("version: 1\n", &c, &error, {{"CRAFTSCAN_SCAN_VIEWS", "abc"}}));
  EXPECT_EQ(error, "CRAFTSCAN_SCAN_VIEWS: scan.views: must be an integer in 2..360, got 'abc'");
  EXPECT_FALSE(Parse("version: 1\n", &c, &error, {{"CRAFTSCAN_DDS_DOMAIN", " 3"}}));
  EXPECT_THAT(error, HasSubstr("CRAFTSCAN_DDS_DOMAIN: dds.domain: must be an integer"));
  EXPECT_FALSE(Parse("version: 1\n", &c, &error, {{"CRAFTSCAN_PLUGINS_PATH", "lib"}}));
  EXPECT_THAT(error, HasSubstr("CRAFTSCAN_PLUGINS_PATH: plugins.path: entry 1"));
  // An override that breaks a cross-field rule is reported too.
  EXPECT_FALSE(Parse("version: 1\n", &c, &error, {{"CRAFTSCAN_SCAN_VIEWS", "7"}}));
  EXPECT_THAT(error, HasSubstr("scan.step_deg: 7 views × 60° = 420°"));
}

TEST(DaemonConfig, EnvironmentVariableNamesAreUniqueAndDocumented) {
  const std::vector<std::string> names = ConfigEnvironmentVariables();
  const std::set<std::string> unique(names.begin(), names.end());
  EXPECT_EQ(unique.size(), names.size());
  for (const char* name :
       {"CRAFTSCAN_STATION", "CRAFTSCAN_DATA_DIR", "CRAFTSCAN_DDS_DOMAIN", "CRAFTSCAN_LOG_LEVEL",
        "CRAFTSCAN_SCAN_VIEWS", "CRAFTSCAN_DDS_CONFIG_FILE", "CRAFTSCAN_AUTH_TOKENS_FILE",
        "CRAFTSCAN_PLUGINS_PATH", "CRAFTSCAN_DEVICES_CAMERA_DRIVER", "CRAFTSCAN_WATCHDOG_ENABLED",
        "CRAFTSCAN_DELIVERABLES_RIGHTS"}) {
    EXPECT_TRUE(unique.count(name)) << name;
  }
}

TEST(DaemonConfig, IsValidNamesTheFieldOfAStructBuiltInCode) {
  std::string why;
  DaemonConfig c;
  c.limits.queue_capacity = 0;
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_EQ(why, "limits.queue_capacity: must be an integer in 1..16, got '0'");
  c = DaemonConfig{};
  c.plugins.path = {"/ok", "a:b"};
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_THAT(why, HasSubstr("plugins.path: entry 2"));
  c = DaemonConfig{};
  c.log_level = static_cast<LogLevel>(9);
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_THAT(why, HasSubstr("log_level: must be one of"));
  c = DaemonConfig{};
  c.pipeline.num_disparities = 64;
  c.pipeline.min_disparity = -10;
  EXPECT_TRUE(c.IsValid(&why)) << why;
  EXPECT_TRUE(c.IsValid(nullptr));
}

class DaemonConfigFile : public testing::TempDirTest {};

TEST_F(DaemonConfigFile, LoadPrefixesThePathAndReadsTheEnvironment) {
  const std::string path = WriteBytes("craftscand.yaml", "version: 1\nscan: {views: 3}\n");
  DaemonConfig c;
  std::string error;
  {
    testing::ScopedEnv env("CRAFTSCAN_SCAN_SETTLE_MS", "750");
    ASSERT_TRUE(LoadDaemonConfig(path, &c, &error)) << error;
  }
  EXPECT_EQ(c.scan.views, 3);
  EXPECT_EQ(c.scan.settle_ms, 750);

  const std::string bad = WriteBytes("bad.yaml", "version: 1\nscan: {views: 999}\n");
  EXPECT_FALSE(LoadDaemonConfig(bad, &c, &error));
  EXPECT_EQ(error, bad + ": scan.views: must be an integer in 2..360, got '999' (line 2)");

  EXPECT_FALSE(LoadDaemonConfig(Path("absent.yaml"), &c, &error));
  EXPECT_THAT(error, HasSubstr("absent.yaml: cannot open"));
  EXPECT_FALSE(LoadDaemonConfig(dir_.string(), &c, &error));
  EXPECT_EQ(error, dir_.string() + ": is a directory");
}

TEST(DaemonConfig, ShippedExampleValidates) {
  const std::string path = std::string(::craftscan::testing::SystemdDir()) + "/craftscand.yaml";
  DaemonConfig c;
  std::string error;
  // Not LoadDaemonConfig: CRAFTSCAN_* variables of the test environment must
  // not change the outcome.
  std::ifstream in(path);
  ASSERT_TRUE(in) << path;
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_TRUE(ParseDaemonConfig(text, {}, &c, &error)) << path << ": " << error;
  // The example runs the simulated station with one shared sim instance.
  EXPECT_EQ(c.devices.camera.driver, "sim");
  EXPECT_TRUE(c.devices.camera.SharesInstanceWith(c.devices.turntable));
  EXPECT_EQ(c.auth.tokens_file, "/etc/craftscan/tokens.yaml");
  EXPECT_EQ(c.data_dir, "/var/lib/craftscan");  // the unit's StateDirectory
}

}  // namespace
}  // namespace craftscan::daemon
