// craftscan_ros_wire_capture: the C++ half of the ros_wire test (ros_wire.mjs
// is the other). Starts craftscand on the simulated station (DaemonFixture),
// subscribes to every ROS 2 topic it publishes (rt/craftscan/<station>/...,
// rt/tf, rt/tf_static) taking each sample's raw CDR as it came off the wire,
// runs a scan, and writes into OUT_DIR:
//   (emptied first)
//   NNN.cdr        one sample's serialised bytes (encapsulation header + CDR)
//   expected.json  {station, views, step_deg, frames, topic_counts, samples:
//                  [{file, topic, type, expected}]} where `expected` holds the field values the
//                  daemon meant to send, rebuilt on the sender side: the
//                  converters (convert.h) applied to what the session stored
//                  (left.png/right.png, disparity.pfm, cloud.ply, fused.ply)
//                  and to the calibration file, with the stamps taken from
//                  the received sample (a stamp is only known once sent) and
//                  the disparity range from it (the daemon's matcher band).
// Big arrays appear as {length, fnv1a32} (FNV-1a, 32 bits, of the bytes).
// With --record PATH (craftscan-record) it also runs `craftscan-record
// --mcap OUT_DIR/recording.mcap --out OUT_DIR/archive --what clouds` (both
// recorders in one process, one DDS domain) through the scan (started after the daemon,
// stopped with SIGTERM after it); topic_counts are then what the taps took
// per ROS 2 topic name, which the recording should hold too.
// Exit 0 when done, 1 with a message on stderr otherwise, 2 on bad usage.
//
//   craftscan_ros_wire_capture OUT_DIR [--views N] [--image-size WxH] [--record PATH]
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "../daemon/sessions/status_util.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/pipeline/common/ply.h"
#include "daemon_fixture.h"
#include "process_util.h"
#include "station_client.h"

