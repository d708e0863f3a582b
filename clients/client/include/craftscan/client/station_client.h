// A DDS client of one craftscan station (DESIGN.md "DDS interface"): sends
// Commands and waits for their Replies, subscribes to what the daemon
// publishes (status, job progress, clouds, captures, disparity maps, preview
// frames) and fetches session files (`get` with files). Used by craftscanctl,
// craftscan-web and the tests; no DDS type appears in this header.
//
//   ConnectOptions options;
//   options.station = "station1";
//   options.token = token;
//   auto client = StationClient::Connect(options, &error);
//   CallResult r = client->Call("status", {}, std::chrono::seconds(10));
//   if (r.status == CallStatus::kUnreachable) ... r.message says what to check
//   else if (!r.reply.ok()) ... r.reply.code_name, r.reply.message
//
// Request ids are "<client name>-<pid>-<counter>", unique per client.
// Every wait is bounded by the timeout it is given.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core/mat.hpp>
#include <opencv2/core/matx.hpp>

#include "craftscan/client/file_assembler.h"
#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan::client {

// Where craftscanctl and other clients find their Cyclone DDS configuration
// when none is given: "" (Cyclone then reads CYCLONEDDS_URI) if
// CYCLONEDDS_URI is set, else "file:///etc/craftscan/cyclonedds.xml" if that
// file exists (the station's own tuning for large samples), else "".
std::string DefaultDdsConfig();

struct ConnectOptions {
  std::string station = "station1";  // station id (topic names craftscan/<station>/...)
  std::uint32_t domain_id = 0;       // DDS domain, 0..230
  // Cyclone configuration: XML, a file (path or file:// URI) or a
  // comma-separated list (see dds::ParticipantOptions); empty = CYCLONEDDS_URI
  // or Cyclone's defaults.
  std::string dds_config;
  std::string token;  // sent with every Command (the daemon's tokens file lists it)
  // Sent as Command.client and prefixed to request ids; empty =
  // "craftscan-client@<host name>". At most 64 printable ASCII bytes, no spaces.
  std::string client_name;

  // False with *why (may be null) naming the field: an invalid station id,
  // domain above 230, a config file that does not exist, a token longer than
  // 128 bytes or with spaces/control characters, a bad client name.
  bool IsValid(std::string* why) const;
};

// A Reply as received.
struct Reply {
  std::int32_t code = -1;  // 0 = ok; otherwise the daemon's error code
  std::string code_name;   // "ok", "forbidden", "busy", ...
  std::string message;
  nlohmann::json result = nlohmann::json::object();  // {} when the result is not JSON
  bool ok() const { return code == 0; }
};

enum class CallStatus {
  kReplied,      // `reply` holds the daemon's answer (which may be an error)
  kUnreachable,  // no daemon matched, or no reply within the timeout
  kError,        // a local DDS failure (message says which)
};

struct CallResult {
  CallStatus status = CallStatus::kError;
  Reply reply;             // kReplied only
  std::string message;     // kUnreachable / kError: what happened and what to check
  std::string request_id;  // of the Command sent ("" if none was)
  bool ok() const { return status == CallStatus::kReplied && reply.ok(); }
};

struct DeviceState {
  std::string name, kind, state, message;
};

// StationStatus (published on change and every second; transient-local, so a
// new subscriber gets the latest at once).
struct StatusUpdate {
  std::string station, state;  // state: "starting", "idle", "busy", "error", "stopping"
  std::vector<DeviceState> devices;
  std::string job_id, job_verb, job_state;  // job_state: "running", "done", "failed", ...
  double progress = 0;                      // 0..1 of the current job
  std::string last_error;
  std::int64_t stamp_ns = 0;  // wall clock
  std::string calibration_id;
};

// JobProgress. A job's last update has stage "done", "failed" or
// "cancelled" (the job's final state) with the job's message.
struct ProgressUpdate {
  std::string job_id, stage;
  std::int64_t current = 0, total = 0;  // total 0 = unknown
  std::string message;
  std::int64_t stamp_ns = 0;
};

struct CloudUpdate {
  std::string session;
  int view_index = -1;                               // −1 = fused
  std::string kind;                                  // "view" or "fused"
  cv::Matx44d world_from_view = cv::Matx44d::eye();  // mm
  PointCloud cloud;                                  // mm
  std::int64_t stamp_ns = 0;
  std::string frame_id;
};

struct CaptureUpdate {
  std::string session;
  int view_index = 0;
  double angle_deg = 0, exposure_us = 0, gain_db = 0;
  cv::Mat left, right;  // owned copies (CV_8UC1 or CV_8UC3)
  std::int64_t left_stamp_ns = 0, right_stamp_ns = 0;
};

// A view's disparity map as the daemon matched it (the Disparity topic).
struct DisparityUpdate {
  std::string session;
  int view_index = 0;
  // CV_32FC1, height × width, owned copy: d = x_left − x_right in rectified
  // px, NaN (or ±inf) where the matcher found none.
  cv::Mat disparity;
  float f_px = 0;  // rectified focal length
  float baseline_mm = 0;
  float cx_offset_px = 0;   // rectified cx_left − cx_right
  float min_disparity = 0;  // the searched range, px
  float max_disparity = 0;
  std::int64_t stamp_ns = 0;
  std::string frame_id;
};

// One image of a live preview frame.
struct PreviewImageUpdate {
  std::vector<std::uint8_t> jpeg;
  std::vector<float> focus;              // grid_rows × grid_cols, row-major
  std::vector<std::uint32_t> histogram;  // 64 bins of 4 grey levels
  float clipped_pct = 0, black_pct = 0;
};

