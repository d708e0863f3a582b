// A DDS client of one station for the daemon's tests, over the client
// library (craftscan/client/station_client.h): sends Commands and waits for
// their Replies, and collects what the daemon publishes (progress, captures,
// disparity maps, clouds, status) into vectors the tests read under Lock()
// or in WaitFor(). Also: a second client that keeps every StationStatus sample
// (StatusWatcher), and waiting for a job's end through the status verb
// (WaitForJobEnd).
#pragma once

#include <algorithm>
#include <cfloat>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "craftscan/client/station_client.h"
#include "craftscan/pipeline/common/point_cloud.h"

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

struct DisparityRecord {
  std::string session;
  int view = 0;
  int width = 0, height = 0;
  std::int64_t valid_pixels = 0;  // finite values
  std::uint64_t hash = 0;         // FNV-1a of the map's bytes
  float min_disparity = 0, max_disparity = 0, f_px = 0, baseline_mm = 0;
};

// What tests compare of a disparity map (CV_32FC1): its finite pixels and
// the FNV-1a of its bytes (rows packed).
inline void SummarizeDisparity(const cv::Mat& map, std::int64_t* valid_pixels,
                               std::uint64_t* hash) {
  const cv::Mat packed = map.isContinuous() ? map : map.clone();
  client::Fnv1a64Hasher hasher;
  hasher.Update(packed.data, packed.total() * packed.elemSize());
  *hash = hasher.value();
  *valid_pixels = cv::countNonZero((packed >= -FLT_MAX) & (packed <= FLT_MAX));
}

class StationClient {
 public:
  // `config`: the Cyclone configuration (see dds::ParticipantOptions).
  bool Start(std::uint32_t domain, const std::string& config, const std::string& station,
             std::string* error) {
    client::ConnectOptions options;
    options.station = station;
    options.domain_id = domain;
    options.dds_config = config;
    options.client_name = "test";
    client_ = client::StationClient::Connect(options, error);
    if (!client_) return false;
    return client_->SubscribeProgress(
               [this](const client::ProgressUpdate& p) {
                 Record([&] {
                   progress.emplace_back(p.job_id, p.stage);
                   progress_messages.push_back(p.message);
                 });
               },
               error) &&
           client_->SubscribeClouds(
               [this](const client::CloudUpdate& c) {
                 Record([&] { clouds.push_back({c.session, c.view_index, c.cloud}); });
               },
               error) &&
           client_->SubscribeCaptures(
               [this](const client::CaptureUpdate& c) {
                 client::Fnv1a64Hasher hash;  // the clone is continuous: rows packed
                 hash.Update(c.left.data, c.left.total() * c.left.elemSize());
                 Record([&] {
                   captures.push_back({c.session, c.view_index, c.angle_deg, c.left.cols,
                                       c.left.rows, hash.value()});
                 });
               },
               error) &&
           client_->SubscribeDisparity(
               [this](const client::DisparityUpdate& d) {
                 DisparityRecord r;
                 r.session = d.session;
                 r.view = d.view_index;
                 r.width = d.disparity.cols;
                 r.height = d.disparity.rows;
                 r.min_disparity = d.min_disparity;
                 r.max_disparity = d.max_disparity;
                 r.f_px = d.f_px;
                 r.baseline_mm = d.baseline_mm;
                 SummarizeDisparity(d.disparity, &r.valid_pixels, &r.hash);
                 Record([&] { disparities.push_back(std::move(r)); });
               },
               error) &&
           client_->SubscribeStatus(
               [this](const client::StatusUpdate& s) {
                 Record([&] {
                   last_status_state = s.state;
                   last_job_state = s.job_state;
                   last_job_id = s.job_id;
                 });
               },
               error);
  }

  // Stops the subscription threads before the records they fill go.
  ~StationClient() { client_.reset(); }

  // Waits until the daemon's command reader and reply writer are matched.
  bool WaitForDaemon(std::chrono::milliseconds timeout) { return client_->WaitForDaemon(timeout); }