namespace {

using namespace craftscan;
using namespace std::chrono_literals;
using nlohmann::json;

int Fail(const std::string& message) {
  std::cerr << "craftscan_ros_wire_capture: " << message << "\n";
  return 1;
}

// --- Field values as JSON (the same layout ros_wire.mjs builds from the
// decoded messages) --------------------------------------------------------

template <typename Sequence>
json Bytes(const Sequence& s) {
  std::uint32_t h = 2166136261u;
  const auto* p = reinterpret_cast<const std::uint8_t*>(s._buffer);
  const std::size_t n = std::size_t{s._length} * sizeof(*s._buffer);
  for (std::size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 16777619u;
  return {{"length", s._length}, {"fnv1a32", h}};
}

json Header(const dds::ros::Header& h) {
  return {{"stamp", {{"sec", h.stamp.sec}, {"nanosec", h.stamp.nanosec}}},
          {"frame_id", dds::View(h.frame_id)}};
}

json Roi(const dds::ros::RegionOfInterest& r) {
  return {{"x_offset", r.x_offset},
          {"y_offset", r.y_offset},
          {"height", r.height},
          {"width", r.width},
          {"do_rectify", r.do_rectify}};
}

json ToJson(const dds::ros::Image& m) {
  return {{"header", Header(m.header)},
          {"height", m.height},
          {"width", m.width},
          {"encoding", dds::View(m.encoding)},
          {"is_bigendian", m.is_bigendian},
          {"step", m.step},
          {"data", Bytes(m.data)}};
}

json ToJson(const dds::ros::CameraInfo& m) {
  return {{"header", Header(m.header)},
          {"height", m.height},
          {"width", m.width},
          {"distortion_model", dds::View(m.distortion_model)},
          {"d", std::vector<double>(m.d._buffer, m.d._buffer + m.d._length)},
          {"k", std::vector<double>(m.k, m.k + 9)},
          {"r", std::vector<double>(m.r, m.r + 9)},
          {"p", std::vector<double>(m.p, m.p + 12)},
          {"binning_x", m.binning_x},
          {"binning_y", m.binning_y},
          {"roi", Roi(m.roi)}};
}

json ToJson(const dds::ros::PointCloud2& m) {
  json fields = json::array();
  for (std::uint32_t i = 0; i < m.fields._length; ++i) {
    const dds::ros::PointField& f = m.fields._buffer[i];
    fields.push_back({{"name", dds::View(f.name)},
                      {"offset", f.offset},
                      {"datatype", f.datatype},
                      {"count", f.count}});
  }
  return {{"header", Header(m.header)},
          {"height", m.height},
          {"width", m.width},
          {"fields", fields},
          {"is_bigendian", m.is_bigendian},
          {"point_step", m.point_step},
          {"row_step", m.row_step},
          {"data", Bytes(m.data)},
          {"is_dense", m.is_dense}};
}

json ToJson(const dds::ros::DisparityImage& m) {
  return {{"header", Header(m.header)},
          {"image", ToJson(m.image)},
          {"f", m.f},
          {"t", m.t},
          {"valid_window", Roi(m.valid_window)},
          {"min_disparity", m.min_disparity},
          {"max_disparity", m.max_disparity},
          {"delta_d", m.delta_d}};
}

json ToJson(const dds::ros::TFMessage& m) {
  json transforms = json::array();
  for (std::uint32_t i = 0; i < m.transforms._length; ++i) {
    const dds::ros::TransformStamped& t = m.transforms._buffer[i];
    const auto& v = t.transform.translation;
    const auto& q = t.transform.rotation;
    transforms.push_back({{"header", Header(t.header)},
                          {"child_frame_id", dds::View(t.child_frame_id)},
                          {"transform",
                           {{"translation", {{"x", v.x}, {"y", v.y}, {"z", v.z}}},
                            {"rotation", {{"x", q.x}, {"y", q.y}, {"z", q.z}, {"w", q.w}}}}}});
  }
  return {{"transforms", transforms}};
}

// --- Taking raw samples ------------------------------------------------------

struct Taken {
  std::string topic, type;
  dds::RawSample raw;
  std::function<json()> received;     // the sample as Cyclone decodes it
  std::function<int64_t()> stamp_ns;  // its header stamp
  std::function<json(int64_t stamp_ns, const json& received)> expected;
};

// A raw reader of one topic and what the test expects of its samples.
struct Tap {
  std::function<bool(std::vector<Taken>*, std::string*)> poll;  // true if it took one
};

template <typename Msg>
Tap MakeTap(const std::shared_ptr<dds::Participant>& participant, dds::TopicSpec<Msg> topic,
            std::string type,
            std::function<json(int index, int64_t stamp_ns, const json& received)> expected,
            std::function<int64_t(const Msg&)> stamp, std::string* error) {
  topic.qos.history_depth = 32;  // the test takes them as they come; keep a burst
  std::shared_ptr<dds::Reader<Msg>> reader = dds::Reader<Msg>::Create(participant, topic, error);
  if (!reader) return {};
  auto count = std::make_shared<int>(0);
  return {[=](std::vector<Taken>* out, std::string* why) {
    auto decoded = std::make_shared<dds::Sample<Msg>>();
    dds::RawSample raw;
    const dds::TakeStatus status = reader->TakeRaw(0ns, &raw, decoded.get(), why);
    if (status != dds::TakeStatus::kOk) return false;
    const int index = (*count)++;
    Taken t;
    t.topic = topic.name;
    t.type = type;
    t.raw = std::move(raw);
    t.received = [decoded] { return ToJson(**decoded); };
    t.stamp_ns = [decoded, stamp] { return stamp(**decoded); };
    t.expected = [expected, index](int64_t stamp_ns, const json& received) {
      return expected(index, stamp_ns, received);
    };
    out->push_back(std::move(t));
    return true;
  }};
}

template <typename Msg>
json Built(const std::function<bool(dds::Outgoing<Msg>*, std::string*)>& make) {
  dds::Outgoing<Msg> out;
  std::string error;
  if (!make(&out, &error)) return {{"error", error}};
  return ToJson(out.msg());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: craftscan_ros_wire_capture OUT_DIR [--views N] [--image-size WxH] "
                 "[--record PATH]\n";
    return 2;
  }
  const std::string out_dir = argv[1];
  int views = 3;
  std::string image_size = "640x512";
  std::string record_path;
  for (int i = 2; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--views") {
      views = std::atoi(argv[i + 1]);
    } else if (key == "--image-size") {
      image_size = argv[i + 1];
    } else if (key == "--record") {
      record_path = argv[i + 1];
    } else {
      std::cerr << "craftscan_ros_wire_capture: unknown option " << key << "\n";
      return 2;
    }
  }
  if (views < 2 || views > 12) return Fail("--views must be 2..12");
  const double step_deg = 360.0 / views;
  std::error_code ignored;  // a previous run's files go
  std::filesystem::remove_all(out_dir, ignored);
  std::filesystem::create_directories(out_dir);

