// StationClient: the DDS side (participant, typed readers/writers, threads).
#include "craftscan/client/station_client.h"

#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

namespace craftscan::client {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr std::size_t kMaxTokenBytes = 128;  // the daemon's limit for ids and tokens
constexpr std::size_t kMaxClientNameBytes = 64;
constexpr milliseconds kPoll{50};  // how often reader threads look at the stop flag

bool SetError(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

bool IsPrintableWord(std::string_view text) {
  for (char c : text) {
    if (c <= ' ' || c >= 0x7f) return false;
  }
  return true;
}

std::string DefaultClientName() {
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) != 0) host[0] = '\0';
  std::string name = "craftscan-client@";
  for (const char* p = host; *p && name.size() < 48; ++p) {
    name += (*p > ' ' && *p < 0x7f) ? *p : '_';
  }
  if (name.back() == '@') name += "localhost";
  return name;
}

std::string Seconds(milliseconds timeout) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f", static_cast<double>(timeout.count()) / 1000.0);
  return text;
}

std::string Str(const char* text) { return std::string(dds::View(text)); }

milliseconds Remaining(Clock::time_point deadline) {
  const auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
  return left.count() > 0 ? left : milliseconds(0);
}

}  // namespace

std::string DefaultDdsConfig() {
  const char* uri = std::getenv("CYCLONEDDS_URI");
  if (uri && *uri) return "";
  std::error_code ec;
  if (std::filesystem::is_regular_file("/etc/craftscan/cyclonedds.xml", ec)) {
    return dds::ConfigFileUri("/etc/craftscan/cyclonedds.xml");
  }
  return "";
}

bool ConnectOptions::IsValid(std::string* why) const {
  std::string problem;
  if (!dds::IsValidStationId(station, &problem)) return SetError(why, problem);
  dds::ParticipantOptions participant;
  participant.domain_id = domain_id;
  participant.config = dds_config;
  if (!participant.IsValid(&problem)) return SetError(why, "DDS: " + problem);
  if (token.size() > kMaxTokenBytes || !IsPrintableWord(token)) {
    return SetError(why, "token: must be at most " + std::to_string(kMaxTokenBytes) +
                             " printable characters without spaces");
  }
  if (client_name.size() > kMaxClientNameBytes || !IsPrintableWord(client_name)) {
    return SetError(why, "client name: must be at most " + std::to_string(kMaxClientNameBytes) +
                             " printable characters without spaces");
  }
  return true;
}

struct StationClient::Impl {
  ConnectOptions options;
  std::string client_name;
  std::string request_prefix;  // "<client>-<pid>-"
  std::atomic<std::uint64_t> next_request{1};
  std::shared_ptr<dds::Participant> participant;
  std::unique_ptr<dds::Writer<dds::msg::Command>> commands;
  std::unique_ptr<dds::Reader<dds::msg::Reply>> replies;
  std::timed_mutex discovery_mutex;  // one thread waits on the match waitsets at a time

  std::mutex mutex;
  std::condition_variable replied;
  std::map<std::string, std::optional<Reply>> pending;  // guarded by mutex

  std::mutex subscribe_mutex;  // guards the readers below and `threads`
  std::unique_ptr<dds::Reader<dds::msg::StationStatus>> status;
  std::unique_ptr<dds::Reader<dds::msg::JobProgress>> progress;
  std::unique_ptr<dds::Reader<dds::msg::PointCloud>> clouds;
  std::unique_ptr<dds::Reader<dds::msg::StereoCapture>> captures;
  std::unique_ptr<dds::Reader<dds::msg::Disparity>> disparity;
  std::unique_ptr<dds::Reader<dds::msg::Preview>> preview;
  std::unique_ptr<dds::Reader<dds::msg::SessionFile>> files;
  std::atomic<bool> running{true};
  std::vector<std::thread> threads;

