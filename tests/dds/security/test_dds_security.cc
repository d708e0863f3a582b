// DDS Security as a station option (issue 8), end to end with Debian's
// Cyclone DDS and its security plugins.
//
// The tests of a process share a station PKI made with
// scripts/dds-security-setup in a temp dir (a CA, the daemon's and clients'
// identities, signed governance and permissions). Each runs the daemon's side
// in this process (status writer, command reader, capture writer; the daemon
// identity) and clients in craftscan_dds_security_peer processes on the same
// private loopback domain.
// Shown: an authenticated client gets status and large captures intact and
// its commands arrive; a viewer reads but cannot command; a participant
// without security, one from another CA and one impersonating a client with
// another CA's certificate get no sample and deliver no command, during a
// window in which the authenticated client keeps receiving. A control run
// without security shows the same intruder does get through then. The
// permissions allow every topic of topics.h to its role; on a site (a
// site CA, --site, --worker) each role gets its site topics in the site's
// partition only (the site end to end, with craftscand and
// craftscan-worker as hosts: tests/scale/test_site_security.cc). The
// script's idempotence and key protection are checked too.
//
// No timed assertions: the window only bounds how long we watch for samples
// that must never arrive. Cyclone logs the refused handshakes on stderr
// ("Certificate not valid", "Remote secure participant ... not allowed";
// the latter also once in a while when a peer's announcement arrives before
// the local participant is complete, and is then retried): expected.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"
#include "craftscan/dds/topics.h"
#include "dds_test_util.h"
#include "file_util.h"
#include "process_util.h"
#include "security_test_util.h"
#include "test_paths.h"

namespace craftscan::dds {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;

constexpr milliseconds kTimeout{20000};  // for what must happen; generous (shared machine)
// How long intruders are watched after the authenticated client is seen to
// work: at the daemon's 20 status samples/s, 60 samples they must not get.
constexpr milliseconds kWindow{3000};

using ::craftscan::testing::ProcessDomainId;
using ::craftscan::testing::ReadFile;
using ::craftscan::testing::TempDir;
using ::craftscan::testing::UniqueStation;

// A child process with stdout (and stderr, if asked) to a file. Killed and
// reaped on destruction if still running.
class Process {
 public:
  Process() = default;
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;
  bool Start(const std::vector<std::string>& args, const std::string& output, bool with_stderr) {
    ::craftscan::testing::SpawnOptions options;
    options.stdout_path = output;
    options.stderr_to_stdout = with_stderr;
    return ::craftscan::testing::Spawn(args, options, &child_);
  }

  void Terminate() { child_.Signal(SIGTERM); }

  // The exit code (128 + signal if killed by one), or −1 if it did not exit
  // within `timeout` (then it is killed on destruction).
  int Wait(milliseconds timeout) { return child_.Wait(timeout); }

 private:
  ::craftscan::testing::ChildProcess child_;
};

struct ScriptRun {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

// scripts/dds-security-setup --out <out> --station <station> --domain
// <ProcessDomainId> --base-config <the shipped cyclonedds.xml> <extra...>.
ScriptRun RunSetup(const std::string& out, const std::string& station,
                   const std::vector<std::string>& extra) {
  std::vector<std::string> args = {::craftscan::testing::DdsSecuritySetupPath(),
                                   "--out",
                                   out,
                                   "--station",
                                   station,
                                   "--domain",
                                   std::to_string(ProcessDomainId()),
                                   "--base-config",
                                   ::craftscan::testing::CycloneDdsXml()};
  args.insert(args.end(), extra.begin(), extra.end());
  const std::string log = out + ".log";
  ScriptRun run;
  Process process;
  if (process.Start(args, log, /*with_stderr=*/true)) run.exit_code = process.Wait(kTimeout);
  run.output = ReadFile(log);
  fs::remove(log);
  return run;
}

std::string PlainConfig() {
  return ConfigFileUri(::craftscan::testing::CycloneDdsXml()) + "," + LoopbackOnlyConfigXml();
}

// The shipped config, an identity's generated security fragment, loopback.
std::string SecuredConfig(const std::string& identity_dir) {
  return ConfigFileUri(::craftscan::testing::CycloneDdsXml()) + "," +
         ConfigFileUri(identity_dir + "/cyclonedds-security.xml") + "," + LoopbackOnlyConfigXml();
}

// A <Security> configuration from explicit files (Cyclone's default plugin
// names), for mixing the files of two PKIs.
std::string SecurityXml(const std::string& identity_ca, const std::string& cert,
                        const std::string& key, const std::string& permissions_ca,
                        const std::string& governance, const std::string& permissions) {
  return "<CycloneDDS><Domain><Security><Authentication>"
         "<IdentityCA>file:" +
         identity_ca + "</IdentityCA><IdentityCertificate>file:" + cert +
         "</IdentityCertificate><PrivateKey>file:" + key +
         "</PrivateKey></Authentication><AccessControl><PermissionsCA>file:" + permissions_ca +
         "</PermissionsCA><Governance>file:" + governance +
         "</Governance><Permissions>file:" + permissions +
         "</Permissions></AccessControl></Security></Domain></CycloneDDS>";
}

// A client process (craftscan_dds_security_peer) and its report.
class Peer {
 public:
  Peer(const std::string& work_dir, const std::string& name, const std::string& config,
       const std::string& station)
      : name_(name), report_path_(work_dir + "/" + name + ".report") {
    started_ = process_.Start(
        {::craftscan::testing::DdsSecurityPeerPath(), "--domain", std::to_string(ProcessDomainId()),
         "--config", config, "--station", station, "--name", name, "--max-ms", "60000"},
        report_path_, /*with_stderr=*/false);
  }
  bool started() const { return started_; }

