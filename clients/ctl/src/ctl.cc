#include "ctl.h"

#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <deque>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <variant>

#include "craftscan/pipeline/common/bagit.h"

#include "progress_view.h"

namespace craftscan::ctl {
namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

std::chrono::milliseconds Ms(double seconds) {
  return std::chrono::milliseconds(static_cast<long long>(seconds * 1000.0 + 0.5));
}

void Error(const std::string& message) {
  std::fprintf(stderr, "craftscanctl: %s\n", message.c_str());
}

// A string member of a JSON object, "" if absent or not a string.
std::string Str(const json& object, const char* key) {
  if (!object.is_object()) return "";
  const auto it = object.find(key);
  return it != object.end() && it->is_string() ? it->get<std::string>() : "";
}

std::string Trim(std::string text) {
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return "";
  const auto last = text.find_last_not_of(" \t\r\n");
  return text.substr(first, last - first + 1);
}

std::string ClientName() {
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) != 0 || host[0] == '\0') std::strcpy(host, "localhost");
  std::string name = "craftscanctl@";
  for (const char* p = host; *p && name.size() < 60; ++p)
    name += (*p > ' ' && *p < 0x7f) ? *p : '_';
  return name;
}

std::string LocalTime() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  ::localtime_r(&now, &tm);
  char text[16];
  std::strftime(text, sizeof text, "%H:%M:%S", &tm);
  return text;
}

std::string Percent(double fraction) {
  return std::to_string(static_cast<int>(fraction * 100 + 0.5)) + "%";
}

std::string HumanBytes(std::uint64_t bytes) {
  char text[32];
  if (bytes < 10 * 1024) {
    std::snprintf(text, sizeof text, "%llu B", static_cast<unsigned long long>(bytes));
  } else if (bytes < 10 * 1024 * 1024) {
    std::snprintf(text, sizeof text, "%.1f KiB", static_cast<double>(bytes) / 1024);
  } else {
    std::snprintf(text, sizeof text, "%.1f MiB", static_cast<double>(bytes) / (1024 * 1024));
  }
  return text;
}

// A queue the subscription threads fill and the main thread drains.
template <typename Event>
class EventQueue {
 public:
  void Push(Event event) {
    std::lock_guard lock(mutex_);
    events_.push_back(std::move(event));
    ready_.notify_one();
  }
  // Everything queued, waiting up to `timeout` for the first.
  std::deque<Event> Drain(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    ready_.wait_for(lock, timeout, [&] { return !events_.empty(); });
    return std::exchange(events_, {});
  }

 private:
  std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<Event> events_;
};

bool IsTerminalStage(const std::string& stage) {
  return stage == "done" || stage == "failed" || stage == "cancelled";
}

}  // namespace

std::string ResolveDdsConfig(const std::string& given) {
  if (given.empty()) return client::DefaultDdsConfig();
  if (given.front() != '<' && given.find("://") == std::string::npos &&
      given.find(',') == std::string::npos) {
    // A plain path: Cyclone wants a file:// URI.
    std::error_code ec;
    return "file://" + std::filesystem::absolute(given, ec).string();
  }
  return given;
}

int Ctl::Init(const GlobalOptions& options) {
  options_ = options;
  std::string token = options.token;
  if (token.empty() && !options.token_file.empty()) {
    std::ifstream in(options.token_file);
    if (!in) {
      Error("cannot read the token file '" + options.token_file + "': " + std::strerror(errno));
      return kExitUsage;
    }
    std::getline(in, token);
    token = Trim(token);
    if (token.empty()) {
      Error("the token file '" + options.token_file + "' is empty");
      return kExitUsage;
    }
  }
  if (token.empty()) {
    if (const char* env = std::getenv("CRAFTSCAN_TOKEN")) token = Trim(env);
  }
  if (token.empty()) {
    Error(
        "no token: give --token TOKEN, --token-file FILE or set CRAFTSCAN_TOKEN (the station's "
        "admin issues tokens; the daemon's tokens file lists them)");
    return kExitUsage;
  }
  client::ConnectOptions connect;
  connect.station = options.station;
  connect.domain_id = options.domain;
  connect.token = token;
  connect.client_name = ClientName();
  connect.dds_config = ResolveDdsConfig(options.dds_config);
  std::string why;
  if (!connect.IsValid(&why)) {
    Error(why);
    return kExitUsage;
  }
  client_ = client::StationClient::Connect(connect, &why);
  if (!client_) {
    Error("cannot join DDS domain " + std::to_string(options.domain) + ": " + why);
    return kExitLocalError;
  }
  return kExitOk;
}

