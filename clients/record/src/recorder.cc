#include "craftscan/record/recorder.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <mutex>
#include <set>
#include <thread>
#include <utility>

#include <spdlog/spdlog.h>

#include "craftscan/client/station_client.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"
#include "reader_loop.h"

namespace craftscan::record {
namespace {

using internal::SetError;

// "capture of session 'x' view 3" for log lines (the session as received).
std::string Describe(std::string_view what, const ItemInfo& item) {
  return std::string(what) + " of session '" + PrintableForLog(item.session) + "' view " +
         std::to_string(item.view_index);
}

}  // namespace

std::string_view ToString(RecordKind kind) {
  switch (kind) {
    case RecordKind::kCaptures:
      return "captures";
    case RecordKind::kClouds:
      return "clouds";
    case RecordKind::kDisparity:
      return "disparity";
    case RecordKind::kModels:
      return "models";
  }
  return "unknown";
}

bool RecordKindFromString(std::string_view text, RecordKind* kind) {
  for (RecordKind k :
       {RecordKind::kCaptures, RecordKind::kClouds, RecordKind::kDisparity, RecordKind::kModels}) {
    if (text == ToString(k)) {
      *kind = k;
      return true;
    }
  }
  return false;
}

std::string_view ToString(StopReason reason) {
  switch (reason) {
    case StopReason::kNone:
      return "running";
    case StopReason::kRequested:
      return "requested";
    case StopReason::kCountReached:
      return "count_reached";
    case StopReason::kLimitReached:
      return "limit_reached";
    case StopReason::kError:
      return "error";
  }
  return "unknown";
}

bool RecorderOptions::IsValid(std::string* why) const {
  if (!internal::CheckReaderOptions(stations, domain_id, reader_history, poll_ms, why)) {
    return false;
  }
  if (what.empty()) return SetError(why, "what: nothing to record");
  if (std::set<RecordKind>(what.begin(), what.end()).size() != what.size()) {
    return SetError(why, "what: a kind is given twice");
  }
  if (std::find(what.begin(), what.end(), RecordKind::kModels) != what.end() && token.empty()) {
    return SetError(why, "models: fetching a model needs a token (--token or CRAFTSCAN_TOKEN)");
  }
  return true;
}

struct Recorder::State {
  RecorderOptions options;
  std::shared_ptr<Archive> archive;
  std::shared_ptr<dds::Participant> participant;
  std::atomic<bool> stopping{false};

  std::mutex join_mutex;  // one Stop() joins
  std::vector<std::thread> threads;

  mutable std::mutex mutex;  // guards everything below
  std::condition_variable done;
  std::vector<StationStats> stats;
  uint64_t items = 0;
  uint64_t reserved = 0;  // items stored or being stored, for max_items
  uint64_t rotated_files = 0, rotated_bytes = 0;
  StopReason reason = StopReason::kNone;
  std::string message;
  // kModels: sessions whose fused cloud came, waiting for their mesh.glb.
  bool record_clouds = false, record_models = false;
  std::deque<std::pair<std::size_t, ItemInfo>> models_due;
  std::condition_variable model_due;
  static constexpr int kModelFetchAttempts = 3;
  static constexpr std::size_t kMaxModelsDue = 16;  // a model per finished scan: never near

  void FinishLocked(StopReason why, const std::string& text) {
    if (reason == StopReason::kNone) {
      reason = why;
      message = text;
    }
    stopping = true;
    done.notify_all();
    model_due.notify_all();
  }

  void Finish(StopReason why, const std::string& text) {
    std::lock_guard lock(mutex);
    FinishLocked(why, text);
  }

  // A slot for one more item under max_items; false once all are taken.
  bool Reserve() {
    std::lock_guard lock(mutex);
    if (options.max_items > 0 && reserved >= options.max_items) return false;
    ++reserved;
    return true;
  }

  void Malformed(std::size_t station, std::string_view what, const ItemInfo& item,
                 const std::string& error) {
    spdlog::warn("{}: skipped malformed {}: {}", item.station, Describe(what, item), error);
    std::lock_guard lock(mutex);
    stats[station].malformed += 1;
  }