  // Stops the peer and parses its report ("key=value ..."); empty on failure.
  std::map<std::string, std::string> Stop() {
    process_.Terminate();
    std::map<std::string, std::string> report;
    if (process_.Wait(kTimeout) != 0) return report;
    std::istringstream words(ReadFile(report_path_));
    std::string word;
    while (words >> word) {
      const std::size_t equals = word.find('=');
      if (equals != std::string::npos) report[word.substr(0, equals)] = word.substr(equals + 1);
    }
    return report;
  }

 private:
  std::string name_, report_path_;
  Process process_;
  bool started_ = false;
};

long Number(const std::map<std::string, std::string>& report, const std::string& key) {
  const auto it = report.find(key);
  return it == report.end() ? -1 : std::atol(it->second.c_str());
}

std::string Text(const std::map<std::string, std::string>& report, const std::string& key) {
  const auto it = report.find(key);
  return it == report.end() ? "<missing>" : it->second;
}

std::string Describe(const std::map<std::string, std::string>& report) {
  std::string text;
  for (const auto& [key, value] : report) text += key + "=" + value + " ";
  return text.empty() ? "<no report>" : text;
}

// The daemon's side of a station: writes StationStatus 20 times a second,
// counts Commands per client, and writes captures on request. Its own thread
// does the status and commands.
class DaemonSide {
 public:
  static std::unique_ptr<DaemonSide> Create(const std::string& config, const std::string& station,
                                            std::string* error) {
    std::unique_ptr<DaemonSide> side(new DaemonSide(station));
    ParticipantOptions options;
    options.domain_id = ProcessDomainId();
    options.config = config;
    side->participant_ = Participant::Create(options, error);
    if (!side->participant_) return nullptr;
    side->status_ =
        Writer<msg::StationStatus>::Create(side->participant_, StatusTopic(station), error);
    if (!side->status_) return nullptr;
    side->commands_ =
        Reader<msg::Command>::Create(side->participant_, CommandTopic(station), error);
    if (!side->commands_) return nullptr;
    side->captures_ =
        Writer<msg::StereoCapture>::Create(side->participant_, CaptureTopic(station), error);
    if (!side->captures_) return nullptr;
    side->thread_ = std::thread([raw = side.get()] { raw->Run(); });
    return side;
  }
  ~DaemonSide() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

  const std::shared_ptr<Participant>& participant() const { return participant_; }