void Ctl::PrintJson(const json& value) const {
  std::printf("%s\n", value.dump(2, ' ', false, json::error_handler_t::replace).c_str());
  std::fflush(stdout);
}

int Ctl::Unreachable(const std::string& message) const {
  char used[160];
  std::snprintf(used, sizeof used, " [used --station %s --domain %u --timeout %g]",
                options_.station.c_str(), options_.domain, options_.timeout_s);
  if (options_.json) PrintJson({{"ok", false}, {"error", "unreachable"}, {"message", message}});
  Error(message + used);
  return kExitUnreachable;
}

int Ctl::Call(const std::string& verb, const json& args, client::Reply* reply) {
  const client::CallResult r = client_->Call(verb, args, Ms(options_.timeout_s));
  if (r.status == client::CallStatus::kUnreachable) return Unreachable(r.message);
  if (r.status == client::CallStatus::kError) {
    Error(r.message);
    return kExitLocalError;
  }
  if (!r.reply.ok()) {
    if (options_.json) {
      PrintJson({{"ok", false},
                 {"code", r.reply.code},
                 {"code_name", r.reply.code_name},
                 {"message", r.reply.message},
                 {"result", r.reply.result}});
    }
    Error(verb + " refused: " + r.reply.code_name + ": " + r.reply.message);
    return kExitRefused;
  }
  *reply = r.reply;
  return kExitOk;
}

int Ctl::Status() {
  client::Reply reply;
  if (const int rc = Call("status", nullptr, &reply)) return rc;
  const json& s = reply.result;
  if (options_.json) {
    PrintJson(s);
    return kExitOk;
  }
  const std::string calibration = Str(s, "calibration_id");
  std::printf("station      %s (DDS domain %u)\n", Str(s, "station").c_str(), options_.domain);
  std::printf("state        %s\n", Str(s, "state").c_str());
  std::printf("calibration  %s\n",
              calibration.empty() ? "none (run: craftscanctl calibrate)" : calibration.c_str());
  std::printf("devices\n");
  for (const json& d : s.value("devices", json::array())) {
    std::printf("  %-12s %-10s %-12s %s\n", Str(d, "name").c_str(), Str(d, "kind").c_str(),
                Str(d, "state").c_str(), Str(d, "message").c_str());
  }
  const json job = s.value("job", json::object());
  if (!Str(job, "id").empty()) {
    std::printf("job          %s %s %s %s%s%s\n", Str(job, "id").c_str(), Str(job, "verb").c_str(),
                Str(job, "state").c_str(), Percent(job.value("progress", 0.0)).c_str(),
                Str(job, "stage").empty() ? "" : (" (" + Str(job, "stage") + ")").c_str(),
                Str(job, "session").empty() ? "" : ("  session " + Str(job, "session")).c_str());
    if (job.value("turn", 0) > 1) std::printf("turn         %d\n", job.value("turn", 0));
    if (!Str(job, "message").empty()) std::printf("             %s\n", Str(job, "message").c_str());
  } else {
    std::printf("job          none yet\n");
  }
  if (!Str(s, "last_error").empty()) std::printf("last error   %s\n", Str(s, "last_error").c_str());
  return kExitOk;
}

int Ctl::Devices() {
  client::Reply reply;
  if (const int rc = Call("devices", nullptr, &reply)) return rc;
  if (options_.json) {
    PrintJson(reply.result);
    return kExitOk;
  }
  std::printf("%-12s %-10s %-18s %-12s %s\n", "NAME", "KIND", "DRIVER", "STATE", "MESSAGE");
  for (const json& d : reply.result.value("devices", json::array())) {
    std::printf("%-12s %-10s %-18s %-12s %s\n", Str(d, "name").c_str(), Str(d, "kind").c_str(),
                Str(d, "driver").c_str(), Str(d, "state").c_str(), Str(d, "message").c_str());
  }
  return kExitOk;
}

