#include "dds_bridge.h"

#include <fcntl.h>
#include <malloc.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <string_view>
#include <utility>

#include <spdlog/spdlog.h>

#include "craftscan/dds/convert.h"

namespace craftscan::daemon {
namespace {

// Writes `msg`; a failure is logged as "<what>: <error>".
template <typename Msg>
void WriteOrLog(dds::Writer<Msg>& writer, const Msg& msg, const char* what) {
  std::string error;
  if (!writer.Write(msg, &error)) spdlog::warn("{}: {}", what, error);
}

// Builds a sample with make(&out, &error) and writes it; a failure to build
// it is logged as "<what> topic: <error>", one to write it as in WriteOrLog.
template <typename Msg, typename Make>
void MakeAndWrite(dds::Writer<Msg>& writer, const char* what, Make make) {
  dds::Outgoing<Msg> out;
  std::string error;
  if (make(&out, &error)) {
    WriteOrLog(writer, out.msg(), what);
  } else {
    spdlog::warn("{} topic: {}", what, error);
  }
}

}  // namespace

std::int64_t WallNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// --- CommandChannel ---------------------------------------------------------

bool CommandChannel::Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
                            std::string* error) {
  return (reply_writer_ =
              dds::Writer<dds::msg::Reply>::Create(p, dds::ReplyTopic(station), error)) &&
         (command_reader_ =
              dds::Reader<dds::msg::Command>::Create(p, dds::CommandTopic(station), error));
}

dds::TakeStatus CommandChannel::Take(std::chrono::milliseconds timeout, const CommandLimits& limits,
                                     CommandRequest* request, std::string* error) {
  const dds::TakeStatus taken = command_reader_->Take(timeout, &command_, error);
  if (taken != dds::TakeStatus::kOk) return taken;
  const std::string_view fields[] = {dds::View(command_->request_id), dds::View(command_->client),
                                     dds::View(command_->token), dds::View(command_->verb),
                                     dds::View(command_->arguments)};
  *request = CutCommandRequest(fields[0], fields[1], fields[2], fields[3], fields[4], limits);
  std::size_t received_bytes = 0;
  for (const std::string_view field : fields) received_bytes += field.size();
  if (received_bytes > kReleaseAboveBytes) {
    command_.Reset();
    ::malloc_trim(0);
  }
  return taken;
}

void CommandChannel::Reply(const CommandReply& reply) {
  dds::Outgoing<dds::msg::Reply> out;
  out.msg().request_id = out.Keep(reply.request_id);
  out.msg().client = out.Keep(reply.client);
  out.msg().code = static_cast<std::int32_t>(reply.code);
  out.msg().code_name = out.Keep(ToString(reply.code));
  out.msg().message = out.Keep(reply.message);
  std::string result = reply.result.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  if (result.size() > dds::kMaxReplyResultBytes) result = "{\"truncated\":true}";
  out.msg().result = out.Keep(result);
  WriteOrLog(*reply_writer_, out.msg(), "reply");
}

// --- StatusWriter -----------------------------------------------------------

bool StatusWriter::Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
                          std::string* error) {
  writer_ = dds::Writer<dds::msg::StationStatus>::Create(p, dds::StatusTopic(station), error);
  return writer_ != nullptr;
}

