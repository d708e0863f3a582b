// Bad input over DDS (issue 8): the real craftscand on the sim station gets
// Command samples written straight to its command topic — malformed,
// oversized, out of range, unauthorised, and a flood from three writers —
// and must answer each one it answers with the right code, never crash or
// stall, and keep its memory bounded.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <dds/dds.h>
#include <dds/ddsi/ddsi_serdata.h>
#include <dds/ddsi/ddsi_serdata_default.h>
#include <nlohmann/json.hpp>

#include "craftscan/daemon/commands.h"
#include "daemon_fixture.h"
#include "daemon_probe.h"
#include "station_client.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using daemon::ReplyCode;
using Clock = std::chrono::steady_clock;

constexpr std::size_t kFieldLimit = 128;  // CommandLimits::max_field_bytes
const std::string kUnknownSession = "20260101-000000-nothing";

// The daemon, a StationClient (which creates this process's DDS domain), a
// raw command writer, a reply collector and a StationStatus monitor.
struct Station {
  DaemonFixture fixture{"320x256"};
  StationClient client;
  std::unique_ptr<CommandPeer> peer;
  std::unique_ptr<ReplyCollector> replies;
  std::unique_ptr<StatusMonitor> status;
};

std::unique_ptr<Station> StartStation() {
  auto s = std::make_unique<Station>();
  s->fixture.pipeline_extra = ", mesh: false";
  std::string error;
  if (!s->fixture.Prepare(&error) || !s->fixture.Start(&error) ||
      !s->client.Start(s->fixture.domain(), s->fixture.dds_config(), s->fixture.station(),
                       &error) ||
      !(s->peer = CommandPeer::Create(s->fixture.domain(), s->fixture.station(), &error)) ||
      !(s->replies = ReplyCollector::Create(s->fixture.domain(), s->fixture.station(), &error)) ||
      !(s->status = StatusMonitor::Create(s->fixture.domain(), s->fixture.station(), &error))) {
    ADD_FAILURE() << error;
    return nullptr;
  }
  if (!s->client.WaitForDaemon(30s) || !s->peer->WaitForDaemon(30s) ||
      !s->replies->WaitForDaemon(30s)) {
    ADD_FAILURE() << "the daemon's command reader or reply writer never matched; log:\n"
                  << s->fixture.Log();
    return nullptr;
  }
  return s;
}

// Writes `command` and waits for its reply (matched on the request id and
// client as the daemon echoes them: cut to kFieldLimit bytes).
std::optional<RawReply> Call(Station& s, const RawCommand& command,
                             std::chrono::milliseconds timeout = 20s) {
  std::string error;
  if (!s.peer->Write(command, &error)) {
    ADD_FAILURE() << "write: " << error;
    return std::nullopt;
  }
  return s.replies->WaitFor(command.request_id.substr(0, kFieldLimit),
                            command.client.substr(0, kFieldLimit), timeout);
}

// The last 4000 bytes of the daemon's log.
std::string LogTail(const DaemonFixture& fixture) {
  const std::string log = fixture.Log();
  return log.substr(log.size() > 4000 ? log.size() - 4000 : 0);
}

// A status request answered ok: the daemon still serves.
void ExpectServing(Station& s, const std::string& id, std::chrono::milliseconds timeout = 5s) {
  const auto reply = Call(s, {id, "probe", kObserverToken, "status", ""}, timeout);
  ASSERT_TRUE(reply) << "no reply to status within " << timeout.count() << " ms; log tail:\n"
                     << LogTail(s.fixture);
  EXPECT_EQ(reply->code_name, "ok") << reply->message;
}

std::string Json(const nlohmann::json& j) { return j.dump(); }

struct Case {
  std::string what;
  RawCommand command;
  ReplyCode code;
  std::string mention = "";  // the message must contain this
};