  // Once `readers` capture readers are matched, writes a random 1280×1024
  // bgr8 stereo capture (7.9 MB) and waits until they all acknowledged it;
  // prints how long that took (`what` names the link). *hash: its
  // testing::CaptureHash.
  ::testing::AssertionResult SendCapture(int readers, const std::string& what, std::string* hash) {
    if (!captures_->WaitForReaders(readers, kTimeout)) {
      return ::testing::AssertionFailure() << "fewer than " << readers << " capture readers";
    }
    cv::Mat left(1024, 1280, CV_8UC3), right(1024, 1280, CV_8UC3);
    cv::RNG rng(8);
    rng.fill(left, cv::RNG::UNIFORM, 0, 256);
    rng.fill(right, cv::RNG::UNIFORM, 0, 256);
    StereoCaptureMeta meta;
    meta.session = "20240611-101500-carved_egg";
    Outgoing<msg::StereoCapture> capture;
    std::string error;
    if (!MakeStereoCapture(left, right, meta, &capture, &error)) {
      return ::testing::AssertionFailure() << error;
    }
    const auto start = std::chrono::steady_clock::now();
    if (!captures_->Write(capture.msg(), &error) || !captures_->WaitForAcks(kTimeout, &error)) {
      return ::testing::AssertionFailure() << "capture: " << error;
    }
    const auto elapsed = std::chrono::steady_clock::now() - start;
    std::cout << "figure: a 7.9 MB capture, " << what << ", acknowledged by " << readers
              << " reader(s) in " << std::chrono::duration_cast<milliseconds>(elapsed).count()
              << " ms\n";
    *hash = testing::CaptureHash(capture.msg());
    return ::testing::AssertionSuccess();
  }

  int CommandsFrom(const std::string& client) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = received_.find(client);
    return it == received_.end() ? 0 : it->second;
  }
  bool WaitForCommandFrom(const std::string& client, milliseconds timeout) const {
    std::unique_lock<std::mutex> lock(mutex_);
    return arrived_.wait_for(lock, timeout, [&] { return received_.count(client) > 0; });
  }

 private:
  explicit DaemonSide(std::string station) : station_(std::move(station)) {}

  void Run() {
    Outgoing<msg::StationStatus> status;
    status.msg().station = status.Keep(station_);
    status.msg().state = status.Keep("idle");
    std::string error;
    auto next_status = std::chrono::steady_clock::now();
    Sample<msg::Command> command;
    while (!stop_) {
      if (std::chrono::steady_clock::now() >= next_status) {
        ++status.msg().stamp_ns;
        status_->Write(status.msg(), &error);
        next_status += milliseconds(50);
      }
      if (commands_->Take(milliseconds(10), &command, &error) == TakeStatus::kOk) {
        std::lock_guard<std::mutex> lock(mutex_);
        ++received_[std::string(View(command->client))];
        arrived_.notify_all();
      }
    }
  }

  const std::string station_;
  std::shared_ptr<Participant> participant_;
  std::unique_ptr<Writer<msg::StationStatus>> status_;
  std::unique_ptr<Reader<msg::Command>> commands_;
  std::unique_ptr<Writer<msg::StereoCapture>> captures_;
  mutable std::mutex mutex_;
  mutable std::condition_variable arrived_;
  std::map<std::string, int> received_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// What a failed secured participant most likely means.
constexpr char kSecuredHint[] =
    " (Cyclone's log above names the cause; the security plugins "
    "libdds_security_{auth,ac,crypto}.so come with Debian's libddsc0debian)";

class DdsSecurity : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { suite_dir_ = std::make_unique<TempDir>("craftscan-ddssec"); }
  static void TearDownTestSuite() {
    suite_dir_.reset();
    made_.clear();
  }

  // The station PKI the tests of this process share (identities daemon,
  // client "console", viewer "recorder"), made on first use: the script runs
  // a dozen openssl processes, which is slow on a loaded machine.
  static ::testing::AssertionResult StationPki(std::string* pki) {
    return SharedPki("pki", {"--client", "console", "--viewer", "recorder"}, pki);
  }
  // Another CA's PKI for the same station, with a client "console": the
  // same subjects as in StationPki.
  static ::testing::AssertionResult OtherPki(std::string* pki) {
    return SharedPki("other", {"--client", "console"}, pki);
  }
  static std::string Identity(const std::string& pki, const std::string& name) {
    return pki + "/identities/" + name;
  }
  static const std::string& station() { return station_; }

  // StationPki, and the daemon's side with the daemon identity.
  static ::testing::AssertionResult StartSecuredDaemon(std::string* pki,
                                                       std::unique_ptr<DaemonSide>* daemon) {
    ::testing::AssertionResult made = StationPki(pki);
    if (!made) return made;
    std::string error;
    *daemon = DaemonSide::Create(SecuredConfig(Identity(*pki, "daemon")), station_, &error);
    if (!*daemon) {
      return ::testing::AssertionFailure()
             << "secured daemon participant: " << error << kSecuredHint;
    }
    return ::testing::AssertionSuccess();
  }

  TempDir temp_{"craftscan-ddssec"};  // this test's own files (peer reports)