void StatusWriter::Publish(const StationStatusFields& status) {
  dds::Outgoing<dds::msg::StationStatus> out;
  auto& m = out.msg();
  m.station = out.Keep(status.station);
  m.state = out.Keep(ToString(status.state));
  std::vector<dds::msg::DeviceStatus> list;
  for (const DeviceReport& d : status.devices) {
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
  m.job_id = out.Keep(status.job.id);
  m.job_verb = out.Keep(status.job.verb);
  m.job_state = out.Keep(ToString(status.job.state));
  m.progress = status.job.progress;
  m.last_error = out.Keep(status.last_error);
  m.stamp_ns = WallNs();
  m.calibration_id = out.Keep(status.calibration_id);
  WriteOrLog(*writer_, m, "status");
}

// --- SiteWriter -------------------------------------------------------------

namespace {

// The 1-minute load average per online core, 0 when unknown.
double LoadPerCore() {
  double load[1] = {0};
  const long cores = ::sysconf(_SC_NPROCESSORS_ONLN);
  if (::getloadavg(load, 1) != 1 || cores <= 0) return 0;
  return load[0] / static_cast<double>(cores);
}

}  // namespace

bool SiteWriter::Create(const std::shared_ptr<dds::Participant>& p, const std::string& site,
                        const std::string& station, std::string_view reconstruction,
                        std::string* error) {
  std::lock_guard lock(mutex_);
  station_ = station;
  reconstruction_ = std::string(reconstruction);
  writer_ = dds::Writer<dds::msg::SiteStation>::Create(p, dds::SiteStationTopic(site), error);
  return writer_ != nullptr;
}

void SiteWriter::Publish(const StationStatusFields& status) {
  std::lock_guard lock(mutex_);
  state_ = status.state;
  job_ = status.job;
  WriteLocked();
}

void SiteWriter::SetRemoteJob(std::string job_id, std::string worker) {
  std::lock_guard lock(mutex_);
  if (job_id == remote_job_ && worker == remote_worker_) return;
  remote_job_ = std::move(job_id);
  remote_worker_ = std::move(worker);
  WriteLocked();
}

void SiteWriter::Dispose() {
  std::lock_guard lock(mutex_);
  if (!writer_ || disposed_) return;
  disposed_ = true;
  dds::Outgoing<dds::msg::SiteStation> out;
  out.msg().station = out.Keep(station_);
  std::string error;
  if (!writer_->Dispose(out.msg(), &error)) {
    spdlog::warn("site station: {}", error);
  } else if (!writer_->WaitForAcks(kDisposeAckTimeout, &error)) {
    spdlog::debug("site station: the disposal was not acknowledged by every reader: {}", error);
  }
}

bool SiteWriter::RenewalDue(Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  return now - last_write_ >= kRenewInterval;
}

void SiteWriter::WriteLocked() {
  if (!writer_ || disposed_) return;
  dds::Outgoing<dds::msg::SiteStation> out;
  auto& m = out.msg();
  m.station = out.Keep(station_);
  m.state = out.Keep(ToString(state_));
  m.job_id = out.Keep(job_.id);
  m.job_verb = out.Keep(job_.verb);
  m.job_state = out.Keep(ToString(job_.state));
  m.progress = job_.progress;
  m.reconstruction = out.Keep(reconstruction_);
  m.remote_job = out.Keep(remote_job_);
  m.remote_worker = out.Keep(remote_worker_);
  m.load = LoadPerCore();
  m.stamp_ns = WallNs();
  WriteOrLog(*writer_, m, "site station");
  last_write_ = Clock::now();
}

// --- DdsPublisher -----------------------------------------------------------

bool DdsPublisher::Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
                          std::string* error) {
  station_ = station;
  frames_ = dds::FramesOf(station);
  using dds::Side;
  return (progress_ =
              dds::Writer<dds::msg::JobProgress>::Create(p, dds::ProgressTopic(station), error)) &&
         (capture_ =
              dds::Writer<dds::msg::StereoCapture>::Create(p, dds::CaptureTopic(station), error)) &&
         (disparity_ =
              dds::Writer<dds::msg::Disparity>::Create(p, dds::DisparityTopic(station), error)) &&
         (cloud_ = dds::Writer<dds::msg::PointCloud>::Create(p, dds::CloudTopic(station), error)) &&
         (preview_ =
              dds::Writer<dds::msg::Preview>::Create(p, dds::PreviewTopic(station), error)) &&
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
              dds::Writer<dds::ros::PointCloud2>::Create(p, dds::RosCloudTopic(station), error)) &&
         (ros_tf_ = dds::Writer<dds::ros::TFMessage>::Create(p, dds::RosTfTopic(), error)) &&
         (ros_tf_static_ =
              dds::Writer<dds::ros::TFMessage>::Create(p, dds::RosTfStaticTopic(), error));
}