  testing::DaemonFixture fixture(image_size);
  // /tf and /tf_static carry every station of a domain, and the other tests'
  // daemons pick domains 1–200 at random: on a shared one a foreign
  // station's transform was taken as this daemon's (an ASan run in CI). A
  // domain of its own keeps the samples compared this daemon's.
  fixture.set_domain(224);
  fixture.pipeline_extra = ", mesh: false";
  std::string error;
  if (!fixture.Prepare(&error)) return Fail(error);
  StereoCalibration calibration;
  if (!LoadCalibration(fixture.data_dir() + "/calibration/current.yaml", &calibration, &error)) {
    return Fail(error);
  }

  // The readers exist before the daemon starts: nothing is missed, and the
  // transient-local camera_info and tf_static arrive as well.
  dds::ParticipantOptions options;
  options.domain_id = fixture.domain();
  options.config = fixture.dds_config();
  auto participant = dds::Participant::Create(options, &error);
  if (!participant) return Fail(error);
  const std::string station = fixture.station();
  const dds::StationFrames frames = dds::FramesOf(station);
  std::unique_ptr<daemon::SessionStore> store;
  std::unique_ptr<daemon::Session> session;
  const auto stamp_of = [](const dds::ros::Header& h) { return dds::NsFromRosTime(h.stamp); };

