// craftscan-worker's config (worker_config.h): a full file, every field's
// range named with its line, unknown keys and a missing version refused,
// environment overrides, the token file's rules, and the WorkerOptions made
// from it.
#include "worker_config.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>

#include "file_util.h"
#include "test_paths.h"

namespace craftscan::worker {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

using Env = std::map<std::string, std::string>;

// Every key, none at its default.
constexpr const char* kFullConfig = R"(version: 1
worker: gpu_box_2
site: museum-east
log_level: debug
dds:
  domain: 7
  config_file: /etc/craftscan/cyclonedds.xml
auth:
  token_file: /etc/craftscan/other.token
threads: 6
jobs: 3
work_dir: /srv/worker
watchdog:
  enabled: false
)";

std::string Parse(const std::string& text, WorkerConfig* config, const Env& env = {}) {
  std::string error;
  if (!ParseWorkerConfig(text, env, config, &error) && error.empty()) return "(no message)";
  return error;
}

// The error for `text` ("" if it parsed).
std::string ErrorFor(const std::string& text, const Env& env = {}) {
  WorkerConfig config;
  return Parse(text, &config, env);
}

TEST(WorkerConfig, ReadsEveryKey) {
  WorkerConfig c;
  ASSERT_EQ(Parse(kFullConfig, &c), "");
  EXPECT_EQ(c.worker, "gpu_box_2");
  EXPECT_EQ(c.site, "museum-east");
  EXPECT_EQ(c.log_level, WorkerLogLevel::kDebug);
  EXPECT_EQ(c.dds.domain, 7u);
  EXPECT_EQ(c.dds.config_file, "/etc/craftscan/cyclonedds.xml");
  EXPECT_EQ(c.auth.token_file, "/etc/craftscan/other.token");
  EXPECT_EQ(c.threads, 6);
  EXPECT_EQ(c.jobs, 3);
  EXPECT_EQ(c.work_dir, "/srv/worker");
  EXPECT_FALSE(c.watchdog.enabled);
}

TEST(WorkerConfig, OnlyVersionGivesTheDefaults) {
  WorkerConfig c;
  c.threads = 99;  // overwritten: a parse starts from the defaults
  ASSERT_EQ(Parse("version: 1\n", &c), "");
  EXPECT_EQ(c.worker, DefaultWorkerId());
  EXPECT_EQ(c.site, "default");
  EXPECT_EQ(c.log_level, WorkerLogLevel::kInfo);
  EXPECT_EQ(c.dds.domain, 0u);
  EXPECT_EQ(c.dds.config_file, "");
  EXPECT_EQ(c.auth.token_file, "/etc/craftscan/worker.token");
  EXPECT_EQ(c.threads, 2);
  EXPECT_EQ(c.jobs, 1);
  EXPECT_EQ(c.work_dir, "/var/lib/craftscan-worker");
  EXPECT_TRUE(c.watchdog.enabled);
  EXPECT_TRUE(c.IsValid(nullptr));
}

// The annotated example the package installs as
// /etc/craftscan/craftscan-worker.yaml: valid, and the defaults.
TEST(WorkerConfig, ShippedExampleIsValidAndHasTheDefaults) {
  const std::string text =
      testing::ReadFile(std::filesystem::path(testing::SystemdDir()) / "craftscan-worker.yaml");
  ASSERT_FALSE(text.empty());
  WorkerConfig shipped;
  ASSERT_EQ(Parse(text, &shipped), "");
  EXPECT_EQ(DumpWorkerConfig(shipped), DumpWorkerConfig(WorkerConfig()));
}

TEST(WorkerConfig, DefaultWorkerIdIsMadeValidFromAnyHostName) {
  EXPECT_EQ(WorkerIdForHost("scan-pc.museum.local"), "worker_scan_pc_museum_local");
  EXPECT_EQ(WorkerIdForHost("9box"), "worker_9box");
  EXPECT_EQ(WorkerIdForHost(""), "worker_");
  EXPECT_EQ(WorkerIdForHost(std::string(100, 'h')).size(), 64u);
  EXPECT_EQ(WorkerIdForHost("ünï"), "worker___n__");  // each UTF-8 byte
  WorkerOptions options;
  options.work_dir = "/w";
  for (const std::string& id : {WorkerIdForHost("a.b-c"), WorkerIdForHost(""), WorkerIdForHost("1"),
                                WorkerIdForHost(std::string(300, '.')), DefaultWorkerId()}) {
    options.worker_id = id;
    std::string why;
    EXPECT_TRUE(options.IsValid(&why)) << id << ": " << why;
  }
}

struct BadField {
  std::string yaml;      // the whole file
  std::string expected;  // in the message: field, problem and line
};

class WorkerConfigBadField : public ::testing::TestWithParam<BadField> {};