  void Stored(std::size_t station, RecordKind kind, const ItemInfo& item,
              const StoreResult& result) {
    const std::string what = Describe(kind == RecordKind::kCaptures    ? "capture"
                                      : kind == RecordKind::kClouds    ? "cloud"
                                      : kind == RecordKind::kDisparity ? "disparity map"
                                                                       : "model",
                                      item);
    std::lock_guard lock(mutex);
    StationStats& s = stats[station];
    rotated_files += result.rotated_files;
    rotated_bytes += result.rotated_bytes;
    if (result.rotated_files > 0) {
      spdlog::info("rotation deleted the {} oldest file(s) ({} bytes) to stay under the limit",
                   result.rotated_files, result.rotated_bytes);
    }
    if (result.status != StoreStatus::kStored) reserved -= 1;
    switch (result.status) {
      case StoreStatus::kStored:
        s.files += result.files;
        s.bytes += result.bytes;
        (kind == RecordKind::kCaptures    ? s.captures
         : kind == RecordKind::kClouds    ? s.clouds
         : kind == RecordKind::kDisparity ? s.disparities
                                          : s.models) += 1;
        items += 1;
        spdlog::info("{}: stored {}: {} file(s), {} bytes", item.station, what, result.files,
                     result.bytes);
        if (options.max_items > 0 && items >= options.max_items) {
          FinishLocked(StopReason::kCountReached,
                       std::to_string(items) + " item(s) stored (--count)");
        }
        break;
      case StoreStatus::kRefused:
        s.refused += 1;
        spdlog::warn("{}: skipped {}: {}", item.station, what, result.message);
        break;
      case StoreStatus::kTooLarge:
        s.too_large += 1;
        spdlog::warn("{}: skipped {}: {}", item.station, what, result.message);
        break;
      case StoreStatus::kLimitReached:
        if (reason == StopReason::kNone) spdlog::warn("stopping: {}", result.message);
        FinishLocked(StopReason::kLimitReached, result.message);
        break;
      case StoreStatus::kFailed:
        s.failed += 1;
        spdlog::error("{}: could not store {}: {}", item.station, what, result.message);
        FinishLocked(StopReason::kError, result.message);
        break;
    }
  }

  void OnCapture(std::size_t station, const dds::msg::StereoCapture& m) {
    const ItemInfo item{options.stations[station], std::string(dds::View(m.session)), m.view_index,
                        m.left_stamp_ns};
    cv::Mat left, right;
    std::string error;
    if (!dds::StereoCaptureToMats(m, &left, &right, &error)) {
      Malformed(station, "capture", item, error);
    } else if (Reserve()) {
      Stored(station, RecordKind::kCaptures, item,
             archive->StoreCapture(item, left, right, m.angle_deg));
    }
  }

  void OnCloud(std::size_t station, const dds::msg::PointCloud& m) {
    const ItemInfo item{options.stations[station], std::string(dds::View(m.session)), m.view_index,
                        m.stamp_ns};
    PointCloud cloud;
    dds::CloudMeta meta;
    std::string error;
    if (!dds::CloudFromMessage(m, &cloud, &meta, &error)) {
      Malformed(station, "cloud", item, error);
    } else if ((meta.kind == "fused") != (meta.view_index == -1) ||
               (meta.kind != "fused" && meta.kind != "view")) {
      Malformed(station, "cloud", item,
                "kind '" + PrintableForLog(meta.kind) + "' does not fit view index " +
                    std::to_string(meta.view_index) + " (fused clouds have view -1)");
    } else {
      if (record_clouds && Reserve()) {
        Stored(station, RecordKind::kClouds, item,
               archive->StoreCloud(item, cloud, meta.world_from_view));
      }
      // Published after the session's outputs are durable: its model is there.
      if (record_models && meta.view_index == -1) {
        std::lock_guard lock(mutex);
        if (models_due.size() < kMaxModelsDue) {
          models_due.emplace_back(station, item);
          model_due.notify_one();
        } else {
          spdlog::warn("{}: model of session '{}' skipped: {} models already waiting", item.station,
                       PrintableForLog(item.session), kMaxModelsDue);
        }
      }
    }
  }