  std::string UnreachableMessage(milliseconds timeout) const {
    return "no craftscand found for station '" + options.station + "' on DDS domain " +
           std::to_string(options.domain_id) + " within " + Seconds(timeout) +
           " s. Check that craftscand is running (systemctl status craftscand), that the station "
           "id and domain match its config (station, dds.domain), and that both sides use the "
           "same Cyclone DDS network set-up (CYCLONEDDS_URI or the DDS config: interface, "
           "peers, multicast)";
  }

  // Waits until the daemon's command reader and reply writer are matched.
  bool WaitForDaemon(Clock::time_point deadline) {
    if (commands->MatchedReaders() >= 1 && replies->MatchedWriters() >= 1) return true;
    std::unique_lock lock(discovery_mutex, std::defer_lock);
    if (!lock.try_lock_until(deadline)) return false;
    return commands->WaitForReaders(1, Remaining(deadline)) &&
           replies->WaitForWriters(1, Remaining(deadline));
  }

  // Registers a request id for the reply thread; then writes the Command
  // (status kReplied: sent, the reply is awaited next).
  CallResult Send(std::string_view verb, std::string_view arguments, std::string_view token,
                  Clock::time_point deadline, milliseconds timeout) {
    CallResult result;
    if (!WaitForDaemon(deadline)) {
      result.status = CallStatus::kUnreachable;
      result.message = UnreachableMessage(timeout);
      return result;
    }
    const std::string id = request_prefix + std::to_string(next_request++);
    {
      std::lock_guard lock(mutex);
      pending[id];
    }
    std::string error;
    if (!Write(id, verb, arguments, token, &error)) {
      Forget(id);
      result.status = CallStatus::kError;
      result.message = "cannot send '" + std::string(verb) + "': " + error;
      return result;
    }
    result.request_id = id;
    result.status = CallStatus::kReplied;
    return result;
  }

  // Writes the Command under request id `id` (again, when its reply is late:
  // the daemon answers a repeated id with the reply it gave, ReplyMemory).
  bool Write(const std::string& id, std::string_view verb, std::string_view arguments,
             std::string_view token, std::string* error) {
    dds::Outgoing<dds::msg::Command> out;
    out.msg().request_id = out.Keep(id);
    out.msg().client = out.Keep(client_name);
    out.msg().token = out.Keep(token);
    out.msg().verb = out.Keep(verb);
    out.msg().arguments = out.Keep(arguments);
    return commands->Write(out.msg(), error);
  }

  // The reply to `id` if it arrived, waiting until `deadline`.
  std::optional<Reply> WaitReply(const std::string& id, Clock::time_point deadline) {
    std::unique_lock lock(mutex);
    replied.wait_until(lock, deadline, [&] {
      const auto it = pending.find(id);
      return it == pending.end() || it->second.has_value();
    });
    const auto it = pending.find(id);
    if (it == pending.end() || !it->second) return std::nullopt;
    return it->second;
  }

  void Forget(const std::string& id) {
    std::lock_guard lock(mutex);
    pending.erase(id);
  }

  void ReplyLoop() {
    dds::Sample<dds::msg::Reply> sample;
    std::string error;
    while (running) {
      if (replies->Take(kPoll, &sample, &error) != dds::TakeStatus::kOk) continue;
      const std::string id = Str(sample->request_id);
      std::lock_guard lock(mutex);
      const auto it = pending.find(id);
      if (it == pending.end()) continue;  // another client's, or given up
      Reply reply;
      reply.code = sample->code;
      reply.code_name = Str(sample->code_name);
      reply.message = Str(sample->message);
      const std::string_view text = dds::View(sample->result);
      if (!text.empty()) {
        reply.result = nlohmann::json::parse(text, nullptr, false);
        if (reply.result.is_discarded()) reply.result = nlohmann::json::object();
      }
      it->second = std::move(reply);
      replied.notify_all();
    }
  }