TEST_P(WorkerConfigBadField, IsRefusedNamingTheFieldAndLine) {
  const std::string error = ErrorFor(GetParam().yaml);
  EXPECT_THAT(error, HasSubstr(GetParam().expected)) << GetParam().yaml;
}

INSTANTIATE_TEST_SUITE_P(
    EveryField, WorkerConfigBadField,
    ::testing::Values(
        BadField{"version: 1\nworker: 9lives\n",
                 "worker: worker id '9lives': must start with a letter"},
        BadField{"version: 1\nworker: a.b\n", "(line 2)"},
        BadField{"version: 1\n\nsite: a/b\n", "site: must be 1 to 64 characters"},
        BadField{"version: 1\n\nsite: a/b\n", "got 'a/b' (line 3)"},
        BadField{"version: 1\nlog_level: loud\n",
                 "log_level: must be one of debug, info, warning, error; got 'loud' (line 2)"},
        BadField{"version: 1\ndds:\n  domain: 231\n",
                 "dds.domain: must be an integer in 0..230, got '231' (line 3)"},
        BadField{"version: 1\ndds:\n  domain: -1\n", "dds.domain: must be an integer in 0..230"},
        BadField{"version: 1\ndds:\n  domain: seven\n", "got 'seven' (line 3)"},
        BadField{"version: 1\ndds:\n  config_file: cyclone.xml\n",
                 "dds.config_file: must be an absolute path or \"\", got 'cyclone.xml' (line 3)"},
        BadField{"version: 1\nauth:\n  token_file: worker.token\n",
                 "auth.token_file: must be an absolute path, got 'worker.token' (line 3)"},
        BadField{"version: 1\nauth:\n  token_file:\n",
                 "auth.token_file: must be an absolute path, "
                 "got nothing (line 3)"},
        BadField{"version: 1\nthreads: 0\n",
                 "threads: must be an integer in 1..256, got '0' (line 2)"},
        BadField{"version: 1\nthreads: 257\n", "threads: must be an integer in 1..256, got '257'"},
        BadField{"version: 1\njobs: 17\n", "jobs: must be an integer in 1..16, got '17'"},
        BadField{"version: 1\nthreads: 2.5\n", "threads: must be an integer in 1..256, got '2.5'"},
        BadField{"version: 1\nwork_dir: scratch\n",
                 "work_dir: must be an absolute path, got 'scratch' (line 2)"},
        BadField{"version: 1\nwatchdog:\n  enabled: maybe\n",
                 "watchdog.enabled: must be true or false, got 'maybe' (line 3)"},
        BadField{"version: 1\nthreads: [1, 2]\n", "threads: must be a single value, not a list"},
        BadField{"version: 1\ndds: 3\n",
                 "dds: must be a mapping of keys (known in dds: domain, "
                 "config_file) (line 2)"},
        BadField{"version: 1\nthreads: 2\nthreads: 3\n",
                 "threads: given more than once (line 3)"}));

TEST(WorkerConfig, UnknownKeysAreRefusedWithTheirPath) {
  EXPECT_THAT(ErrorFor("version: 1\nworkers: 2\n"),
              AllOf(HasSubstr("workers: unknown key (known: version, worker, site, log_level, "
                              "dds, auth, threads, jobs, work_dir, watchdog)"),
                    HasSubstr("(line 2)")));
  EXPECT_THAT(ErrorFor("version: 1\ndds:\n  domain: 1\n  domian: 2\n"),
              AllOf(HasSubstr("dds.domian: unknown key (known in dds: domain, config_file)"),
                    HasSubstr("(line 4)")));
  // A station's key in the worker's file.
  EXPECT_THAT(ErrorFor("version: 1\nstation: st1\n"), HasSubstr("station: unknown key"));
}

TEST(WorkerConfig, VersionIsRequiredAndChecked) {
  EXPECT_THAT(ErrorFor("threads: 2\n"), HasSubstr("version: missing; add 'version: 1'"));
  EXPECT_THAT(ErrorFor("version: 2\nthreads: 2\n"),
              AllOf(HasSubstr("version: 2 is not supported; this craftscan-worker reads config "
                              "version 1"),
                    HasSubstr("(line 1)")));
  EXPECT_THAT(ErrorFor("version: one\n"), HasSubstr("version: must be an integer"));
  EXPECT_THAT(ErrorFor(""), HasSubstr("empty configuration"));
  EXPECT_THAT(ErrorFor("- version\n"), HasSubstr("must be a mapping of keys"));
  EXPECT_THAT(ErrorFor("version: 1\n---\nversion: 1\n"), HasSubstr("one YAML document, found 2"));
  EXPECT_THAT(ErrorFor("version: 1\nthreads: [\n"), HasSubstr("YAML syntax error at line"));
  // yaml-cpp 0.7 would loop forever on this (yaml_document.h).
  EXPECT_NE(ErrorFor(","), "");
}