int Ctl::Sessions() {
  client::Reply reply;
  if (const int rc = Call("sessions", nullptr, &reply)) return rc;
  if (options_.json) {
    PrintJson(reply.result);
    return kExitOk;
  }
  const json list = reply.result.value("sessions", json::array());
  if (list.empty()) {
    std::printf("no sessions yet\n");
    return kExitOk;
  }
  std::printf("%-40s %-14s %-9s %5s  %s\n", "SESSION", "STATE", "JOB", "VIEWS", "OBJECT");
  for (const json& s : list) {
    std::printf("%-40s %-14s %-9s %5d  %s%s\n", Str(s, "id").c_str(), Str(s, "state").c_str(),
                Str(s, "job").c_str(), s.value("views_captured", 0), Str(s, "object").c_str(),
                Str(s, "problem").empty() ? "" : ("  (" + Str(s, "problem") + ")").c_str());
    for (const json& t : s.value("turns", json::array())) {
      std::printf("  turn %d: views %d-%d, %s%s\n", t.value("turn", 0), t.value("first_view", 0),
                  t.value("first_view", 0) + t.value("views", 0) - 1, Str(t, "state").c_str(),
                  Str(t, "join").empty() ? "" : ("; " + Str(t, "join")).c_str());
    }
  }
  return kExitOk;
}

int Ctl::Job(const std::string& verb, const json& args, const WaitOptions& wait) {
  EventQueue<client::ProgressUpdate> events;
  std::string error;
  if (wait.wait && !client_->SubscribeProgress(
                       [&](const client::ProgressUpdate& p) { events.Push(p); }, &error)) {
    Error("cannot subscribe to progress: " + error);
    return kExitLocalError;
  }
  client::Reply reply;
  if (const int rc = Call(verb, args, &reply)) return rc;
  const std::string id = Str(reply.result, "id");
  const std::string session = Str(reply.result, "session");
  if (options_.json && !wait.wait) {
    PrintJson(reply.result);
    return kExitOk;
  }
  if (!options_.json) {
    std::printf("%s started as %s%s\n", verb.c_str(), id.c_str(),
                session.empty() ? "" : (", session " + session).c_str());
    std::fflush(stdout);
    if (!wait.wait) return kExitOk;
  }

  ProgressView view(stdout, IsTerminal(stdout));
  const auto start = Clock::now();
  auto last_poll = start;
  bool ended = false;     // a terminal progress update of this job was seen
  int unknown_polls = 0;  // status polls that showed another job and no end of ours
  json final_job;
  for (;;) {
    if (Interrupted()) {
      view.Finish();
      Error("stopped waiting; " + id +
            " goes on at the station (follow it with `craftscanctl "
            "watch`, stop it with `craftscanctl cancel`)");
      return kExitInterrupted;
    }
    for (const client::ProgressUpdate& p : events.Drain(std::chrono::milliseconds(250))) {
      if (p.job_id != id) continue;
      if (IsTerminalStage(p.stage)) {
        ended = true;
        final_job = {{"id", id},
                     {"verb", verb},
                     {"state", p.stage},
                     {"session", session},
                     {"message", p.message}};
      } else if (!options_.json) {
        view.Update(p.stage, p.current, p.total, p.message);
      }
    }
    const auto now = Clock::now();
    if (ended || now - last_poll >= std::chrono::seconds(1)) {
      // The status verb has the job's final record (with its result), and
      // proves the daemon is still there.
      last_poll = now;
      const client::CallResult r = client_->Call("status", nullptr, Ms(options_.timeout_s));
      if (ended && !r.ok()) break;  // the end is known; its details are not needed
      if (r.status != client::CallStatus::kReplied || !r.reply.ok()) {
        view.Finish();
        if (r.status == client::CallStatus::kUnreachable) {
          return Unreachable("lost contact with the station while waiting for " + id + ": " +
                             r.message);
        }
        Error("status: " + (r.status == client::CallStatus::kError
                                ? r.message
                                : r.reply.code_name + ": " + r.reply.message));
        return r.status == client::CallStatus::kError ? kExitLocalError : kExitRefused;
      }
      const json job = r.reply.result.value("job", json::object());
      if (Str(job, "id") == id && Str(job, "state") != "running") {
        final_job = job;
        break;
      }
      if (ended && Str(job, "id") != id) break;  // a later job already replaced ours
      // Neither current nor ended: the daemon restarted (its jobs are gone;
      // the session, if any, was marked interrupted) or the end was missed
      // while another job started. The session's state tells.
      if (Str(job, "id") != id && ++unknown_polls >= 3) {
        final_job = {
            {"id", id},
            {"verb", verb},
            {"session", session},
            {"state", "failed"},
            {"message", "the station no longer reports " + id + " (craftscand restarted?)"}};
        if (!session.empty()) {
          const client::CallResult list =
              client_->Call("sessions", nullptr, Ms(options_.timeout_s));
          for (const json& s :
               list.ok() ? list.reply.result.value("sessions", json::array()) : json::array()) {
            if (Str(s, "id") != session) continue;
            final_job["state"] = Str(s, "state") == "done" ? "done" : "failed";
            final_job["message"] = "the station no longer reports " + id + "; session " + session +
                                   " is " + Str(s, "state");
          }
        }
        break;
      }
    }
    if (wait.max_wait_s > 0 && now - start > Ms(wait.max_wait_s)) {
      view.Finish();
      Error(id + " is still running after --max-wait " + std::to_string(wait.max_wait_s) +
            " s; it goes on at the station");
      return kExitStillRunning;
    }
  }
  view.Finish();
  const std::string state = Str(final_job, "state");
  if (options_.json) {
    PrintJson(final_job);
  } else {
    std::printf("%s %s %s: %s\n", id.c_str(), verb.c_str(), state.c_str(),
                Str(final_job, "message").c_str());
    const json result = final_job.value("result", json::object());
    if (result.is_object() && result.contains("box_mm") && result["box_mm"].is_array() &&
        result["box_mm"].size() == 3) {
      std::printf("bounding box %.1f x %.1f x %.1f mm\n", result["box_mm"][0].get<double>(),
                  result["box_mm"][1].get<double>(), result["box_mm"][2].get<double>());
    }
    if (state == "done" && !session.empty() && verb != "capture") {
      std::printf("fetch the results: craftscanctl get %s --out DIR\n", session.c_str());
    } else if (state == "cancelled" || (state == "failed" && !session.empty())) {
      if (!session.empty()) std::printf("continue it: craftscanctl resume %s\n", session.c_str());
    }
  }
  return state == "done" ? kExitOk : kExitJobFailed;
}

