// A DDS client of one station for the daemon's tests: sends Commands and
// waits for their Replies, and collects what the daemon publishes (progress,
// captures, clouds, status) on background readers.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"
#include "craftscan/pipeline/point_cloud.h"

namespace craftscan::testing {

struct ReplyRecord {
  std::int32_t code = -1;
  std::string code_name, message;
  nlohmann::json result;
};

struct CloudRecord {
  std::string session;
  int view = 0;
  PointCloud cloud;
};

struct CaptureRecord {
  std::string session;
  int view = 0;
  double angle_deg = 0;
  int width = 0, height = 0;
  std::uint64_t left_hash = 0;  // FNV-1a of the left pixels
};

class StationClient {
 public:
  // `config`: the Cyclone configuration (see dds::ParticipantOptions).
  bool Start(std::uint32_t domain, const std::string& config, const std::string& station,
             std::string* error) {
    dds::ParticipantOptions options;
    options.domain_id = domain;
    options.config = config;
    participant_ = dds::Participant::Create(options, error);
    if (!participant_) return false;
    if (!(commands_ = dds::Writer<dds::msg::Command>::Create(participant_, dds::CommandTopic(station), error)) ||
        !(replies_ = dds::Reader<dds::msg::Reply>::Create(participant_, dds::ReplyTopic(station), error)) ||
        !(progress_ = dds::Reader<dds::msg::JobProgress>::Create(participant_, dds::ProgressTopic(station), error)) ||
        !(clouds_ = dds::Reader<dds::msg::PointCloud>::Create(participant_, dds::CloudTopic(station), error)) ||
        !(captures_ = dds::Reader<dds::msg::StereoCapture>::Create(participant_, dds::CaptureTopic(station), error)) ||
        !(status_ = dds::Reader<dds::msg::StationStatus>::Create(participant_, dds::StatusTopic(station), error))) {
      return false;
    }
    running_ = true;
    threads_.emplace_back([this] { ReplyLoop(); });
    threads_.emplace_back([this] { ProgressLoop(); });
    threads_.emplace_back([this] { CloudLoop(); });
    threads_.emplace_back([this] { CaptureLoop(); });
    threads_.emplace_back([this] { StatusLoop(); });
    return true;
  }

  ~StationClient() {
    running_ = false;
    for (std::thread& t : threads_) t.join();
  }

  // Waits until the daemon's command reader and status writer are matched.
  bool WaitForDaemon(std::chrono::milliseconds timeout) {
    return commands_->WaitForReaders(1, timeout) && replies_->WaitForWriters(1, timeout);
  }

  std::optional<ReplyRecord> Send(const std::string& verb, const nlohmann::json& args,
                                  const std::string& token,
                                  std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
    return SendRaw(verb, args.is_null() ? "" : args.dump(), token, timeout);
  }

  std::optional<ReplyRecord> SendRaw(const std::string& verb, const std::string& arguments,
                                     const std::string& token,
                                     std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
    const std::string id = "req-" + std::to_string(++next_id_);
    dds::Outgoing<dds::msg::Command> out;
    out.msg().request_id = out.Keep(id);
    out.msg().client = out.Keep("test");
    out.msg().token = out.Keep(token);
    out.msg().verb = out.Keep(verb);
    out.msg().arguments = out.Keep(arguments);
    std::string error;
    if (!commands_->Write(out.msg(), &error)) return std::nullopt;
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::unique_lock lock(mutex_);
    while (std::chrono::steady_clock::now() < deadline) {
      if (auto it = replies_by_id_.find(id); it != replies_by_id_.end()) return it->second;
      changed_.wait_until(lock, deadline);
    }
    return std::nullopt;
  }

  // Waits until `predicate` (called under the lock) holds.
  template <typename Predicate>
  bool WaitFor(Predicate predicate, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout, [&] { return predicate(*this); });
  }

  // Guarded by the mutex (read inside WaitFor or after Lock()).
  std::vector<std::pair<std::string, std::string>> progress;  // (job, stage)
  std::vector<std::string> progress_messages;
  std::vector<CloudRecord> clouds;
  std::vector<CaptureRecord> captures;
  std::string last_status_state, last_job_state, last_job_id;
  std::unique_lock<std::mutex> Lock() { return std::unique_lock(mutex_); }

 private:
  template <typename Msg, typename Handle>
  void Loop(dds::Reader<Msg>& reader, Handle handle) {
    dds::Sample<Msg> sample;
    std::string error;
    while (running_) {
      if (reader.Take(std::chrono::milliseconds(50), &sample, &error) != dds::TakeStatus::kOk) continue;
      std::lock_guard lock(mutex_);
      handle(*sample);
      changed_.notify_all();
    }
  }
  void ReplyLoop() {
    Loop(*replies_, [this](const dds::msg::Reply& r) {
      ReplyRecord record;
      record.code = r.code;
      record.code_name = std::string(dds::View(r.code_name));
      record.message = std::string(dds::View(r.message));
      const std::string_view result = dds::View(r.result);
      record.result = result.empty() ? nlohmann::json::object()
                                     : nlohmann::json::parse(result, nullptr, false);
      replies_by_id_[std::string(dds::View(r.request_id))] = record;
    });
  }
  void ProgressLoop() {
    Loop(*progress_, [this](const dds::msg::JobProgress& p) {
      progress.emplace_back(std::string(dds::View(p.job_id)), std::string(dds::View(p.stage)));
      progress_messages.emplace_back(dds::View(p.message));
    });
  }
  void CloudLoop() {
    Loop(*clouds_, [this](const dds::msg::PointCloud& c) {
      CloudRecord record;
      record.session = std::string(dds::View(c.session));
      record.view = c.view_index;
      std::string error;
      if (dds::CloudFromMessage(c, &record.cloud, nullptr, &error)) clouds.push_back(std::move(record));
    });
  }
  void CaptureLoop() {
    Loop(*captures_, [this](const dds::msg::StereoCapture& c) {
      CaptureRecord record;
      record.session = std::string(dds::View(c.session));
      record.view = c.view_index;
      record.angle_deg = c.angle_deg;
      record.width = static_cast<int>(c.width);
      record.height = static_cast<int>(c.height);
      std::uint64_t h = 1469598103934665603ull;
      for (std::uint32_t i = 0; i < c.left_data._length; ++i) {
        h = (h ^ c.left_data._buffer[i]) * 1099511628211ull;
      }
      record.left_hash = h;
      captures.push_back(record);
    });
  }
  void StatusLoop() {
    Loop(*status_, [this](const dds::msg::StationStatus& s) {
      last_status_state = std::string(dds::View(s.state));
      last_job_state = std::string(dds::View(s.job_state));
      last_job_id = std::string(dds::View(s.job_id));
    });
  }

  std::shared_ptr<dds::Participant> participant_;
  std::unique_ptr<dds::Writer<dds::msg::Command>> commands_;
  std::unique_ptr<dds::Reader<dds::msg::Reply>> replies_;
  std::unique_ptr<dds::Reader<dds::msg::JobProgress>> progress_;
  std::unique_ptr<dds::Reader<dds::msg::PointCloud>> clouds_;
  std::unique_ptr<dds::Reader<dds::msg::StereoCapture>> captures_;
  std::unique_ptr<dds::Reader<dds::msg::StationStatus>> status_;
  std::atomic<bool> running_{false};
  std::vector<std::thread> threads_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, ReplyRecord> replies_by_id_;
  int next_id_ = 0;
};

}  // namespace craftscan::testing
