// craftscanctl end to end: the real binary against the real craftscand on
// the simulated station (640x512 images), over loopback DDS on a private
// domain. Each test reuses one daemon for several subcommands.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "../../daemon/sessions/status_util.h"
#include "bagit_check.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "ctl_runner.h"
#include "daemon_fixture.h"
#include "file_util.h"
#include "process_util.h"
#include "test_paths.h"
#include "wait_util.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;

// A daemon on the sim station and the arguments that reach it.
class Station {
 public:
  // `pipeline_extra`: see DaemonFixture::pipeline_extra; `extra_sim`: more
  // sim driver keys (", object: egg").
  explicit Station(std::string pipeline_extra = "", std::string extra_sim = "",
                   std::string image_size = "640x512")
      : fixture_(std::move(image_size), std::move(extra_sim)) {
    fixture_.pipeline_extra = std::move(pipeline_extra);
  }
  // Writes the configuration; Start may follow later.
  bool Prepare(std::string* error) { return fixture_.Prepare(error); }
  bool Launch(std::string* error) { return fixture_.Start(error); }
  bool Start(std::string* error) {
    if (!fixture_.Prepare(error) || !fixture_.Start(error)) return false;
    return true;
  }
  DaemonFixture& fixture() { return fixture_; }
  const std::string& dir() const { return fixture_.root(); }

  // --station, --domain, --dds-config, --timeout and --token before `args`.
  std::vector<std::string> Args(const std::string& token, std::vector<std::string> args,
                                const std::string& timeout = "20") const {
    std::vector<std::string> all = {
        "--station",    fixture_.station(),    "--domain",  std::to_string(fixture_.domain()),
        "--dds-config", fixture_.dds_config(), "--timeout", timeout};
    if (!token.empty()) {
      all.push_back("--token");
      all.push_back(token);
    }
    all.insert(all.end(), args.begin(), args.end());
    return all;
  }

  CtlRun Run(const std::string& token, const std::vector<std::string>& args,
             std::chrono::seconds limit = 120s) {
    CtlProcess process(dir(), "run" + std::to_string(++runs_), Args(token, args));
    return process.Wait(limit);
  }

 private:
  DaemonFixture fixture_;
  int runs_ = 0;
};