int Ctl::Action(const std::string& verb, const json& args,
                const std::function<std::string(const client::Reply&)>& text) {
  client::Reply reply;
  if (const int rc = Call(verb, args, &reply)) return rc;
  if (options_.json) {
    PrintJson({{"ok", true}, {"message", reply.message}, {"result", reply.result}});
  } else {
    std::printf("%s\n", text(reply).c_str());
  }
  return kExitOk;
}

int Ctl::Cancel() {
  return Action("cancel", nullptr, [](const client::Reply& r) { return r.message; });
}

int Ctl::Turntable(const json& args) {
  return Action("turntable", args, [](const client::Reply& r) {
    if (!r.result.contains("angle_deg")) return "turntable " + r.message;
    char text[64];
    std::snprintf(text, sizeof text, "turntable at %.2f deg", r.result["angle_deg"].get<double>());
    return std::string(text);
  });
}

int Ctl::Camera(const json& args) {
  return Action("camera", args, [](const client::Reply& r) {
    char text[96];
    std::snprintf(text, sizeof text, "camera: exposure %g us, gain %g dB",
                  r.result.value("exposure_us", 0.0), r.result.value("gain_db", 0.0));
    return std::string(text);
  });
}

int Ctl::Fetch(const std::string& session, const std::string& out_dir,
               const std::vector<std::string>& files, bool whole_session, std::size_t chunk_bytes,
               client::FetchResult* fetched) {
  client::FetchRequest request;
  request.session = session;
  request.files = files;
  request.whole_session = whole_session && files.empty();
  request.out_dir = out_dir;
  request.chunk_bytes = chunk_bytes;
  request.timeout = Ms(options_.timeout_s);
  request.cancel = interrupted_;
  const bool live = !options_.json && IsTerminal(stdout);
  bool drawn = false;
  if (live) {
    request.on_progress = [&](const client::FetchProgress& p) {
      const int columns = TerminalColumns(stdout);
      std::string line = "\r\x1b[2K" + p.name + " " +
                         Bar(static_cast<std::int64_t>(p.bytes_done),
                             static_cast<std::int64_t>(p.bytes_total), 24) +
                         " " + HumanBytes(p.bytes_done) + " / " + HumanBytes(p.bytes_total) +
                         " (file " + std::to_string(p.file_index + 1) + "/" +
                         std::to_string(p.file_count) + ")";
      if (static_cast<int>(line.size()) > columns + 4)
        line.resize(static_cast<std::size_t>(columns + 4));
      std::fputs(line.c_str(), stdout);
      std::fflush(stdout);
      drawn = true;
    };
  }
  const client::FetchResult result = client_->Fetch(request);
  if (drawn) std::fputs("\r\x1b[2K", stdout);
  switch (result.status) {
    case client::FetchStatus::kOk:
      break;
    case client::FetchStatus::kRefused:
      if (options_.json) {
        PrintJson({{"ok", false},
                   {"code", result.reply.code},
                   {"code_name", result.reply.code_name},
                   {"message", result.reply.message}});
      }
      Error("get refused: " + result.message);
      return kExitRefused;
    case client::FetchStatus::kUnreachable:
      return Unreachable(result.message);
    case client::FetchStatus::kTransferFailed:
      if (options_.json)
        PrintJson({{"ok", false}, {"error", "transfer_failed"}, {"message", result.message}});
      Error("get " + session + ": " + result.message + " (" + std::to_string(result.files.size()) +
            " files were written before)");
      return kExitJobFailed;
    case client::FetchStatus::kLocalError:
      Error("get " + session + ": " + result.message);
      return Interrupted() ? kExitInterrupted : kExitLocalError;
  }
  *fetched = result;
  return kExitOk;
}

