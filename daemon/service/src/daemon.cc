#include "craftscan/daemon/daemon.h"

#include <fcntl.h>
#include <malloc.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <ctime>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include <spdlog/spdlog.h>

#include "craftscan/daemon/auth.h"
#include "craftscan/daemon/commands.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/notify.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

namespace craftscan::daemon {
namespace {

using Clock = std::chrono::steady_clock;

// How often an unusable data directory is tried again (like the devices).
constexpr std::chrono::seconds kStoreRetryInterval{10};

std::int64_t WallNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void Log(drivers::LogLevel level, std::string_view message) {
  switch (level) {
    case drivers::LogLevel::kDebug:
      spdlog::debug("{}", message);
      break;
    case drivers::LogLevel::kInfo:
      spdlog::info("{}", message);
      break;
    case drivers::LogLevel::kWarning:
      spdlog::warn("{}", message);
      break;
    case drivers::LogLevel::kError:
      spdlog::error("{}", message);
      break;
  }
}

// Publishes what the jobs produce on the station's topics (craftscan's and
// the ROS 2-compatible ones). A failed write is logged, never fatal: a slow
// subscriber must not stop a scan (the data is on disk).
class DdsPublisher : public JobSink {
 public:
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error) {
    station_ = station;
    using dds::Side;
    return (progress_ = dds::Writer<dds::msg::JobProgress>::Create(p, dds::ProgressTopic(station),
                                                                   error)) &&
           (capture_ = dds::Writer<dds::msg::StereoCapture>::Create(p, dds::CaptureTopic(station),
                                                                    error)) &&
           (disparity_ =
                dds::Writer<dds::msg::Disparity>::Create(p, dds::DisparityTopic(station), error)) &&
           (cloud_ =
                dds::Writer<dds::msg::PointCloud>::Create(p, dds::CloudTopic(station), error)) &&
           (ros_left_ = dds::Writer<dds::ros::Image>::Create(
                p, dds::RosImageTopic(station, Side::kLeft), error)) &&
           (ros_right_ = dds::Writer<dds::ros::Image>::Create(
                p, dds::RosImageTopic(station, Side::kRight), error)) &&
           (ros_info_left_ = dds::Writer<dds::ros::CameraInfo>::Create(
                p, dds::RosCameraInfoTopic(station, Side::kLeft), error)) &&
           (ros_info_right_ = dds::Writer<dds::ros::CameraInfo>::Create(
                p, dds::RosCameraInfoTopic(station, Side::kRight), error)) &&
           (ros_disparity_ = dds::Writer<dds::ros::DisparityImage>::Create(
                p, dds::RosDisparityTopic(station), error)) &&
           (ros_cloud_ =
                dds::Writer<dds::ros::PointCloud2>::Create(p, dds::RosCloudTopic(station), error));
  }

  Clock::time_point last_activity() const {
    std::lock_guard lock(mutex_);
    return last_activity_;
  }

  void Progress(const std::string& job, const std::string& stage, int current, int total,
                const std::string& message) override {
    Touch();
    dds::Outgoing<dds::msg::JobProgress> out;
    out.msg().job_id = out.Keep(job);
    out.msg().stage = out.Keep(stage);
    out.msg().current = current;
    out.msg().total = total;
    out.msg().message = out.Keep(message);
    out.msg().stamp_ns = WallNs();
    Write(*progress_, out.msg(), "progress");
  }

  void Capture(const std::string& session, int view, double angle_deg,
               const drivers::StereoFrame& frame) override {
    Touch();
    std::string error;
    dds::StereoCaptureMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.angle_deg = angle_deg;
    meta.exposure_us = frame.settings.exposure_us;
    meta.gain_db = frame.settings.gain_db;
    const std::int64_t now = WallNs();
    meta.left_stamp_ns = meta.right_stamp_ns = now;
    meta.left_frame_id = station_ + "_left_optical";
    meta.right_frame_id = station_ + "_right_optical";
    dds::Outgoing<dds::msg::StereoCapture> out;
    if (dds::MakeStereoCapture(frame.left.image, frame.right.image, meta, &out, &error)) {
      Write(*capture_, out.msg(), "capture");
    } else {
      spdlog::warn("capture topic: {}", error);
    }
    dds::Outgoing<dds::ros::Image> left, right;
    if (dds::MakeImage(frame.left.image, now, meta.left_frame_id, &left, &error) &&
        dds::MakeImage(frame.right.image, now, meta.right_frame_id, &right, &error)) {
      Write(*ros_left_, left.msg(), "left image_raw");
      Write(*ros_right_, right.msg(), "right image_raw");
    } else {
      spdlog::warn("image_raw topics: {}", error);
    }
  }