  template <typename Msg, typename Handler>
  void StartLoop(dds::Reader<Msg>* reader, Handler handler) {
    threads.emplace_back([this, reader, handler = std::move(handler)] {
      dds::Sample<Msg> sample;
      std::string error;
      while (running) {
        if (reader->Take(kPoll, &sample, &error) == dds::TakeStatus::kOk) handler(*sample);
      }
    });
  }

  // Creates the topic's reader (once) and the thread feeding `handler`.
  template <typename Msg, typename Handler>
  bool Subscribe(std::unique_ptr<dds::Reader<Msg>>* reader, const dds::TopicSpec<Msg>& topic,
                 const char* what, Handler handler, std::string* error) {
    std::lock_guard lock(subscribe_mutex);
    if (!MakeReader(reader, topic, what, error)) return false;
    StartLoop(reader->get(), std::move(handler));
    return true;
  }

  template <typename Msg>
  bool MakeReader(std::unique_ptr<dds::Reader<Msg>>* reader, const dds::TopicSpec<Msg>& topic,
                  const char* what, std::string* error) {
    if (*reader) return SetError(error, std::string("already subscribed to ") + what);
    *reader = dds::Reader<Msg>::Create(participant, topic, error);
    return *reader != nullptr;
  }
};

StationClient::StationClient(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

StationClient::~StationClient() {
  impl_->running = false;
  std::lock_guard lock(impl_->subscribe_mutex);
  for (std::thread& t : impl_->threads) t.join();
}

std::unique_ptr<StationClient> StationClient::Connect(const ConnectOptions& options,
                                                      std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) {
    SetError(error, why);
    return nullptr;
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->client_name = options.client_name.empty() ? DefaultClientName() : options.client_name;
  impl->request_prefix = impl->client_name + "-" + std::to_string(::getpid()) + "-";
  dds::ParticipantOptions participant;
  participant.domain_id = options.domain_id;
  participant.config = options.dds_config;
  impl->participant = dds::Participant::Create(participant, &why);
  // The reply reader first: the daemon's reply writer then matches it before
  // our first Command can arrive.
  if (!impl->participant ||
      !(impl->replies = dds::Reader<dds::msg::Reply>::Create(
            impl->participant, dds::ReplyTopic(options.station), &why)) ||
      !(impl->commands = dds::Writer<dds::msg::Command>::Create(
            impl->participant, dds::CommandTopic(options.station), &why))) {
    SetError(error, "DDS: " + why);
    return nullptr;
  }
  Impl* raw = impl.get();
  impl->threads.emplace_back([raw] { raw->ReplyLoop(); });
  return std::unique_ptr<StationClient>(new StationClient(std::move(impl)));
}

const ConnectOptions& StationClient::options() const { return impl_->options; }
const std::string& StationClient::client_name() const { return impl_->client_name; }

bool StationClient::WaitForDaemon(milliseconds timeout) {
  return impl_->WaitForDaemon(Clock::now() + timeout);
}

CallResult StationClient::Call(std::string_view verb, const nlohmann::json& args,
                               milliseconds timeout) {
  return CallRaw(verb, args.is_null() ? std::string() : args.dump(), impl_->options.token, timeout);
}

CallResult StationClient::CallRaw(std::string_view verb, std::string_view arguments,
                                  std::string_view token, milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  CallResult result = impl_->Send(verb, arguments, token, deadline, timeout);
  if (result.status != CallStatus::kReplied) return result;
  // DDS discovery is asymmetric: the daemon may not have matched this
  // client's writer or reader yet when the first Command goes, and a
  // volatile topic then loses the Command or its Reply. So the Command is
  // sent again under the same id after 1, 2, 4, ... s without a reply (the
  // daemon runs it once and repeats its reply: ReplyMemory).
  std::optional<Reply> reply;
  auto resend_after = std::chrono::milliseconds(1000);
  for (auto next = Clock::now() + resend_after;; next = Clock::now() + resend_after) {
    reply = impl_->WaitReply(result.request_id, std::min(next, deadline));
    if (reply || Clock::now() >= deadline) break;
    std::string ignored;  // a failed repeat is like a lost one
    impl_->Write(result.request_id, verb, arguments, token, &ignored);
    resend_after *= 2;
  }
  impl_->Forget(result.request_id);
  if (!reply) {
    result.status = CallStatus::kUnreachable;
    result.message = "station '" + impl_->options.station + "' (DDS domain " +
                     std::to_string(impl_->options.domain_id) +
                     ") was found but sent no reply to '" + std::string(verb) + "' within " +
                     Seconds(timeout) +
                     " s; it may be stopping or overloaded: retry with a longer timeout and "
                     "check its log (journalctl -u craftscand)";
    return result;
  }
  result.reply = std::move(*reply);
  return result;
}

bool StationClient::SubscribeStatus(std::function<void(const StatusUpdate&)> handler,
                                    std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::StationStatus& s) {
    StatusUpdate u;
    u.station = Str(s.station);
    u.state = Str(s.state);
    for (std::uint32_t i = 0; i < s.devices._length; ++i) {
      const dds::msg::DeviceStatus& device = s.devices._buffer[i];
      u.devices.push_back(
          {Str(device.name), Str(device.kind), Str(device.state), Str(device.message)});
    }
    u.job_id = Str(s.job_id);
    u.job_verb = Str(s.job_verb);
    u.job_state = Str(s.job_state);
    u.progress = s.progress;
    u.last_error = Str(s.last_error);
    u.stamp_ns = s.stamp_ns;
    u.calibration_id = Str(s.calibration_id);
    handler(u);
  };
  return d.Subscribe(&d.status, dds::StatusTopic(d.options.station), "status", std::move(convert),
                     error);
}