int Ctl::Get(const std::string& session, const std::string& out_dir,
             const std::vector<std::string>& files, std::size_t chunk_bytes) {
  client::FetchResult result;
  if (const int rc = Fetch(session, out_dir, files, /*whole_session=*/false, chunk_bytes, &result))
    return rc;
  if (options_.json) {
    json list = json::array();
    for (const client::FetchedFile& f : result.files) {
      list.push_back({{"name", f.name},
                      {"path", f.path},
                      {"size", f.size_bytes},
                      {"fnv1a64", client::Hex64(f.fnv1a64)}});
    }
    PrintJson({{"ok", true},
               {"session", session},
               {"out", out_dir},
               {"files", list},
               {"transfer_seconds", result.transfer_seconds}});
  } else {
    std::uint64_t total = 0;
    for (const client::FetchedFile& f : result.files) {
      std::printf("%-24s %12llu bytes  %s\n", f.name.c_str(),
                  static_cast<unsigned long long>(f.size_bytes), f.path.c_str());
      total += f.size_bytes;
    }
    std::printf("%zu files, %s in %.2f s, sizes and checksums verified\n", result.files.size(),
                HumanBytes(total).c_str(), result.transfer_seconds);
  }
  return kExitOk;
}

int Ctl::GetBag(const std::string& session, const std::string& bag_dir,
                const std::string& source_organization, const std::vector<std::string>& files,
                std::size_t chunk_bytes) {
  craftscan::Status status;  // (Ctl::Status is the status subcommand)
  std::unique_ptr<BagWriter> bag = BagWriter::Start(bag_dir, &status);
  if (!bag) {
    Error("get " + session + " --bagit: " + status.message());
    return kExitLocalError;
  }
  client::FetchResult result;
  // Without --file, the whole session: what an archive keeps (captures,
  // calibration, manifest, outputs).
  if (const int rc =
          Fetch(session, bag->data_dir(), files, /*whole_session=*/true, chunk_bytes, &result)) {
    return rc;
  }
  // The bag's manifest hashes the files again from disk; each must equal
  // the SHA-256 of the bytes received, which the transfer checked against
  // the station's manifest (end to end: station disk → DDS → bag).
  std::map<std::string, std::string> expected;
  for (const client::FetchedFile& f : result.files) expected[f.name] = f.sha256;
  BagSummary summary;
  const BagInfo info{source_organization, session, ""};
  if (status = bag->Finish(info, expected, &summary); !status.ok()) {
    Error("get " + session + " --bagit: " + status.message());
    return status.code() == ErrorCode::kCorrupt ? kExitJobFailed : kExitLocalError;
  }
  if (options_.json) {
    PrintJson({{"ok", true},
               {"session", session},
               {"bag", summary.path},
               {"payload_files", summary.payload_files},
               {"payload_bytes", summary.payload_bytes},
               {"transfer_seconds", result.transfer_seconds}});
  } else {
    std::printf("bag '%s': %llu files, %s (Payload-Oxum %llu.%llu), SHA-256 verified\n",
                summary.path.c_str(), static_cast<unsigned long long>(summary.payload_files),
                HumanBytes(summary.payload_bytes).c_str(),
                static_cast<unsigned long long>(summary.payload_bytes),
                static_cast<unsigned long long>(summary.payload_files));
  }
  return kExitOk;
}