// Everything a confused or hostile client may send that fits in one sample
// of ordinary size. Request ids are the case index; the client names it.
std::vector<Case> MalformedCases() {
  const std::string obs = kObserverToken, op = kOperatorToken, adm = kAdminToken;
  const nlohmann::json session = kUnknownSession;
  auto c = [](std::string token, std::string verb, std::string args) {
    return RawCommand{"", "", std::move(token), std::move(verb), std::move(args)};
  };
  std::vector<Case> cases = {
      // Broken JSON and JSON that is not an object.
      {"unterminated object", c(op, "scan", "{\"views\": 6"), ReplyCode::kBadRequest, "JSON"},
      {"unquoted key", c(op, "scan", "{views: 6}"), ReplyCode::kBadRequest},
      {"trailing garbage", c(obs, "status", "{}}"), ReplyCode::kBadRequest},
      {"blank arguments", c(obs, "status", "   "), ReplyCode::kBadRequest},
      {"array", c(obs, "status", "[]"), ReplyCode::kBadRequest, "object"},
      {"string", c(obs, "status", "\"status\""), ReplyCode::kBadRequest},
      {"number", c(obs, "status", "42"), ReplyCode::kBadRequest},
      {"null", c(obs, "status", "null"), ReplyCode::kBadRequest},
      {"overflowing number", c(op, "scan", "{\"step_deg\": 1e999}"), ReplyCode::kBadRequest},
      {"bad escape", c(op, "scan", "{\"object\": \"\\x41\"}"), ReplyCode::kBadRequest},
      {"lone surrogate", c(op, "scan", "{\"object\": \"\\ud800\"}"), ReplyCode::kBadRequest},
      {"60000 unclosed brackets", c(obs, "status", std::string(60000, '[')),
       ReplyCode::kBadRequest},
      {"30000 nested arrays",
       c(obs, "status", "{\"a\":" + std::string(30000, '[') + std::string(30000, ']') + "}"),
       ReplyCode::kBadArgument, "'a'"},
      {"duplicate key", c(obs, "status", "{\"a\":1,\"a\":2}"), ReplyCode::kBadArgument},
      {"JSON before the token", c("no-such-token", "scan", "{"), ReplyCode::kBadRequest},
      // Invalid UTF-8 and NUL bytes.
      {"invalid UTF-8 in a JSON string", c(op, "scan", "{\"object\": \"\xff\xfe\"}"),
       ReplyCode::kBadRequest},
      {"invalid UTF-8 as arguments", c(obs, "status", "\xc3\x28"), ReplyCode::kBadRequest},
      {"invalid UTF-8 verb", c(obs, "\xc3\x28\xff", ""), ReplyCode::kUnknownVerb},
      {"invalid UTF-8 token", c("\xff\xfe\xfd", "status", ""), ReplyCode::kUnauthenticated},
      {"escaped NUL in a session id", c(obs, "get", "{\"session\": \"20260101-000000-a\\u0000b\"}"),
       ReplyCode::kBadArgument, "session"},
      // A NUL ends a DDS string at the writer: the daemon sees "" and "{".
      {"NUL-first verb", c(obs, std::string("\0status", 7), ""), ReplyCode::kUnknownVerb},
      {"NUL inside arguments", c(obs, "status", std::string("{\0}", 3)), ReplyCode::kBadRequest},
      // Empty verb and token.
      {"empty verb", c(obs, "", ""), ReplyCode::kUnknownVerb},
      {"empty token", c("", "status", ""), ReplyCode::kUnauthenticated},
      {"empty token and verb", c("", "", ""), ReplyCode::kUnauthenticated},
      // Unknown tokens and verbs; roles.
      {"random token", c("e3b0c44298fc1c149afbf4c8996fb924", "status", ""),
       ReplyCode::kUnauthenticated},
      {"token with a trailing space", c(obs + " ", "status", ""), ReplyCode::kUnauthenticated},
      {"token prefix", c(obs.substr(0, obs.size() - 1), "status", ""), ReplyCode::kUnauthenticated},
      {"token of 128 bytes", c(std::string(128, 'a'), "status", ""), ReplyCode::kUnauthenticated},
      {"upper-case verb", c(obs, "STATUS", ""), ReplyCode::kUnknownVerb},
      {"verb with a space", c(obs, "status ", ""), ReplyCode::kUnknownVerb},
      {"shell in the verb", c(adm, "scan;rm -rf /", ""), ReplyCode::kUnknownVerb},
      {"observer scans", c(obs, "scan", ""), ReplyCode::kForbidden, "operator"},
      {"observer moves the turntable", c(obs, "turntable", Json({{"action", "home"}})),
       ReplyCode::kForbidden},
      {"operator calibrates", c(op, "calibrate", ""), ReplyCode::kForbidden, "admin"},
      // Wrong types.
      {"views as a string", c(op, "scan", Json({{"views", "six"}})), ReplyCode::kBadArgument,
       "views"},
      {"views as a fraction", c(op, "scan", Json({{"views", 6.5}})), ReplyCode::kBadArgument,
       "views"},
      {"views as a bool", c(op, "scan", Json({{"views", true}})), ReplyCode::kBadArgument, "views"},
      {"views null", c(op, "scan", Json({{"views", nullptr}})), ReplyCode::kBadArgument, "views"},
      {"object as a number", c(op, "scan", Json({{"object", 5}})), ReplyCode::kBadArgument,
       "object"},
      {"object as a list", c(op, "scan", Json({{"object", {"a"}}})), ReplyCode::kBadArgument,
       "object"},
      {"step as a string", c(op, "scan", Json({{"step_deg", "60"}})), ReplyCode::kBadArgument,
       "step_deg"},
      {"session as a number", c(obs, "get", Json({{"session", 7}})), ReplyCode::kBadArgument,
       "session"},
      {"files as a number", c(obs, "get", Json({{"session", session}, {"files", 5}})),
       ReplyCode::kBadArgument, "files"},
      {"files of numbers", c(obs, "get", Json({{"session", session}, {"files", {1, 2}}})),
       ReplyCode::kBadArgument, "files"},
      {"chunk as a string", c(obs, "get", Json({{"session", session}, {"chunk_bytes", "big"}})),
       ReplyCode::kBadArgument, "chunk_bytes"},
      {"action as a bool", c(op, "turntable", Json({{"action", true}})), ReplyCode::kBadArgument,
       "action"},
      {"gain as a string", c(op, "camera", Json({{"gain_db", "3"}})), ReplyCode::kBadArgument,
       "gain_db"},
      {"unknown key", c(op, "scan", Json({{"colour", "red"}})), ReplyCode::kBadArgument, "colour"},
      {"arguments to a verb without any", c(obs, "status", Json({{"verbose", true}})),
       ReplyCode::kBadArgument, "verbose"},
      // Missing arguments.
      {"get without session", c(obs, "get", "{}"), ReplyCode::kBadArgument, "session"},
      {"resume without session", c(op, "resume", ""), ReplyCode::kBadArgument, "session"},
      {"turntable without action", c(op, "turntable", "{}"), ReplyCode::kBadArgument, "action"},
      {"move without angle", c(op, "turntable", Json({{"action", "move"}})),
       ReplyCode::kBadArgument, "angle_deg"},
      // Out of range.
      {"one view", c(op, "scan", Json({{"views", 1}})), ReplyCode::kBadArgument, "views"},
      {"zero views", c(op, "scan", Json({{"views", 0}})), ReplyCode::kBadArgument, "views"},
      {"negative views", c(op, "scan", Json({{"views", -6}})), ReplyCode::kBadArgument, "views"},
      {"361 views", c(op, "scan", Json({{"views", 361}})), ReplyCode::kBadArgument, "views"},
      {"2^63 views", c(op, "scan", "{\"views\": 9223372036854775808}"), ReplyCode::kBadArgument,
       "views"},
      {"1e300 views", c(op, "scan", "{\"views\": 1e300}"), ReplyCode::kBadArgument, "views"},
      {"step over a turn", c(op, "scan", Json({{"step_deg", 360.001}})), ReplyCode::kBadArgument,
       "step_deg"},
      {"step -1e308", c(op, "scan", Json({{"step_deg", -1e308}})), ReplyCode::kBadArgument,
       "step_deg"},
      {"zero exposure", c(op, "camera", Json({{"exposure_us", 0}})), ReplyCode::kBadArgument,
       "exposure_us"},
      {"exposure over 10 s", c(op, "camera", Json({{"exposure_us", 10000001}})),
       ReplyCode::kBadArgument, "exposure_us"},
      {"negative gain", c(op, "camera", Json({{"gain_db", -0.5}})), ReplyCode::kBadArgument,
       "gain_db"},
      {"gain over 48 dB", c(op, "camera", Json({{"gain_db", 48.5}})), ReplyCode::kBadArgument,
       "gain_db"},
      {"chunk below 4 KiB", c(obs, "get", Json({{"session", session}, {"chunk_bytes", 4095}})),
       ReplyCode::kBadArgument, "chunk_bytes"},
      {"chunk above 4 MiB", c(obs, "get", Json({{"session", session}, {"chunk_bytes", 4194305}})),
       ReplyCode::kBadArgument, "chunk_bytes"},
      {"angle past ten turns",
       c(op, "turntable", Json({{"action", "move"}, {"angle_deg", 3600.5}})),
       ReplyCode::kBadArgument, "angle_deg"},
      {"empty object name", c(op, "scan", Json({{"object", ""}})), ReplyCode::kBadArgument,
       "object"},
      {"object name of 129 bytes", c(op, "scan", Json({{"object", std::string(129, 'o')}})),
       ReplyCode::kBadArgument, "object"},
      {"no files", c(obs, "get", Json({{"session", session}, {"files", nlohmann::json::array()}})),
       ReplyCode::kBadArgument, "files"},
      {"257 files",
       c(obs, "get",
         Json({{"session", session}, {"files", std::vector<std::string>(257, "fused.ply")}})),
       ReplyCode::kBadArgument, "files"},
      {"file outside the session",
       c(obs, "get", Json({{"session", session}, {"files", {"../tokens.yaml"}}})),
       ReplyCode::kBadArgument, "files"},
      {"session traversal", c(op, "resume", Json({{"session", "../../etc"}})),
       ReplyCode::kBadArgument, "session"},
      {"unknown action", c(op, "turntable", Json({{"action", "spin"}})), ReplyCode::kBadArgument,
       "action"},
      // Well formed, but nothing to act on.
      {"unknown session", c(obs, "get", Json({{"session", session}})), ReplyCode::kNotFound},
      {"files of an unknown session", c(obs, "get", Json({{"session", session}, {"files", "all"}})),
       ReplyCode::kNotFound},
      {"resume an unknown session", c(op, "resume", Json({{"session", session}})),
       ReplyCode::kNotFound},
      {"cancel without a job", c(op, "cancel", ""), ReplyCode::kFailed},
      // Field sizes at and past the limit.
      {"verb of 129 bytes", c(obs, std::string(129, 'v'), ""), ReplyCode::kTooLarge, "128"},
      {"token of 129 bytes", c(std::string(129, 't'), "status", ""), ReplyCode::kTooLarge, "128"},
      {"arguments of 70000 bytes", c(op, "scan", Json({{"object", std::string(70000, 'x')}})),
       ReplyCode::kTooLarge, "65536"},
      // Answered: odd but valid.
      {"arguments of exactly {}", c(obs, "status", "{}"), ReplyCode::kOk},
      {"whitespace around {}", c(obs, "status", " \n{ }\t"), ReplyCode::kOk},
  };
  for (std::size_t i = 0; i < cases.size(); ++i) {
    cases[i].command.request_id = "m" + std::to_string(i);
    cases[i].command.client = "abuse-" + std::to_string(i);
  }
  // Odd ids and client names: the daemon echoes them as they are.
  cases.push_back({"invalid UTF-8 request id and client",
                   {"id-\xff\xfe", "client-\xc3\x28", obs, "status", ""},
                   ReplyCode::kOk});
  cases.push_back({"request id of 128 bytes",
                   {std::string(128, 'r'), "abuse-128", obs, "status", ""},
                   ReplyCode::kOk});
  cases.push_back({"request id of 129 bytes",
                   {std::string(129, 'q'), "abuse-129", obs, "status", ""},
                   ReplyCode::kTooLarge});
  cases.push_back({"client of 129 bytes",
                   {"c129", std::string(129, 'c'), obs, "status", ""},
                   ReplyCode::kTooLarge});
  cases.push_back({"empty request id",
                   {"", "abuse-empty-id", obs, "status", ""},
                   ReplyCode::kBadRequest,
                   "request_id"});
  return cases;
}