std::string Describe(const CtlRun& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

json ParseJson(const CtlRun& r) {
  json value = json::parse(r.out, nullptr, false);
  return value.is_discarded() ? json() : value;
}

// The independent checks of a bag (bagit_check.h): sha256sum -c on both
// manifests from inside the bag, and RFC 8493's structure rules.
void ExpectVerifiableBag(const std::string& bag, const std::string& organization,
                         const std::string& session) {
  std::string out;
  EXPECT_EQ(RunSha256sumCheck(bag, "manifest-sha256.txt", &out), 0) << out;
  EXPECT_EQ(RunSha256sumCheck(bag, "tagmanifest-sha256.txt", &out), 0) << out;
  EXPECT_EQ(BagStructureProblems(bag, organization, session), std::vector<std::string>{});
  // Nothing but the bag in its folder (no staging folder left beside it).
  for (const auto& entry :
       std::filesystem::directory_iterator(std::filesystem::path(bag).parent_path())) {
    EXPECT_NE(entry.path().filename().string().front(), '.') << "left: " << entry.path();
  }
}

// One payload byte flipped (size unchanged): sha256sum -c fails, naming it.
void ExpectFlippedByteFails(const std::string& bag, const std::string& payload) {
  std::fstream f(bag + "/" + payload, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(0);
  const char c = static_cast<char>(f.get());
  f.seekp(0);
  f.put(static_cast<char>(c ^ 0x01));
  f.close();
  std::string out;
  EXPECT_EQ(RunSha256sumCheck(bag, "manifest-sha256.txt", &out), 1) << out;
  EXPECT_NE(out.find(payload + ": FAILED"), std::string::npos) << out;
  EXPECT_EQ(RunSha256sumCheck(bag, "tagmanifest-sha256.txt", &out), 0)
      << "the tag files are untouched: " << out;
}

TEST(Craftscanctl, StatusDevicesCaptureTurntableCameraAndRefusals) {
  Station station;
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;

  // status waits for discovery (within --timeout) and reports the station.
  CtlRun r = station.Run(kObserverToken, {"status", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  json status = ParseJson(r);
  EXPECT_EQ(status.value("station", ""), station.fixture().station()) << r.out;
  r = station.Run(kObserverToken, {"status"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NE(r.out.find("calibration"), std::string::npos) << r.out;

  r = station.Run(kObserverToken, {"devices", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  const json devices = ParseJson(r).value("devices", json::array());
  std::set<std::string> names;
  for (const json& d : devices) names.insert(d.value("name", ""));
  EXPECT_EQ(names, (std::set<std::string>{"camera", "turntable"})) << r.out;
  r = station.Run(kObserverToken, {"devices"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NE(r.out.find("turntable"), std::string::npos) << r.out;

  r = station.Run(kObserverToken, {"sessions"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NE(r.out.find("no sessions"), std::string::npos) << r.out;

  // Refused by the daemon: 3, with its reason.
  r = station.Run(kObserverToken, {"scan", "--object", "box", "--views", "4", "--step", "90"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("forbidden"), std::string::npos) << r.err;
  r = station.Run("wrong-token-0123456789", {"status"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("unauthenticated"), std::string::npos) << r.err;
  r = station.Run(kOperatorToken, {"calibrate"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  r = station.Run(kOperatorToken, {"resume", "20260101-000000-nothing"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("not_found"), std::string::npos) << r.err;
  r = station.Run(kOperatorToken, {"cancel"});  // nothing runs
  EXPECT_EQ(r.exit_code, 3) << Describe(r);

  // Bad arguments, caught before the daemon is asked: 2.
  const std::vector<std::vector<std::string>> usage_errors = {
      {"scan", "--views", "4"},                       // --object missing
      {"scan", "--object", "box", "--views", "1"},    // out of range
      {"scan", "--object", "box", "--views", "six"},  // not a number
      {"turntable", "spin"},
      {"turntable", "move"},
      {"camera", "set", "shutter=5"},
      {"camera", "set", "exposure=-3"},
      {"get", "20260101-000000-x"},  // --out missing
      {"get", "20260101-000000-x", "--out", station.dir() + "/o", "--file", "../etc/passwd"},
      {"frobnicate"},
      {},
  };
  for (const auto& args : usage_errors) {
    r = station.Run(kOperatorToken, args);
    std::string joined;
    for (const std::string& a : args) joined += a + " ";
    EXPECT_EQ(r.exit_code, 2) << joined << "\n" << Describe(r);
    EXPECT_FALSE(r.err.empty()) << joined;
  }
  {
    CtlProcess no_token(station.dir(), "no-token", station.Args("", {"status"}));
    r = no_token.Wait(60s);
    EXPECT_EQ(r.exit_code, 2) << Describe(r);
    EXPECT_NE(r.err.find("CRAFTSCAN_TOKEN"), std::string::npos) << r.err;
  }
  // The token from the environment and from a file.
  {
    CtlProcess env_token(station.dir(), "env-token", station.Args("", {"sessions", "--json"}),
                         {std::string("CRAFTSCAN_TOKEN=") + kObserverToken});
    r = env_token.Wait(60s);
    EXPECT_EQ(r.exit_code, 0) << Describe(r);
    std::ofstream(station.dir() + "/token.txt") << kObserverToken << "\n";
    r = station.Run("", {"--token-file", station.dir() + "/token.txt", "status"});
    EXPECT_EQ(r.exit_code, 0) << Describe(r);
  }

  // Turntable and camera.
  r = station.Run(kOperatorToken, {"turntable", "home"});
  EXPECT_EQ(r.exit_code, 0) << Describe(r);
  r = station.Run(kOperatorToken, {"turntable", "move", "90", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NEAR(ParseJson(r)["result"].value("angle_deg", -1.0), 90.0, 0.01) << r.out;
  r = station.Run(kOperatorToken, {"turntable", "move", "-45"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NE(r.out.find("-45.00"), std::string::npos) << r.out;
  r = station.Run(kOperatorToken, {"camera", "set", "exposure=5000", "gain=2", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_DOUBLE_EQ(ParseJson(r)["result"].value("exposure_us", 0.0), 5000.0) << r.out;
  EXPECT_DOUBLE_EQ(ParseJson(r)["result"].value("gain_db", -1.0), 2.0) << r.out;

  // capture waits for the job, printing plain progress lines when piped,
  // while `watch` follows status and progress until Ctrl-C.
  CtlProcess watch(station.dir(), "watch",
                   station.Args(kObserverToken, {"watch", "--json", "--duration", "300"}));
  // Subscribed once it printed the current status.
  for (int i = 0; i < 300 && watch.Output().empty() && watch.Running(); ++i) {
    std::this_thread::sleep_for(100ms);
  }
  ASSERT_FALSE(watch.Output().empty()) << "watch printed no status";
  r = station.Run(kOperatorToken, {"capture", "--object", "egg"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  EXPECT_NE(r.out.find("capture started as job-"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("capture "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" done: "), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("\x1b["), std::string::npos) << "no terminal codes when piped";
  // watch saw the job end (its status line), then stops on SIGINT with 0.
  bool saw_end = false;
  for (int i = 0; i < 300 && !saw_end && watch.Running(); ++i) {
    saw_end = watch.Output().find("\"state\":\"done\"") != std::string::npos;
    if (!saw_end) std::this_thread::sleep_for(100ms);
  }
  watch.Signal(SIGINT);
  const CtlRun watched = watch.Wait(30s);
  EXPECT_EQ(watched.exit_code, 0) << Describe(watched);
  EXPECT_TRUE(saw_end) << watched.out;
  std::size_t start = 0;
  int progress_lines = 0;
  while (start < watched.out.size()) {
    const std::size_t end = watched.out.find('\n', start);
    const json line = json::parse(watched.out.substr(start, end - start), nullptr, false);
    ASSERT_FALSE(line.is_discarded()) << watched.out.substr(start, end - start);
    EXPECT_TRUE(line.value("type", "") == "status" || line.value("type", "") == "progress") << line;
    if (line.value("type", "") == "progress") ++progress_lines;
    start = end == std::string::npos ? watched.out.size() : end + 1;
  }
  EXPECT_GE(progress_lines, 1) << watched.out;

  r = station.Run(kObserverToken, {"sessions", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  const json sessions = ParseJson(r).value("sessions", json::array());
  ASSERT_EQ(sessions.size(), 1u) << r.out;
  EXPECT_EQ(sessions[0].value("state", ""), "done");
  EXPECT_EQ(sessions[0].value("job", ""), "capture");
  // A capture has no outputs to fetch.
  r = station.Run(kObserverToken,
                  {"get", sessions[0].value("id", ""), "--out", station.dir() + "/o"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("no outputs"), std::string::npos) << r.err;

  // --no-wait returns at once with the started job.
  r = station.Run(kOperatorToken, {"capture", "--no-wait", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_EQ(ParseJson(r).value("verb", ""), "capture") << r.out;
  EXPECT_FALSE(ParseJson(r).value("id", "").empty()) << r.out;
}

TEST(Craftscanctl, ScanThenGetEveryOutputByteForByte) {
  Station station;
  std::string error;
  // The station's rights statement (config key deliverables.rights, here
  // through its environment override) goes into every mesh.glb.
  const std::string rights = "© 2026 Test Museum, CC BY 4.0";
  ::setenv("CRAFTSCAN_DELIVERABLES_RIGHTS", rights.c_str(), 1);
  const bool started = station.Start(&error);
  ::unsetenv("CRAFTSCAN_DELIVERABLES_RIGHTS");
  ASSERT_TRUE(started) << error;
  // craftscan-record keeps each finished scan's model (--what models).
  const std::string recorded = station.dir() + "/recorded";
  ::craftscan::testing::ChildProcess recorder;
  {
    ::craftscan::testing::SpawnOptions options;
    options.stdout_path = station.dir() + "/record.out";
    options.stderr_path = station.dir() + "/record.err";
    ASSERT_TRUE(::craftscan::testing::Spawn(
        {::craftscan::testing::RecordPath(), "--station", station.fixture().station(), "--domain",
         std::to_string(station.fixture().domain()), "--dds-config", station.fixture().dds_config(),
         "--out", recorded, "--what", "models", "--token", kObserverToken},
        options, &recorder));
  }

  // A full turn in 4 views closes the loop.
  CtlRun r = station.Run(
      kOperatorToken, {"scan", "--object", "carved box", "--views", "4", "--step", "90", "--json"},
      300s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  const json job = ParseJson(r);
  EXPECT_EQ(job.value("state", ""), "done") << r.out;
  const std::string session = job.value("session", "");
  ASSERT_FALSE(session.empty()) << r.out;
  std::printf("4-view 640x512 scan through craftscanctl: %.1f s\n", r.seconds);

  // get: every durable output, byte for byte.
  auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  auto opened = store->OpenSession(session, StatusInto(&error));
  ASSERT_TRUE(opened) << error;
  const daemon::Manifest manifest = opened->manifest();
  opened.reset();
  ASSERT_TRUE(manifest.outputs.count("fused.ply"));
  ASSERT_TRUE(manifest.outputs.count("mesh.glb"));  // fetched below with the rest
  const std::string out = station.dir() + "/fetched";
  r = station.Run(kObserverToken, {"get", session, "--out", out});
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  EXPECT_NE(r.out.find("checksums verified"), std::string::npos) << r.out;
  const std::string session_dir = station.fixture().data_dir() + "/sessions/" + session;
  std::uint64_t bytes = 0;
  for (const auto& [name, record] : manifest.outputs) {
    const std::string fetched = ReadFile(out + "/" + name);
    EXPECT_EQ(fetched.size(), record.size_bytes) << name;
    EXPECT_TRUE(fetched == ReadFile(session_dir + "/" + name)) << name << " differs";
    bytes += fetched.size();
  }
  std::size_t entries = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(out)) {
    if (entry.is_regular_file()) ++entries;
    EXPECT_NE(entry.path().filename().string().front(), '.') << "temporary left: " << entry.path();
  }
  EXPECT_EQ(entries, manifest.outputs.size());
  std::printf("get: %zu files, %llu bytes in %.2f s\n", manifest.outputs.size(),
              static_cast<unsigned long long>(bytes), r.seconds);
  // The fetched mesh.glb says who made it, of what (glb.h; its JSON chunk
  // follows the 12-byte header and the chunk's 8-byte header).
  const std::string glb = ReadFile(out + "/mesh.glb");
  ASSERT_GT(glb.size(), 20u);
  std::uint32_t json_length = 0;
  std::memcpy(&json_length, glb.data() + 12, 4);
  ASSERT_LE(20u + json_length, glb.size());
  const json gltf = json::parse(glb.substr(20, json_length), nullptr, false);
  ASSERT_TRUE(gltf.is_object());
  EXPECT_EQ(gltf["asset"].value("copyright", ""), rights);
  const json provenance = gltf["asset"]["extras"]["craftscan"];
  EXPECT_EQ(provenance.value("rights", ""), rights);
  EXPECT_FALSE(provenance.value("client", "").empty()) << provenance.dump();
  EXPECT_FALSE(provenance.value("captured_utc", "").empty()) << provenance.dump();
  // (The sim's exact calibration has no RMS: none is recorded; test_report_glb
  // checks the figures.)
  EXPECT_FALSE(provenance["calibration"].contains("rms_stereo_px")) << provenance.dump();
  EXPECT_EQ(provenance.value("object_name", ""), "carved box");
  EXPECT_EQ(provenance.value("session_id", ""), session);
  EXPECT_EQ(provenance.value("station", ""), station.fixture().station());
  EXPECT_EQ(provenance.value("source_frame", ""), "turntable");
  EXPECT_EQ(provenance.value("software", "").rfind("craftscan ", 0), 0u) << provenance.dump();
  EXPECT_EQ(provenance["calibration"].value("id", ""), manifest.calibration_id);
  // The recorder's copy of the model is the session's, byte for byte.
  const std::string recorded_glb =
      recorded + "/" + station.fixture().station() + "/" + session + "/mesh.glb";
  EXPECT_TRUE(::craftscan::testing::WaitFor([&] { return std::filesystem::exists(recorded_glb); },
                                            30s, 100ms))
      << ReadFile(station.dir() + "/record.err");
  recorder.Signal(SIGTERM);
  EXPECT_EQ(recorder.Wait(20s), 0) << ReadFile(station.dir() + "/record.err");
  EXPECT_TRUE(ReadFile(recorded_glb) == glb) << "recorded mesh.glb differs";
  EXPECT_NE(ReadFile(recorded + "/" + station.fixture().station() + "/" + session + "/index.jsonl")
                .find("\"kind\":\"model\""),
            std::string::npos);
  // The fetched outputs through independent readers (tests/deliverables):
  // the Khronos glTF-Validator (0 errors, 0 warnings) and Open3D (counts
  // and bounds as report.json says).
  const std::string checks = std::string(::craftscan::testing::SourceDir()) + "/tests/deliverables";
  ::setenv("NODE_PATH",
           (std::string(::craftscan::testing::SourceDir()) + "/clients/web/node_modules").c_str(),
           1);
  for (const std::vector<std::string>& argv :
       {std::vector<std::string>{"/usr/bin/node", checks + "/validate_glb.mjs", out},
        std::vector<std::string>{"/usr/bin/python3", checks + "/third_party_readers.py", out}}) {
    if (!std::filesystem::exists(argv[0])) {
      std::printf("%s skipped: no %s\n", argv[1].c_str(), argv[0].c_str());
      continue;
    }
    const std::string log = station.dir() + "/check.log";
    ::craftscan::testing::ChildProcess child;
    ::craftscan::testing::SpawnOptions options;
    options.stdout_path = log;
    options.stderr_to_stdout = true;
    ASSERT_TRUE(::craftscan::testing::Spawn(argv, options, &child)) << argv[0];
    const int code = child.Wait(60s);
    std::printf("%s", ReadFile(log).c_str());
    if (code == 77) continue;  // its reader is not installed: said in the log
    EXPECT_EQ(code, 0) << argv[1] << ":\n" << ReadFile(log);
  }

  // One file in small chunks (many chunks, several acknowledgement windows).
  const std::string one = station.dir() + "/one";
  r = station.Run(kObserverToken, {"get", session, "--out", one, "--file", "fused.ply",
                                   "--chunk-kib", "16", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_TRUE(ReadFile(one + "/fused.ply") == ReadFile(session_dir + "/fused.ply"));
  const json listed = ParseJson(r);
  ASSERT_EQ(listed.value("files", json::array()).size(), 1u) << r.out;
  EXPECT_EQ(listed["files"][0].value("fnv1a64", ""), [&] {
    char hex[17];
    std::snprintf(hex, sizeof hex, "%016llx",
                  static_cast<unsigned long long>(manifest.outputs.at("fused.ply").fnv1a64));
    return std::string(hex);
  }());
  r = station.Run(kObserverToken, {"get", session, "--out", one, "--file", "nothing.ply"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("fused.ply"), std::string::npos) << "names what there is: " << r.err;
  EXPECT_FALSE(std::filesystem::exists(one + "/nothing.ply"));

  // The whole session as a BagIt bag (what an archive keeps: manifest,
  // calibration copy, every view's captures, disparity and cloud, the
  // outputs), checked independently: sha256sum -c on both manifests inside
  // the bag, the RFC 8493 structure rules, every file byte for byte against
  // the session folder, and a flipped byte caught.
  const std::string bag = station.dir() + "/bags/" + session;
  r = station.Run(kObserverToken,
                  {"get", session, "--bagit", bag, "--source-organization", "Craft Museum"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  std::printf("get --bagit in %.2f s: %s", r.seconds, r.out.c_str());
  ExpectVerifiableBag(bag, "Craft Museum", session);
  std::vector<std::string> expected = {"manifest.json"};
  if (manifest.calibration) expected.push_back("calibration.yaml");
  for (const auto& [index, view] : manifest.views) {
    char folder[16];
    std::snprintf(folder, sizeof folder, "views/%03d/", index);
    for (const auto& [name, record] : view.files) expected.push_back(folder + name);
  }
  for (const auto& [name, record] : manifest.outputs) expected.push_back(name);
  EXPECT_TRUE(manifest.calibration.has_value());
  EXPECT_GE(expected.size(), manifest.outputs.size() + 2 + 4 * manifest.views.size());
  for (const std::string& name : expected) {
    EXPECT_TRUE(ReadFile(bag + "/data/" + name) == ReadFile(session_dir + "/" + name)) << name;
  }
  std::size_t payload = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(bag + "/data")) {
    payload += entry.is_regular_file() ? 1 : 0;
  }
  EXPECT_EQ(payload, expected.size());
  ExpectFlippedByteFails(bag, "data/fused.ply");
  ExpectFlippedByteFails(bag, "data/views/000/left.png");
}

TEST(Craftscanctl, CancelOfARunningScanExitsFourAndResumeCompletesIt) {
  Station station(", mesh: false");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  // The waiting craftscanctl exits 4 once the scan is cancelled; the session
  // is interrupted, and resume completes it.
  CtlProcess scan(
      station.dir(), "scan",
      station.Args(kOperatorToken, {"scan", "--object", "egg", "--views", "4", "--step", "90"}));
  // Wait until it runs (the status shows a running scan).
  CtlRun r;
  bool running = false;
  for (int i = 0; i < 200 && !running && scan.Running(); ++i) {
    const CtlRun s = station.Run(kObserverToken, {"status", "--json"});
    const json st = ParseJson(s);
    running = st.contains("job") && st["job"].value("verb", "") == "scan" &&
              st["job"].value("state", "") == "running";
    if (!running) std::this_thread::sleep_for(100ms);
  }
  ASSERT_TRUE(running) << "the scan never ran";
  r = station.Run(kOperatorToken, {"cancel"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  const CtlRun cancelled = scan.Wait(120s);
  EXPECT_EQ(cancelled.exit_code, 4) << Describe(cancelled);
  EXPECT_NE(cancelled.out.find("cancelled"), std::string::npos) << cancelled.out;
  r = station.Run(kObserverToken, {"sessions", "--json"});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  std::string interrupted;
  for (const json& s : ParseJson(r).value("sessions", json::array())) {
    if (s.value("state", "") == "interrupted") interrupted = s.value("id", "");
  }
  ASSERT_FALSE(interrupted.empty()) << r.out;
  r = station.Run(kOperatorToken, {"resume", interrupted}, 300s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  EXPECT_NE(r.out.find("resume done"), std::string::npos) << r.out;
  r = station.Run(kObserverToken, {"sessions", "--json"});
  const json sessions = ParseJson(r).value("sessions", json::array());
  ASSERT_EQ(sessions.size(), 1u) << r.out;
  EXPECT_EQ(sessions[0].value("id", ""), interrupted);
  EXPECT_EQ(sessions[0].value("state", ""), "done") << r.out;
  EXPECT_EQ(sessions[0].value("views_captured", 0), 4) << r.out;
}

// A session made on disk before the daemon starts: a 48 MiB output streams
// intact; a file changed behind the manifest's back is refused.
// Every "sha256" key below `j`, removed: a manifest as craftscand wrote it
// before SHA-256 (FNV-1a 64 only).
void DropSha256(json* j) {
  if (j->is_object()) {
    j->erase("sha256");
    for (auto& [key, value] : j->items()) DropSha256(&value);
  } else if (j->is_array()) {
    for (auto& value : *j) DropSha256(&value);
  }
}

TEST(Craftscanctl, GetBagitMakesVerifiableBagsOfNewAndOldSessionsAndRefusesClearly) {
  Station station;
  std::string error;
  ASSERT_TRUE(station.Prepare(&error)) << error;
  const std::map<std::string, std::string> outputs = {
      {"fused.ply", "ply\nformat binary_little_endian 1.0\n" + std::string(100000, '\x5a')},
      {"report.json", "{\"ok\": true}"},
      {"previews/top.png", std::string(5000, 'x')}};
  std::string ids[2];  // [0]: SHA-256 manifest, [1]: an old FNV-1a-only one
  {
    auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    for (std::string& id : ids) {
      auto session = store->Create(&id == &ids[0] ? "new" : "old", "scan", {{"views", 2}},
                                   std::chrono::system_clock::now(), StatusInto(&error));
      ASSERT_TRUE(session) << error;
      id = session->id();
      ASSERT_TRUE(Ok(session->SetState(daemon::SessionState::kReconstructing, ""), &error));
      for (const auto& [name, bytes] : outputs) {
        ASSERT_TRUE(Ok(session->StoreOutput(name, bytes), &error)) << error;
      }
      ASSERT_TRUE(Ok(session->SetState(daemon::SessionState::kDone, ""), &error)) << error;
    }
  }
  const std::string old_manifest =
      station.fixture().data_dir() + "/sessions/" + ids[1] + "/manifest.json";
  json old = json::parse(ReadFile(old_manifest));
  DropSha256(&old);
  ASSERT_TRUE(WriteFileAtomically(old_manifest, old.dump(2), &error)) << error;
  ASSERT_TRUE(station.Launch(&error)) << error;

  for (const std::string& id : ids) {
    const std::string bag = station.dir() + "/bags/" + id;
    const CtlRun r = station.Run(
        kObserverToken, {"get", id, "--bagit", bag, "--json", "--source-organization", "Museum A"});
    ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
    const json done = ParseJson(r);
    EXPECT_EQ(done.value("bag", ""), bag) << r.out;
    EXPECT_EQ(done.value("payload_files", 0), 4) << r.out;  // the manifest and 3 outputs
    ExpectVerifiableBag(bag, "Museum A", id);
    for (const auto& [name, bytes] : outputs) {
      EXPECT_TRUE(ReadFile(bag + "/data/" + name) == bytes) << id << " " << name;
    }
    EXPECT_TRUE(ReadFile(bag + "/data/manifest.json") ==
                ReadFile(station.fixture().data_dir() + "/sessions/" + id + "/manifest.json"))
        << id;
    ExpectFlippedByteFails(bag, "data/previews/top.png");
  }

  // A target that is not empty: refused before anything is fetched.
  const std::string full = station.dir() + "/full";
  std::filesystem::create_directories(full);
  std::ofstream(full + "/mine.txt") << "keep";
  CtlRun r = station.Run(kObserverToken,
                         {"get", ids[0], "--bagit", full, "--source-organization", "Museum A"});
  EXPECT_EQ(r.exit_code, 1) << Describe(r);
  EXPECT_NE(r.err.find("exists and is not empty"), std::string::npos) << r.err;
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(full),
                          std::filesystem::directory_iterator()),
            1);
  // No Source-Organization: a usage error naming what is missing.
  r = station.Run(kObserverToken, {"get", ids[0], "--bagit", station.dir() + "/bags/none"});
  EXPECT_EQ(r.exit_code, 2) << Describe(r);
  EXPECT_NE(r.err.find("Source-Organization"), std::string::npos) << r.err;
  // A file damaged on the station (same size): the transfer's SHA-256 check
  // refuses it and no bag appears.
  const std::string damaged = station.fixture().data_dir() + "/sessions/" + ids[0] + "/report.json";
  std::ofstream(damaged, std::ios::trunc) << "{\"ok\": null}";
  const std::string refused = station.dir() + "/bags/refused";
  r = station.Run(kObserverToken,
                  {"get", ids[0], "--bagit", refused, "--source-organization", "Museum A"});
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_NE(r.err.find("report.json': SHA-256 checksum"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(refused));
  for (const auto& entry : std::filesystem::directory_iterator(station.dir() + "/bags")) {
    EXPECT_NE(entry.path().filename().string().front(), '.') << "staging left: " << entry.path();
  }
}

TEST(Craftscanctl, GetStreamsALargeOutputAndRefusesChangedFiles) {
  Station station;
  std::string error;
  ASSERT_TRUE(station.Prepare(&error)) << error;
  std::string big(48u << 20, '\0');
  std::mt19937_64 random(7);
  for (std::size_t i = 0; i + 8 <= big.size(); i += 8) {
    const std::uint64_t v = random();
    std::memcpy(&big[i], &v, 8);
  }
  std::string id;
  {
    auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    auto session = store->Create("big", "scan", {{"views", 2}}, std::chrono::system_clock::now(),
                                 StatusInto(&error));
    ASSERT_TRUE(session) << error;
    id = session->id();
    ASSERT_TRUE(Ok(session->SetState(daemon::SessionState::kReconstructing, ""), &error)) << error;
    ASSERT_TRUE(Ok(session->StoreOutput("fused.ply", big), &error)) << error;
    ASSERT_TRUE(Ok(session->StoreOutput("report.json", "{\"ok\": true}"), &error)) << error;
    ASSERT_TRUE(Ok(session->StoreOutput("previews/top.png", std::string(5000, 'x')), &error))
        << error;
    ASSERT_TRUE(Ok(session->SetState(daemon::SessionState::kDone, ""), &error)) << error;
  }
  ASSERT_TRUE(station.Launch(&error)) << error;

  const std::string out = station.dir() + "/big";
  for (const char* chunk_kib : {"1024", "4096"}) {  // 1024: the default
    const std::string dir = out + chunk_kib;
    const CtlRun r = station.Run(kObserverToken, {"get", id, "--out", dir, "--file", "fused.ply",
                                                  "--chunk-kib", chunk_kib, "--json"});
    ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
    EXPECT_TRUE(ReadFile(dir + "/fused.ply") == big);
    const double seconds = ParseJson(r).value("transfer_seconds", 0.0);
    std::printf(
        "get of a 48 MiB output in %s KiB chunks (loopback): transfer %.2f s = %.0f MiB/s; "
        "%.2f s with process start and discovery\n",
        chunk_kib, seconds, seconds > 0 ? 48 / seconds : 0.0, r.seconds);
  }

  // Same size, other bytes: the client's checksum check refuses it.
  const std::string session_dir = station.fixture().data_dir() + "/sessions/" + id;
  std::ofstream(session_dir + "/report.json", std::ios::trunc) << "{\"ok\": 1234}";
  CtlRun r = station.Run(kObserverToken, {"get", id, "--out", out, "--file", "report.json"});
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_NE(r.err.find("checksum"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(out + "/report.json"));
  // Another size: the station refuses to send it.
  std::ofstream(session_dir + "/previews/top.png", std::ios::trunc) << "short";
  r = station.Run(kObserverToken, {"get", id, "--out", out, "--file", "previews/top.png"});
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_NE(r.err.find("differs from the manifest"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(out + "/previews/top.png"));
}

TEST(Craftscanctl, WithoutADaemonExitsFiveWithinTheTimeoutAndSaysWhatToCheck) {
  const TempDir temp("craftscanctl-test");
  ASSERT_FALSE(temp.path().empty());
  const std::string& dir = temp.path();
  // A private domain nobody serves.
  const std::string domain = std::to_string(200 + ::getpid() % 30);
  const std::string config = dds::LoopbackOnlyConfigXml();
  const std::vector<std::vector<std::string>> commands = {
      {"status"}, {"watch", "--count", "1"}, {"get", "20260101-000000-x", "--out", dir + "/o"}};
  for (const auto& command : commands) {
    std::vector<std::string> args = {"--station", "nobody", "--domain", domain,
                                     "--timeout", "2",      "--token",  kObserverToken};
    args.insert(args.end(), command.begin(), command.end());
    CtlProcess process(dir, command[0], args, {"CYCLONEDDS_URI=" + config});
    const CtlRun r = process.Wait(60s);
    EXPECT_EQ(r.exit_code, 5) << command[0] << ": " << Describe(r);
    EXPECT_LT(r.seconds, 2.0 + 8.0) << command[0] << " took too long beyond its 2 s timeout";
    EXPECT_NE(r.err.find("craftscand"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("domain " + domain), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("CYCLONEDDS_URI"), std::string::npos) << r.err;
  }
}

}  // namespace
}  // namespace craftscan::testing

namespace craftscan::testing {
namespace {

// --- two turns (README 4.2 "The base": scan --add-to) ------------------------

// The session's manifest, read without taking its lock.
daemon::Manifest ReadManifestOf(Station& station, const std::string& session) {
  daemon::Manifest manifest;
  std::string error;
  EXPECT_TRUE(daemon::ManifestFromJson(
      ReadFile(station.fixture().data_dir() + "/sessions/" + session + "/manifest.json"), &manifest,
      &error))
      << error;
  return manifest;
}

// The only session's id (sessions --json).
std::string OnlySession(Station& station) {
  const CtlRun r = station.Run(kObserverToken, {"sessions", "--json"});
  const json list = ParseJson(r).value("sessions", json::array());
  EXPECT_EQ(list.size(), 1u) << r.out;
  return list.empty() ? std::string() : list[0].value("id", "");
}

// Fused points of `ply` within `radius_mm` of the turntable axis and below
// `height_mm`: the middle of the base a turn standing on it never sees.
std::size_t BasePoints(const std::string& ply, double radius_mm, double height_mm) {
  PointCloud cloud;
  std::string error;
  EXPECT_TRUE(ReadPly(ply, &cloud, &error)) << error;
  std::size_t n = 0;
  for (const cv::Vec3f& p : cloud.points_mm)
    n += std::hypot(p[0], p[1]) < radius_mm && p[2] < height_mm;
  return n;
}

// The carved box (80 × 60 × 50 mm), 6 views a turn (4 fit only 64 % of the
// second turn, refused): turn 2 (laid on its
// side, the sim's default second pose) joined onto turn 1 with the base in
// the model; a crash (SIGKILL) in turn 2 loses nothing of turn 1 and
// resume finishes the turn; a third turn and bad --add-to values are refused.
TEST(Craftscanctl, SecondTurnJoinsTheBaseCrashInItKeepsTheFirstAndResumeFinishesIt) {
  Station station;
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  CtlRun r = station.Run(kOperatorToken, {"scan", "--object", "carved box", "--views", "6"}, 300s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  const std::string session = OnlySession(station);
  ASSERT_FALSE(session.empty());
  const std::string dir = station.fixture().data_dir() + "/sessions/" + session;
  const daemon::Manifest first = ReadManifestOf(station, session);
  ASSERT_TRUE(first.outputs.count("fused.ply") && first.outputs.count("report.html"));
  const std::size_t first_base = BasePoints(dir + "/fused.ply", 20, 3);
  std::printf("turn 1: %.1f s, %zu fused points in the base's middle\n", r.seconds, first_base);

  // Turn 2, killed while it captures.
  CtlProcess second(station.dir(), "turn2",
                    station.Args(kOperatorToken, {"scan", "--add-to", session, "--no-wait"}));
  ASSERT_EQ(second.Wait(60s).exit_code, 0) << station.fixture().Log();
  bool capturing = false;
  for (int i = 0; i < 600 && !capturing; ++i) {
    const json st = ParseJson(station.Run(kObserverToken, {"status", "--json"}));
    const json job = st.value("job", json::object());
    // A view of turn 2 on disk, its outputs not begun.
    const std::string stage = job.value("stage", "");
    capturing = job.value("turn", 0) == 2 && job.value("state", "") == "running" &&
                (stage == "match" || (stage == "capture" && job.value("progress", 0.0) > 0));
    if (!capturing) {
      // (--no-wait returned once turn 2's job started: it is the current job.)
      ASSERT_EQ(job.value("state", ""), "running")
          << "turn 2 ended before it could be killed: " << st.dump();
      std::this_thread::sleep_for(50ms);
    }
  }
  ASSERT_TRUE(capturing) << station.fixture().Log();
  ASSERT_GE(station.fixture().Stop(SIGKILL), 0);

  // Turn 1's captures and outputs verify by their checksums; its outputs
  // are kept under turn1/ too.
  {
    auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    const daemon::VerifyResult verify = store->Verify(session);
    EXPECT_TRUE(verify.IsIntact()) << ::testing::PrintToString(verify.problems);
    const daemon::Manifest now = ReadManifestOf(station, session);
    for (const auto& [name, record] : first.outputs) {
      ASSERT_TRUE(now.outputs.count(name)) << name;
      EXPECT_EQ(now.outputs.at(name).sha256, record.sha256) << name;
      ASSERT_TRUE(now.outputs.count("turn1/" + name)) << name;
      EXPECT_EQ(now.outputs.at("turn1/" + name).sha256, record.sha256) << name;
    }
    for (const auto& [index, view] : first.views) EXPECT_EQ(now.views.at(index).files, view.files);
    EXPECT_EQ(now.params["turns"][1].value("state", ""), "capturing") << now.params.dump();
  }
  ASSERT_TRUE(station.Launch(&error)) << error;
  r = station.Run(kObserverToken, {"sessions"});
  EXPECT_NE(r.out.find("interrupted"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("turn 2: views 6-11, interrupted"), std::string::npos) << r.out;

  // Resume finishes turn 2 and joins it.
  r = station.Run(kOperatorToken, {"resume", session, "--json"}, 300s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  std::printf("turn 2 resumed and joined: %.1f s\n", r.seconds);
  const json report = json::parse(ReadFile(dir + "/report.json"), nullptr, false);
  ASSERT_TRUE(report.is_object());
  const json join = report.value("turn_join", json());
  ASSERT_TRUE(join.is_object()) << report.dump(1).substr(0, 2000);
  EXPECT_EQ(join.value("status", ""), "joined") << join.dump();
  EXPECT_GE(join.value("overlap_pct", 0.0), 65.0) << join.dump();
  EXPECT_LT(join.value("rmse_mm", 99.0), 1.0) << join.dump();
  ASSERT_EQ(report["turns"].size(), 2u) << report["turns"].dump();
  EXPECT_EQ(report["turns"][0].value("views", 0), 6);
  EXPECT_EQ(report["turns"][1].value("first_view", 0), 6);
  EXPECT_EQ(report["turns"][1].value("state", ""), "joined");
  // The base is in the model: the first turn saw (almost) nothing of its
  // middle, the joined model covers it; the box measures 80 × 60 × 50 mm.
  const std::size_t joined_base = BasePoints(dir + "/fused.ply", 20, 3);
  std::printf(
      "joined: fit %.1f %%, RMSE %.3f mm, ambiguity %.2f, constraint %.3f, contact "
      "points dropped %d / %d, %zu points in the base's middle\n",
      join.value("overlap_pct", 0.0), join.value("rmse_mm", 0.0), join.value("ambiguity", 0.0),
      join.value("constraint", 0.0), join.value("contact_dropped_a", 0),
      join.value("contact_dropped_b", 0), joined_base);
  EXPECT_GT(joined_base, 200u);
  EXPECT_GT(joined_base, 10 * first_base + 100) << "turn 1 had " << first_base;
  std::vector<double> box;
  for (const json& e : report["measurement"]["oriented_box"].value("extents_mm", json::array()))
    box.push_back(e.get<double>());
  ASSERT_EQ(box.size(), 3u) << report["measurement"].dump();
  std::sort(box.rbegin(), box.rend());
  EXPECT_NEAR(box[0], 80, 4);
  EXPECT_NEAR(box[1], 60, 4);
  EXPECT_NEAR(box[2], 50, 4);
  const std::string html = ReadFile(dir + "/report.html");
  EXPECT_NE(html.find("id=\"turns\""), std::string::npos);
  EXPECT_NE(html.find("joined"), std::string::npos);
  // Everything verifies, turn 1's outputs kept under turn1/.
  {
    auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    EXPECT_TRUE(store->Verify(session).IsIntact());
    const daemon::Manifest done = ReadManifestOf(station, session);
    EXPECT_EQ(done.state, daemon::SessionState::kDone);
    EXPECT_EQ(done.CapturedViews().size(), 12u);
    EXPECT_EQ(done.outputs.at("turn1/fused.ply").sha256, first.outputs.at("fused.ply").sha256);
    EXPECT_NE(done.outputs.at("fused.ply").sha256, first.outputs.at("fused.ply").sha256);
  }
  r = station.Run(kObserverToken, {"sessions"});
  EXPECT_NE(r.out.find("turn 2: views 6-11, joined; joined (fit"), std::string::npos) << r.out;

  // Refused: a third turn, an unknown session, a bad id, --object with --add-to.
  r = station.Run(kOperatorToken, {"scan", "--add-to", session});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("already has turn 2 joined"), std::string::npos) << r.err;
  r = station.Run(kOperatorToken, {"scan", "--add-to", "20200101-000000-nothing"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("not_found"), std::string::npos) << r.err;
  r = station.Run(kOperatorToken, {"scan", "--add-to", "../etc"});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("add_to: not a session id"), std::string::npos) << r.err;
  r = station.Run(kOperatorToken, {"scan", "--add-to", session, "--object", "x"});
  EXPECT_EQ(r.exit_code, 2) << Describe(r);
  r = station.Run(kOperatorToken, {"scan"});
  EXPECT_EQ(r.exit_code, 2) << Describe(r);
  EXPECT_NE(r.err.find("--add-to SESSION"), std::string::npos) << r.err;
  r = station.Run(kObserverToken, {"status"});
  EXPECT_EQ(r.exit_code, 0) << Describe(r) << "the daemon serves on";
}

// The egg laid on its side turns about its own axis without telling where:
// the join is refused with what to do, the session keeps turn 1's model and
// outputs intact (done again, turn 2 kept on disk marked refused), and
// another turn may be added, laid otherwise. 320x256, 4 views a turn.
TEST(Craftscanctl, RefusedSecondTurnKeepsTheFirstTurnsModelAndSaysWhatToDo) {
  Station station("", ", object: egg, turn_rotations_deg: \"90,0,0;0,90,0\"", "320x256");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  CtlRun r = station.Run(kOperatorToken, {"scan", "--object", "egg", "--views", "4"}, 300s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture().Log();
  const std::string session = OnlySession(station);
  ASSERT_FALSE(session.empty());
  const daemon::Manifest first = ReadManifestOf(station, session);

  // A turn of a session that is not a finished scan is refused.
  r = station.Run(kOperatorToken, {"capture", "--object", "probe"}, 120s);
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  std::string capture;
  for (const json& s : ParseJson(station.Run(kObserverToken, {"sessions", "--json"}))
                           .value("sessions", json::array()))
    if (s.value("job", "") == "capture") capture = s.value("id", "");
  r = station.Run(kOperatorToken, {"scan", "--add-to", capture});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("only a scan's session takes another turn"), std::string::npos) << r.err;

  // ... and so is one whose first turn did not finish.
  std::string unfinished;
  {
    auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    auto half = store->Create("half", "scan", {{"views", 4}, {"step_deg", 90}},
                              std::chrono::system_clock::now(), StatusInto(&error));
    ASSERT_TRUE(half) << error;
    ASSERT_TRUE(half->SetState(daemon::SessionState::kCapturing, "").ok());
    ASSERT_TRUE(half->SetState(daemon::SessionState::kInterrupted, "stopped").ok());
    unfinished = half->id();
  }
  r = station.Run(kOperatorToken, {"scan", "--add-to", unfinished});
  EXPECT_EQ(r.exit_code, 3) << Describe(r);
  EXPECT_NE(r.err.find("is interrupted: its first turn is not finished (resume it first)"),
            std::string::npos)
      << r.err;

  r = station.Run(kOperatorToken, {"scan", "--add-to", session}, 300s);
  std::printf("turn 2 of the egg: %.1f s\n", r.seconds);
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_NE(r.out.find("turn 2 not joined (refused_"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("the session keeps turn 1's model: lay the object differently"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("craftscanctl scan --add-to " + session), std::string::npos) << r.out;

  auto store = daemon::SessionStore::Open(station.fixture().data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  EXPECT_TRUE(store->Verify(session).IsIntact());
  const daemon::Manifest after = ReadManifestOf(station, session);
  EXPECT_EQ(after.state, daemon::SessionState::kDone);
  EXPECT_FALSE(after.outputs.count("turn1/fused.ply") == 0) << "kept under turn1/ as well";
  for (const auto& [name, record] : first.outputs) {
    ASSERT_TRUE(after.outputs.count(name)) << name;
    EXPECT_EQ(after.outputs.at(name).sha256, record.sha256) << name << " changed";
  }
  ASSERT_EQ(after.params["turns"].size(), 2u) << after.params.dump();
  const json turn = after.params["turns"][1];
  EXPECT_EQ(turn.value("state", ""), "refused") << turn.dump();
  EXPECT_EQ(turn.value("first_view", 0), 4);
  EXPECT_TRUE(turn["join"].value("status", "").rfind("refused_", 0) == 0) << turn.dump();
  std::printf("egg turn 2: %s\n", turn["join"].value("message", "").c_str());
  EXPECT_EQ(after.CapturedViews().size(), 8u) << "the refused turn's views stay";
  r = station.Run(kObserverToken, {"sessions"});
  EXPECT_NE(r.out.find("turn 2: views 4-7, refused; refused_"), std::string::npos) << r.out;

  // The operator lays it again and adds another turn (the sim's
  // turn_rotations_deg: "90,0,0;0,90,0"): turn 3, after the refused turn's
  // views; the egg on its end is no better, and the session keeps turn 1's
  // model again.
  r = station.Run(kOperatorToken, {"scan", "--add-to", session}, 300s);
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_NE(r.out.find("turn 3 not joined"), std::string::npos) << r.out;
  const daemon::Manifest retried = ReadManifestOf(station, session);
  EXPECT_EQ(retried.state, daemon::SessionState::kDone);
  ASSERT_EQ(retried.params["turns"].size(), 3u) << retried.params.dump();
  EXPECT_EQ(retried.params["turns"][1].value("state", ""), "refused");
  EXPECT_EQ(retried.params["turns"][2].value("first_view", 0), 8);
  EXPECT_EQ(retried.CapturedViews().size(), 12u);
  for (const auto& [name, record] : first.outputs)
    EXPECT_EQ(retried.outputs.at(name).sha256, record.sha256) << name << " changed";
  EXPECT_TRUE(store->Verify(session).IsIntact());
}

}  // namespace
}  // namespace craftscan::testing