bool StationClient::SubscribeProgress(std::function<void(const ProgressUpdate&)> handler,
                                      std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::JobProgress& p) {
    handler(ProgressUpdate{Str(p.job_id), Str(p.stage), p.current, p.total, Str(p.message),
                           p.stamp_ns});
  };
  return d.Subscribe(&d.progress, dds::ProgressTopic(d.options.station), "progress",
                     std::move(convert), error);
}

bool StationClient::SubscribeClouds(std::function<void(const CloudUpdate&)> handler,
                                    std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::PointCloud& c) {
    CloudUpdate u;
    dds::CloudMeta meta;
    std::string why;
    if (!dds::CloudFromMessage(c, &u.cloud, &meta, &why)) return;
    u.session = std::move(meta.session);
    u.view_index = meta.view_index;
    u.kind = std::move(meta.kind);
    u.world_from_view = meta.world_from_view;
    u.stamp_ns = meta.stamp_ns;
    u.frame_id = std::move(meta.frame_id);
    handler(u);
  };
  return d.Subscribe(&d.clouds, dds::CloudTopic(d.options.station), "clouds", std::move(convert),
                     error);
}

bool StationClient::SubscribeCaptures(std::function<void(const CaptureUpdate&)> handler,
                                      std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::StereoCapture& c) {
    CaptureUpdate u;
    cv::Mat left, right;
    std::string why;
    if (!dds::StereoCaptureToMats(c, &left, &right, &why)) return;
    u.session = Str(c.session);
    u.view_index = c.view_index;
    u.angle_deg = c.angle_deg;
    u.exposure_us = c.exposure_us;
    u.gain_db = c.gain_db;
    u.left = left.clone();  // the message's buffers are reused by the next take
    u.right = right.clone();
    u.left_stamp_ns = c.left_stamp_ns;
    u.right_stamp_ns = c.right_stamp_ns;
    handler(u);
  };
  return d.Subscribe(&d.captures, dds::CaptureTopic(d.options.station), "captures",
                     std::move(convert), error);
}