  void Disparity(const std::string& session, int view, const cv::Mat& disparity, double focal_px,
                 double baseline_mm, int min_disparity, int num_disparities) override {
    Touch();
    std::string error;
    dds::DisparityMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.f_px = static_cast<float>(focal_px);
    meta.baseline_mm = static_cast<float>(baseline_mm);
    meta.cx_offset_px = cx_offset_px_;
    meta.min_disparity = static_cast<float>(min_disparity);
    meta.max_disparity = static_cast<float>(min_disparity + num_disparities - 1);
    meta.stamp_ns = WallNs();
    meta.frame_id = station_ + "_rig";
    dds::Outgoing<dds::msg::Disparity> out;
    if (dds::MakeDisparity(disparity, meta, &out, &error)) {
      Write(*disparity_, out.msg(), "disparity");
    } else {
      spdlog::warn("disparity topic: {}", error);
    }
    dds::Outgoing<dds::ros::DisparityImage> ros;
    if (dds::MakeDisparityImage(disparity, meta, &ros, &error)) {
      Write(*ros_disparity_, ros.msg(), "ros disparity");
    } else {
      spdlog::warn("ros disparity topic: {}", error);
    }
  }

  void Cloud(const std::string& session, int view, const PointCloud& cloud,
             const cv::Matx44d& world_from_cloud) override {
    Touch();
    std::string error;
    dds::CloudMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.kind = view < 0 ? "fused" : "view";
    meta.world_from_view = world_from_cloud;
    meta.stamp_ns = WallNs();
    meta.frame_id = view < 0 ? station_ + "_turntable" : station_ + "_rig";
    dds::Outgoing<dds::msg::PointCloud> out;
    if (dds::MakeCloud(cloud, meta, &out, &error)) {
      Write(*cloud_, out.msg(), "cloud");
    } else {
      spdlog::warn("cloud topic: {}", error);
    }
    dds::Outgoing<dds::ros::PointCloud2> ros;
    if (dds::MakePointCloud2(cloud, meta.stamp_ns, meta.frame_id, &ros, &error)) {
      Write(*ros_cloud_, ros.msg(), "ros cloud");
    } else {
      spdlog::warn("ros cloud topic: {}", error);
    }
  }

  void CalibrationChanged(const StereoCalibration& calibration) override {
    std::string error;
    cx_offset_px_ = static_cast<float>(calibration.P1(0, 2) - calibration.P2(0, 2));
    const std::int64_t now = WallNs();
    dds::Outgoing<dds::ros::CameraInfo> left, right;
    if (dds::MakeCameraInfo(calibration, dds::Side::kLeft, now, station_ + "_left_optical", &left,
                            &error) &&
        dds::MakeCameraInfo(calibration, dds::Side::kRight, now, station_ + "_right_optical",
                            &right, &error)) {
      Write(*ros_info_left_, left.msg(), "left camera_info");
      Write(*ros_info_right_, right.msg(), "right camera_info");
    } else {
      spdlog::warn("camera_info topics: {}", error);
    }
  }

 private:
  void Touch() {
    std::lock_guard lock(mutex_);
    last_activity_ = Clock::now();
  }
  template <typename Msg>
  void Write(dds::Writer<Msg>& writer, const Msg& msg, const char* what) {
    std::string error;
    if (!writer.Write(msg, &error)) spdlog::warn("{}: {}", what, error);
  }

