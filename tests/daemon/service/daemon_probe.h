// Probes for the daemon's abuse and soak tests (test_daemon_abuse.cc,
// test_daemon_soak.cc): the daemon's memory and open files from /proc, raw
// Command samples written straight to the station's command topic (anything
// a well-behaved client would never send), every Reply collected on its own
// thread, and the arrival times of StationStatus samples.
//
// All of these join the DDS domain that a StationClient (station_client.h)
// of the same test created with the station's configuration: they create
// their participants with an empty config, so they must be destroyed before
// that client (declare them after it).
#pragma once

#include <sys/types.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define CRAFTSCAN_PROBE_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define CRAFTSCAN_PROBE_SANITIZED 1
#endif
#endif

namespace craftscan::testing {

// Whether this build (and so the daemon, built alike) runs under ASan or
// TSan, whose allocators keep freed memory (quarantine) and shadow all of
// it: bounds on the daemon's RSS do not apply there.
#ifdef CRAFTSCAN_PROBE_SANITIZED
inline constexpr bool kSanitizedBuild = true;
#else
inline constexpr bool kSanitizedBuild = false;
#endif

// What /proc says about a process: resident set now and at its peak (kB),
// its threads, its open file descriptors and the CPU time it has used
// (user + system, seconds). -1 when /proc/<pid> cannot be read.
struct ProcFigures {
  long rss_kb = -1, hwm_kb = -1;
  int threads = -1, fds = -1;
  double cpu_s = -1;
};

inline ProcFigures ReadProcFigures(pid_t pid) {
  ProcFigures figures;
  const std::string dir = "/proc/" + std::to_string(pid);
  std::ifstream status(dir + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) figures.rss_kb = std::stol(line.substr(6));
    if (line.rfind("VmHWM:", 0) == 0) figures.hwm_kb = std::stol(line.substr(6));
    if (line.rfind("Threads:", 0) == 0) figures.threads = std::stoi(line.substr(8));
  }
  std::ifstream stat(dir + "/stat");
  std::string text((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
  const std::size_t after_name = text.rfind(')');  // the name may hold spaces
  if (after_name != std::string::npos) {
    std::istringstream fields(text.substr(after_name + 2));
    std::string field;
    unsigned long long utime = 0, stime = 0;
    // Fields 3.. of proc(5): state, ppid, ..., utime is 14th, stime 15th.
    for (int i = 3; i <= 15 && fields >> field; ++i) {
      if (i == 14) utime = std::stoull(field);
      if (i == 15) stime = std::stoull(field);
    }
    figures.cpu_s =
        static_cast<double>(utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
  }
  std::error_code ec;
  int fds = 0;
  for (std::filesystem::directory_iterator it(dir + "/fd", ec), end; !ec && it != end;
       it.increment(ec)) {
    ++fds;
  }
  if (!ec) figures.fds = fds;
  return figures;
}

// A Command as the test wants it on the wire. Strings go out as C strings:
// a NUL inside one ends it at the sender.
struct RawCommand {
  std::string request_id, client, token, verb, arguments;
};

struct RawReply {
  std::string request_id, client;
  std::int32_t code = -1;
  std::string code_name, message, result;
  std::chrono::steady_clock::time_point arrived;  // when the collector took it
};

// Joins the domain of `domain_id` (already created in this process) with a
// participant of its own.
inline std::shared_ptr<dds::Participant> JoinDomain(std::uint32_t domain_id, std::string* error) {
  dds::ParticipantOptions options;
  options.domain_id = domain_id;
  return dds::Participant::Create(options, error);
}

// A reader or writer (Endpoint: dds::Reader<Msg> or dds::Writer<Msg>) of
// `topic` in a participant of its own that joins the domain. Null with
// *error.
template <typename Endpoint, typename Topic>
std::unique_ptr<Endpoint> JoinWith(std::uint32_t domain_id, const Topic& topic,
                                   std::string* error) {
  auto participant = JoinDomain(domain_id, error);
  return participant ? Endpoint::Create(participant, topic, error) : nullptr;
}

// A writer on the station's command topic, in a participant of its own.
class CommandPeer {
 public:
  static std::unique_ptr<CommandPeer> Create(std::uint32_t domain_id, const std::string& station,
                                             std::string* error) {
    auto writer =
        JoinWith<dds::Writer<dds::msg::Command>>(domain_id, dds::CommandTopic(station), error);
    return writer ? std::unique_ptr<CommandPeer>(new CommandPeer(std::move(writer))) : nullptr;
  }

  // Waits until the daemon's command reader is matched.
  bool WaitForDaemon(std::chrono::milliseconds timeout) {
    return writer_->WaitForReaders(1, timeout);
  }

  // Writes `command` (serialised during the call). Thread-safe.
  bool Write(const RawCommand& command, std::string* error) {
    dds::Outgoing<dds::msg::Command> out;
    out.msg().request_id = out.Keep(command.request_id);
    out.msg().client = out.Keep(command.client);
    out.msg().token = out.Keep(command.token);
    out.msg().verb = out.Keep(command.verb);
    out.msg().arguments = out.Keep(command.arguments);
    return writer_->Write(out.msg(), error);
  }
  // Writes a Command whose strings are all null pointers.
  bool WriteEmpty(std::string* error) {
    dds::Outgoing<dds::msg::Command> out;
    return writer_->Write(out.msg(), error);
  }
  bool WaitForAcks(std::chrono::milliseconds timeout, std::string* error) {
    return writer_->WaitForAcks(timeout, error);
  }

 private:
  explicit CommandPeer(std::unique_ptr<dds::Writer<dds::msg::Command>> writer)
      : writer_(std::move(writer)) {}
  std::unique_ptr<dds::Writer<dds::msg::Command>> writer_;
};

// A reader of Msg whose own thread hands every sample it takes to
// `on_sample` until this object is destroyed.
template <typename Msg>
class ReaderThread {
 public:
  ReaderThread(std::unique_ptr<dds::Reader<Msg>> reader, std::function<void(const Msg&)> on_sample)
      : reader_(std::move(reader)), on_sample_(std::move(on_sample)), thread_([this] { Loop(); }) {}
  ~ReaderThread() {
    running_ = false;
    thread_.join();
  }
  dds::Reader<Msg>& reader() { return *reader_; }

 private:
  void Loop() {
    dds::Sample<Msg> sample;
    std::string error;
    while (running_) {
      if (reader_->Take(std::chrono::milliseconds(50), &sample, &error) == dds::TakeStatus::kOk) {
        on_sample_(*sample);
      }
    }
  }

  std::unique_ptr<dds::Reader<Msg>> reader_;
  std::function<void(const Msg&)> on_sample_;
  std::atomic<bool> running_{true};
  std::thread thread_;  // last: starts after the members it uses
};

// Takes every Reply of the station on its own thread and keeps them all.
class ReplyCollector {
 public:
  static std::unique_ptr<ReplyCollector> Create(std::uint32_t domain_id, const std::string& station,
                                                std::string* error) {
    auto reader =
        JoinWith<dds::Reader<dds::msg::Reply>>(domain_id, dds::ReplyTopic(station), error);
    return reader ? std::unique_ptr<ReplyCollector>(new ReplyCollector(std::move(reader)))
                  : nullptr;
  }

  bool WaitForDaemon(std::chrono::milliseconds timeout) {
    return thread_.reader().WaitForWriters(1, timeout);
  }

  // The first reply with this request id and client that arrives within
  // `timeout` (already arrived ones count).
  std::optional<RawReply> WaitFor(const std::string& request_id, const std::string& client,
                                  std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    const auto key = std::make_pair(request_id, client);
    if (!changed_.wait_for(lock, timeout, [&] { return index_.count(key) > 0; }))
      return std::nullopt;
    return replies_[index_.at(key)];
  }
  std::vector<RawReply> All() {
    std::lock_guard lock(mutex_);
    return replies_;
  }

 private:
  explicit ReplyCollector(std::unique_ptr<dds::Reader<dds::msg::Reply>> reader)
      : thread_(std::move(reader), [this](const dds::msg::Reply& m) { Keep(m); }) {}

  void Keep(const dds::msg::Reply& m) {
    RawReply r{std::string(dds::View(m.request_id)),
               std::string(dds::View(m.client)),
               m.code,
               std::string(dds::View(m.code_name)),
               std::string(dds::View(m.message)),
               std::string(dds::View(m.result)),
               std::chrono::steady_clock::now()};
    std::lock_guard lock(mutex_);
    index_.emplace(std::make_pair(r.request_id, r.client), replies_.size());
    replies_.push_back(std::move(r));
    changed_.notify_all();
  }

  std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<RawReply> replies_;                                     // guarded by mutex_
  std::map<std::pair<std::string, std::string>, std::size_t> index_;  // first of each key
  ReaderThread<dds::msg::Reply> thread_;  // last: starts after the members it uses
};

// Records when each StationStatus sample arrives (steady clock).
class StatusMonitor {
 public:
  using Clock = std::chrono::steady_clock;

  static std::unique_ptr<StatusMonitor> Create(std::uint32_t domain_id, const std::string& station,
                                               std::string* error) {
    auto reader =
        JoinWith<dds::Reader<dds::msg::StationStatus>>(domain_id, dds::StatusTopic(station), error);
    return reader ? std::unique_ptr<StatusMonitor>(new StatusMonitor(std::move(reader))) : nullptr;
  }

  // The longest time without a status sample within [from, to], counting
  // from `from` to the first sample and from the last one to `to`.
  std::chrono::duration<double> LongestGap(Clock::time_point from, Clock::time_point to) {
    std::lock_guard lock(mutex_);
    Clock::time_point previous = from;
    Clock::duration longest{0};
    for (const Clock::time_point t : arrivals_) {
      if (t < from) continue;
      if (t > to) break;
      longest = std::max(longest, t - previous);
      previous = t;
    }
    return std::max(longest, to - previous);
  }
  std::size_t CountBetween(Clock::time_point from, Clock::time_point to) {
    std::lock_guard lock(mutex_);
    return static_cast<std::size_t>(
        std::count_if(arrivals_.begin(), arrivals_.end(),
                      [&](Clock::time_point t) { return t >= from && t <= to; }));
  }

 private:
  explicit StatusMonitor(std::unique_ptr<dds::Reader<dds::msg::StationStatus>> reader)
      : thread_(std::move(reader), [this](const dds::msg::StationStatus&) {
          std::lock_guard lock(mutex_);
          arrivals_.push_back(Clock::now());
        }) {}

  std::mutex mutex_;
  std::vector<Clock::time_point> arrivals_;       // guarded by mutex_
  ReaderThread<dds::msg::StationStatus> thread_;  // last: starts after the members it uses
};

}  // namespace craftscan::testing