DdsPublisher::Clock::time_point DdsPublisher::last_activity() const {
  std::lock_guard lock(mutex_);
  return last_activity_;
}

void DdsPublisher::Touch() {
  std::lock_guard lock(mutex_);
  last_activity_ = Clock::now();
}

void DdsPublisher::Progress(const std::string& job, const std::string& stage, int current,
                            int total, const std::string& message) {
  Touch();
  dds::Outgoing<dds::msg::JobProgress> out;
  out.msg().job_id = out.Keep(job);
  out.msg().stage = out.Keep(stage);
  out.msg().current = current;
  out.msg().total = total;
  out.msg().message = out.Keep(message);
  out.msg().stamp_ns = WallNs();
  WriteOrLog(*progress_, out.msg(), "progress");
}

void DdsPublisher::Preview(const PreviewFrame& frame) {
  Touch();
  dds::Outgoing<dds::msg::Preview> out;
  dds::msg::Preview& m = out.msg();
  m.job_id = out.Keep(frame.job_id);
  m.frame_number = frame.sequence;
  m.stamp_ns = frame.stamp_ns;
  m.ready_ns = frame.ready_ns;
  m.exposure_us = frame.exposure_us;
  m.gain_db = frame.gain_db;
  m.full_width = static_cast<std::uint32_t>(frame.full_size.width);
  m.full_height = static_cast<std::uint32_t>(frame.full_size.height);
  m.width = static_cast<std::uint32_t>(frame.size.width);
  m.height = static_cast<std::uint32_t>(frame.size.height);
  dds::Borrow(&m.left_jpeg, frame.left.jpeg.data(), frame.left.jpeg.size());
  dds::Borrow(&m.right_jpeg, frame.right.jpeg.data(), frame.right.jpeg.size());
  m.grid_cols = static_cast<std::uint32_t>(frame.grid_cols);
  m.grid_rows = static_cast<std::uint32_t>(frame.grid_rows);
  dds::Borrow(&m.left_focus, frame.left.focus.data(), frame.left.focus.size());
  dds::Borrow(&m.right_focus, frame.right.focus.data(), frame.right.focus.size());
  dds::Borrow(&m.left_histogram, frame.left.histogram.data(), frame.left.histogram.size());
  dds::Borrow(&m.right_histogram, frame.right.histogram.data(), frame.right.histogram.size());
  m.left_clipped_pct = frame.left.clipped_pct;
  m.right_clipped_pct = frame.right.clipped_pct;
  m.left_black_pct = frame.left.black_pct;
  m.right_black_pct = frame.right.black_pct;
  m.overlay = out.Keep(frame.overlay);
  WriteOrLog(*preview_, m, "preview");
}

void DdsPublisher::Capture(const std::string& session, int view, double angle_deg,
                           const drivers::StereoFrame& frame) {
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
  meta.left_frame_id = frames_.left;
  meta.right_frame_id = frames_.right;
  MakeAndWrite(*capture_, "capture",
               [&](dds::Outgoing<dds::msg::StereoCapture>* out, std::string* why) {
                 return dds::MakeStereoCapture(frame.left.image, frame.right.image, meta, out, why);
               });
  std::shared_ptr<const StereoCalibration> calibration;
  {
    std::lock_guard lock(mutex_);
    calibration = calibration_;
  }
  // Each image's camera_info first, so a tool pairing them by stamp has it
  // when the image arrives.
  if (calibration) PublishCameraInfo(*calibration, now);
  dds::Outgoing<dds::ros::Image> left, right;
  if (dds::MakeImage(frame.left.image, now, meta.left_frame_id, &left, &error) &&
      dds::MakeImage(frame.right.image, now, meta.right_frame_id, &right, &error)) {
    WriteOrLog(*ros_left_, left.msg(), "left image_raw");
    WriteOrLog(*ros_right_, right.msg(), "right image_raw");
  } else {
    spdlog::warn("image_raw topics: {}", error);
  }
  if (calibration) {
    constexpr double kRadPerDeg = 3.14159265358979323846 / 180;
    MakeAndWrite(*ros_tf_, "tf", [&](dds::Outgoing<dds::ros::TFMessage>* out, std::string* why) {
      return dds::MakeTfMessage({dds::TurntableTransform(frames_, angle_deg * kRadPerDeg)}, now,
                                out, why);
    });
  }
}