int Ctl::Watch(int count, double duration_s) {
  client::Reply reply;
  // Proves the daemon is there and the token valid before waiting on topics.
  if (const int rc = Call("status", nullptr, &reply)) return rc;
  using Event = std::variant<client::StatusUpdate, client::ProgressUpdate>;
  EventQueue<Event> events;
  std::string error;
  if (!client_->SubscribeStatus([&](const client::StatusUpdate& s) { events.Push(s); }, &error) ||
      !client_->SubscribeProgress([&](const client::ProgressUpdate& p) { events.Push(p); },
                                  &error)) {
    Error("cannot subscribe: " + error);
    return kExitLocalError;
  }
  const auto start = Clock::now();
  auto last_status = start;
  const auto silence = std::max(Ms(options_.timeout_s), std::chrono::milliseconds(3000));
  std::string last_summary;
  int printed = 0;
  while (!Interrupted() && (count <= 0 || printed < count) &&
         (duration_s <= 0 || Clock::now() - start < Ms(duration_s))) {
    for (const Event& event : events.Drain(std::chrono::milliseconds(200))) {
      if (count > 0 && printed >= count) break;
      if (const auto* s = std::get_if<client::StatusUpdate>(&event)) {
        last_status = Clock::now();
        json devices = json::array();
        std::string device_text;
        for (const client::DeviceState& d : s->devices) {
          devices.push_back(
              {{"name", d.name}, {"kind", d.kind}, {"state", d.state}, {"message", d.message}});
          device_text += " " + d.name + ":" + d.state;
        }
        std::string summary = s->state + " | job " +
                              (s->job_id.empty() ? "none"
                                                 : s->job_id + " " + s->job_verb + " " +
                                                       s->job_state + " " + Percent(s->progress)) +
                              " |" + device_text;
        if (!s->last_error.empty()) summary += " | error: " + s->last_error;
        if (summary == last_summary) continue;  // published every second even when unchanged
        last_summary = summary;
        if (options_.json) {
          std::printf("%s\n", json({{"type", "status"},
                                    {"station", s->station},
                                    {"state", s->state},
                                    {"job",
                                     {{"id", s->job_id},
                                      {"verb", s->job_verb},
                                      {"state", s->job_state},
                                      {"progress", s->progress}}},
                                    {"devices", devices},
                                    {"last_error", s->last_error},
                                    {"calibration_id", s->calibration_id},
                                    {"stamp_ns", s->stamp_ns}})
                                  .dump(-1, ' ', false, json::error_handler_t::replace)
                                  .c_str());
        } else {
          std::printf("%s status %s\n", LocalTime().c_str(), summary.c_str());
        }
      } else {
        const auto& p = std::get<client::ProgressUpdate>(event);
        if (options_.json) {
          std::printf("%s\n", json({{"type", "progress"},
                                    {"job", p.job_id},
                                    {"stage", p.stage},
                                    {"current", p.current},
                                    {"total", p.total},
                                    {"message", p.message},
                                    {"stamp_ns", p.stamp_ns}})
                                  .dump(-1, ' ', false, json::error_handler_t::replace)
                                  .c_str());
        } else {
          std::printf("%s %s %s %lld/%lld %s\n", LocalTime().c_str(), p.job_id.c_str(),
                      p.stage.c_str(), static_cast<long long>(p.current),
                      static_cast<long long>(p.total), p.message.c_str());
        }
      }
      std::fflush(stdout);
      ++printed;
    }
    if (Clock::now() - last_status > silence) {
      return Unreachable(
          "no status from station '" + options_.station + "' for " +
          std::to_string(silence.count() / 1000) +
          " s (it publishes one every second): craftscand stopped or the network is down");
    }
  }
  return kExitOk;
}

}  // namespace craftscan::ctl