TEST(DaemonAbuse, MalformedCommandsGetTheRightCodeAndTheDaemonKeepsServing) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  const std::vector<Case> cases = MalformedCases();
  for (const Case& k : cases) {
    SCOPED_TRACE(k.what);
    const auto reply = Call(*s, k.command);
    ASSERT_TRUE(reply) << "no reply; log tail:\n" << LogTail(s->fixture);
    EXPECT_EQ(reply->code_name, daemon::ToString(k.code)) << reply->message;
    EXPECT_EQ(reply->code, static_cast<std::int32_t>(k.code));
    if (k.code != ReplyCode::kOk) {
      EXPECT_FALSE(reply->message.empty());
    }
    EXPECT_NE(reply->message.find(k.mention), std::string::npos) << reply->message;
    EXPECT_TRUE(nlohmann::json::accept(reply->result)) << reply->result.substr(0, 200);
  }
  // A Command with every string null (as a careless C client may write).
  std::string error;
  ASSERT_TRUE(s->peer->WriteEmpty(&error)) << error;
  const auto empty = s->replies->WaitFor("", "", 20s);
  ASSERT_TRUE(empty);
  EXPECT_EQ(empty->code_name, "bad_request") << empty->message;

  ExpectServing(*s, "after-malformed");
  // Nothing was started and nothing stored.
  const auto sessions = s->client.Send("sessions", nullptr, kObserverToken);
  ASSERT_TRUE(sessions);
  EXPECT_EQ(sessions->result["sessions"].size(), 0u);
  std::printf("FIGURE abuse_malformed_cases %zu\n", cases.size() + 1);
}