bool StationClient::SubscribeDisparity(std::function<void(const DisparityUpdate&)> handler,
                                       std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::Disparity& m) {
    DisparityUpdate u;
    cv::Mat map;
    std::string why;
    if (!dds::DisparityToMat(m, &map, &why)) return;
    u.session = Str(m.session);
    u.view_index = m.view_index;
    u.disparity = map.clone();  // the message's buffer is reused by the next take
    u.f_px = m.f_px;
    u.baseline_mm = m.baseline_mm;
    u.cx_offset_px = m.cx_offset_px;
    u.min_disparity = m.min_disparity;
    u.max_disparity = m.max_disparity;
    u.stamp_ns = m.stamp_ns;
    u.frame_id = Str(m.frame_id);
    handler(u);
  };
  return d.Subscribe(&d.disparity, dds::DisparityTopic(d.options.station), "disparity",
                     std::move(convert), error);
}

bool StationClient::SubscribePreview(std::function<void(const PreviewUpdate&)> handler,
                                     std::string* error) {
  Impl& d = *impl_;
  auto convert = [handler = std::move(handler)](const dds::msg::Preview& p) {
    PreviewUpdate u;
    u.job_id = Str(p.job_id);
    u.frame_number = p.frame_number;
    u.stamp_ns = p.stamp_ns;
    u.ready_ns = p.ready_ns;
    u.exposure_us = p.exposure_us;
    u.gain_db = p.gain_db;
    u.full_width = static_cast<int>(p.full_width);
    u.full_height = static_cast<int>(p.full_height);
    u.width = static_cast<int>(p.width);
    u.height = static_cast<int>(p.height);
    u.grid_cols = static_cast<int>(p.grid_cols);
    u.grid_rows = static_cast<int>(p.grid_rows);
    auto copy = [](const auto& sequence, auto* into) {
      into->assign(sequence._buffer, sequence._buffer + sequence._length);
    };
    copy(p.left_jpeg, &u.left.jpeg);
    copy(p.right_jpeg, &u.right.jpeg);
    copy(p.left_focus, &u.left.focus);
    copy(p.right_focus, &u.right.focus);
    copy(p.left_histogram, &u.left.histogram);
    copy(p.right_histogram, &u.right.histogram);
    u.left.clipped_pct = p.left_clipped_pct;
    u.right.clipped_pct = p.right_clipped_pct;
    u.left.black_pct = p.left_black_pct;
    u.right.black_pct = p.right_black_pct;
    u.overlay = Str(p.overlay);
    // A malformed frame (focus grid of the wrong size) is skipped.
    const std::size_t cells = static_cast<std::size_t>(u.grid_cols) * u.grid_rows;
    if (u.left.focus.size() != cells || u.right.focus.size() != cells) return;
    handler(u);
  };
  return d.Subscribe(&d.preview, dds::PreviewTopic(d.options.station), "preview",
                     std::move(convert), error);
}

