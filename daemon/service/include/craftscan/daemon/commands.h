// Command handling, independent of DDS: a Command (request id, client,
// token, verb, JSON arguments) becomes a Reply with a code, a message and a
// JSON result. Every command is checked in this order, and the first failure
// is the reply:
//
//   busy             the client sent more than its share of commands
//                    (CommandRateLimiter, below; the service checks it first)
//   too_large        the arguments exceed limits.max_command_bytes, or an id
//                    or name is longer than 128 bytes
//   bad_request      request id missing, arguments not a JSON object
//   unauthenticated  the token is not in the tokens file
//   unknown_verb     the verb is not one of the verbs below
//   forbidden        the token's role is below the verb's role
//   bad_argument     an unknown key, a wrong type or an out-of-range value
//                    (the message names the key)
//   busy             a job is running (for verbs that start one)
//   not_found        unknown session
//   unavailable      the devices are not open, or the session store is not
//                    (SetStore: sessions, get and every verb that starts a
//                    job needing the data directory)
//   failed           the action was tried and failed (message says why)
//   ok
//
// Floods. The command topic's reader keeps the last 16 samples (topics.h),
// so commands arriving faster than the service answers them are lost in DDS
// before the service sees them; what the service takes it answers, one Reply
// each. So that a flood costs little per sample: each client name gets
// kClientCommandsPerSecond with bursts of kClientCommandBurst, and commands
// beyond that are answered `busy` without being parsed or acted on
// (CommandRateLimiter); refused and read-only commands (IsQueryVerb) do not
// republish StationStatus; the service logs at most a few refusals a second
// and counts the rest; a field longer than its limit is measured, never
// copied (CutCommandRequest). The client name is the sender's own claim: a
// flooder that changes it every time gets a bucket per name, up to
// kMaxRateLimitedClients, then all new names share one.
//
// Verbs (role; arguments):
//   status, devices, sessions            observer; none (status's result also
//                                        has "you": {"name", "role"}: the
//                                        token's entry in the tokens file)
//   get                                  observer; {"session": str}: manifest + verification;
//                                        with "files": a file transfer (below)
//   capture                              operator; {"object": str}
//   scan                                 operator; {"object": str, "views": int 2..360,
//                                                   "step_deg": number, "exposure_bracket":
//                                                   [number] (≤ 4; [] = off; default:
//                                                   the station's scan.exposure_bracket)}
//   cancel                               operator; none
//   resume                               operator; {"session": str}
//   turntable                            operator; {"action": "home"|"move",
//                                                   "angle_deg": number}
//   camera                               operator; {"exposure_us": number, "gain_db": number}
//                                        (during a preview: applied, the preview goes on)
//   preview                              operator; {"action": "start"|"stop", "fps": 0.1..15,
//                                                   "width": int 64..4096, "seconds": 1..600}
//                                        the live preview (topic craftscan/<station>/preview)
//                                        until `seconds` after the last start; refused busy
//                                        while a job runs; any job verb stops it first
//   calibrate, calibrate-turntable       admin; none
//   delete                               admin; {"session": str}: the session folder moved to
//                                        <data_dir>/trash (busy while a job holds it)
//
// get with files: {"session": str, "files": "all" | "session" | [name, ...],
//                  "chunk_bytes": int 4096..4194304 (default 1 MiB)}
// sends durable outputs of the session (the manifest's "outputs": fused.ply,
// mesh.ply, mesh.obj, report.json, report.html, previews/...), or with
// "session" the whole session as it is on disk (manifest.json as read now,
// calibration.yaml, every view's durable files views/NNN/..., the outputs:
// what an archive keeps, e.g. `craftscanctl get --bagit`), over the
// station's file topic (craftscan/<station>/file, SessionFile). Names are
// checked with IsValidOutputName (bad_argument) and must be listed in the
// manifest (not_found, naming the outputs there are; "all" of a session
// without outputs is not_found too). The ok Reply's result is
//   {"session": id, "state": "done", "chunk_bytes": n, "total_bytes": n,
//    "files": [{"name": "fused.ply", "size": n, "fnv1a64": "16 hex digits",
//               "sha256": "64 hex digits"}, ...]}
// with size and checksums from the manifest ("sha256" is left out for a file
// listed by a manifest from before SHA-256; receivers then check FNV-1a 64
// only). The checksums travel in this JSON result, not in the SessionFile
// chunks, so the IDL is unchanged and clients that know only fnv1a64 keep
// working. CommandReply::transfer then holds
// the plan the service streams after the Reply: each file in order, in
// chunks of chunk_bytes at increasing offsets, last = true on its last chunk,
// or one chunk with `error` set if the file cannot be sent (the transfer
// stops there). Receivers check offsets (a gap means lost chunks), sizes and
// the checksums (SHA-256 where listed, and FNV-1a 64). At most kMaxQueuedTransfers transfers wait
// at a time; beyond that get answers busy.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/daemon/auth.h"

