// craftscan-record: archives what one or more stations publish over DDS
// (captures as PNG, clouds as PLY, disparity maps as PFM; with --what models
// each finished scan's mesh.glb, fetched with `get`) with an optional
// size/count limit; see craftscan/record/archive.h for the layout. With
// --mcap FILE it also (or, without --out, only) records their ROS 2 topics
// into an MCAP file (craftscan/record/mcap_recorder.h). Parses arguments,
// opens the archive and/or the MCAP file, runs the recorders until
// SIGINT/SIGTERM, --duration, --count or a full archive, then prints a
// summary on stdout.
//
// Exit codes: 0 stopped cleanly (signal, duration, count, archive full);
// 1 could not start, or an I/O error stopped the recording; 2 bad arguments.
#include <pthread.h>
#include <signal.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <spdlog/fmt/fmt.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>

#include "craftscan/record/archive.h"
#include "craftscan/record/mcap_recorder.h"
#include "craftscan/record/recorder.h"

namespace {

using namespace craftscan::record;

constexpr int kExitOk = 0, kExitFailure = 1, kExitUsage = 2;

void PrintSummary(const RecorderSummary& summary, const std::string& out_dir, double seconds) {
  const auto row = [](const auto& station, const auto& files, const auto& bytes,
                      const auto& captures, const auto& clouds, const auto& disparity,
                      const auto& malformed, const auto& refused) {
    return fmt::format("{:<16} {:>7} {:>12} {:>9} {:>7} {:>10} {:>10} {:>8}\n", station, files,
                       bytes, captures, clouds, disparity, malformed, refused);
  };
  std::string text = fmt::format("craftscan-record: stopped after {:.1f} s ({}): {}\n", seconds,
                                 ToString(summary.reason), summary.message);
  text +=
      row("station", "files", "bytes", "captures", "clouds", "disparity", "malformed", "refused");
  StationStats total{.station = "total"};
  for (const StationStats& s : summary.stations) {
    text += row(s.station, s.files, s.bytes, s.captures, s.clouds, s.disparities, s.malformed,
                s.refused + s.too_large);
    total.files += s.files;
    total.bytes += s.bytes;
    total.captures += s.captures;
    total.clouds += s.clouds;
    total.disparities += s.disparities;
    total.malformed += s.malformed;
    total.refused += s.refused + s.too_large;
  }
  text += row(total.station, total.files, total.bytes, total.captures, total.clouds,
              total.disparities, total.malformed, total.refused);
  text += fmt::format("archive '{}': {} files, {} bytes; rotation deleted {} files, {} bytes\n",
                      out_dir, summary.archive.files, summary.archive.bytes, summary.rotated_files,
                      summary.rotated_bytes);
  std::fputs(text.c_str(), stdout);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "craftscan-record: archives the captures (PNG), clouds (PLY) and disparity maps (PFM) "
      "that craftscan stations publish over DDS, as <out>/<station>/<session>/... with an "
      "index.jsonl per session"};
  RecorderOptions recorder_options;
  ArchiveOptions archive_options;
  std::vector<std::string> what = {"clouds", "captures"};
  std::string max_bytes_text, log_level = "info";
  bool rotate = false;
  double duration_s = 0;
  std::string bag_root, source_organization;
  app.add_option("--station", recorder_options.stations,
                 "station id to record (repeat for several stations)")
      ->required();
  app.add_option("--domain", recorder_options.domain_id, "DDS domain id (0..230)")
      ->capture_default_str();
  app.add_option("--dds-config", recorder_options.dds_config,
                 "Cyclone DDS configuration: XML, a file (absolute path or file:// URI) or a "
                 "comma-separated list (default: CYCLONEDDS_URI)");
  app.add_option("--out", archive_options.out_dir, "archive folder (created if missing)");
  std::string mcap_path;
  app.add_option("--mcap", mcap_path,
                 "record the stations' ROS 2 topics (image_raw, camera_info, disparity, cloud, "
                 "/tf, /tf_static) into this MCAP file (profile ros2, ros2msg schemas, CDR "
                 "messages), besides or instead of --out");
  app.add_option("--what", what, "what to record, comma-separated")
      ->delimiter(',')
      ->check(CLI::IsMember({"clouds", "captures", "disparity", "models"}))
      ->capture_default_str();
  app.add_option("--token", recorder_options.token,
                 "token for fetching each session's mesh.glb (--what models; observer is enough)")
      ->envname("CRAFTSCAN_TOKEN");
  app.add_option("--max-bytes", max_bytes_text,
                 "limit on the archive's data files, N[K|M|G] (binary multiples)");
  app.add_option("--max-files", archive_options.max_files, "limit on the number of data files")
      ->check(CLI::PositiveNumber);
  app.add_flag("--rotate", rotate,
               "at a limit, delete the oldest recorded files (default: stop recording)");
  app.add_option("--duration", duration_s, "stop after this many seconds")
      ->check(CLI::PositiveNumber);
  app.add_option("--count", recorder_options.max_items,
                 "stop after this many items (a capture, a cloud or a disparity map)")
      ->check(CLI::PositiveNumber);
  CLI::Option* bagit_option = app.add_option(
      "--bagit", bag_root,
      "when the recording stops, also write each session recorded in this run as a BagIt 1.0 "
      "bag (RFC 8493) at DIR/<station>/<session> (DIR: new or empty)");
  app.add_option("--source-organization", source_organization,
                 "bag-info.txt Source-Organization of the --bagit bags (default: "
                 "CRAFTSCAN_SOURCE_ORGANIZATION)")
      ->needs(bagit_option);
  app.add_option("--log-level", log_level, "debug, info, warn or error")
      ->check(CLI::IsMember({"debug", "info", "warn", "error"}))
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }

  std::string error;
  const auto usage_error = [&](const std::string& message) {
    std::fprintf(stderr, "craftscan-record: %s\nRun with --help for more information.\n",
                 message.c_str());
    return kExitUsage;
  };
  if (archive_options.out_dir.empty() && mcap_path.empty()) {
    return usage_error("--out or --mcap is needed");
  }
  if (!bag_root.empty() && archive_options.out_dir.empty()) {
    return usage_error("--bagit bags the archive's sessions: it needs --out");
  }
  if (!max_bytes_text.empty() &&
      !ParseByteSize(max_bytes_text, &archive_options.max_bytes, &error)) {
    return usage_error("--max-bytes: " + error);
  }
  if (!bag_root.empty() && source_organization.empty()) {
    if (const char* env = std::getenv("CRAFTSCAN_SOURCE_ORGANIZATION")) source_organization = env;
    if (source_organization.empty()) {
      return usage_error(
          "--bagit needs the bags' Source-Organization: --source-organization NAME or "
          "CRAFTSCAN_SOURCE_ORGANIZATION");
    }
  }
  if (rotate && archive_options.max_bytes == 0 && archive_options.max_files == 0) {
    return usage_error("--rotate needs --max-bytes or --max-files");
  }
  archive_options.on_limit = rotate ? LimitPolicy::kRotate : LimitPolicy::kStop;
  recorder_options.what.clear();
  for (const std::string& name : what) {
    RecordKind kind;
    RecordKindFromString(name, &kind);  // checked by CLI11
    if (std::find(recorder_options.what.begin(), recorder_options.what.end(), kind) ==
        recorder_options.what.end()) {
      recorder_options.what.push_back(kind);
    }
  }
  if (!recorder_options.IsValid(&error)) return usage_error(error);

  auto logger = spdlog::stderr_color_mt("craftscan-record");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  spdlog::set_level(spdlog::level::from_str(log_level));

  // Signals are taken by this thread (sigtimedwait); every thread created
  // from here on (DDS, readers) inherits the blocked mask.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  // Refused now rather than after a recording that could not be bagged.
  if (!bag_root.empty()) {
    if (const craftscan::Status free = craftscan::CheckBagTarget(bag_root); !free.ok()) {
      spdlog::critical("cannot start: --bagit: {}", free.message());
      return kExitFailure;
    }
  }
  std::shared_ptr<Archive> archive;
  std::unique_ptr<Recorder> recorder;
  if (!archive_options.out_dir.empty()) {
    archive = Archive::Open(archive_options, &error);
    if (archive) recorder = Recorder::Create(recorder_options, archive, &error);
    if (!recorder) {
      spdlog::critical("cannot start: {}", error);
      return kExitFailure;
    }
    const ArchiveTotals held = archive->totals();
    spdlog::info("recording {} of {} on domain {} into '{}' (holds {} files, {} bytes)",
                 fmt::join(what, ","), fmt::join(recorder_options.stations, ", "),
                 recorder_options.domain_id, archive_options.out_dir, held.files, held.bytes);
  }
  std::unique_ptr<McapRecorder> mcap;
  if (!mcap_path.empty()) {
    McapRecorderOptions mcap_options;
    mcap_options.stations = recorder_options.stations;
    mcap_options.domain_id = recorder_options.domain_id;
    // A second participant of a domain this process has joined takes the
    // first one's configuration (Cyclone: one configuration per domain).
    mcap_options.dds_config = recorder ? "" : recorder_options.dds_config;
    mcap_options.path = mcap_path;
    mcap = McapRecorder::Create(mcap_options, &error);
    if (!mcap) {
      spdlog::critical("cannot start: {}", error);
      return kExitFailure;
    }
    spdlog::info("recording the ROS 2 topics of {} on domain {} into '{}'",
                 fmt::join(recorder_options.stations, ", "), recorder_options.domain_id, mcap_path);
  }

  const auto start = std::chrono::steady_clock::now();
  const auto elapsed_s = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  std::string stop_message;
  while (!(recorder && recorder->WaitUntilDone(std::chrono::milliseconds(0)))) {
    if (mcap && mcap->Failed()) break;
    double wait_s = 0.1;
    if (duration_s > 0) {
      const double left_s = duration_s - elapsed_s();
      if (left_s <= 0) {
        stop_message = fmt::format("--duration {} s elapsed", duration_s);
        break;
      }
      wait_s = std::min(wait_s, left_s);
    }
    timespec wait{};
    wait.tv_nsec = static_cast<long>(wait_s * 1e9);
    const int signal_number = sigtimedwait(&signals, nullptr, &wait);
    if (signal_number == SIGINT || signal_number == SIGTERM) {
      stop_message = signal_number == SIGINT ? "SIGINT" : "SIGTERM";
      break;
    }
  }
  if (!stop_message.empty()) spdlog::info("stopping: {}", stop_message);
  bool failed = false;
  if (recorder) {
    recorder->Stop(stop_message.empty() ? "stop requested" : stop_message);
    const RecorderSummary summary = recorder->Summary();
    recorder.reset();  // leaves the DDS domain
    PrintSummary(summary, archive_options.out_dir, elapsed_s());
    failed = summary.reason == StopReason::kError;
    if (!bag_root.empty()) {
      std::vector<craftscan::BagSummary> bags;
      const craftscan::Status bagged = archive->WriteBags(bag_root, source_organization, &bags);
      for (const craftscan::BagSummary& bag : bags) {
        std::printf("bag '%s': Payload-Oxum %llu.%llu\n", bag.path.c_str(),
                    static_cast<unsigned long long>(bag.payload_bytes),
                    static_cast<unsigned long long>(bag.payload_files));
      }
      std::fflush(stdout);
      if (!bagged.ok()) {
        spdlog::error("--bagit: {}", bagged.message());
        failed = true;
      }
    }
  }
  if (mcap) {
    const bool closed = mcap->Stop(&error);
    const McapSummary summary = mcap->Summary();
    std::string text = fmt::format("mcap '{}': {} messages{}\n", mcap_path, summary.total,
                                   closed ? "" : " (ERROR: " + error + ")");
    for (const auto& [topic, count] : summary.messages) {
      text += fmt::format("  {:<48} {:>7}\n", topic, count);
    }
    std::fputs(text.c_str(), stdout);
    std::fflush(stdout);
    failed = failed || !closed;
  }
  return failed ? kExitFailure : kExitOk;
}