TEST(DaemonAbuse, OversizedFieldsAreRefusedWithoutUnboundedMemory) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  ExpectServing(*s, "warm-up");
  const ProcFigures before = ReadProcFigures(s->fixture.pid());
  const auto start = Clock::now();
  ASSERT_GT(before.rss_kb, 0);
  const std::string mb(1 << 20, 'x'), mb16(16 << 20, 'y');
  struct Big {
    std::string what;
    RawCommand command;
  };
  // The IDL's strings are unbounded, so each of these reaches the daemon:
  // first fields of up to 16 MB, then one sample of 5 x 16 MB.
  const std::vector<Big> cases = {
      {"1 MB arguments",
       {"big-args-1", "abuse", kOperatorToken, "scan", "{\"object\": \"" + mb + "\"}"}},
      {"16 MB arguments", {"big-args-16", "abuse", kOperatorToken, "scan", mb16}},
      {"1 MB request id", {"big-id-" + mb, "abuse", kObserverToken, "status", ""}},
      {"16 MB client name", {"big-client", "big-client-" + mb16, kObserverToken, "status", ""}},
      {"1 MB token", {"big-token", "abuse", mb, "status", ""}},
      {"1 MB verb", {"big-verb", "abuse", kObserverToken, mb, ""}},
      {"16 MB of everything", {mb16, mb16, mb16, mb16, mb16}},
  };
  ProcFigures after_16mb;
  for (const Big& k : cases) {
    SCOPED_TRACE(k.what);
    if (k.command.request_id.size() == mb16.size()) after_16mb = ReadProcFigures(s->fixture.pid());
    const auto start = Clock::now();
    const auto reply = Call(*s, k.command, 30s);
    ASSERT_TRUE(reply) << "no reply; log tail:\n" << LogTail(s->fixture);
    EXPECT_EQ(reply->code_name, "too_large") << reply->message;
    EXPECT_LE(reply->request_id.size(), kFieldLimit);
    EXPECT_LE(reply->client.size(), kFieldLimit);
    EXPECT_LE(reply->message.size(), 4096u);
    std::printf("FIGURE oversized '%s' answered in %.0f ms\n", k.what.c_str(),
                std::chrono::duration<double, std::milli>(Clock::now() - start).count());
    ExpectServing(*s, "after " + k.what);
  }
  const ProcFigures after = ReadProcFigures(s->fixture.pid());
  // StationStatus kept coming (every second) while the big samples arrived.
  const double gap_s = s->status->LongestGap(start, Clock::now()).count();
  std::printf("FIGURE oversized longest StationStatus gap %.2f s\n", gap_s);
  EXPECT_LT(gap_s, 5.0);
  const double peak_16mb = (after_16mb.hwm_kb - before.rss_kb) / 1024.0;
  const double peak_80mb = (after.hwm_kb - before.rss_kb) / 1024.0;
  const double kept_mb = (after.rss_kb - before.rss_kb) / 1024.0;
  std::printf(
      "FIGURE oversized rss before %.1f MB, after %.1f MB (kept %.1f MB); peak growth "
      "%.1f MB with samples up to 16 MB, %.1f MB with one of 80 MB\n",
      before.rss_kb / 1024.0, after.rss_kb / 1024.0, kept_mb, peak_16mb, peak_80mb);
  if (kSanitizedBuild) return;  // memory bounds do not apply there
  // The daemon takes one Command at a time and copies no oversized field;
  // Cyclone holds a sample up to three times while it arrives (fragments,
  // the serialised sample, the deserialised one). Bounds: four times the
  // largest sample plus 20 MB of slack (allocator arenas, DDS buffers).
  EXPECT_LT(peak_16mb, 4 * 16 + 20.0);
  EXPECT_LT(peak_80mb, 4 * 80 + 20.0);
  // Nothing of it stays: the daemon hands the buffers of a sample above
  // 1 MiB back to the system.
  EXPECT_LT(kept_mb, 20.0);
}

// The flood protection's parts, without a daemon (commands.h, "Floods").
TEST(CommandFloodLimits, TokenBucketRefillsAtItsRateUpToItsBurst) {
  const auto t0 = Clock::now();
  daemon::TokenBucket bucket(50, 100, t0);
  for (int i = 0; i < 100; ++i) ASSERT_TRUE(bucket.Take(t0)) << i;
  EXPECT_FALSE(bucket.Take(t0));
  EXPECT_FALSE(bucket.Take(t0 + 10ms));  // half a token
  EXPECT_TRUE(bucket.Take(t0 + 21ms));
  EXPECT_FALSE(bucket.Full(t0 + 1s));
  EXPECT_TRUE(bucket.Full(t0 + 3s));
  for (int i = 0; i < 100; ++i) ASSERT_TRUE(bucket.Take(t0 + 3s)) << i;  // never above the burst
  EXPECT_FALSE(bucket.Take(t0 + 3s));
}

TEST(CommandFloodLimits, RateLimiterKeepsClientsApartAndItsTableBounded) {
  daemon::CommandRateLimiter limiter;
  const auto t0 = Clock::now();
  int admitted = 0;
  for (int i = 0; i < 1000; ++i) admitted += limiter.Admit("chatty", t0 + i * 1ms);
  // The burst plus what one second at the rate refills.
  EXPECT_NEAR(admitted, daemon::kClientCommandBurst + daemon::kClientCommandsPerSecond, 2);
  EXPECT_TRUE(limiter.Admit("quiet", t0 + 1s));
  // Names beyond the table's size share one bucket...
  for (std::size_t i = 0; i < daemon::kMaxRateLimitedClients + 500; ++i) {
    limiter.Admit("name-" + std::to_string(i), t0 + 1s);
  }
  EXPECT_EQ(limiter.tracked_clients(), daemon::kMaxRateLimitedClients);
  EXPECT_FALSE(limiter.Admit("another-name", t0 + 1s));  // the shared bucket is spent
  // ...until the quiet ones are forgotten.
  EXPECT_TRUE(limiter.Admit("another-name", t0 + 10s));
  EXPECT_LT(limiter.tracked_clients(), 10u);
  const std::string message = daemon::CommandRateLimiter::RefusalMessage(std::string(300, 'c'));
  EXPECT_NE(message.find(std::string(128, 'c') + "'"), std::string::npos) << message;
}