// A live preview frame (the preview verb, the guided calibration).
struct PreviewUpdate {
  std::string job_id;
  std::uint32_t frame_number = 0;
  std::int64_t stamp_ns = 0;  // capture (wall clock)
  std::int64_t ready_ns = 0;  // in the daemon's hands (wall clock); 0 = not sent
  double exposure_us = 0, gain_db = 0;
  int full_width = 0, full_height = 0, width = 0, height = 0;
  int grid_cols = 0, grid_rows = 0;
  PreviewImageUpdate left, right;
  std::string overlay;  // JSON or ""
};

// Progress of a Fetch, after each chunk.
struct FetchProgress {
  std::string name;  // file being received
  std::uint32_t file_index = 0, file_count = 0;
  std::uint64_t file_bytes = 0, file_size = 0;    // of this file
  std::uint64_t bytes_done = 0, bytes_total = 0;  // of the transfer
};

struct FetchRequest {
  std::string session;             // session id
  std::vector<std::string> files;  // output names; empty = all the session's outputs
  // Instead of outputs: every file of the session folder (manifest.json,
  // calibration.yaml, views/NNN/..., the outputs), as an archive keeps it.
  bool whole_session = false;
  std::string out_dir;  // created if missing; files replace same-named ones
  std::size_t chunk_bytes = std::size_t{1} << 20;  // 4096 .. 4 MiB
  // For the reply, and then for each chunk (the transfer may take longer as
  // long as data keeps coming).
  std::chrono::milliseconds timeout{10000};
  std::function<void(const FetchProgress&)> on_progress;  // may be empty; caller's thread
  const std::atomic<bool>* cancel = nullptr;              // may be null; checked every 50 ms
  // Sent with `get` instead of ConnectOptions::token when not empty (a
  // client relaying for several users, such as craftscan-web).
  std::string token;
};

enum class FetchStatus {
  kOk,              // every file is in out_dir, sizes and checksums verified
  kRefused,         // the daemon answered with an error (reply says which)
  kUnreachable,     // no daemon, no reply, or no data for `timeout` mid-transfer
  kTransferFailed,  // lost chunks, the station could not send a file, a checksum differs
  kLocalError,      // out_dir not writable, invalid request, DDS failure, cancelled
};

struct FetchResult {
  FetchStatus status = FetchStatus::kLocalError;
  std::string message;
  Reply reply;                     // when the daemon replied
  std::vector<FetchedFile> files;  // in place (all of them on kOk)
  double transfer_seconds = 0;     // from the reply to the last file in place
  // `get`s sent again because the transfer's first chunks went by before the
  // station's file writer had matched this client's reader.
  int retries = 0;
};

class StationClient {
 public:
  // Joins the domain and creates the command writer and reply reader (their
  // reply-routing thread starts here). Null with *error (may be null) for
  // invalid options or a DDS failure.
  static std::unique_ptr<StationClient> Connect(const ConnectOptions& options, std::string* error);
  // Stops and joins every thread this client started.
  ~StationClient();
  StationClient(const StationClient&) = delete;
  StationClient& operator=(const StationClient&) = delete;

  const ConnectOptions& options() const;
  const std::string& client_name() const;

  // Waits until a daemon's command reader and reply writer are matched
  // (discovery done). False on timeout. Thread-safe.
  bool WaitForDaemon(std::chrono::milliseconds timeout);

  // Sends `verb` with `args` (a JSON object, or null for none) and waits for
  // its Reply, all within `timeout`: first for a daemon to be discovered,
  // then for the reply. Thread-safe: several calls may wait at once.
  CallResult Call(std::string_view verb, const nlohmann::json& args,
                  std::chrono::milliseconds timeout);
  // The same with the arguments as text, sent as given (JSON or not: the
  // daemon judges it; "" = none), and `token` instead of options().token.
  // For relaying commands and for testing the daemon's checks.
  CallResult CallRaw(std::string_view verb, std::string_view arguments, std::string_view token,
                     std::chrono::milliseconds timeout);

  // Subscribe*: creates the topic's reader and a thread that calls `handler`
  // for every sample taken, in order, until the client is destroyed. Each
  // kind may be subscribed once (false with *error the second time). A
  // handler must return quickly and must not destroy the client; it may
  // call Call(). Malformed clouds/captures/disparity maps/preview frames are
  // skipped.
  bool SubscribeStatus(std::function<void(const StatusUpdate&)> handler, std::string* error);
  bool SubscribeProgress(std::function<void(const ProgressUpdate&)> handler, std::string* error);
  bool SubscribeClouds(std::function<void(const CloudUpdate&)> handler, std::string* error);
  bool SubscribeCaptures(std::function<void(const CaptureUpdate&)> handler, std::string* error);
  bool SubscribeDisparity(std::function<void(const DisparityUpdate&)> handler, std::string* error);
  bool SubscribePreview(std::function<void(const PreviewUpdate&)> handler, std::string* error);

  // Fetches session files into request.out_dir: subscribes to the file topic
  // (once per client), waits for the daemon's file writer, sends `get` with
  // {"session", "files": [...] | "all", "chunk_bytes"} and reassembles the
  // chunks with a FileAssembler (atomic writes, sizes and FNV-1a 64 checked
  // against the station's manifest); a transfer seen to start late (its first
  // chunks sent before the station matched this reader) is asked for again,
  // up to twice. Blocks the calling thread; bounded by
  // request.timeout per step (reply, each chunk). One Fetch per client at a
  // time.
  FetchResult Fetch(const FetchRequest& request);

 private:
  struct Impl;
  explicit StationClient(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::client