 private:
  static ::testing::AssertionResult SharedPki(const std::string& subdir,
                                              const std::vector<std::string>& identities,
                                              std::string* pki) {
    if (suite_dir_->path().empty()) return ::testing::AssertionFailure() << "no temp dir";
    *pki = suite_dir_->path() + "/" + subdir;
    if (made_.count(subdir)) return ::testing::AssertionSuccess();
    const ScriptRun run = RunSetup(*pki, station_, identities);
    if (run.exit_code != 0) {
      return ::testing::AssertionFailure() << "dds-security-setup exited " << run.exit_code << ":\n"
                                           << run.output;
    }
    made_.insert(subdir);
    return ::testing::AssertionSuccess();
  }

  static inline std::unique_ptr<TempDir> suite_dir_;
  static inline std::set<std::string> made_;  // SharedPki subdirs made so far
  static inline const std::string station_ = UniqueStation("s");
};

TEST_F(DdsSecurity, AuthenticatedClientsReadAndCommandAsTheirPermissionsAllow) {
  ASSERT_FALSE(temp_.path().empty());
  std::string pki;
  std::unique_ptr<DaemonSide> daemon;
  ASSERT_TRUE(StartSecuredDaemon(&pki, &daemon));
  std::string error;

  // Access control in the daemon's own process: its permissions let it read
  // commands and publish status, not the other way round.
  EXPECT_EQ(Writer<msg::Command>::Create(daemon->participant(), CommandTopic(station()), &error),
            nullptr);
  EXPECT_EQ(
      Reader<msg::StationStatus>::Create(daemon->participant(), StatusTopic(station()), &error),
      nullptr);
  EXPECT_EQ(Writer<msg::StationStatus>::Create(daemon->participant(), StatusTopic("other_station"),
                                               &error),
            nullptr);

  Peer console(temp_.path(), "console", SecuredConfig(Identity(pki, "console")), station());
  Peer recorder(temp_.path(), "recorder", SecuredConfig(Identity(pki, "recorder")), station());
  ASSERT_TRUE(console.started() && recorder.started());
  ASSERT_TRUE(daemon->WaitForCommandFrom("console", kTimeout));

  // A 7.9 MB capture through the encrypted link, with the shipped large-sample
  // settings, to both clients.
  std::string expected_hash;
  ASSERT_TRUE(daemon->SendCapture(2, "encrypted", &expected_hash));

  const auto console_report = console.Stop();
  const auto recorder_report = recorder.Stop();
  // Both read status and got the capture intact; the viewer, whose
  // permissions allow no publication, cannot even create a command writer.
  for (const auto& [report, command_writer] :
       {std::pair{&console_report, "ok"}, std::pair{&recorder_report, "refused"}}) {
    SCOPED_TRACE(Describe(*report));
    EXPECT_EQ(Text(*report, "participant"), "ok");
    EXPECT_EQ(Text(*report, "command_writer"), command_writer);
    EXPECT_GE(Number(*report, "status"), 1);
    EXPECT_EQ(Number(*report, "captures"), 1);
    EXPECT_EQ(Text(*report, "capture_hash"), expected_hash);
  }
  EXPECT_GE(daemon->CommandsFrom("console"), 1);
  EXPECT_EQ(daemon->CommandsFrom("recorder"), 0);
}

TEST_F(DdsSecurity, UnauthenticatedParticipantCanNeitherReadNorCommand) {
  ASSERT_FALSE(temp_.path().empty());
  std::string pki;
  std::unique_ptr<DaemonSide> daemon;
  ASSERT_TRUE(StartSecuredDaemon(&pki, &daemon));

  Peer console(temp_.path(), "console", SecuredConfig(Identity(pki, "console")), station());
  Peer intruder(temp_.path(), "intruder", PlainConfig(), station());
  ASSERT_TRUE(console.started() && intruder.started());
  ASSERT_TRUE(daemon->WaitForCommandFrom("console", kTimeout));
  std::this_thread::sleep_for(kWindow);

  const auto intruder_report = intruder.Stop();
  const auto console_report = console.Stop();
  SCOPED_TRACE("intruder: " + Describe(intruder_report));
  SCOPED_TRACE("console: " + Describe(console_report));
  // The secured client kept receiving throughout the window...
  EXPECT_GE(Number(console_report, "status"), 10);
  // ...while the intruder, a working participant that tried all along, saw
  // no daemon writer, got no sample and reached no reader.
  EXPECT_EQ(Text(intruder_report, "participant"), "ok");
  EXPECT_EQ(Text(intruder_report, "command_writer"), "ok");
  EXPECT_GE(Number(intruder_report, "commands"), 20);
  EXPECT_EQ(Number(intruder_report, "status"), 0);
  EXPECT_EQ(Number(intruder_report, "status_writers"), 0);
  EXPECT_EQ(Number(intruder_report, "command_readers"), 0);
  EXPECT_EQ(daemon->CommandsFrom("intruder"), 0);
}

TEST_F(DdsSecurity, ParticipantsWithAnotherCasCertificateAreRefused) {
  ASSERT_FALSE(temp_.path().empty());
  std::string pki, other;
  std::unique_ptr<DaemonSide> daemon;
  ASSERT_TRUE(StartSecuredDaemon(&pki, &daemon));
  // Another CA that issued a certificate with the very same subject.
  ASSERT_TRUE(OtherPki(&other));

  // "foreign": everything from the other PKI. "impostor": the other CA's
  // certificate for CN=console with the station's own (public) CA,
  // governance and the real console's signed permissions, so only the
  // identity certificate's issuer is wrong.
  const std::string fake = Identity(other, "console"), real = Identity(pki, "console");
  const std::string impostor_config =
      ConfigFileUri(::craftscan::testing::CycloneDdsXml()) + "," +
      SecurityXml(fake + "/ca.pem", fake + "/cert.pem", fake + "/key.pem", real + "/ca.pem",
                  real + "/governance.p7s", real + "/permissions.p7s") +
      "," + LoopbackOnlyConfigXml();
  Peer console(temp_.path(), "console", SecuredConfig(real), station());
  Peer foreign(temp_.path(), "foreign", SecuredConfig(fake), station());
  Peer impostor(temp_.path(), "impostor", impostor_config, station());
  ASSERT_TRUE(console.started() && foreign.started() && impostor.started());
  ASSERT_TRUE(daemon->WaitForCommandFrom("console", kTimeout));
  std::this_thread::sleep_for(kWindow);

  const auto foreign_report = foreign.Stop();
  const auto impostor_report = impostor.Stop();
  const auto console_report = console.Stop();
  SCOPED_TRACE("foreign: " + Describe(foreign_report));
  SCOPED_TRACE("impostor: " + Describe(impostor_report));
  SCOPED_TRACE("console: " + Describe(console_report));
  EXPECT_GE(Number(console_report, "status"), 10);
  for (const auto* report : {&foreign_report, &impostor_report}) {
    // Both are valid secured participants on their own; the handshake with
    // the station is what fails.
    EXPECT_EQ(Text(*report, "participant"), "ok");
    EXPECT_EQ(Text(*report, "command_writer"), "ok");
    EXPECT_GE(Number(*report, "commands"), 20);
    EXPECT_EQ(Number(*report, "status"), 0);
    EXPECT_EQ(Number(*report, "status_writers"), 0);
    EXPECT_EQ(Number(*report, "command_readers"), 0);
  }
  EXPECT_EQ(daemon->CommandsFrom("foreign"), 0);
  EXPECT_EQ(daemon->CommandsFrom("impostor"), 0);
}

// Creates a writer (publish) or reader of `topic`; "" if allowed, else the
// topic name and Cyclone's refusal.
template <typename Msg>
std::string TryEndpoint(const std::shared_ptr<Participant>& participant, bool publish,
                        const TopicSpec<Msg>& topic) {
  std::string error;
  const bool ok = publish ? Writer<Msg>::Create(participant, topic, &error) != nullptr
                          : Reader<Msg>::Create(participant, topic, &error) != nullptr;
  return ok ? "" : (publish ? "publish " : "subscribe ") + topic.name + ": " + error + "\n";
}

// Every topic of topics.h the daemon publishes (a client's reads) or
// subscribes (a client's writes); refusals are collected.
std::string TryStationTopics(const std::shared_ptr<Participant>& participant,
                             const std::string& station, bool as_daemon) {
  std::string refused;
  const bool out = as_daemon;  // the daemon publishes what clients subscribe
  refused += TryEndpoint(participant, out, StatusTopic(station));
  refused += TryEndpoint(participant, out, ReplyTopic(station));
  refused += TryEndpoint(participant, out, ProgressTopic(station));
  refused += TryEndpoint(participant, out, CaptureTopic(station));
  refused += TryEndpoint(participant, out, DisparityTopic(station));
  refused += TryEndpoint(participant, out, CloudTopic(station));
  refused += TryEndpoint(participant, out, PreviewTopic(station));
  refused += TryEndpoint(participant, out, FileTopic(station));
  for (Side side : {Side::kLeft, Side::kRight}) {
    refused += TryEndpoint(participant, out, RosImageTopic(station, side));
    refused += TryEndpoint(participant, out, RosCameraInfoTopic(station, side));
  }
  refused += TryEndpoint(participant, out, RosDisparityTopic(station));
  refused += TryEndpoint(participant, out, RosCloudTopic(station));
  refused += TryEndpoint(participant, out, RosTfTopic());
  refused += TryEndpoint(participant, out, RosTfStaticTopic());
  refused += TryEndpoint(participant, !out, CommandTopic(station));
  return refused;
}

// The permissions template lists topics explicitly; this catches a topic
// added to topics.h but not to systemd/security/permissions.xml.
TEST_F(DdsSecurity, PermissionsCoverEveryStationTopic) {
  ASSERT_FALSE(temp_.path().empty());
  std::string pki;
  ASSERT_TRUE(StationPki(&pki));
  for (const std::string name : {"daemon", "console"}) {
    ParticipantOptions options;
    options.domain_id = ProcessDomainId();
    options.config = SecuredConfig(Identity(pki, name));
    std::string error;
    auto participant = Participant::Create(options, &error);
    ASSERT_TRUE(participant) << name << ": " << error << kSecuredHint;
    EXPECT_EQ(TryStationTopics(participant, station(), name == "daemon"), "") << name;
    // ...and nothing of another station.
    EXPECT_NE(TryEndpoint(participant, true, StatusTopic("other_station")), "") << name;
    EXPECT_NE(TryEndpoint(participant, false, StatusTopic("other_station")), "") << name;
  }
}

// The site (issue 21), with a site CA (--ca), --site and a --worker: each
// role may use its site topics in the site's partition and nothing more (a
// worker offers no job and reads no capture; no site topic in another
// site's partition), and the worker may `get` from any station.
TEST_F(DdsSecurity, SitePermissionsGiveEachRoleItsSiteTopicsOnly) {
  ASSERT_FALSE(temp_.path().empty());
  const std::string pki = temp_.path() + "/site", site = "museum";
  const ScriptRun made = RunSetup(pki, station(),
                                  {"--ca", temp_.path() + "/site-ca", "--site", site, "--client",
                                   "console", "--viewer", "recorder", "--worker", "w1"});
  ASSERT_EQ(made.exit_code, 0) << made.output;
  EXPECT_NE(ReadFile(Identity(pki, "w1") + "/permissions.xml").find("<grant name=\"worker\">"),
            std::string::npos);
  // role: {allowed, refused}, as "pub "/"sub " + topic + " " + partition.
  const auto try_all = [&](const std::shared_ptr<Participant>& p,
                           const std::vector<std::string>& which) {
    std::string refused;
    for (const std::string& w : which) {
      const std::size_t a = w.find(' '), b = w.rfind(' ');
      const bool pub = w.substr(0, a) == "pub";
      const std::string topic = w.substr(a + 1, b - a - 1), part = w.substr(b + 1);
      const std::string one = topic == "station"   ? TryEndpoint(p, pub, SiteStationTopic(part))
                              : topic == "worker"  ? TryEndpoint(p, pub, WorkerStatusTopic(part))
                              : topic == "job"     ? TryEndpoint(p, pub, JobOfferTopic(part))
                              : topic == "claim"   ? TryEndpoint(p, pub, JobClaimTopic(part))
                              : topic == "result"  ? TryEndpoint(p, pub, JobResultTopic(part))
                              : topic == "command" ? TryEndpoint(p, pub, CommandTopic(part))
                              : topic == "reply"   ? TryEndpoint(p, pub, ReplyTopic(part))
                              : topic == "file"    ? TryEndpoint(p, pub, FileTopic(part))
                              : topic == "status"  ? TryEndpoint(p, pub, StatusTopic(part))
                                                   : TryEndpoint(p, pub, CaptureTopic(part));
      refused += one.empty() ? "" : w + "\n";
    }
    return refused;
  };
  const std::string s = station(), other = "other_station", elsewhere = "elsewhere";
  struct Role {
    std::string identity;
    std::vector<std::string> allowed, refused;
  };
  const std::vector<Role> roles = {
      {"daemon",
       {"pub station " + site, "pub job " + site, "sub claim " + site, "sub result " + site,
        "sub worker " + site},
       {"pub station " + elsewhere, "pub job " + elsewhere, "pub worker " + site,
        "pub claim " + site, "pub result " + site, "sub job " + site}},
      {"console",
       {"sub station " + site, "sub worker " + site},
       {"sub station " + elsewhere, "sub job " + site, "sub claim " + site, "sub result " + site,
        "pub station " + site, "pub worker " + site}},
      {"recorder",
       {"sub station " + site, "sub worker " + site},
       {"pub command " + s, "pub worker " + site, "sub job " + site}},
      {"w1",
       {"pub worker " + site, "pub claim " + site, "pub result " + site, "sub job " + site,
        "pub command " + s, "pub command " + other, "sub reply " + s, "sub reply " + other,
        "sub file " + s, "sub file " + other},
       {"pub worker " + elsewhere, "pub claim " + elsewhere, "sub job " + elsewhere,
        "pub job " + site, "pub station " + site, "sub claim " + site, "sub result " + site,
        "sub worker " + site, "sub command " + s, "pub reply " + s, "pub file " + s,
        "sub status " + s, "sub capture " + s}},
  };
  for (const Role& role : roles) {
    ParticipantOptions options;
    options.domain_id = ProcessDomainId();
    options.config = SecuredConfig(Identity(pki, role.identity));
    std::string error;
    auto participant = Participant::Create(options, &error);
    ASSERT_TRUE(participant) << role.identity << ": " << error << kSecuredHint;
    EXPECT_EQ(try_all(participant, role.allowed), "") << role.identity << ": refused";
    std::string allowed;
    for (const std::string& w : role.refused)
      if (try_all(participant, {w}).empty()) allowed += w + "\n";
    EXPECT_EQ(allowed, "") << role.identity << ": allowed";
  }
  // A second station of the site reuses the site CA: its daemon's certificate
  // has the same issuer as w1's.
  const ScriptRun second = RunSetup(temp_.path() + "/second", "second_station",
                                    {"--ca", temp_.path() + "/site-ca", "--site", site});
  ASSERT_EQ(second.exit_code, 0) << second.output;
  EXPECT_EQ(ReadFile(temp_.path() + "/second/identities/daemon/ca.pem"),
            ReadFile(Identity(pki, "w1") + "/ca.pem"));
  EXPECT_FALSE(fs::exists(temp_.path() + "/second/ca"));
  // --force reissues identities but never replaces the site CA.
  const ScriptRun forced = RunSetup(temp_.path() + "/second", "second_station",
                                    {"--ca", temp_.path() + "/site-ca", "--site", site, "--force"});
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_EQ(ReadFile(temp_.path() + "/site-ca/ca.pem"), ReadFile(Identity(pki, "w1") + "/ca.pem"));
  // The site CA of another site is not taken for this one.
  const ScriptRun wrong = RunSetup(temp_.path() + "/third", "third_station",
                                   {"--ca", temp_.path() + "/site-ca", "--site", "another"});
  EXPECT_EQ(wrong.exit_code, 1) << wrong.output;
  EXPECT_NE(wrong.output.find("the CA of another site"), std::string::npos) << wrong.output;
}

// Control for the two tests above: without security on the daemon's side
// the same intruder peer reads status and its commands arrive, so their
// zero counts come from DDS Security, not from the harness.
TEST_F(DdsSecurity, WithoutSecurityTheSameIntruderGetsThrough) {
  std::string error;
  auto daemon = DaemonSide::Create(PlainConfig(), station(), &error);
  ASSERT_TRUE(daemon) << error;
  Peer intruder(temp_.path(), "intruder", PlainConfig(), station());
  ASSERT_TRUE(intruder.started());
  ASSERT_TRUE(daemon->WaitForCommandFrom("intruder", kTimeout));
  std::string expected_hash;  // and a capture, for the figure of the plain link
  ASSERT_TRUE(daemon->SendCapture(1, "not encrypted", &expected_hash));
  const auto report = intruder.Stop();
  SCOPED_TRACE("intruder: " + Describe(report));
  EXPECT_EQ(Text(report, "capture_hash"), expected_hash);
  EXPECT_GE(Number(report, "status"), 1);
  EXPECT_EQ(Number(report, "status_writers"), 1);
  EXPECT_EQ(Number(report, "command_readers"), 1);
}

// --- the setup script ---------------------------------------------------------

std::map<std::string, std::string> Snapshot(const std::string& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) files[entry.path().string()] = ReadFile(entry.path().string());
  }
  return files;
}