// A command sent again under its request id gets the reply it had
// (ReplyMemory): by client, id and token, bounded, repeated a bounded number
// of times, and without the file transfer of the first reply.
TEST(ReplyMemory, ARepeatedRequestGetsItsReplyAndTheMemoryIsBounded) {
  daemon::ReplyMemory memory;
  const daemon::CommandRequest scan{"id-1", "client", kOperatorToken, "scan", "{}"};
  bool known = true;
  EXPECT_EQ(memory.Find(scan, &known), nullptr);
  EXPECT_FALSE(known);
  daemon::CommandReply reply;
  reply.request_id = "id-1";
  reply.client = "client";
  reply.code = ReplyCode::kOk;
  reply.message = "scan started as job-7";
  reply.transfer.emplace();
  memory.Remember(scan, reply);
  const daemon::CommandReply* again = memory.Find(scan, &known);
  ASSERT_NE(again, nullptr);
  EXPECT_TRUE(known);
  EXPECT_EQ(again->message, "scan started as job-7");
  EXPECT_EQ(again->code, ReplyCode::kOk);
  EXPECT_FALSE(again->transfer.has_value());
  // Another token, client or id is another command.
  daemon::CommandRequest other = scan;
  other.token = "someone-else";
  EXPECT_EQ(memory.Find(other), nullptr);
  other = scan;
  other.client = "client2";
  EXPECT_EQ(memory.Find(other), nullptr);
  other = scan;
  other.request_id = "id-2";
  EXPECT_EQ(memory.Find(other), nullptr);
  // No id, nothing remembered.
  other.request_id = "";
  memory.Remember(other, reply);
  EXPECT_EQ(memory.Find(other), nullptr);
  // Repeated at most kMaxReplyRepeats times (one repeat above), then dropped.
  for (int i = 1; i < daemon::kMaxReplyRepeats; ++i) ASSERT_NE(memory.Find(scan), nullptr) << i;
  EXPECT_EQ(memory.Find(scan, &known), nullptr);
  EXPECT_TRUE(known);
  // Bounded: the oldest are forgotten first.
  for (std::size_t i = 0; i < daemon::kRememberedReplies + 10; ++i) {
    daemon::CommandRequest r = scan;
    r.request_id = "bulk-" + std::to_string(i);
    memory.Remember(r, reply);
  }
  EXPECT_EQ(memory.size(), daemon::kRememberedReplies);
  daemon::CommandRequest oldest = scan, newest = scan;
  oldest.request_id = "bulk-0";
  newest.request_id = "bulk-" + std::to_string(daemon::kRememberedReplies + 9);
  EXPECT_EQ(memory.Find(oldest), nullptr);
  EXPECT_NE(memory.Find(newest), nullptr);
}

TEST(CommandFloodLimits, OversizedFieldsAreMeasuredNotCopied) {
  const daemon::CommandLimits limits;
  const std::string huge(16 << 20, 'x');
  const daemon::CommandRequest request =
      daemon::CutCommandRequest(huge, huge, huge, huge, huge, limits);
  EXPECT_EQ(request.request_id.size(), limits.max_field_bytes + 1);
  EXPECT_EQ(request.token.size(), limits.max_field_bytes + 1);
  EXPECT_EQ(request.arguments.size(), limits.max_argument_bytes + 1);
  EXPECT_EQ(request.received_arguments_bytes, huge.size());
  const daemon::CommandCheck check = daemon::CheckCommand(request, limits, nullptr);
  EXPECT_EQ(check.code, ReplyCode::kTooLarge);
  EXPECT_NE(check.message.find(std::to_string(huge.size()) + " bytes"), std::string::npos)
      << check.message;
  // Within the limits nothing is cut.
  const daemon::CommandRequest small = daemon::CutCommandRequest(
      "id", "client", "token", "status", std::string(limits.max_argument_bytes, ' '), limits);
  EXPECT_EQ(small.arguments.size(), limits.max_argument_bytes);
  EXPECT_EQ(small.received_arguments_bytes, 0u);
}

TEST(DaemonAbuse, AChattyClientIsToldToSlowDownAndOthersAreServed) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  int ok = 0, limited = 0;
  const auto start = Clock::now();
  for (int i = 0; i < 200; ++i) {
    const auto reply =
        Call(*s, {"chat-" + std::to_string(i), "chatty", kObserverToken, "status", ""});
    ASSERT_TRUE(reply) << i;
    if (reply->code_name == "ok") ++ok;
    if (reply->code_name == "busy") {
      ++limited;
      EXPECT_NE(reply->message.find("too many commands from client 'chatty'"), std::string::npos)
          << reply->message;
    }
  }
  const double elapsed_s = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf("FIGURE rate limit: 200 status requests in %.2f s, one at a time: %d ok, %d busy\n",
              elapsed_s, ok, limited);
  EXPECT_EQ(ok + limited, 200);
  EXPECT_GE(ok, static_cast<int>(daemon::kClientCommandBurst));
  EXPECT_LE(ok, static_cast<int>(daemon::kClientCommandBurst +
                                 daemon::kClientCommandsPerSecond * elapsed_s) +
                    1);
  ExpectServing(*s, "another client");
}

// A job command sent twice under one request id (a client whose first
// reply was lost sends it again) starts one job, and both copies are
// answered with the same reply; the job is not refused as busy by itself.
TEST(DaemonAbuse, ACommandSentAgainIsAnsweredAgainAndRunOnce) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  const RawCommand capture{"again-1", "repeater", kOperatorToken, "capture",
                           "{\"object\": \"twice\"}"};
  const auto first = Call(*s, capture);
  ASSERT_TRUE(first) << LogTail(s->fixture);
  ASSERT_EQ(first->code_name, "ok") << first->message;
  std::string error;
  ASSERT_TRUE(s->peer->Write(capture, &error)) << error;
  // The replies to "again-1" from "repeater", once `count` have come.
  auto copies = [&](std::size_t count) {
    std::vector<RawReply> found;
    const auto deadline = Clock::now() + 20s;
    while (Clock::now() < deadline && found.size() < count) {
      found.clear();
      for (const RawReply& r : s->replies->All()) {
        if (r.request_id == "again-1" && r.client == "repeater") found.push_back(r);
      }
      std::this_thread::sleep_for(50ms);
    }
    return found;
  };
  // Both replies carry the one job's id.
  std::vector<RawReply> replies = copies(2);
  ASSERT_EQ(replies.size(), 2u) << LogTail(s->fixture);
  EXPECT_EQ(replies[1].code_name, "ok") << replies[1].message;
  EXPECT_EQ(replies[1].message, replies[0].message);
  EXPECT_EQ(replies[1].result, replies[0].result);
  EXPECT_NE(replies[0].result.find("\"id\""), std::string::npos) << replies[0].result;
  // The same id with another token is a new command, checked as such.
  ASSERT_TRUE(
      s->peer->Write({"again-1", "repeater", "not-a-token-000000", "capture", "{}"}, &error))
      << error;
  replies = copies(3);
  ASSERT_EQ(replies.size(), 3u) << LogTail(s->fixture);
  EXPECT_EQ(replies[2].code_name, "unauthenticated") << replies[2].message;
  ExpectServing(*s, "after-repeats");
}