TEST(WorkerConfig, EnvironmentOverridesTheFile) {
  WorkerConfig c;
  ASSERT_EQ(Parse(kFullConfig, &c,
                  {{"CRAFTSCAN_WORKER_THREADS", "3"},
                   {"CRAFTSCAN_WORKER_DDS_DOMAIN", "12"},
                   {"CRAFTSCAN_WORKER_WORKER", "night_shift"},
                   {"CRAFTSCAN_WORKER_WATCHDOG_ENABLED", "true"},
                   {"CRAFTSCAN_WORKER_AUTH_TOKEN_FILE", "/run/secrets/token"},
                   // craftscand's variables are not the worker's.
                   {"CRAFTSCAN_PIPELINE_THREADS", "9"},
                   {"CRAFTSCAN_SITE", "elsewhere"}}),
            "");
  EXPECT_EQ(c.threads, 3);
  EXPECT_EQ(c.dds.domain, 12u);
  EXPECT_EQ(c.worker, "night_shift");
  EXPECT_TRUE(c.watchdog.enabled);
  EXPECT_EQ(c.auth.token_file, "/run/secrets/token");
  EXPECT_EQ(c.site, "museum-east");
}

TEST(WorkerConfig, BadEnvironmentValueNamesTheVariable) {
  EXPECT_EQ(ErrorFor("version: 1\n", {{"CRAFTSCAN_WORKER_THREADS", "0"}}),
            "CRAFTSCAN_WORKER_THREADS: threads: must be an integer in 1..256, got '0'");
  EXPECT_THAT(ErrorFor("version: 1\n", {{"CRAFTSCAN_WORKER_SITE", ""}}),
              HasSubstr("CRAFTSCAN_WORKER_SITE: site: must be"));
}

TEST(WorkerConfig, EnvironmentVariablesFollowTheKeyPaths) {
  EXPECT_THAT(
      WorkerEnvironmentVariables(),
      ::testing::ElementsAre("CRAFTSCAN_WORKER_WORKER", "CRAFTSCAN_WORKER_SITE",
                             "CRAFTSCAN_WORKER_LOG_LEVEL", "CRAFTSCAN_WORKER_DDS_DOMAIN",
                             "CRAFTSCAN_WORKER_DDS_CONFIG_FILE", "CRAFTSCAN_WORKER_AUTH_TOKEN_FILE",
                             "CRAFTSCAN_WORKER_THREADS", "CRAFTSCAN_WORKER_JOBS",
                             "CRAFTSCAN_WORKER_WORK_DIR", "CRAFTSCAN_WORKER_WATCHDOG_ENABLED"));
}

TEST(WorkerConfig, DumpReadsBackTheSame) {
  WorkerConfig c;
  ASSERT_EQ(Parse(kFullConfig, &c), "");
  const std::string dump = DumpWorkerConfig(c);
  EXPECT_THAT(dump,
              HasSubstr("dds:\n  domain: 7\n  config_file: \"/etc/craftscan/cyclonedds.xml\""));
  WorkerConfig again;
  ASSERT_EQ(Parse(dump, &again), "") << dump;
  EXPECT_EQ(DumpWorkerConfig(again), dump);
  EXPECT_EQ(again.worker, "gpu_box_2");
  EXPECT_FALSE(again.watchdog.enabled);
}

TEST(WorkerConfig, IsValidNamesTheField) {
  WorkerConfig c;
  std::string why;
  ASSERT_TRUE(c.IsValid(&why)) << why;
  c.threads = 0;
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_EQ(why, "threads: must be an integer in 1..256, got '0'");
  c = WorkerConfig();
  c.dds.domain = 500;
  EXPECT_FALSE(c.IsValid(&why));
  EXPECT_THAT(why, HasSubstr("dds.domain: must be an integer in 0..230, got '500'"));
}

// A fresh folder per test for token files.
class WorkerToken : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("craftscan_test_worker_token_" + std::to_string(std::random_device{}()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& text, mode_t mode = 0600) {
    const std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << text;
    ::chmod(path.c_str(), mode);
    return path;
  }

  std::string TokenError(const std::string& path) {
    std::string token, error;
    if (ReadWorkerToken(path, &token, &error)) return "read '" + token + "'";
    return error;
  }

  fs::path dir_;
};

TEST_F(WorkerToken, FirstLineIsTheToken) {
  std::string token, error;
  ASSERT_TRUE(ReadWorkerToken(Write("t", "s3cret-worker \r\nsecond line\n"), &token, &error))
      << error;
  EXPECT_EQ(token, "s3cret-worker");
  ASSERT_TRUE(ReadWorkerToken(Write("u", "no-newline", 0400), &token, &error)) << error;
  EXPECT_EQ(token, "no-newline");
}