  std::vector<Tap> taps;
  for (const dds::Side side : {dds::Side::kLeft, dds::Side::kRight}) {
    const std::string frame = side == dds::Side::kLeft ? frames.left : frames.right;
    taps.push_back(MakeTap<dds::ros::Image>(
        participant, dds::RosImageTopic(station, side), "sensor_msgs/msg/Image",
        [&, side, frame](int index, int64_t stamp_ns, const json&) {
          // The view-th image of a side is that view's stored PNG.
          cv::Mat left, right;
          json meta;
          if (!session->LoadCapture(index, &left, &right, &meta, &error)) {
            return json{{"error", error}};
          }
          const cv::Mat image = side == dds::Side::kLeft ? left : right;
          return Built<dds::ros::Image>([&](auto* out, std::string* why) {
            return dds::MakeImage(image, stamp_ns, frame, out, why);
          });
        },
        [&](const dds::ros::Image& m) { return stamp_of(m.header); }, &error));
    taps.push_back(MakeTap<dds::ros::CameraInfo>(
        participant, dds::RosCameraInfoTopic(station, side), "sensor_msgs/msg/CameraInfo",
        [&, side, frame](int, int64_t stamp_ns, const json&) {
          return Built<dds::ros::CameraInfo>([&](auto* out, std::string* why) {
            return dds::MakeCameraInfo(calibration, side, stamp_ns, frame, out, why);
          });
        },
        [&](const dds::ros::CameraInfo& m) { return stamp_of(m.header); }, &error));
  }
  taps.push_back(MakeTap<dds::ros::DisparityImage>(
      participant, dds::RosDisparityTopic(station), "stereo_msgs/msg/DisparityImage",
      [&](int index, int64_t stamp_ns, const json& received) {
        cv::Mat disparity;
        if (!session->LoadDisparity(index, &disparity, &error)) return json{{"error", error}};
        dds::DisparityMeta meta;
        meta.f_px = static_cast<float>(calibration.rectified_focal_px());
        meta.baseline_mm = static_cast<float>(calibration.baseline_mm());
        meta.cx_offset_px = static_cast<float>(calibration.P1(0, 2) - calibration.P2(0, 2));
        // The matcher's band (from the daemon's config) is only known from
        // the sample; ROS's range is ours shifted by the cx offset.
        meta.min_disparity = received["min_disparity"].get<float>() + meta.cx_offset_px;
        meta.max_disparity = received["max_disparity"].get<float>() + meta.cx_offset_px;
        meta.stamp_ns = stamp_ns;
        meta.frame_id = frames.rig;
        return Built<dds::ros::DisparityImage>([&](auto* out, std::string* why) {
          return dds::MakeDisparityImage(disparity, meta, out, why);
        });
      },
      [&](const dds::ros::DisparityImage& m) { return stamp_of(m.header); }, &error));
  taps.push_back(MakeTap<dds::ros::PointCloud2>(
      participant, dds::RosCloudTopic(station), "sensor_msgs/msg/PointCloud2",
      [&](int index, int64_t stamp_ns, const json&) {
        // Views 0..n-1, then the fused cloud.
        PointCloud cloud;
        const bool fused = index >= views;
        const bool loaded = fused ? ReadPly(session->dir() + "/fused.ply", &cloud, &error)
                                  : session->LoadCloud(index, &cloud, &error);
        if (!loaded) return json{{"error", error}};
        return Built<dds::ros::PointCloud2>([&](auto* out, std::string* why) {
          return dds::MakePointCloud2(cloud, stamp_ns, fused ? frames.turntable_base : frames.rig,
                                      out, why);
        });
      },
      [&](const dds::ros::PointCloud2& m) { return stamp_of(m.header); }, &error));
  const auto tf_stamp = [&](const dds::ros::TFMessage& m) {
    return m.transforms._length > 0 ? stamp_of(m.transforms._buffer[0].header) : int64_t{0};
  };
  taps.push_back(MakeTap<dds::ros::TFMessage>(
      participant, dds::RosTfStaticTopic(), "tf2_msgs/msg/TFMessage",
      [&](int, int64_t stamp_ns, const json&) {
        return Built<dds::ros::TFMessage>([&](auto* out, std::string* why) {
          std::vector<dds::FrameTransform> transforms;
          return dds::StaticStationTransforms(calibration, frames, &transforms, why) &&
                 dds::MakeTfMessage(transforms, stamp_ns, out, why);
        });
      },
      tf_stamp, &error));
  taps.push_back(MakeTap<dds::ros::TFMessage>(
      participant, dds::RosTfTopic(), "tf2_msgs/msg/TFMessage",
      [&](int index, int64_t stamp_ns, const json&) {
        constexpr double kRadPerDeg = 3.14159265358979323846 / 180;
        return Built<dds::ros::TFMessage>([&](auto* out, std::string* why) {
          return dds::MakeTfMessage(
              {dds::TurntableTransform(frames, index * step_deg * kRadPerDeg)}, stamp_ns, out, why);
        });
      },
      tf_stamp, &error));
  for (const Tap& tap : taps) {
    if (!tap.poll) return Fail("creating the readers: " + error);
  }

  if (!fixture.Start(&error)) return Fail(error);
  testing::StationClient client;
  // The domain exists in this process already (the taps' participant): the
  // client's participant joins it with an empty config.
  if (!client.Start(fixture.domain(), "", station, &error)) return Fail(error);
  if (!client.WaitForDaemon(30s)) return Fail("the daemon never answered; log:\n" + fixture.Log());

  // craftscan-record --mcap, once its readers exist ("recording ..." in its
  // log) and discovery on loopback has matched them (well under a second).
  testing::ChildProcess recorder;
  const std::string mcap_path = out_dir + "/recording.mcap";
  const std::string recorder_log = out_dir + "/craftscan-record.log";
  if (!record_path.empty()) {
    testing::SpawnOptions spawn;
    spawn.stdout_path = recorder_log;
    spawn.stderr_to_stdout = true;
    if (!testing::Spawn({record_path, "--station", station, "--domain",
                         std::to_string(fixture.domain()), "--dds-config", fixture.dds_config(),
                         "--mcap", mcap_path, "--out", out_dir + "/archive", "--what", "clouds"},
                        spawn, &recorder)) {
      return Fail("cannot start " + record_path);
    }
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    while (testing::ReadFile(recorder_log).find("recording the ROS 2 topics") ==
           std::string::npos) {
      if (!recorder.Running() || std::chrono::steady_clock::now() > deadline) {
        return Fail("craftscan-record did not start:\n" + testing::ReadFile(recorder_log));
      }
      std::this_thread::sleep_for(20ms);
    }
    std::this_thread::sleep_for(1500ms);
  }