  std::string station_;
  std::atomic<float> cx_offset_px_{0};
  mutable std::mutex mutex_;
  Clock::time_point last_activity_ = Clock::now();
  std::unique_ptr<dds::Writer<dds::msg::JobProgress>> progress_;
  std::unique_ptr<dds::Writer<dds::msg::StereoCapture>> capture_;
  std::unique_ptr<dds::Writer<dds::msg::Disparity>> disparity_;
  std::unique_ptr<dds::Writer<dds::msg::PointCloud>> cloud_;
  std::unique_ptr<dds::Writer<dds::ros::Image>> ros_left_, ros_right_;
  std::unique_ptr<dds::Writer<dds::ros::CameraInfo>> ros_info_left_, ros_info_right_;
  std::unique_ptr<dds::Writer<dds::ros::DisparityImage>> ros_disparity_;
  std::unique_ptr<dds::Writer<dds::ros::PointCloud2>> ros_cloud_;
};

// Streams the files of `get` transfers (commands.h) on the station's file
// topic, one transfer at a time on its own thread, so a large file never
// stalls the command loop. Every kAckWindowBytes the sender waits for the
// readers' acknowledgements (bounded by kAckTimeout), so it never runs
// ahead of the network; readers keep kFileTopicDepth chunks for an
// application that lags behind, and a reader gone silent ends the transfer
// (with a log line) instead of stalling it. Chunks go to every reader of the
// topic; clients keep those with their request id.
class FileSender {
 public:
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error) {
    writer_ = dds::Writer<dds::msg::SessionFile>::Create(p, dds::FileTopic(station), error);
    if (!writer_) return false;
    thread_ = std::thread([this] { Loop(); });
    return true;
  }
  ~FileSender() { Stop(); }

  // Whether Enqueue would not exceed kMaxQueuedTransfers waiting transfers.
  // Only the command loop enqueues, so the answer holds until it does.
  bool HasRoom() const {
    std::lock_guard lock(mutex_);
    return queue_.size() < kMaxQueuedTransfers;
  }
  void Enqueue(std::string request_id, std::string client, FileTransfer transfer) {
    std::lock_guard lock(mutex_);
    queue_.push_back({std::move(request_id), std::move(client), std::move(transfer)});
    wake_.notify_one();
  }
  // Drops waiting transfers, ends the running one with an error chunk and
  // joins the thread.
  void Stop() {
    {
      std::lock_guard lock(mutex_);
      stopping_ = true;
      queue_.clear();
      wake_.notify_one();
    }
    if (thread_.joinable()) thread_.join();
  }

 private:
  static constexpr std::size_t kAckWindowBytes = std::size_t{8} << 20;
  static constexpr std::size_t kMaxWindowChunks = 16;  // well below kFileTopicDepth
  static constexpr auto kAckTimeout = std::chrono::seconds(10);

  struct Job {
    std::string request_id, client;
    FileTransfer transfer;
  };

  void Loop() {
    for (;;) {
      Job job;
      {
        std::unique_lock lock(mutex_);
        wake_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
        if (stopping_) return;
        job = std::move(queue_.front());
        queue_.pop_front();
      }
      const auto start = Clock::now();
      std::string error;
      if (Send(job, &error)) {
        spdlog::debug("get {}: sent {} files of session {} in {:.2f} s", job.request_id,
                      job.transfer.files.size(), job.transfer.session,
                      std::chrono::duration<double>(Clock::now() - start).count());
      } else {
        spdlog::warn("get {}: transfer of session {} ended: {}", job.request_id,
                     job.transfer.session, error);
      }
    }
  }

  bool Stopping() const {
    std::lock_guard lock(mutex_);
    return stopping_;
  }

  // Writes one chunk of file `index`. `data` may be null for no data.
  bool WriteChunk(const Job& job, std::uint32_t index, std::uint64_t offset,
                  const std::uint8_t* data, std::size_t size, bool last, const std::string& problem,
                  std::string* error) {
    const TransferFile& file = job.transfer.files[index];
    dds::Outgoing<dds::msg::SessionFile> out;
    auto& m = out.msg();
    m.request_id = out.Keep(job.request_id);
    m.client = out.Keep(job.client);
    m.session = out.Keep(job.transfer.session);
    m.name = out.Keep(file.name);
    m.file_index = index;
    m.file_count = static_cast<std::uint32_t>(job.transfer.files.size());
    m.total_size = file.size_bytes;
    m.offset = offset;
    if (size > 0) dds::Borrow(&m.data, data, size);
    m.last = last;
    m.error = out.Keep(problem);
    return writer_->Write(m, error);
  }

