// The DDS bridge of craftscand: everything the service says or hears on the
// station's topics (DESIGN.md "DDS interface"), so the rest of the service
// deals in CommandRequest/CommandReply, JobSink calls and plain status
// fields, never in DDS types.
//
//   CommandChannel  craftscan/<station>/command in, .../reply out
//   StatusWriter    craftscan/<station>/status (StationStatus)
//   SiteWriter      craftscan/site/station (SiteStation) in the site's partition
//   DdsPublisher    what the jobs produce (JobSink): progress, capture,
//                   disparity, cloud, and the ROS 2-compatible rt/... topics
//   FileSender      craftscan/<station>/file: the chunks of `get` transfers
//
// Each class is made with Create() on the station's participant; Create()
// returns false with *error naming the topic's problem. A failed write is
// logged, never fatal: a slow or absent subscriber must not stop the station
// (what a job produces is on disk first).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "craftscan/daemon/commands.h"
#include "craftscan/daemon/daemon.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"
#include "craftscan/dds/topics.h"

namespace craftscan::daemon {

// Nanoseconds since the Unix epoch: the stamp of every sample the bridge
// writes.
std::int64_t WallNs();

// The command topic's reader and the reply topic's writer. Thread-safety:
// one thread (the service's command loop) calls Take and Reply.
class CommandChannel {
 public:
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error);

  // Waits up to `timeout` for a Command. kOk: *request holds it, its fields
  // cut to `limits` (CutCommandRequest: an oversized field is measured,
  // never copied); the buffers of a sample above kReleaseAboveBytes are then
  // handed back to the system rather than kept for the next Take.
  // kTimeout: nothing arrived. kError: *error says why.
  dds::TakeStatus Take(std::chrono::milliseconds timeout, const CommandLimits& limits,
                       CommandRequest* request, std::string* error);

  // Writes the Reply to `reply`: its code as number and name, its message,
  // and its result as JSON text (invalid UTF-8 replaced), or
  // {"truncated":true} when that exceeds dds::kMaxReplyResultBytes. A
  // failed write is logged.
  void Reply(const CommandReply& reply);

 private:
  static constexpr std::size_t kReleaseAboveBytes = std::size_t{1} << 20;

  std::unique_ptr<dds::Writer<dds::msg::Reply>> reply_writer_;
  std::unique_ptr<dds::Reader<dds::msg::Command>> command_reader_;
  dds::Sample<dds::msg::Command> command_;
};

// What one StationStatus sample says.
struct StationStatusFields {
  std::string station;
  StationState state = StationState::kStarting;  // sent as ToString(state)
  std::vector<DeviceReport> devices;
  JobInfo job;             // the running job, else the last one
  std::string last_error;  // the problems the station has, "" for none
  std::string calibration_id;
};

// The status topic's writer (reliable, transient-local, keep-last 1: a late
// subscriber gets the last one). Thread-safety: one thread at a time.
class StatusWriter {
 public:
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error);
  // Publishes `status`, stamped now; a failed write is logged.
  void Publish(const StationStatusFields& status);

 private:
  std::unique_ptr<dds::Writer<dds::msg::StationStatus>> writer_;
};

// The station's instance on the site's topic (dds::SiteStationTopic(site):
// SiteStation keyed by the station id, in the site's DDS partition): what
// `craftscanctl site` and the site's workers see of this station. The writer
// has a manual-by-topic liveliness lease (dds::kStationLeaseMs): the service
// writes at least every kRenewInterval, so a daemon that died or froze shows
// at the readers as NOT_ALIVE_NO_WRITERS within the lease; a clean stop
// disposes the instance (Dispose).
// Thread-safety: every method may be called from any thread; the fields and
// each write are under one mutex, so the writes keep the order of the calls.
class SiteWriter {
 public:
  using Clock = std::chrono::steady_clock;
  // How often the instance must be written at least (a quarter of the lease).
  static constexpr std::chrono::milliseconds kRenewInterval{dds::kStationLeaseMs / 4};