  std::vector<Taken> taken;
  std::atomic<bool> done{false};
  std::string poll_error;
  std::thread poller([&] {
    while (!done) {
      bool any = false;
      for (const Tap& tap : taps) any = tap.poll(&taken, &poll_error) || any;
      if (!any) std::this_thread::sleep_for(5ms);
    }
  });
  const auto reply =
      client.Send("scan", {{"object", "wire check"}, {"views", views}, {"step_deg", step_deg}},
                  testing::kOperatorToken);
  if (!reply || reply->code_name != "ok") {
    done = true;
    poller.join();
    return Fail("scan refused: " + (reply ? reply->message : std::string("no reply")));
  }
  const std::string session_id = reply->result["session"];
  const json job = testing::WaitForJobEnd(client, testing::kObserverToken,
                                          reply->result["id"].get<std::string>(), 300s);
  // The last samples (the fused cloud) are on their way when the job ends.
  std::this_thread::sleep_for(1500ms);
  done = true;
  poller.join();
  if (job.value("state", "") != "done") {
    return Fail("scan ended " + job.dump() + "; log:\n" + fixture.Log());
  }
  if (recorder.started()) {
    recorder.Signal(SIGTERM);
    if (recorder.Wait(30s) != 0) {
      return Fail("craftscan-record --mcap did not stop cleanly:\n" +
                  testing::ReadFile(recorder_log));
    }
    // The archive recorder beside it (same process, same domain) got the
    // views' clouds and the fused one as well.
    const std::string index =
        testing::ReadFile(out_dir + "/archive/" + station + "/" + session_id + "/index.jsonl");
    const auto lines = std::count(index.begin(), index.end(), '\n');
    if (lines != views + 1) {
      return Fail("the archive beside the MCAP recording holds " + std::to_string(lines) +
                  " clouds, want " + std::to_string(views + 1) + ":\n" +
                  testing::ReadFile(recorder_log));
    }
  }

  store = daemon::SessionStore::Open(fixture.data_dir(), testing::StatusInto(&error));
  if (!store) return Fail(error);
  session = store->OpenSession(session_id, testing::StatusInto(&error));
  if (!session) return Fail(error);

  json samples = json::array();
  std::map<std::string, int> topic_counts;  // by ROS 2 name: "/tf" for "rt/tf"
  for (const Taken& t : taken) topic_counts[t.topic.substr(2)] += 1;
  for (std::size_t i = 0; i < taken.size(); ++i) {
    Taken& t = taken[i];
    char name[32];
    std::snprintf(name, sizeof(name), "%03zu.cdr", i);
    std::ofstream file(out_dir + "/" + name, std::ios::binary);
    file.write(reinterpret_cast<const char*>(t.raw.cdr.data()),
               static_cast<std::streamsize>(t.raw.cdr.size()));
    if (!file) return Fail("cannot write " + out_dir + "/" + name);
    const json received = t.received();
    samples.push_back({{"file", name},
                       {"topic", t.topic},
                       {"type", t.type},
                       {"expected", t.expected(t.stamp_ns(), received)}});
  }
  std::ofstream manifest(out_dir + "/expected.json");
  manifest << json{
      {"station", station},
      {"views", views},
      {"step_deg", step_deg},
      {"frames",
       {{"base", frames.base},
        {"rig", frames.rig},
        {"left", frames.left},
        {"right", frames.right},
        {"turntable_base", frames.turntable_base},
        {"turntable", frames.turntable}}},
      {"topic_counts", topic_counts},
      {"samples",
       samples}}.dump(1);
  if (!manifest) return Fail("cannot write expected.json");
  std::printf("ros_wire_capture: %zu samples of a %d-view scan in %s\n", taken.size(), views,
              out_dir.c_str());
  return fixture.Stop(SIGTERM) == 0 ? 0 : Fail("craftscand did not exit cleanly");
}