void DdsPublisher::Disparity(const std::string& session, int view, const cv::Mat& disparity,
                             double focal_px, double baseline_mm, int min_disparity,
                             int num_disparities) {
  Touch();
  dds::DisparityMeta meta;
  meta.session = session;
  meta.view_index = view;
  meta.f_px = static_cast<float>(focal_px);
  meta.baseline_mm = static_cast<float>(baseline_mm);
  meta.cx_offset_px = cx_offset_px_;
  meta.min_disparity = static_cast<float>(min_disparity);
  meta.max_disparity = static_cast<float>(min_disparity + num_disparities - 1);
  meta.stamp_ns = WallNs();
  meta.frame_id = frames_.rig;
  MakeAndWrite(*disparity_, "disparity",
               [&](dds::Outgoing<dds::msg::Disparity>* out, std::string* why) {
                 return dds::MakeDisparity(disparity, meta, out, why);
               });
  MakeAndWrite(*ros_disparity_, "ros disparity",
               [&](dds::Outgoing<dds::ros::DisparityImage>* out, std::string* why) {
                 return dds::MakeDisparityImage(disparity, meta, out, why);
               });
}

void DdsPublisher::Cloud(const std::string& session, int view, const PointCloud& cloud,
                         const cv::Matx44d& world_from_cloud) {
  Touch();
  dds::CloudMeta meta;
  meta.session = session;
  meta.view_index = view;
  meta.kind = view < 0 ? "fused" : "view";
  meta.world_from_view = world_from_cloud;
  meta.stamp_ns = WallNs();
  meta.frame_id = view < 0 ? frames_.turntable_base : frames_.rig;
  MakeAndWrite(*cloud_, "cloud", [&](dds::Outgoing<dds::msg::PointCloud>* out, std::string* why) {
    return dds::MakeCloud(cloud, meta, out, why);
  });
  MakeAndWrite(*ros_cloud_, "ros cloud",
               [&](dds::Outgoing<dds::ros::PointCloud2>* out, std::string* why) {
                 return dds::MakePointCloud2(cloud, meta.stamp_ns, meta.frame_id, out, why);
               });
}

void DdsPublisher::PublishCameraInfo(const StereoCalibration& calibration, std::int64_t stamp_ns) {
  std::string error;
  dds::Outgoing<dds::ros::CameraInfo> left, right;
  if (dds::MakeCameraInfo(calibration, dds::Side::kLeft, stamp_ns, frames_.left, &left, &error) &&
      dds::MakeCameraInfo(calibration, dds::Side::kRight, stamp_ns, frames_.right, &right,
                          &error)) {
    WriteOrLog(*ros_info_left_, left.msg(), "left camera_info");
    WriteOrLog(*ros_info_right_, right.msg(), "right camera_info");
  } else {
    spdlog::warn("camera_info topics: {}", error);
  }
}