TEST_F(WorkerToken, MissingFileIsNamed) {
  const std::string path = (dir_ / "absent.token").string();
  EXPECT_EQ(TokenError(path),
            "auth.token_file: " + path + ": cannot open: No such file or directory");
}

TEST_F(WorkerToken, EmptyFileOrFirstLineIsRefused) {
  const std::string empty = Write("empty", "");
  EXPECT_EQ(TokenError(empty), "auth.token_file: " + empty +
                                   ": the first line is empty; put the worker's token there");
  EXPECT_THAT(TokenError(Write("blank", "  \ntoken-on-line-2\n")),
              HasSubstr("the first line is empty"));
}

TEST_F(WorkerToken, ReadableByOthersIsRefused) {
  const std::string path = Write("open", "token\n", 0644);
  EXPECT_THAT(TokenError(path), AllOf(HasSubstr("auth.token_file: " + path + ": mode 0644"),
                                      HasSubstr("group or others"), HasSubstr("chmod 0600")));
  EXPECT_THAT(TokenError(Write("group", "token\n", 0640)), HasSubstr("mode 0640"));
}

TEST_F(WorkerToken, TooLongOrControlCharactersAreRefused) {
  EXPECT_EQ(TokenError(Write("ok", std::string(128, 'k') + "\n")),
            "read '" + std::string(128, 'k') + "'");
  EXPECT_THAT(TokenError(Write("long", std::string(129, 'k'))),
              HasSubstr("the token is longer than 128 bytes"));
  EXPECT_THAT(TokenError(Write("ctl", std::string("to\x01ken\n"))),
              HasSubstr("the token has a control character"));
  EXPECT_THAT(TokenError(dir_.string()), HasSubstr("not a regular file"));
}

TEST_F(WorkerToken, OptionsComeFromTheConfig) {
  WorkerConfig c;
  ASSERT_EQ(Parse(kFullConfig, &c), "");
  c.auth.token_file = Write("worker.token", "tok-123\n");
  c.dds.config_file = Write("cyclonedds.xml", "<CycloneDDS/>\n", 0644);
  WorkerOptions options;
  std::string error;
  ASSERT_TRUE(MakeWorkerOptions(c, &options, &error)) << error;
  EXPECT_EQ(options.worker_id, "gpu_box_2");
  EXPECT_EQ(options.site, "museum-east");
  EXPECT_EQ(options.domain, 7u);
  EXPECT_EQ(options.dds_config, "file://" + c.dds.config_file);
  EXPECT_EQ(options.token, "tok-123");
  EXPECT_EQ(options.threads, 6);
  EXPECT_EQ(options.work_dir, "/srv/worker");
  // A Cyclone file that is not there is named (Cyclone would not say which).
  const std::string given = c.dds.config_file;
  c.dds.config_file = (dir_ / "absent.xml").string();
  EXPECT_FALSE(MakeWorkerOptions(c, &options, &error));
  EXPECT_EQ(error,
            "dds.config_file: " + c.dds.config_file + ": cannot read: No such file or directory");
  EXPECT_EQ(options.dds_config, "file://" + given);  // untouched
  // No Cyclone file: CYCLONEDDS_URI decides.
  c.dds.config_file.clear();
  ASSERT_TRUE(MakeWorkerOptions(c, &options, &error)) << error;
  EXPECT_EQ(options.dds_config, "");
  // A token problem fails the options.
  c.auth.token_file = (dir_ / "none").string();
  WorkerOptions untouched;
  EXPECT_FALSE(MakeWorkerOptions(c, &untouched, &error));
  EXPECT_THAT(error, HasSubstr("auth.token_file: " + c.auth.token_file + ": cannot open"));
  EXPECT_EQ(untouched.token, "");
}

TEST(WorkerOptions, IsValidNamesTheField) {
  WorkerOptions o;
  o.worker_id = "w1";
  o.work_dir = "/tmp/w";
  std::string why;
  ASSERT_TRUE(o.IsValid(&why)) << why;
  auto bad = [&](auto change) {
    WorkerOptions copy = o;
    change(copy);
    std::string message;
    EXPECT_FALSE(copy.IsValid(&message));
    return message;
  };
  EXPECT_THAT(bad([](WorkerOptions& x) { x.worker_id = ""; }), HasSubstr("worker: "));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.site = "a b"; }), HasSubstr("site: "));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.domain = 231; }), HasSubstr("domain: must be 0..230"));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.threads = 0; }), HasSubstr("threads: must be 1..256"));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.threads = 257; }), HasSubstr("threads"));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.work_dir = "rel"; }),
              HasSubstr("work_dir: must be an absolute path"));
  EXPECT_THAT(bad([](WorkerOptions& x) { x.token = std::string(129, 't'); }),
              HasSubstr("token: longer than 128 bytes"));
}

}  // namespace
}  // namespace craftscan::worker