  // Sends an error chunk for file `index` (best effort) and returns false
  // with *error = problem.
  bool Abort(const Job& job, std::uint32_t index, const std::string& problem, std::string* error) {
    std::string ignored;
    WriteChunk(job, index, 0, nullptr, 0, true, problem, &ignored);
    *error = job.transfer.files[index].name + ": " + problem;
    return false;
  }

  bool Send(const Job& job, std::string* error) {
    const std::size_t chunk = std::clamp(job.transfer.chunk_bytes, kMinTransferChunkBytes,
                                         std::min(kMaxTransferChunkBytes, dds::kMaxFileChunkBytes));
    const std::size_t window =
        std::clamp<std::size_t>(kAckWindowBytes / chunk, 1, kMaxWindowChunks);
    std::vector<std::uint8_t> buffer(chunk);
    std::size_t unacknowledged = 0;
    for (std::uint32_t index = 0; index < job.transfer.files.size(); ++index) {
      const TransferFile& file = job.transfer.files[index];
      const int fd = ::open(file.path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY);
      if (fd < 0)
        return Abort(job, index, std::string("cannot open it: ") + std::strerror(errno), error);
      struct Closer {
        int fd;
        ~Closer() { ::close(fd); }
      } closer{fd};
      struct stat st {};
      if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        return Abort(job, index, "not a regular file", error);
      }
      if (static_cast<std::uint64_t>(st.st_size) != file.size_bytes) {
        return Abort(job, index,
                     "its size on the station (" + std::to_string(st.st_size) +
                         " bytes) differs from the manifest's (" + std::to_string(file.size_bytes) +
                         "): changed since it was stored",
                     error);
      }
      std::uint64_t offset = 0;
      do {
        if (Stopping()) return Abort(job, index, "craftscand is stopping", error);
        const std::size_t n =
            static_cast<std::size_t>(std::min<std::uint64_t>(chunk, file.size_bytes - offset));
        std::size_t got = 0;
        while (got < n) {
          const ssize_t r =
              ::pread(fd, buffer.data() + got, n - got, static_cast<off_t>(offset + got));
          if (r < 0 && errno == EINTR) continue;
          if (r <= 0) {
            return Abort(job, index,
                         r < 0 ? std::string("read error: ") + std::strerror(errno)
                               : std::string("shorter than the manifest says"),
                         error);
          }
          got += static_cast<std::size_t>(r);
        }
        const bool last = offset + n == file.size_bytes;
        if (!WriteChunk(job, index, offset, buffer.data(), n, last, "", error)) return false;
        offset += n;
        if (++unacknowledged >= window) {
          if (!writer_->WaitForAcks(kAckTimeout, error)) return false;
          unacknowledged = 0;
        }
      } while (offset < file.size_bytes);
    }
    return writer_->WaitForAcks(kAckTimeout, error);
  }

  std::unique_ptr<dds::Writer<dds::msg::SessionFile>> writer_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<Job> queue_;  // guarded by mutex_
  bool stopping_ = false;  // guarded by mutex_
  std::thread thread_;
};

}  // namespace

struct Daemon::Impl {
  DaemonConfig config;
  SystemdNotifier notifier;
  std::unique_ptr<SessionStore> store;
  std::optional<TokenAuthority> tokens;
  std::shared_ptr<dds::Participant> participant;
  std::unique_ptr<dds::Writer<dds::msg::StationStatus>> status_writer;
  std::unique_ptr<dds::Writer<dds::msg::Reply>> reply_writer;
  std::unique_ptr<dds::Reader<dds::msg::Command>> command_reader;
  DdsPublisher publisher;
  FileSender files;
  std::unique_ptr<DeviceManager> devices;
  std::unique_ptr<JobEngine> jobs;
  std::unique_ptr<CommandHandler> handler;
  std::atomic<bool> status_dirty{true};
  std::string last_error;
  // Why the session store is not open ("" when it is): the station serves
  // degraded (status, devices) and OpenStore() is retried.
  std::string storage_error;
  std::string state = "starting";

  nlohmann::json StatusJson() const;
  void PublishStatus();
  // last_error and storage_error, as the status shows them.
  std::string Problems() const;
  // Tries to open the session store; on success marks unfinished sessions
  // interrupted and hands the store to the jobs and commands, else records
  // why in storage_error and has the commands refuse what needs it.
  bool OpenStore();
};