void DdsPublisher::CalibrationChanged(const StereoCalibration& calibration) {
  cx_offset_px_ = static_cast<float>(calibration.P1(0, 2) - calibration.P2(0, 2));
  {
    std::lock_guard lock(mutex_);
    calibration_ = std::make_shared<const StereoCalibration>(calibration);
  }
  const std::int64_t now = WallNs();
  PublishCameraInfo(calibration, now);
  MakeAndWrite(*ros_tf_static_, "tf_static",
               [&](dds::Outgoing<dds::ros::TFMessage>* out, std::string* why) {
                 std::vector<dds::FrameTransform> transforms;
                 return dds::StaticStationTransforms(calibration, frames_, &transforms, why) &&
                        dds::MakeTfMessage(transforms, now, out, why);
               });
}

// --- FileSender -------------------------------------------------------------

bool FileSender::Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
                        std::string* error) {
  writer_ = dds::Writer<dds::msg::SessionFile>::Create(p, dds::FileTopic(station), error);
  if (!writer_) return false;
  thread_ = std::thread([this] { Loop(); });
  return true;
}

bool FileSender::HasRoom() const {
  std::lock_guard lock(mutex_);
  return queue_.size() < kMaxQueuedTransfers;
}

void FileSender::Enqueue(std::string request_id, std::string client, FileTransfer transfer) {
  std::lock_guard lock(mutex_);
  queue_.push_back({std::move(request_id), std::move(client), std::move(transfer)});
  wake_.notify_one();
}

void FileSender::Stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
    queue_.clear();
    wake_.notify_one();
  }
  if (thread_.joinable()) thread_.join();
}

void FileSender::Loop() {
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
      spdlog::warn("get {}: transfer of session {} ended: {}", job.request_id, job.transfer.session,
                   error);
    }
  }
}

bool FileSender::Stopping() const {
  std::lock_guard lock(mutex_);
  return stopping_;
}

bool FileSender::WriteChunk(const Job& job, std::uint32_t index, std::uint64_t offset,
                            const std::uint8_t* data, std::size_t size, bool last,
                            const std::string& problem, std::string* error) {
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

bool FileSender::Abort(const Job& job, std::uint32_t index, const std::string& problem,
                       std::string* error) {
  std::string ignored;
  WriteChunk(job, index, 0, nullptr, 0, true, problem, &ignored);
  *error = job.transfer.files[index].name + ": " + problem;
  return false;
}

bool FileSender::Send(const Job& job, std::string* error) {
  const std::size_t chunk = std::clamp(job.transfer.chunk_bytes, kMinTransferChunkBytes,
                                       std::min(kMaxTransferChunkBytes, dds::kMaxFileChunkBytes));
  const std::size_t window = std::clamp<std::size_t>(kAckWindowBytes / chunk, 1, kMaxWindowChunks);
  std::vector<std::uint8_t> buffer(chunk);
  std::size_t unacknowledged = 0;
  for (std::uint32_t index = 0; index < job.transfer.files.size(); ++index) {
    if (!SendFile(job, index, window, &buffer, &unacknowledged, error)) return false;
  }
  return writer_->WaitForAcks(kAckTimeout, error);
}

bool FileSender::SendFile(const Job& job, std::uint32_t index, std::size_t window,
                          std::vector<std::uint8_t>* buffer, std::size_t* unacknowledged,
                          std::string* error) {
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
  const std::size_t chunk = buffer->size();
  std::uint64_t offset = 0;
  do {
    if (Stopping()) return Abort(job, index, "craftscand is stopping", error);
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>(chunk, file.size_bytes - offset));
    std::size_t got = 0;
    while (got < n) {
      const ssize_t r =
          ::pread(fd, buffer->data() + got, n - got, static_cast<off_t>(offset + got));
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
    if (!WriteChunk(job, index, offset, buffer->data(), n, last, "", error)) return false;
    offset += n;
    if (++*unacknowledged >= window) {
      if (!writer_->WaitForAcks(kAckTimeout, error)) return false;
      *unacknowledged = 0;
    }
  } while (offset < file.size_bytes);
  return true;
}

}  // namespace craftscan::daemon