  std::optional<ReplyRecord> Send(const std::string& verb, const nlohmann::json& args,
                                  const std::string& token,
                                  std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
    return SendRaw(verb, args.is_null() ? "" : args.dump(), token, timeout);
  }

  std::optional<ReplyRecord> SendRaw(const std::string& verb, const std::string& arguments,
                                     const std::string& token,
                                     std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
    const client::CallResult r = client_->CallRaw(verb, arguments, token, timeout);
    if (r.status != client::CallStatus::kReplied) return std::nullopt;
    return ReplyRecord{r.reply.code, r.reply.code_name, r.reply.message, r.reply.result};
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
  std::vector<DisparityRecord> disparities;
  std::string last_status_state, last_job_state, last_job_id;
  std::unique_lock<std::mutex> Lock() { return std::unique_lock(mutex_); }

 private:
  template <typename Update>
  void Record(Update update) {
    std::lock_guard lock(mutex_);
    update();
    changed_.notify_all();
  }

  std::mutex mutex_;
  std::condition_variable changed_;
  std::unique_ptr<client::StationClient> client_;
};

// Polls the status verb (as `token`, every 100 ms) until job `id` has left
// the running state; returns the job's record then, or
// {"state": "still running after the timeout", "last_status": the last reply}.
inline nlohmann::json WaitForJobEnd(StationClient& client, const std::string& token,
                                    const std::string& id, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::string last = "no reply";
  while (std::chrono::steady_clock::now() < deadline) {
    const auto reply = client.Send("status", nullptr, token, std::chrono::seconds(10));
    if (reply && reply->code == 0) {
      nlohmann::json job = reply->result["job"];
      if (job["id"] == id && job["state"] != "running") return job;
      last = reply->result.dump();
    } else if (reply) {
      last = reply->code_name + ": " + reply->message;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return {{"state", "still running after the timeout"}, {"last_status", last}};
}

// Every StationStatus sample, from a second client of the station (the
// StationClient keeps only the latest states). Thread-safe.
class StatusWatcher {
 public:
  // Joins the domain the StationClient already created in this process.
  bool Start(std::uint32_t domain, const std::string& station, std::string* error) {
    client::ConnectOptions options;
    options.station = station;
    options.domain_id = domain;
    options.dds_config = "";  // the domain exists in this process: its config holds
    options.client_name = "watcher";
    client_ = client::StationClient::Connect(options, error);
    return client_ && client_->SubscribeStatus(
                          [this](const client::StatusUpdate& s) {
                            std::lock_guard lock(mutex_);
                            seen_.push_back(s);
                            changed_.notify_all();
                          },
                          error);
  }
  // Stops the subscription thread before the samples it fills go.
  ~StatusWatcher() { client_.reset(); }

  // True once any sample so far satisfies `predicate` (StatusUpdate -> bool).
  template <typename Predicate>
  bool WaitFor(Predicate predicate, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout,
                             [&] { return std::any_of(seen_.begin(), seen_.end(), predicate); });
  }

  // True once the latest sample satisfies `predicate`.
  template <typename Predicate>
  bool WaitForLatest(Predicate predicate, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout,
                             [&] { return !seen_.empty() && predicate(seen_.back()); });
  }

  // True once the latest sample shows `device` in `state` (e.g.
  // "turntable", "Fault").
  bool WaitForDeviceState(const std::string& device, const std::string& state,
                          std::chrono::milliseconds timeout = std::chrono::seconds(10)) {
    return WaitForLatest(
        [&](const client::StatusUpdate& s) { return Device(s, device).state == state; }, timeout);
  }

  // The latest sample (empty before the first).
  client::StatusUpdate Last() {
    std::lock_guard lock(mutex_);
    return seen_.empty() ? client::StatusUpdate{} : seen_.back();
  }

  // The device's line in `s` ("camera", "turntable"); empty if absent.
  static client::DeviceState Device(const client::StatusUpdate& s, const std::string& name) {
    for (const client::DeviceState& d : s.devices)
      if (d.name == name) return d;
    return {};
  }

 private:
  std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<client::StatusUpdate> seen_;
  std::unique_ptr<client::StationClient> client_;
};

}  // namespace craftscan::testing