std::string Daemon::Impl::Problems() const {
  if (storage_error.empty()) return last_error;
  if (last_error.empty()) return storage_error;
  return last_error + "; " + storage_error;
}

bool Daemon::Impl::OpenStore() {
  std::string why;
  store = SessionStore::Open(config.data_dir, &why);
  if (!store) {
    storage_error = "data_dir: " + why;
    handler->SetStore(nullptr, "storage unavailable: " + why + " (craftscand retries every " +
                                   std::to_string(kStoreRetryInterval.count()) + " s)");
    jobs->SetStore(nullptr);
    return false;
  }
  std::vector<std::string> problems;
  for (const std::string& id : store->MarkInterrupted(&problems)) {
    spdlog::warn("session {} was unfinished: marked interrupted", id);
  }
  for (const std::string& p : problems) spdlog::error("sessions: {}", p);
  storage_error.clear();
  jobs->SetStore(store.get());
  handler->SetStore(store.get(), "");
  return true;
}

nlohmann::json Daemon::Impl::StatusJson() const {
  nlohmann::json devices_json = nlohmann::json::array();
  for (const DeviceReport& d : devices->Reports()) {
    devices_json.push_back({{"name", d.name},
                            {"kind", d.kind},
                            {"driver", d.driver},
                            {"state", d.state},
                            {"message", d.message}});
  }
  const JobInfo job = jobs->Current();
  return {{"station", config.station},
          {"state", state},
          {"devices", devices_json},
          {"job",
           {{"id", job.id},
            {"verb", job.verb},
            {"state", ToString(job.state)},
            {"session", job.session},
            {"stage", job.stage},
            {"progress", job.progress},
            {"message", job.message},
            {"result", job.result}}},
          {"last_error", Problems()},
          {"storage",
           {{"data_dir", config.data_dir}, {"ok", store != nullptr}, {"error", storage_error}}},
          {"calibration_id", jobs->calibration_id()}};
}

void Daemon::Impl::PublishStatus() {
  const JobInfo job = jobs->Current();
  dds::Outgoing<dds::msg::StationStatus> out;
  auto& m = out.msg();
  m.station = out.Keep(config.station);
  m.state = out.Keep(state);
  std::vector<dds::msg::DeviceStatus> list;
  for (const DeviceReport& d : devices->Reports()) {
    dds::msg::DeviceStatus s{};
    s.name = out.Keep(d.name);
    s.kind = out.Keep(d.kind);
    s.state = out.Keep(d.state);
    s.message = out.Keep(d.message);
    list.push_back(s);
  }
  const std::size_t count = list.size();
  dds::msg::DeviceStatus* devices_data = out.Keep(std::move(list));
  dds::Borrow(&m.devices, devices_data, count);
  m.job_id = out.Keep(job.id);
  m.job_verb = out.Keep(job.verb);
  m.job_state = out.Keep(ToString(job.state));
  m.progress = job.progress;
  m.last_error = out.Keep(Problems());
  m.stamp_ns = WallNs();
  m.calibration_id = out.Keep(jobs->calibration_id());
  std::string error;
  if (!status_writer->Write(m, &error)) spdlog::warn("status: {}", error);
}