namespace craftscan::daemon {

class DeviceManager;
class JobEngine;
class SessionStore;
struct DeviceReport;
struct JobInfo;

enum class ReplyCode : std::int32_t {
  kOk = 0,
  kBadRequest = 1,
  kUnauthenticated = 2,
  kUnknownVerb = 3,
  kForbidden = 4,
  kBadArgument = 5,
  kBusy = 6,
  kNotFound = 7,
  kUnavailable = 8,
  kFailed = 9,
  kTooLarge = 10,
  kInternal = 11,
};
std::string_view ToString(ReplyCode code);  // "ok", "bad_request", ...

struct CommandRequest {
  std::string request_id, client, token, verb, arguments;  // arguments: JSON text ("" = {})
  // The arguments' size as received when `arguments` holds only their
  // first bytes (CutCommandRequest); 0: arguments.size() is the size.
  std::size_t received_arguments_bytes = 0;
};

// Bounds of a get file transfer (see the top of this header).
inline constexpr std::size_t kMinTransferChunkBytes = 4096;
inline constexpr std::size_t kMaxTransferChunkBytes = std::size_t{4} << 20;
inline constexpr std::size_t kDefaultTransferChunkBytes = std::size_t{1} << 20;
inline constexpr std::size_t kMaxQueuedTransfers = 4;

// One file of a transfer: its output name, absolute path and the size and
// checksum the manifest lists.
struct TransferFile {
  std::string name, path;
  std::uint64_t size_bytes = 0;
  std::uint64_t fnv1a64 = 0;
};

// What a get with files asks the service to send after the Reply.
struct FileTransfer {
  std::string session;
  std::size_t chunk_bytes = kDefaultTransferChunkBytes;
  std::vector<TransferFile> files;
};

struct CommandReply {
  std::string request_id, client;
  ReplyCode code = ReplyCode::kInternal;
  std::string message;
  nlohmann::json result = nlohmann::json::object();
  // Set only by an ok get with files: the files to stream after the Reply.
  std::optional<FileTransfer> transfer;
};

struct CommandLimits {
  std::size_t max_argument_bytes = 65536;
  std::size_t max_field_bytes = 128;  // request id, client, verb, token, names
};

// The request for received strings: each copied up to one byte past its
// limit (arguments: max_argument_bytes, the others: max_field_bytes), which
// CheckCommand refuses as too_large on the size alone; the arguments' full
// size goes to received_arguments_bytes for the message. So a 16 MB string
// is measured, never copied.
CommandRequest CutCommandRequest(std::string_view request_id, std::string_view client,
                                 std::string_view token, std::string_view verb,
                                 std::string_view arguments, const CommandLimits& limits);

// The JSON the status and devices verbs (and the job verbs' results) show
// for a job: {"id", "verb", "state", "session", "stage", "progress",
// "message", "result"}; and for devices: [{"name", "kind", "driver",
// "state", "message"}, ...].
nlohmann::json JobJson(const JobInfo& job);
nlohmann::json DevicesJson(const std::vector<DeviceReport>& devices);

// True for the verbs that only read (status, devices, sessions, get): an
// answer to them changes no state worth republishing.
bool IsQueryVerb(std::string_view verb);

// Commands one client name may send (see "Floods" at the top).
inline constexpr double kClientCommandsPerSecond = 50;
inline constexpr double kClientCommandBurst = 100;
inline constexpr std::size_t kMaxRateLimitedClients = 1024;

// A token bucket: `rate_per_s` tokens a second, at most `burst`, full at
// the start. Not thread-safe.
class TokenBucket {
 public:
  using Clock = std::chrono::steady_clock;
  TokenBucket(double rate_per_s, double burst, Clock::time_point now)
      : rate_per_s_(rate_per_s), burst_(burst), tokens_(burst), last_(now) {}
  // Takes a token: false (nothing taken) when the bucket is empty.
  bool Take(Clock::time_point now);
  // Whether it has refilled to `burst` (its owner has been quiet).
  bool Full(Clock::time_point now) const;

 private:
  double Level(Clock::time_point now) const;
  double rate_per_s_, burst_, tokens_;
  Clock::time_point last_;
};

// Per-client-name admission of commands: a TokenBucket of
// kClientCommandsPerSecond / kClientCommandBurst per name (names compared as
// sent, cut to 128 bytes). At most kMaxRateLimitedClients names are tracked:
// when full, names whose buckets have refilled are forgotten, and if none
// has, new names share one bucket. Not thread-safe (the command loop's).
class CommandRateLimiter {
 public:
  using Clock = TokenBucket::Clock;
  // True if `client` may send a command at `now` (and counts it).
  bool Admit(std::string_view client, Clock::time_point now);
  // The `busy` reply's message for a refused `client`.
  static std::string RefusalMessage(std::string_view client);
  std::size_t tracked_clients() const { return buckets_.size(); }