  // `reconstruction`: the config's reconstruction mode as text ("local",
  // "remote", "auto"), sent in every sample.
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& site,
              const std::string& station, std::string_view reconstruction, std::string* error);

  // Takes state, job and progress from `status` and writes the instance
  // (with the load average, stamped now). A failed write is logged.
  void Publish(const StationStatusFields& status);
  // The job of this station offered or granted to a worker of the site now,
  // and that worker ("" for none; a job offered but not granted has no
  // worker yet). Written at once when it changes. For the job protocol.
  void SetRemoteJob(std::string job_id, std::string worker);
  // Disposes the instance (the station stops): readers drop it. Nothing is
  // written after.
  void Dispose();
  // Whether kRenewInterval has passed since the last write.
  bool RenewalDue(Clock::time_point now) const;

 private:
  // Dispose waits this long at most for the readers to have the disposal.
  static constexpr std::chrono::milliseconds kDisposeAckTimeout{1000};

  void WriteLocked();  // mutex_ held

  std::unique_ptr<dds::Writer<dds::msg::SiteStation>> writer_;
  mutable std::mutex mutex_;
  // Guarded by mutex_:
  std::string station_, reconstruction_;
  StationState state_ = StationState::kStarting;
  JobInfo job_;
  std::string remote_job_, remote_worker_;
  Clock::time_point last_write_{};
  bool disposed_ = false;
};

// Publishes what the jobs produce (JobSink) on the station's topics, in the
// frames of dds::FramesOf(station) (convert.h draws the tree):
//   Progress            craftscan/<station>/progress (JobProgress)
//   Capture             .../capture (StereoCapture, both images); the ROS 2
//                       left and right camera_info then image_raw, both
//                       with the same stamp and frame (the raw camera's
//                       optical frame), as image_proc, stereo_image_proc and
//                       rviz2 pair them; /tf: the turntable at the view's
//                       commanded angle, same stamp
//   Disparity           .../disparity and the ROS 2 DisparityImage (frame
//                       <station>_rig_optical_frame; cx offset from the last
//                       calibration)
//   Cloud               .../cloud and the ROS 2 PointCloud2 (a view in
//                       <station>_rig_optical_frame, the fused cloud, view
//                       −1, in <station>_turntable_base)
//   CalibrationChanged  the ROS 2 left and right camera_info (kept for late
//                       subscribers: transient-local) and /tf_static (the
//                       rig, cameras and turntable axis)
// Before the first calibration no camera_info, /tf_static or /tf is
// published (the images still are).
// Thread-safety: every method may be called from any thread, concurrently
// (the DDS writers are thread-safe; the rest is atomic or locked). No method
// blocks beyond a reliable write's bounded wait.
class DdsPublisher : public JobSink {
 public:
  using Clock = std::chrono::steady_clock;

  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error);

  // When a job last published anything except a calibration (the service's
  // watchdog: a running job silent for too long means a hung driver call).
  Clock::time_point last_activity() const;

  void Progress(const std::string& job, const std::string& stage, int current, int total,
                const std::string& message) override;
  void Capture(const std::string& session, int view, double angle_deg,
               const drivers::StereoFrame& frame) override;
  void Disparity(const std::string& session, int view, const cv::Mat& disparity, double focal_px,
                 double baseline_mm, int min_disparity, int num_disparities) override;
  void Cloud(const std::string& session, int view, const PointCloud& cloud,
             const cv::Matx44d& world_from_cloud) override;
  void CalibrationChanged(const StereoCalibration& calibration) override;
  void Preview(const PreviewFrame& frame) override;

 private:
  void Touch();
  // Writes both camera_info samples of `calibration` stamped `stamp_ns`.
  void PublishCameraInfo(const StereoCalibration& calibration, std::int64_t stamp_ns);

  std::string station_;
  dds::StationFrames frames_;
  std::shared_ptr<const StereoCalibration> calibration_;  // guarded by mutex_; null until set
  std::atomic<float> cx_offset_px_{0};
  mutable std::mutex mutex_;
  Clock::time_point last_activity_ = Clock::now();  // guarded by mutex_
  std::unique_ptr<dds::Writer<dds::msg::JobProgress>> progress_;
  std::unique_ptr<dds::Writer<dds::msg::StereoCapture>> capture_;
  std::unique_ptr<dds::Writer<dds::msg::Disparity>> disparity_;
  std::unique_ptr<dds::Writer<dds::msg::PointCloud>> cloud_;
  std::unique_ptr<dds::Writer<dds::msg::Preview>> preview_;
  std::unique_ptr<dds::Writer<dds::ros::Image>> ros_left_, ros_right_;
  std::unique_ptr<dds::Writer<dds::ros::CameraInfo>> ros_info_left_, ros_info_right_;
  std::unique_ptr<dds::Writer<dds::ros::DisparityImage>> ros_disparity_;
  std::unique_ptr<dds::Writer<dds::ros::PointCloud2>> ros_cloud_;
  std::unique_ptr<dds::Writer<dds::ros::TFMessage>> ros_tf_, ros_tf_static_;
};