FetchResult StationClient::Fetch(const FetchRequest& request) {
  Impl& d = *impl_;
  FetchResult result;
  auto finish = [&](FetchStatus status, std::string message) {
    result.status = status;
    result.message = std::move(message);
    return result;
  };
  std::string why;
  if (request.session.empty()) return finish(FetchStatus::kLocalError, "no session given");
  if (request.out_dir.empty()) return finish(FetchStatus::kLocalError, "no output folder given");
  if (request.chunk_bytes < 4096 || request.chunk_bytes > dds::kMaxFileChunkBytes) {
    return finish(FetchStatus::kLocalError, "chunk size must be 4096 .. 4194304 bytes");
  }
  for (const std::string& name : request.files) {
    if (!IsSafeFileName(name, &why)) return finish(FetchStatus::kLocalError, why);
  }
  std::error_code ec;
  std::filesystem::create_directories(request.out_dir, ec);
  if (ec || !std::filesystem::is_directory(request.out_dir, ec)) {
    return finish(FetchStatus::kLocalError, "cannot create the folder '" + request.out_dir +
                                                "': " + (ec ? ec.message() : "not a folder"));
  }
  const auto deadline = Clock::now() + request.timeout;
  {
    std::lock_guard lock(d.subscribe_mutex);
    if (!d.files) {
      d.files = dds::Reader<dds::msg::SessionFile>::Create(d.participant,
                                                           dds::FileTopic(d.options.station), &why);
      if (!d.files) return finish(FetchStatus::kLocalError, "DDS: " + why);
    }
  }
  // The file reader must be matched before `get` is sent, or the first
  // chunks would go by unseen.
  if (!d.WaitForDaemon(deadline)) {
    return finish(FetchStatus::kUnreachable, d.UnreachableMessage(request.timeout));
  }
  if (!d.files->WaitForWriters(1, Remaining(deadline))) {
    return finish(FetchStatus::kUnreachable,
                  "station '" + d.options.station + "' does not publish its file topic (" +
                      dds::FileTopic(d.options.station).name +
                      "): its craftscand predates file transfers, or discovery is slow (retry "
                      "with a longer timeout)");
  }
  nlohmann::json args = {{"session", request.session}, {"chunk_bytes", request.chunk_bytes}};
  if (request.whole_session) {
    args["files"] = "session";
  } else if (request.files.empty()) {
    args["files"] = "all";
  } else {
    args["files"] = request.files;
  }
  // A station's file writer can match this reader a moment after this
  // reader matched it (discovery runs both ways independently): chunks sent
  // before that go by unseen. A transfer whose first chunk is not the start
  // of file 0, or of which no chunk comes at all, is therefore asked for
  // again, a bounded number of times.
  constexpr int kAttempts = 3;
  constexpr auto kFirstChunkWait = std::chrono::seconds(3);
  for (int attempt = 1;; ++attempt) {
    const auto reply_deadline = attempt == 1 ? deadline : Clock::now() + request.timeout;
    CallResult sent =
        d.Send("get", args.dump(), request.token.empty() ? d.options.token : request.token,
               reply_deadline, request.timeout);
    if (sent.status != CallStatus::kReplied) {
      return finish(sent.status == CallStatus::kUnreachable ? FetchStatus::kUnreachable
                                                            : FetchStatus::kLocalError,
                    sent.message);
    }
    const std::string id = sent.request_id;
    struct Forget {
      Impl& d;
      const std::string& id;
      ~Forget() { d.Forget(id); }
    } forget{d, id};

    FileAssembler assembler(request.out_dir);
    bool have_reply = false, seen_chunk = false, started_late = false;
    // A `get` the station never saw (it had not matched this client's
    // writer yet) is sent again under the same id after 1, 2, 4, ... s, as
    // Call does; the station runs it once (ReplyMemory).
    auto resend_after = std::chrono::milliseconds(1000);
    auto resend_at = Clock::now() + resend_after;
    auto last_data = Clock::now();
    auto replied_at = last_data;
    dds::Sample<dds::msg::SessionFile> sample;
    FetchProgress progress;
    for (;;) {
      if (request.cancel && request.cancel->load())
        return finish(FetchStatus::kLocalError, "cancelled");
      if (!have_reply) {
        if (std::optional<Reply> reply = d.WaitReply(id, Clock::now())) {
          have_reply = true;
          last_data = replied_at = Clock::now();
          result.reply = *reply;
          if (!reply->ok()) {
            return finish(FetchStatus::kRefused, reply->code_name + ": " + reply->message);
          }
          std::vector<ExpectedFile> expected;
          const nlohmann::json& list =
              reply->result.contains("files") ? reply->result["files"] : nlohmann::json();
          for (const nlohmann::json& f : list.is_array() ? list : nlohmann::json::array()) {
            ExpectedFile e;
            e.name = f.value("name", "");
            e.size_bytes = f.value("size", std::uint64_t{0});
            const std::optional<std::uint64_t> hash = ParseHex64(f.value("fnv1a64", ""));
            if (!hash)
              return finish(FetchStatus::kTransferFailed,
                            "the reply lists a file without a checksum");
            e.fnv1a64 = *hash;
            e.sha256 = f.value("sha256", "");  // absent from a station's old manifests
            expected.push_back(std::move(e));
          }
          progress.bytes_total = 0;
          for (const ExpectedFile& e : expected) progress.bytes_total += e.size_bytes;
          if (!assembler.SetExpected(std::move(expected), &why)) {
            return finish(assembler.failed_locally() ? FetchStatus::kLocalError
                                                     : FetchStatus::kTransferFailed,
                          why);
          }
        } else if (Clock::now() >= reply_deadline) {
          return finish(FetchStatus::kUnreachable, "station '" + d.options.station +
                                                       "' sent no reply to 'get' within " +
                                                       Seconds(request.timeout) + " s");
        } else if (Clock::now() >= resend_at) {
          std::string ignored;  // a failed repeat is like a lost one
          d.Write(id, "get", args.dump(), request.token.empty() ? d.options.token : request.token,
                  &ignored);
          resend_after *= 2;
          resend_at = Clock::now() + resend_after;
        }
      }
      if (have_reply && assembler.Complete()) break;
      const dds::TakeStatus taken = d.files->Take(kPoll, &sample, &why);
      if (taken == dds::TakeStatus::kError) return finish(FetchStatus::kLocalError, "DDS: " + why);
      // Any chunk shows the station alive: one for another client means ours
      // waits in the station's queue.
      if (taken == dds::TakeStatus::kOk) last_data = Clock::now();
      if (taken == dds::TakeStatus::kOk && dds::View(sample->request_id) == id) {
        if (!seen_chunk && (sample->file_index != 0 || sample->offset != 0) &&
            attempt < kAttempts) {
          started_late = true;
          break;
        }
        seen_chunk = true;
        FileChunk chunk;
        chunk.name = dds::View(sample->name);
        chunk.file_index = sample->file_index;
        chunk.file_count = sample->file_count;
        chunk.total_size = sample->total_size;
        chunk.offset = sample->offset;
        chunk.data = sample->data._buffer;
        chunk.size = sample->data._length;
        chunk.last = sample->last;
        chunk.error = dds::View(sample->error);
        if (!assembler.Accept(chunk, &why)) {
          result.files = assembler.files();
          return finish(
              assembler.failed_locally() ? FetchStatus::kLocalError : FetchStatus::kTransferFailed,
              why);
        }
        if (request.on_progress) {
          progress.name = std::string(chunk.name);
          progress.file_index = chunk.file_index;
          progress.file_count = chunk.file_count;
          progress.file_bytes = chunk.offset + chunk.size;
          progress.file_size = chunk.total_size;
          progress.bytes_done = assembler.bytes_received();
          request.on_progress(progress);
        }
      }
      // Not one chunk of ours since the reply, and the station quiet: they
      // all went by before its writer matched this reader (a small file is
      // one or two chunks). Asked for again, sooner than the stall timeout.
      if (have_reply && !seen_chunk && !assembler.Complete() && attempt < kAttempts &&
          Clock::now() - last_data > std::min<Clock::duration>(request.timeout, kFirstChunkWait)) {
        started_late = true;
        break;
      }
      if (have_reply && !assembler.Complete() && Clock::now() - last_data > request.timeout) {
        result.files = assembler.files();
        return finish(FetchStatus::kUnreachable,
                      "the transfer stopped: no data from station '" + d.options.station +
                          "' for " + Seconds(request.timeout) +
                          " s (craftscand stopped, or the network is down)");
      }
    }
    if (started_late) {
      ++result.retries;
      continue;
    }
    result.files = assembler.files();
    result.transfer_seconds = std::chrono::duration<double>(Clock::now() - replied_at).count();
    return finish(FetchStatus::kOk, "fetched " + std::to_string(result.files.size()) + " files");
  }
}

}  // namespace craftscan::client