// The kinds of command in the flood, with the code each must get.
struct FloodKind {
  RawCommand command;  // request id and client are filled in per sample
  ReplyCode code;
};

std::vector<FloodKind> FloodKinds() {
  return {
      {{"", "", kObserverToken, "status", ""}, ReplyCode::kOk},
      {{"", "", kOperatorToken, "scan", "{\"views\": "}, ReplyCode::kBadRequest},
      {{"", "", "flood-token", "status", ""}, ReplyCode::kUnauthenticated},
      {{"", "", kObserverToken, "explode", ""}, ReplyCode::kUnknownVerb},
      {{"", "", kOperatorToken, "scan", "{\"views\": 1000}"}, ReplyCode::kBadArgument},
      {{"", "", kObserverToken, "calibrate", ""}, ReplyCode::kForbidden},
      {{"", "", kObserverToken, "get", "{\"session\": \"" + kUnknownSession + "\"}"},
       ReplyCode::kNotFound},
      {{"", "", kObserverToken, std::string(200, 'v'), ""}, ReplyCode::kTooLarge},
  };
}

TEST(DaemonAbuse, FloodFromThreeWritersNeitherStallsNorGrowsAndAScanFollows) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  std::string error;
  constexpr int kWriters = 3;
  constexpr int kCommands = 20000;
  std::vector<std::unique_ptr<CommandPeer>> writers;
  for (int w = 0; w < kWriters; ++w) {
    writers.push_back(CommandPeer::Create(s->fixture.domain(), s->fixture.station(), &error));
    ASSERT_TRUE(writers.back()) << error;
    ASSERT_TRUE(writers.back()->WaitForDaemon(30s));
  }
  ExpectServing(*s, "before-flood");
  std::this_thread::sleep_for(1500ms);  // a status sample or two before the flood
  const ProcFigures before = ReadProcFigures(s->fixture.pid());

  const std::vector<FloodKind> kinds = FloodKinds();
  const auto start = Clock::now();
  std::atomic<int> write_failures{0};
  std::vector<std::thread> threads;
  for (int w = 0; w < kWriters; ++w) {
    threads.emplace_back([&, w] {
      std::string why;
      for (int n = w; n < kCommands; n += kWriters) {
        const std::size_t kind = static_cast<std::size_t>(n) % kinds.size();
        RawCommand command = kinds[kind].command;
        char id[64];
        std::snprintf(id, sizeof id, "f%d-k%zu", n, kind);
        command.request_id = id;
        command.client = "flood-" + std::to_string(w);
        if (!writers[static_cast<std::size_t>(w)]->Write(command, &why)) ++write_failures;
      }
      writers[static_cast<std::size_t>(w)]->WaitForAcks(30s, &why);
    });
  }
  for (std::thread& t : threads) t.join();
  const auto written = Clock::now();

  // Answered promptly once the flood is over.
  const auto probe_start = Clock::now();
  ExpectServing(*s, "after-flood", 5s);
  const double probe_ms =
      std::chrono::duration<double, std::milli>(Clock::now() - probe_start).count();
  std::this_thread::sleep_for(1500ms);  // replies in flight; one more periodic status
  const auto end = Clock::now();
  const ProcFigures after = ReadProcFigures(s->fixture.pid());

  // Every reply the daemon sent has the code of its kind, or says the
  // client is over its rate (busy, naming the client).
  int answered = 0, wrong = 0, rate_limited = 0;
  for (const RawReply& r : s->replies->All()) {
    if (r.client.rfind("flood-", 0) != 0) continue;
    ++answered;
    const std::size_t k = r.request_id.find("-k");
    ASSERT_NE(k, std::string::npos) << r.request_id;
    const FloodKind& kind = kinds.at(std::stoul(r.request_id.substr(k + 2)));
    const bool limited =
        r.code_name == "busy" && r.message == daemon::CommandRateLimiter::RefusalMessage(r.client);
    rate_limited += limited;
    if (!limited && r.code_name != daemon::ToString(kind.code) && ++wrong <= 5) {
      ADD_FAILURE() << r.request_id << ": " << r.code_name << ": " << r.message;
    }
  }
  EXPECT_EQ(wrong, 0);
  EXPECT_EQ(write_failures.load(), 0);
  const double write_s = std::chrono::duration<double>(written - start).count();
  Clock::time_point first_reply = end, last_reply = start;
  for (const RawReply& r : s->replies->All()) {
    if (r.client.rfind("flood-", 0) != 0) continue;
    first_reply = std::min(first_reply, r.arrived);
    last_reply = std::max(last_reply, r.arrived);
  }
  const double reply_s =
      std::max(1e-3, std::chrono::duration<double>(last_reply - first_reply).count());
  const double gap_s = s->status->LongestGap(start, end).count();
  const double peak_growth_mb = (after.hwm_kb - before.rss_kb) / 1024.0;
  std::printf(
      "FIGURE flood %d commands from %d writers written in %.2f s (%.0f/s); %d answered "
      "(%.0f%%) in %.2f s (%.0f/s), %d of them rate-limited; status answered %.0f ms after; "
      "longest "
      "StationStatus gap %.2f s (%zu samples); rss %.1f -> %.1f MB, peak growth %.1f MB\n",
      kCommands, kWriters, write_s, kCommands / write_s, answered, 100.0 * answered / kCommands,
      reply_s, answered / reply_s, rate_limited, probe_ms, gap_s,
      s->status->CountBetween(start, end), before.rss_kb / 1024.0, after.rss_kb / 1024.0,
      peak_growth_mb);
  EXPECT_GT(answered, 0);
  EXPECT_LT(gap_s, 5.0);
  // Small commands: the daemon holds at most its reader's history of them
  // (16) and one Reply at a time; 50 MB is slack for allocator arenas.
  if (!kSanitizedBuild) {
    EXPECT_LT(peak_growth_mb, 50.0);
  }

  // A scan right after the flood completes.
  const auto scan = s->client.Send(
      "scan", {{"object", "after flood"}, {"views", 2}, {"step_deg", 90}}, kOperatorToken);
  ASSERT_TRUE(scan);
  ASSERT_EQ(scan->code_name, "ok") << scan->message;
  const std::string job = scan->result["id"];
  const auto deadline = Clock::now() + 120s;
  std::string state;
  while (Clock::now() < deadline) {
    const auto reply = s->client.Send("status", nullptr, kObserverToken, 10s);
    if (reply && reply->result["job"]["id"] == job) state = reply->result["job"]["state"];
    if (!state.empty() && state != "running") break;
    std::this_thread::sleep_for(200ms);
  }
  EXPECT_EQ(state, "done") << s->fixture.Log();
}