 private:
  std::unordered_map<std::string, TokenBucket> buckets_;
  std::optional<TokenBucket> shared_;  // for names beyond kMaxRateLimitedClients
};

// The replies to the last kRememberedReplies commands, by client, request
// id and token, so that a command sent again under the same request id is
// answered with the reply it had and never run twice. Clients send a
// command again when its reply does not come: DDS discovery is asymmetric,
// so a new client may see the daemon's endpoints before the daemon sees
// its own, and the first Command or its Reply can then be lost. A reply is
// sent again at most kMaxReplyRepeats times. Not thread-safe (the command
// loop's).
inline constexpr std::size_t kRememberedReplies = 256;
inline constexpr int kMaxReplyRepeats = 16;
class ReplyMemory {
 public:
  // The reply given to this request before, or null; counts the repeat.
  // Null too once it was repeated kMaxReplyRepeats times: the caller then
  // drops the request (a client replaying one id in a loop gets nothing).
  // `*known` (if not null) says whether the request was seen at all.
  const CommandReply* Find(const CommandRequest& request, bool* known = nullptr);
  // Remembers `reply` (without its file transfer) for `request`.
  void Remember(const CommandRequest& request, const CommandReply& reply);
  std::size_t size() const { return replies_.size(); }

 private:
  struct Entry {
    CommandReply reply;
    int repeats = 0;
  };
  static std::string Key(const CommandRequest& request);
  std::unordered_map<std::string, Entry> replies_;
  std::deque<std::string> order_;  // oldest first
};

// The result of CheckCommand: kOk with the parsed arguments and the caller's
// identity, or the refusal (code and message) for the reply.
struct CommandCheck {
  ReplyCode code = ReplyCode::kInternal;
  std::string message;                                  // why it was refused; "" for kOk
  nlohmann::json arguments = nlohmann::json::object();  // kOk: a JSON object
  std::optional<Identity> identity;                     // kOk: who sent it
  bool ok() const { return code == ReplyCode::kOk; }
};

// Every check Handle makes before it acts, in the order listed at the top of
// this file up to bad_argument: sizes, request id, argument JSON, token,
// verb, role, and each argument's key, type and range, including the
// values checked by shape (session ids: IsValidSessionId; turntable action
// "home" | "move", "move" needing angle_deg). Never throws; does no I/O and
// touches no job or device state. `tokens` may be null (every token is then
// unknown). Thread-safe (TokenAuthority is immutable).
CommandCheck CheckCommand(const CommandRequest& request, const CommandLimits& limits,
                          const TokenAuthority* tokens);

// Thread-safety: Handle may be called from one thread at a time (the
// service's command loop).
class CommandHandler {
 public:
  // `status` returns the station's status as JSON (for the status verb).
  CommandHandler(CommandLimits limits, const TokenAuthority* tokens, JobEngine* jobs,
                 DeviceManager* devices, SessionStore* store,
                 std::function<nlohmann::json()> status);

  CommandReply Handle(const CommandRequest& request);
  // The reply refusing `request` with `code` and `message` (its request id
  // and client cut to limits().max_field_bytes, an empty result): what
  // Handle answers to a command it refuses, and the service to one it does
  // not hand to Handle (CommandRateLimiter).
  CommandReply Refuse(const CommandRequest& request, ReplyCode code, std::string message) const;
  const CommandLimits& limits() const { return limits_; }

  // Replaces the session store (null while the data directory is not
  // usable). With null, sessions, get, capture, scan, resume, calibrate and
  // calibrate-turntable answer `unavailable` with `why_unavailable` (which
  // should name the data directory and the error). Call from the thread
  // that calls Handle.
  void SetStore(SessionStore* store, std::string why_unavailable);

 private:
  CommandReply Dispatch(const std::string& verb, const nlohmann::json& args, const Identity& who,
                        CommandReply reply);
  // get with "files" (arguments already checked): the reply and the transfer plan.
  CommandReply GetFiles(const std::string& id, const nlohmann::json& args, CommandReply reply);

  CommandLimits limits_;
  const TokenAuthority* tokens_;
  JobEngine* jobs_;
  DeviceManager* devices_;
  SessionStore* store_;
  std::string store_unavailable_;  // the refusal while store_ is null
  std::function<nlohmann::json()> status_;
};

}  // namespace craftscan::daemon