  // kModels: fetches each due session's mesh.glb with `get` (one client per
  // station, connected when first needed) and stores it.
  void ModelLoop() {
    std::vector<std::unique_ptr<client::StationClient>> clients(options.stations.size());
    const std::filesystem::path scratch =
        std::filesystem::temp_directory_path() / ("craftscan-record-" + std::to_string(::getpid()));
    while (true) {
      std::pair<std::size_t, ItemInfo> due;
      {
        std::unique_lock lock(mutex);
        model_due.wait(lock, [&] { return stopping || !models_due.empty(); });
        if (stopping) break;
        due = models_due.front();
        models_due.pop_front();
      }
      const auto& [station, item] = due;
      try {
        FetchModel(station, item, scratch, &clients[station]);
      } catch (const std::exception& e) {
        spdlog::warn("{}: model of session '{}': {}", item.station, PrintableForLog(item.session),
                     e.what());
      }
    }
    std::error_code ignored;
    std::filesystem::remove_all(scratch, ignored);
  }

  void FetchModel(std::size_t station, const ItemInfo& item, const std::filesystem::path& scratch,
                  std::unique_ptr<client::StationClient>* connected) {
    const std::string session = PrintableForLog(item.session);
    std::string error;
    if (!*connected) {
      client::ConnectOptions connect;
      connect.station = item.station;
      connect.domain_id = options.domain_id;
      // The recorder's participant configured the domain in this process:
      // Cyclone wants further participants of it without a config.
      connect.dds_config = "";
      connect.token = options.token;
      connect.client_name = "craftscan-record";
      *connected = client::StationClient::Connect(connect, &error);
      if (!*connected) {
        spdlog::warn("{}: model of session '{}' not fetched: {}", item.station, session, error);
        return;
      }
    }
    client::FetchRequest request;
    request.session = item.session;
    request.files = {"mesh.glb"};
    request.out_dir = (scratch / item.station).string();
    request.cancel = &stopping;
    // A transfer that lost chunks on the way (a network drop, this process
    // falling behind) is fetched again; a refusal is final.
    client::FetchResult fetched;
    for (int attempt = 1; attempt <= kModelFetchAttempts; ++attempt) {
      fetched = (*connected)->Fetch(request);
      if (fetched.status != client::FetchStatus::kTransferFailed || stopping ||
          attempt == kModelFetchAttempts) {
        break;
      }
      spdlog::info("{}: model of session '{}': {}; fetching again ({} of {})", item.station,
                   session, fetched.message, attempt + 1, kModelFetchAttempts);
    }
    if (fetched.status != client::FetchStatus::kOk) {
      spdlog::warn("{}: model of session '{}' not fetched: {}", item.station, session,
                   fetched.message);
      return;
    }
    const std::filesystem::path path = std::filesystem::path(request.out_dir) / "mesh.glb";
    std::ifstream in(path, std::ios::binary);
    const std::string glb((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::error_code ignored;
    std::filesystem::remove(path, ignored);
    if (Reserve()) Stored(station, RecordKind::kModels, item, archive->StoreModel(item, glb));
  }

  void OnDisparity(std::size_t station, const dds::msg::Disparity& m) {
    const ItemInfo item{options.stations[station], std::string(dds::View(m.session)), m.view_index,
                        m.stamp_ns};
    cv::Mat disparity;
    std::string error;
    if (!dds::DisparityToMat(m, &disparity, &error)) {
      Malformed(station, "disparity map", item, error);
    } else if (Reserve()) {
      Stored(station, RecordKind::kDisparity, item, archive->StoreDisparity(item, disparity));
    }
  }

  // Takes samples until stopping; an exception ends the recorder as an error
  // rather than the process.
  template <typename Msg>
  void ReadLoop(std::shared_ptr<dds::Reader<Msg>> reader, std::function<void(const Msg&)> handle) {
    try {
      dds::Sample<Msg> sample;
      internal::TakeUntilStopped(
          reader->topic_name(), options.poll_ms, stopping,
          [&](std::chrono::milliseconds timeout, std::string* error) {
            return reader->Take(timeout, &sample, error);
          },
          [&] { handle(*sample); });
    } catch (const std::exception& e) {
      spdlog::error("{}: {}", reader->topic_name(), e.what());
      Finish(StopReason::kError, reader->topic_name() + ": " + e.what());
    }
  }
};

std::unique_ptr<Recorder> Recorder::Create(const RecorderOptions& options,
                                           std::shared_ptr<Archive> archive, std::string* error) {
  if (!options.IsValid(error)) return nullptr;
  if (!archive) {
    SetError(error, "no archive");
    return nullptr;
  }
  auto state = std::make_shared<State>();
  state->options = options;
  state->archive = std::move(archive);
  for (const std::string& station : options.stations) state->stats.push_back({.station = station});

  dds::ParticipantOptions participant_options;
  participant_options.domain_id = options.domain_id;
  participant_options.config = options.dds_config;
  std::string dds_error;
  state->participant = dds::Participant::Create(participant_options, &dds_error);
  if (!state->participant) {
    SetError(error, "DDS: " + dds_error);
    return nullptr;
  }

  // All readers first, so a failure leaves no thread to join.
  std::vector<std::function<void()>> loops;
  State* s = state.get();
  const auto add = [&]<typename Msg>(dds::TopicSpec<Msg> topic,
                                     void (State::*on)(std::size_t, const Msg&),
                                     std::size_t station) {
    topic.qos.history_depth = options.reader_history;
    std::shared_ptr<dds::Reader<Msg>> reader =
        dds::Reader<Msg>::Create(s->participant, topic, &dds_error);
    if (!reader) return SetError(error, "DDS: " + dds_error);
    loops.push_back([s, reader, on, station] {
      s->ReadLoop<Msg>(reader, [s, on, station](const Msg& m) { (s->*on)(station, m); });
    });
    return true;
  };
  const auto wanted = [&](RecordKind kind) {
    return std::find(options.what.begin(), options.what.end(), kind) != options.what.end();
  };
  state->record_clouds = wanted(RecordKind::kClouds);
  state->record_models = wanted(RecordKind::kModels);
  for (std::size_t i = 0; i < options.stations.size(); ++i) {
    const std::string& station = options.stations[i];
    // Models follow the fused clouds: the cloud topic is read for either.
    if ((state->record_clouds || state->record_models) &&
        !add(dds::CloudTopic(station), &State::OnCloud, i))
      return nullptr;
    if (wanted(RecordKind::kCaptures) && !add(dds::CaptureTopic(station), &State::OnCapture, i))
      return nullptr;
    if (wanted(RecordKind::kDisparity) &&
        !add(dds::DisparityTopic(station), &State::OnDisparity, i))
      return nullptr;
  }
  if (state->record_models) loops.push_back([s] { s->ModelLoop(); });
  // Stop() joins the threads before the state (participant, archive) goes.
  for (auto& loop : loops) state->threads.emplace_back(std::move(loop));
  return std::unique_ptr<Recorder>(new Recorder(std::move(state)));
}

Recorder::Recorder(std::shared_ptr<State> state) : state_(std::move(state)) {}

Recorder::~Recorder() { Stop(); }

bool Recorder::WaitUntilDone(std::chrono::milliseconds timeout) {
  std::unique_lock lock(state_->mutex);
  return state_->done.wait_for(lock, timeout, [&] { return state_->reason != StopReason::kNone; });
}

void Recorder::Stop(const std::string& message) {
  state_->Finish(StopReason::kRequested, message);
  std::lock_guard lock(state_->join_mutex);
  for (std::thread& thread : state_->threads) {
    if (thread.joinable()) thread.join();
  }
}

RecorderSummary Recorder::Summary() const {
  RecorderSummary summary;
  {
    std::lock_guard lock(state_->mutex);
    summary.stations = state_->stats;
    summary.items = state_->items;
    summary.rotated_files = state_->rotated_files;
    summary.rotated_bytes = state_->rotated_bytes;
    summary.reason = state_->reason;
    summary.message = state_->message;
  }
  summary.archive = state_->archive->totals();
  return summary;
}

}  // namespace craftscan::record