// Streams the files of `get` transfers (commands.h) on the station's file
// topic, one transfer at a time on its own thread (started by Create), so a
// large file never stalls the command loop. Every kAckWindowBytes the sender
// waits for the readers' acknowledgements (bounded by kAckTimeout), so it
// never runs ahead of the network; readers keep kFileTopicDepth chunks for an
// application that lags behind, and a reader gone silent ends the transfer
// (with a log line) instead of stalling it. Chunks go to every reader of the
// topic; clients keep those with their request id. A file that cannot be
// sent (gone, not regular, a size other than the manifest's, a read error,
// the daemon stopping) gets one chunk with `error` set and ends the transfer.
// Thread-safety: HasRoom, Enqueue and Stop from one thread (the command
// loop's); the transfers run on the sender's thread.
class FileSender {
 public:
  bool Create(const std::shared_ptr<dds::Participant>& p, const std::string& station,
              std::string* error);
  ~FileSender() { Stop(); }

  // Whether Enqueue would not exceed kMaxQueuedTransfers waiting transfers.
  // Only the command loop enqueues, so the answer holds until it does.
  bool HasRoom() const;
  // Queues `transfer` (sent after the transfers before it).
  void Enqueue(std::string request_id, std::string client, FileTransfer transfer);
  // Drops waiting transfers, ends the running one with an error chunk and
  // joins the thread.
  void Stop();

 private:
  using Clock = std::chrono::steady_clock;
  static constexpr std::size_t kAckWindowBytes = std::size_t{8} << 20;
  static constexpr std::size_t kMaxWindowChunks = 16;  // well below kFileTopicDepth
  static constexpr auto kAckTimeout = std::chrono::seconds(10);

  struct Job {
    std::string request_id, client;
    FileTransfer transfer;
  };

  void Loop();
  bool Stopping() const;
  // Writes one chunk of file `index`. `data` may be null for no data.
  bool WriteChunk(const Job& job, std::uint32_t index, std::uint64_t offset,
                  const std::uint8_t* data, std::size_t size, bool last, const std::string& problem,
                  std::string* error);
  // Sends an error chunk for file `index` (best effort) and returns false
  // with *error = problem.
  bool Abort(const Job& job, std::uint32_t index, const std::string& problem, std::string* error);
  bool Send(const Job& job, std::string* error);
  // Sends file `index` of `job` in chunks through `buffer`, waiting for
  // acknowledgements every `window` chunks (*unacknowledged counts them).
  bool SendFile(const Job& job, std::uint32_t index, std::size_t window,
                std::vector<std::uint8_t>* buffer, std::size_t* unacknowledged, std::string* error);

  std::unique_ptr<dds::Writer<dds::msg::SessionFile>> writer_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<Job> queue_;  // guarded by mutex_
  bool stopping_ = false;  // guarded by mutex_
  std::thread thread_;
};

}  // namespace craftscan::daemon