fs::perms Mode(const std::string& path) { return fs::status(path).permissions() & fs::perms::mask; }

TEST_F(DdsSecurity, SetupScriptIsIdempotentAndGuardsTheKeys) {
  ASSERT_FALSE(temp_.path().empty());
  const std::string pki = temp_.path() + "/pki";
  const ScriptRun first = RunSetup(pki, station(), {"--client", "console"});
  ASSERT_EQ(first.exit_code, 0) << first.output;
  const fs::perms owner_rw = fs::perms::owner_read | fs::perms::owner_write;
  for (const std::string& key : {pki + "/ca/ca.key", Identity(pki, "daemon") + "/key.pem",
                                 Identity(pki, "console") + "/key.pem"}) {
    ASSERT_TRUE(fs::exists(key)) << key;
    EXPECT_EQ(Mode(key), owner_rw) << key;
  }
  for (const std::string file : {"ca.pem", "cert.pem", "governance.p7s", "permissions.p7s",
                                 "cyclonedds-security.xml", "cyclonedds.xml"}) {
    EXPECT_TRUE(fs::exists(Identity(pki, "console") + "/" + file)) << file;
  }
  EXPECT_NE(ReadFile(Identity(pki, "console") + "/permissions.xml").find("<grant name=\"client\">"),
            std::string::npos);
  EXPECT_EQ(ReadFile(Identity(pki, "daemon") + "/permissions.xml").find("<grant name=\"client\">"),
            std::string::npos);
  const auto before = Snapshot(pki);

  // Same options again: nothing written, nothing changed.
  ScriptRun again = RunSetup(pki, station(), {"--client", "console"});
  EXPECT_EQ(again.exit_code, 0) << again.output;
  EXPECT_EQ(again.output.find("wrote"), std::string::npos) << again.output;
  EXPECT_EQ(again.output.find("signed"), std::string::npos) << again.output;
  EXPECT_TRUE(Snapshot(pki) == before);

  // A PKI of another station is not overwritten without --force.
  const ScriptRun other = RunSetup(pki, "another_station", {"--client", "console"});
  EXPECT_EQ(other.exit_code, 1) << other.output;
  EXPECT_NE(other.output.find("another station"), std::string::npos) << other.output;
  EXPECT_NE(other.output.find("--force"), std::string::npos) << other.output;
  EXPECT_TRUE(Snapshot(pki) == before);

  // With the CA key moved offline the CA is not silently replaced.
  fs::rename(pki + "/ca/ca.key", temp_.path() + "/ca.key.offline");
  const ScriptRun offline = RunSetup(pki, station(), {"--client", "console"});
  EXPECT_EQ(offline.exit_code, 1) << offline.output;
  EXPECT_NE(offline.output.find("ca.key is missing"), std::string::npos) << offline.output;
  fs::rename(temp_.path() + "/ca.key.offline", pki + "/ca/ca.key");

  // Bad input is refused before anything is touched.
  EXPECT_EQ(RunSetup(pki, "bad/station", {}).exit_code, 2);
  EXPECT_EQ(RunSetup(pki, station(), {"--client", "../escape"}).exit_code, 2);
  EXPECT_EQ(RunSetup(pki, station(), {"--client", "daemon"}).exit_code, 2);
  EXPECT_TRUE(Snapshot(pki) == before);

  // A new client is added without touching the others' keys.
  const ScriptRun added = RunSetup(pki, station(), {"--client", "console", "--client", "laptop"});
  EXPECT_EQ(added.exit_code, 0) << added.output;
  EXPECT_EQ(Mode(Identity(pki, "laptop") + "/key.pem"), owner_rw);
  const auto after_add = Snapshot(pki);
  for (const auto& [path, content] : before) {
    if (path == pki + "/ca/ca.srl") continue;  // the next serial number
    EXPECT_EQ(after_add.at(path), content) << path;
  }

  // --force makes a new CA and new keys.
  const ScriptRun forced = RunSetup(pki, station(), {"--client", "console", "--force"});
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_NE(ReadFile(pki + "/ca/ca.key"), before.at(pki + "/ca/ca.key"));
  EXPECT_NE(ReadFile(Identity(pki, "console") + "/key.pem"),
            before.at(Identity(pki, "console") + "/key.pem"));
  EXPECT_EQ(Mode(pki + "/ca/ca.key"), owner_rw);
  // laptop was not named: kept, and reported as issued by another CA.
  EXPECT_NE(forced.output.find("identities/laptop was issued by another CA"), std::string::npos)
      << forced.output;
}

}  // namespace
}  // namespace craftscan::dds