// --- Command samples as bytes on the wire -----------------------------------

// Command as XCDR2 (what Cyclone writes for an @appendable struct): the
// encoding header, a DHEADER with the body's size, then each string as a
// 4-aligned length (with its NUL) and its bytes. `header` is the 4 bytes
// Cyclone itself puts first; its padding bits are set here.
std::string CommandCdr(const std::string& header, const std::vector<std::string>& strings) {
  std::string body;
  for (const std::string& text : strings) {
    body.resize((body.size() + 3) / 4 * 4, '\0');
    const std::uint32_t length = static_cast<std::uint32_t>(text.size() + 1);
    body.append(reinterpret_cast<const char*>(&length), 4);
    body.append(text).push_back('\0');
  }
  const std::uint32_t size = static_cast<std::uint32_t>(body.size());
  const std::size_t padding = (4 - body.size() % 4) % 4;
  std::string cdr = header.substr(0, 3);
  cdr.push_back(static_cast<char>((header[3] & ~3) | static_cast<char>(padding)));
  cdr.append(reinterpret_cast<const char*>(&size), 4);
  cdr.append(body).append(padding, '\0');
  return cdr;
}

// A writer on the command topic through Cyclone's C API, which can write
// serialised samples as they are (dds_writecdr).
class CdrWriter {
 public:
  ~CdrWriter() {
    if (serdata_) ddsi_serdata_unref(serdata_);
    if (participant_ > 0) dds_delete(participant_);
  }

  // Joins the domain, writes one valid Command (a status request, id
  // "cdr-probe") and reads it back serialised through a local reader: that
  // gives the topic's serialisation and Cyclone's own bytes.
  bool Start(std::uint32_t domain, const std::string& station, std::string* error) {
    participant_ = dds_create_participant(domain, nullptr, nullptr);
    const dds_entity_t topic =
        participant_ > 0
            ? dds_create_topic(participant_, &craftscan_msg_Command_desc,
                               dds::CommandTopic(station).name.c_str(), nullptr, nullptr)
            : -1;
    dds_qos_t* qos = dds_create_qos();
    dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
    dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, dds::CommandTopic(station).qos.history_depth);
    writer_ = topic > 0 ? dds_create_writer(participant_, topic, qos, nullptr) : -1;
    const dds_entity_t reader =
        topic > 0 ? dds_create_reader(participant_, topic, qos, nullptr) : -1;
    dds_delete_qos(qos);
    if (writer_ < 0 || reader < 0) {
      *error = "cannot create the raw command writer";
      return false;
    }
    // The local reader and the daemon's.
    if (!WaitForReaders(2)) {
      *error = "the daemon's command reader did not match the raw writer";
      return false;
    }
    dds::Outgoing<dds::msg::Command> probe;
    probe.msg().request_id = probe.Keep("cdr-probe");
    probe.msg().client = probe.Keep("cdr");
    probe.msg().token = probe.Keep(kObserverToken);
    probe.msg().verb = probe.Keep("status");
    probe.msg().arguments = probe.Keep("");
    if (dds_write(writer_, &probe.msg()) < 0) {
      *error = "cannot write the probe";
      return false;
    }
    dds_sample_info_t info;
    for (int i = 0; i < 200 && !serdata_; ++i) {
      if (dds_takecdr(reader, &serdata_, 1, &info, 0) != 1) {
        serdata_ = nullptr;
        std::this_thread::sleep_for(10ms);
      }
    }
    dds_delete(reader);
    if (!serdata_) {
      *error = "the probe did not come back through the local reader";
      return false;
    }
    probe_bytes_.resize(ddsi_serdata_size(serdata_));
    ddsi_serdata_to_ser(serdata_, 0, probe_bytes_.size(), probe_bytes_.data());
    return true;
  }

  // Cyclone's serialisation of the probe {"cdr-probe", "cdr", observer
  // token, "status", ""}.
  const std::string& probe_bytes() const { return probe_bytes_; }

  // Writes `cdr` (header included), which Cyclone must accept as a valid
  // sample of the topic. False when it does not.
  bool WriteValid(const std::string& cdr) {
    ddsi_serdata* data = FromBytes(cdr);
    return data && dds_writecdr(writer_, data) == DDS_RETCODE_OK;
  }

  // Writes `bad` as it is: a valid sample of the same size is made from
  // `same_size_valid` and its bytes are then replaced (Cyclone checks bytes
  // only when it makes a sample, not when it sends one). False (and
  // *skip set) if this Cyclone lays out its samples otherwise.
  bool WriteInvalid(const std::string& same_size_valid, const std::string& bad, bool* skip) {
    ddsi_serdata* data = FromBytes(same_size_valid);
    if (!data || bad.size() != same_size_valid.size()) return false;
    auto* raw = reinterpret_cast<ddsi_serdata_default*>(data);
    const std::size_t body = same_size_valid.size() - 4;
    if (raw->pos != body || std::memcmp(raw->data, same_size_valid.data() + 4, body) != 0) {
      *skip = true;
      ddsi_serdata_unref(data);
      return false;
    }
    std::memcpy(raw->data, bad.data() + 4, body);
    return dds_writecdr(writer_, data) == DDS_RETCODE_OK;
  }

 private:
  ddsi_serdata* FromBytes(const std::string& cdr) {
    ddsrt_iovec_t iov;
    iov.iov_base = const_cast<char*>(cdr.data());
    iov.iov_len = cdr.size();
    return ddsi_serdata_from_ser_iov(serdata_->type, SDK_DATA, 1, &iov, cdr.size());
  }
  bool WaitForReaders(std::uint32_t count) {
    for (int i = 0; i < 300; ++i) {
      dds_publication_matched_status_t status;
      if (dds_get_publication_matched_status(writer_, &status) == 0 &&
          status.current_count >= count) {
        return true;
      }
      std::this_thread::sleep_for(100ms);
    }
    return false;
  }

  dds_entity_t participant_ = 0, writer_ = 0;
  ddsi_serdata* serdata_ = nullptr;  // the probe, taken back: holds the sertype
  std::string probe_bytes_;
};