Daemon::Daemon(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Daemon::~Daemon() = default;

std::unique_ptr<Daemon> Daemon::Create(const DaemonConfig& config, std::string* error) {
  auto impl = std::make_unique<Impl>();
  impl->config = config;
  std::string why;
  if (!config.IsValid(&why)) {
    *error = "config: " + why;
    return nullptr;
  }
  impl->tokens = TokenAuthority::Load(config.auth.tokens_file, &why);
  if (!impl->tokens) {
    *error = "auth.tokens_file: " + why;
    return nullptr;
  }
  dds::ParticipantOptions options;
  options.domain_id = static_cast<std::uint32_t>(config.dds.domain);
  if (!config.dds.config_file.empty()) options.config = dds::ConfigFileUri(config.dds.config_file);
  impl->participant = dds::Participant::Create(options, &why);
  if (!impl->participant) {
    *error = "dds: " + why;
    return nullptr;
  }
  const std::string& station = config.station;
  if (!(impl->status_writer = dds::Writer<dds::msg::StationStatus>::Create(
            impl->participant, dds::StatusTopic(station), &why)) ||
      !(impl->reply_writer = dds::Writer<dds::msg::Reply>::Create(
            impl->participant, dds::ReplyTopic(station), &why)) ||
      !(impl->command_reader = dds::Reader<dds::msg::Command>::Create(
            impl->participant, dds::CommandTopic(station), &why)) ||
      !impl->publisher.Create(impl->participant, station, &why) ||
      !impl->files.Create(impl->participant, station, &why)) {
    *error = "dds: " + why;
    return nullptr;
  }

  DeviceSetup setup;
  setup.plugin_path = config.plugins.SearchPath();
  setup.camera = {config.devices.camera.driver, config.devices.camera.config};
  setup.turntable = {config.devices.turntable.driver, config.devices.turntable.config};
  setup.camera_settings.exposure_us = config.scan.exposure_us;
  setup.camera_settings.gain_db = config.scan.gain_db;
  Impl* raw = impl.get();
  impl->devices = std::make_unique<DeviceManager>(setup, Log, [raw] { raw->status_dirty = true; });

  JobEngineOptions jobs;
  jobs.data_dir = config.data_dir;
  jobs.default_views = config.scan.views;
  jobs.default_step_deg = config.scan.step_deg;
  jobs.settle = std::chrono::milliseconds(config.scan.settle_ms);
  jobs.queue_capacity = config.limits.queue_capacity;
  jobs.threads = config.pipeline.threads;
  jobs.view.volume = config.pipeline.volume;
  jobs.view.min_texture_std = config.pipeline.min_texture_std;
  jobs.view.min_disparity = config.pipeline.min_disparity;
  jobs.view.num_disparities = config.pipeline.num_disparities;
  jobs.scan = ReconstructionOptions(config.pipeline);
  jobs.board = config.calibration.board;
  jobs.turntable_board = config.calibration.turntable_board;
  jobs.turntable_board_thickness_mm = config.calibration.turntable_board_thickness_mm;
  jobs.calibration_views = config.calibration.views;
  jobs.max_rms_px = config.calibration.max_rms_px;
  jobs.calibration.rectification.zero_disparity = false;
  impl->jobs = std::make_unique<JobEngine>(jobs, impl->devices.get(), impl->store.get(),
                                           &impl->publisher, Log);
  if (!impl->jobs->LoadCurrentCalibration(&why)) {
    spdlog::error("calibration: {} (starting without one; run calibrate)", why);
    impl->last_error = "calibration: " + why;
  }
  CommandLimits limits;
  limits.max_argument_bytes = static_cast<std::size_t>(config.limits.max_command_bytes);
  impl->handler = std::make_unique<CommandHandler>(limits, &*impl->tokens, impl->jobs.get(),
                                                   impl->devices.get(), impl->store.get(),
                                                   [raw] { return raw->StatusJson(); });
  // An unusable data directory (read-only, missing, a disk not mounted yet)
  // is not fatal: the station serves degraded and Run() retries.
  if (!impl->OpenStore()) {
    spdlog::error("{} (serving without sessions; retrying every {} s)", impl->storage_error,
                  kStoreRetryInterval.count());
  }
  return std::unique_ptr<Daemon>(new Daemon(std::move(impl)));
}

int Daemon::Run() {
  Impl& d = *impl_;
  std::string error;
  if (const auto c = d.jobs->calibration()) d.publisher.CalibrationChanged(*c);

  d.notifier.Status("opening devices");
  d.PublishStatus();
  auto last_open_try = Clock::now();
  if (!d.devices->Open(&error)) {
    d.last_error = "devices: " + error;
    d.state = "error";
    spdlog::error("devices: {} (retrying every 10 s)", error);
  } else {
    d.state = d.store ? "idle" : "degraded";
  }
  // Ready once the devices were tried: a station without its hardware or
  // its data directory still serves what it can, and says why in STATUS=
  // and StationStatus.
  d.notifier.Ready(d.state == "idle" ? "ready: devices up" : "degraded: " + d.Problems());
  spdlog::info("craftscand serving station '{}' on DDS domain {}", d.config.station,
               d.config.dds.domain);

  const auto ping_interval =
      d.config.watchdog.enabled ? d.notifier.WatchdogPingInterval() : std::chrono::microseconds(0);
  auto last_ping = Clock::time_point{};
  auto last_status = Clock::now();
  auto last_store_try = Clock::now();
  std::string last_job_state, last_summary;
  dds::Sample<dds::msg::Command> command;
  // Flood protection (commands.h, "Floods"): a rate per client name, at most
  // kRefusalLogsPerSecond refusals logged one by one (the rest are counted
  // and summed up every second), and the buffers of a sample above
  // kReleaseAboveBytes handed back rather than kept for the next Take.
  constexpr double kRefusalLogsPerSecond = 10;
  constexpr std::size_t kReleaseAboveBytes = std::size_t{1} << 20;
  CommandRateLimiter rate_limiter;
  TokenBucket refusal_log(kRefusalLogsPerSecond, 2 * kRefusalLogsPerSecond, Clock::now());
  std::size_t unlogged_refusals = 0;
  auto last_refusal_summary = Clock::now();
  auto trim_at = Clock::time_point::max();  // see malloc_trim below
  while (!stop_.load()) {
    const dds::TakeStatus taken =
        d.command_reader->Take(std::chrono::milliseconds(100), &command, &error);
    if (taken == dds::TakeStatus::kOk) {
      const auto received = Clock::now();
      const std::string_view fields[] = {dds::View(command->request_id), dds::View(command->client),
                                         dds::View(command->token), dds::View(command->verb),
                                         dds::View(command->arguments)};
      const CommandRequest request = CutCommandRequest(fields[0], fields[1], fields[2], fields[3],
                                                       fields[4], d.handler->limits());
      CommandReply reply;
      if (rate_limiter.Admit(request.client, received)) {
        reply = d.handler->Handle(request);
      } else {
        const std::size_t cut = d.handler->limits().max_field_bytes;
        reply.request_id = request.request_id.substr(0, cut);
        reply.client = request.client.substr(0, cut);
        reply.code = ReplyCode::kBusy;
        reply.message = CommandRateLimiter::RefusalMessage(request.client);
      }
      if (reply.transfer && !d.files.HasRoom()) {
        reply.code = ReplyCode::kBusy;
        reply.message = "busy: " + std::to_string(kMaxQueuedTransfers) +
                        " file transfers are waiting; try again shortly";
        reply.result = nlohmann::json::object();
        reply.transfer.reset();
      }
      spdlog::debug("command {} '{}' from '{}': {}", reply.request_id, request.verb.substr(0, 64),
                    reply.client, ToString(reply.code));
      if (reply.code != ReplyCode::kOk && refusal_log.Take(received)) {
        spdlog::info("command {} '{}' from '{}': {}: {}", reply.request_id,
                     request.verb.substr(0, 64), reply.client, ToString(reply.code), reply.message);
      } else if (reply.code != ReplyCode::kOk) {
        ++unlogged_refusals;
      }
      dds::Outgoing<dds::msg::Reply> out;
      out.msg().request_id = out.Keep(reply.request_id);
      out.msg().client = out.Keep(reply.client);
      out.msg().code = static_cast<std::int32_t>(reply.code);
      out.msg().code_name = out.Keep(ToString(reply.code));
      out.msg().message = out.Keep(reply.message);
      std::string result =
          reply.result.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
      if (result.size() > dds::kMaxReplyResultBytes) result = "{\"truncated\":true}";
      out.msg().result = out.Keep(result);
      if (!d.reply_writer->Write(out.msg(), &error)) spdlog::warn("reply: {}", error);
      // The chunks follow the Reply that lists them.
      if (reply.transfer) {
        d.files.Enqueue(reply.request_id, reply.client, std::move(*reply.transfer));
      }
      // A refusal or a query changes nothing the status shows (a started
      // job is seen below); republishing for each would echo a flood.
      if (reply.code == ReplyCode::kOk && !IsQueryVerb(request.verb)) d.status_dirty = true;
      std::size_t received_bytes = 0;
      for (const std::string_view field : fields) received_bytes += field.size();
      if (received_bytes > kReleaseAboveBytes) {
        command.Reset();
        ::malloc_trim(0);
      }
    } else if (taken == dds::TakeStatus::kError) {
      spdlog::warn("command topic: {}", error);
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    if (unlogged_refusals > 0 && Clock::now() - last_refusal_summary >= std::chrono::seconds(1)) {
      spdlog::warn(
          "{} more commands refused in the last second(s), not logged one by one "
          "(is a client flooding?)",
          unlogged_refusals);
      unlogged_refusals = 0;
      last_refusal_summary = Clock::now();
    }

    const auto now = Clock::now();
    // Devices that failed to open are retried.
    if (!d.devices->IsOpen() && !d.jobs->Busy() && now - last_open_try > std::chrono::seconds(10)) {
      last_open_try = now;
      if (d.devices->Open(&error)) {
        d.state = d.store ? "idle" : "degraded";
        d.last_error.clear();
        d.notifier.Status("ready: devices up");
      } else {
        d.last_error = "devices: " + error;
      }
      d.status_dirty = true;
    }
    // So is a data directory that was not usable.
    if (!d.store && now - last_store_try >= kStoreRetryInterval) {
      last_store_try = now;
      if (d.OpenStore()) {
        spdlog::info("data directory '{}' is usable: serving sessions", d.config.data_dir);
        if (!d.jobs->calibration()) {  // it may have been unreadable until now
          if (!d.jobs->LoadCurrentCalibration(&error)) {
            d.last_error = "calibration: " + error;
          } else if (const auto c = d.jobs->calibration()) {
            d.publisher.CalibrationChanged(*c);
          }
        }
        if (d.devices->IsOpen()) d.state = d.jobs->Busy() ? "busy" : "idle";
      } else {
        spdlog::debug("{}", d.storage_error);
      }
      d.status_dirty = true;
    }
    const JobInfo job = d.jobs->Current();
    const std::string job_state = job.id + std::string(ToString(job.state)) + job.stage;
    if (job_state != last_job_state) {
      last_job_state = job_state;
      d.status_dirty = true;
      if (job.state == JobState::kFailed) d.last_error = job.message;
      if (d.devices->IsOpen()) d.state = d.jobs->Busy() ? "busy" : d.store ? "idle" : "degraded";
    }
    // A job's images and clouds are freed on its threads' malloc arenas,
    // which glibc keeps for reuse; hand the free pages back once it has
    // ended (and its thread has let go of them), so that the daemon's RSS
    // between jobs is what it holds (measured by test_daemon_soak), not the
    // sum of what its threads once held.
    if (d.jobs->Busy()) {
      trim_at = now + std::chrono::milliseconds(250);
    } else if (now >= trim_at) {
      ::malloc_trim(0);
      trim_at = Clock::time_point::max();
    }
    // STATUS= when a job starts or ends (not per stage: each is a datagram
    // the service manager must read).
    // Degraded (devices or storage) stays in STATUS= until it is over, so
    // `systemctl status` shows a missing camera, not "idle".
    const std::string summary =
        !d.store || !d.devices->IsOpen() ? "degraded: " + d.Problems()
        : d.jobs->Busy()                 ? "busy: " + job.id + " " + job.verb
                         : "idle; last job " + job.id + " " + std::string(ToString(job.state));
    if (summary != last_summary) {
      last_summary = summary;
      d.notifier.Status(summary);
    }
    if (d.status_dirty.exchange(false) || now - last_status > std::chrono::seconds(1)) {
      d.PublishStatus();
      last_status = now;
    }
    // Healthy: this loop runs, and a running job has reported within 10 min
    // (a driver call hung forever stops the pings; systemd restarts us and
    // the session resumes).
    const bool healthy =
        !d.jobs->Busy() || now - d.publisher.last_activity() < std::chrono::minutes(10);
    if (ping_interval.count() > 0 && healthy && now - last_ping >= ping_interval) {
      d.notifier.Watchdog();
      last_ping = now;
    }
  }

  spdlog::info("stopping");
  d.notifier.Stopping("stopping: checkpointing the running job");
  d.state = "stopping";
  d.PublishStatus();
  d.files.Stop();
  d.jobs->Shutdown();
  d.devices->Close();
  d.PublishStatus();
  spdlog::info("stopped cleanly");
  return 0;
}

}  // namespace craftscan::daemon