TEST(DaemonAbuse, MalformedBytesOnTheWireAreDroppedAndOddValidOnesAnswered) {
  auto s = StartStation();
  ASSERT_TRUE(s);
  CdrWriter raw;
  std::string error;
  ASSERT_TRUE(raw.Start(s->fixture.domain(), s->fixture.station(), &error)) << error;
  const auto probe = s->replies->WaitFor("cdr-probe", "cdr", 20s);
  ASSERT_TRUE(probe);
  EXPECT_EQ(probe->code_name, "ok");
  // The builder writes what Cyclone writes.
  const std::string header = raw.probe_bytes().substr(0, 4);
  ASSERT_EQ(CommandCdr(header, {"cdr-probe", "cdr", kObserverToken, "status", ""}),
            raw.probe_bytes())
      << "this Cyclone does not write Command as 4-aligned XCDR2 with a DHEADER";

  // Valid on the wire, odd to the daemon.
  struct Odd {
    std::string what;
    std::vector<std::string> strings;
    std::string request_id;  // as the daemon sees it
    ReplyCode code;
  };
  const std::vector<Odd> odd = {
      // A NUL inside a string: the daemon's C strings end there.
      {"NUL inside the verb",
       {std::string("cdr-nul\0tail", 12), "cdr", kObserverToken, std::string("sta\0tus", 7), ""},
       "cdr-nul",
       ReplyCode::kUnknownVerb},
      {"NUL after a valid token",
       {"cdr-nul-token", "cdr", kObserverToken + std::string(1, '\0') + "x", "status", ""},
       "cdr-nul-token",
       ReplyCode::kOk},
      // An older client's Command with only some members (appendable):
      // the rest are empty.
      {"only request id and client",
       {"cdr-short", "cdr"},
       "cdr-short",
       ReplyCode::kUnauthenticated},
      {"no token, verb or arguments",
       {"cdr-short2", "cdr", kObserverToken},
       "cdr-short2",
       ReplyCode::kUnknownVerb},
      // A newer client's Command with a member this daemon does not know.
      {"an extra member",
       {"cdr-long", "cdr", kObserverToken, "status", "", "future"},
       "cdr-long",
       ReplyCode::kOk},
  };
  for (const Odd& k : odd) {
    SCOPED_TRACE(k.what);
    ASSERT_TRUE(raw.WriteValid(CommandCdr(header, k.strings))) << "Cyclone refused the sample";
    const auto reply = s->replies->WaitFor(k.request_id, "cdr", 20s);
    ASSERT_TRUE(reply) << "no reply";
    EXPECT_EQ(reply->code_name, daemon::ToString(k.code)) << reply->message;
  }

  // Malformed: the daemon's Cyclone must drop each (nothing to answer) and
  // the daemon must keep serving.
  const std::string valid =
      CommandCdr(header, {"cdr-bad", "cdr", kObserverToken, "status", "{\"pad\": 0}"});
  auto put32 = [](std::string* cdr, std::size_t offset, std::uint32_t value) {
    std::memcpy(cdr->data() + offset, &value, 4);
  };
  std::vector<std::pair<std::string, std::string>> bad;
  {
    std::string b = valid;
    put32(&b, 8, 0x7fffffffu);  // the request id's length, far past the end
    bad.emplace_back("string length past the end", b);
    b = valid;
    put32(&b, 8, 0);  // a string of length 0 (no room for its NUL)
    bad.emplace_back("string length 0", b);
    b = valid;
    b[8 + 4 + 7] = 'X';  // "cdr-bad\0" loses its NUL
    bad.emplace_back("string without its NUL", b);
    b = valid;
    put32(&b, 4, static_cast<std::uint32_t>(valid.size() * 4));  // DHEADER past the end
    bad.emplace_back("DHEADER past the end", b);
    b = valid;
    put32(&b, 4, 0xfffffff0u);
    bad.emplace_back("DHEADER near 4 GiB", b);
    std::mt19937 random(8);
    for (int i = 0; i < 20; ++i) {
      b = valid;
      for (std::size_t j = 4; j < b.size(); ++j) b[j] = static_cast<char>(random());
      bad.emplace_back("random bytes " + std::to_string(i), b);
    }
  }
  // The path works: bytes swapped for other valid ones are answered.
  bool skip = false;
  ASSERT_TRUE(raw.WriteInvalid(
      valid, CommandCdr(header, {"cdr-ok!", "cdr", kObserverToken, "status", "{\"pad\": 0}"}),
      &skip));
  if (skip) GTEST_SKIP() << "this Cyclone's serdata layout differs; malformed bytes not sent";
  const auto swapped = s->replies->WaitFor("cdr-ok!", "cdr", 20s);
  ASSERT_TRUE(swapped) << "the swapped bytes were not answered";
  EXPECT_EQ(swapped->code_name, "bad_argument") << swapped->message;  // "pad" is no argument
  for (const auto& [what, bytes] : bad) {
    SCOPED_TRACE(what);
    ASSERT_TRUE(raw.WriteInvalid(valid, bytes, &skip));
    ExpectServing(*s, "after " + what);
  }
  EXPECT_FALSE(s->replies->WaitFor("cdr-bad", "cdr", 1s)) << "a malformed sample was answered";
  std::printf("FIGURE abuse_cdr odd %zu answered, malformed %zu dropped\n", odd.size(), bad.size());
}

}  // namespace
}  // namespace craftscan::testing
