// `craftscan-bench site`: a burst of scans from N simulated stations with 0,
// 1, 2 … reconstruction workers, each station and worker a host of its own
// (tests/scale/site_harness.h: a network namespace on a bridge with its own
// CPU share, so the 2-core machine stands for a site of weaker PCs), the
// real craftscand, craftscan-worker and craftscanctl. Prints the burst's
// time, scans per hour, the speed-up over no workers, the bytes moved per
// job, and the same figures on paper for a larger site from the measured
// per-job costs. Needs real root (network namespaces, cgroups).
//
//   craftscan-bench site [--stations 3] [--workers 0,1,2] [--views 6]
//                        [--image-size 640x512] [--station-cpu 0.3]
//                        [--worker-cpu 0.5] [--worker-jobs 2] [--paper 10x4] [--json FILE]
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "command.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "process_util.h"
#include "site_harness.h"
#include "test_paths.h"

namespace craftscan::bench {
namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;
using testing::ChildProcess;
using testing::HostCommand;
using testing::SiteNetwork;

constexpr const char* kToken = "site-bench-operator-token-0123";

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

bool WriteText(const std::string& path, const std::string& text, std::string* error) {
  std::ofstream out(path);
  out << text;
  if (!out) *error = "cannot write " + path;
  return static_cast<bool>(out);
}

// CPU seconds (user + system) a process has used so far; 0 if unknown.
double CpuSeconds(pid_t pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
  const std::size_t end = text.rfind(')');  // the name may hold spaces
  if (end == std::string::npos) return 0;
  std::istringstream rest(text.substr(end + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) stime = std::stoull(field);
  }
  return static_cast<double>(utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

struct Run {
  int workers = 0;
  double burst_s = 0;
  double station_cpu_s = 0, worker_cpu_s = 0;  // the burst's, all stations / all workers
  std::vector<json> jobs;                      // each scan's job result (craftscanctl scan --json)
  bool ok = true;
  std::string error;
};

class SiteCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "site",
        "A burst of simulated scans from N stations with 0, 1, 2 … workers, each a host "
        "with its own CPU share (needs root)");
    sub->add_option("--stations", stations_, "Stations (hosts), each scanning once")
        ->check(CLI::Range(1, 20));
    sub->add_option("--workers", workers_, "Worker counts to run, e.g. 0,1,2")->delimiter(',');
    sub->add_option("--views", views_, "Views per scan")->check(CLI::Range(2, 36));
    sub->add_option("--image-size", image_size_, "The sim cameras' size, WxH");
    sub->add_option("--station-cpu", station_cpu_, "Cores per station host")
        ->check(CLI::Range(0.05, 2.0));
    sub->add_option("--worker-cpu", worker_cpu_, "Cores per worker host")
        ->check(CLI::Range(0.05, 2.0));
    sub->add_option("--worker-jobs", worker_jobs_, "Jobs a worker holds at once (its jobs: key)")
        ->check(CLI::Range(1, 16));
    sub->add_option("--paper", paper_, "A site figured on paper from the costs, SxW");
    sub->add_option("--json", json_path_, "Write the figures as JSON");
    sub->add_option("--keep", keep_dir_,
                    "Copy each burst's logs and scan results into this folder (<workers>w/)");
    return sub;
  }

  int Run() override {
    int paper_stations = 0, paper_workers = 0;
    if (std::sscanf(paper_.c_str(), "%dx%d", &paper_stations, &paper_workers) != 2 ||
        paper_stations < 1 || paper_workers < 0) {
      std::cerr << "craftscan-bench site: --paper: want SxW, e.g. 10x4, got '" << paper_ << "'\n";
      return kExitUsage;
    }
    if (testing::CraftscandPath()[0] == '\0' || testing::CraftscanctlPath()[0] == '\0') {
      std::cerr << "craftscan-bench site: built without craftscand/craftscanctl\n";
      return kExitDataError;
    }
    std::vector<bench::Run> runs;
    for (int w : workers_) {
      std::printf(
          "site: %d stations (%.2f core each), %d workers (%.2f core each), %d views "
          "at %s ...\n",
          stations_, station_cpu_, w, worker_cpu_, views_, image_size_.c_str());
      std::fflush(stdout);
      runs.push_back(Burst(w));
      const bench::Run& r = runs.back();
      if (!r.ok) {
        std::cerr << "craftscan-bench site: " << w << " workers: " << r.error << "\n";
        return kExitDataError;
      }
      std::printf("  burst done in %.1f s (%.1f scans/h)\n", r.burst_s,
                  stations_ * 3600.0 / r.burst_s);
    }
    return Report(runs, paper_stations, paper_workers);
  }

 private:
  // Writes one station's tokens, config and exact sim calibration in `dir`.
  bool PrepareStation(const std::string& dir, int index, bool remote, std::string* error) const {
    std::filesystem::create_directories(dir + "/data/calibration");
    const std::string tokens = dir + "/tokens.yaml";
    if (!WriteText(
            tokens,
            std::string("tokens:\n  - {name: site, token: \"") + kToken + "\", role: operator}\n",
            error))
      return false;
    ::chmod(tokens.c_str(), 0600);
    const std::string sim = "{driver: sim, config: {image_size: " + image_size_ + ", threads: 1}}";
    const std::string config =
        "version: 1\nstation: st" + std::to_string(index) + "\nsite: bench\ndata_dir: " + dir +
        "/data\ndds: {domain: " + std::to_string(kDomain) + "}\nauth: {tokens_file: " + tokens +
        "}\nplugins: {path: [" + testing::PluginDir() + "]}\ndevices:\n  camera: " + sim +
        "\n  turntable: " + sim +
        "\nscan: {settle_ms: 0}\npipeline: {threads: 1, volume_radius_mm: 65, "
        "volume_max_height_mm: 70, platter_radius_mm: 0}\nreconstruction: {mode: " +
        (remote ? "remote" : "local") + ", offer_timeout_ms: 30000}\n";
    if (!WriteText(dir + "/craftscand.yaml", config, error)) return false;
    sim::SimDriverOptions options;
    if (!sim::SimDriverOptionsFromConfig({{"image_size", image_size_}}, &options, error))
      return false;
    auto station = sim::SimStation::Create(sim::SimRigOptions(options), error);
    return station &&
           SaveCalibration(dir + "/data/calibration/current.yaml", station->calibration(), error);
  }

  bool PrepareWorker(const std::string& dir, int index, std::string* error) const {
    std::filesystem::create_directories(dir + "/work");
    const std::string token = dir + "/worker.token";
    if (!WriteText(token, std::string(kToken) + "\n", error)) return false;
    ::chmod(token.c_str(), 0600);
    return WriteText(dir + "/craftscan-worker.yaml",
                     "version: 1\nworker: wk" + std::to_string(index) +
                         "\nsite: bench\ndds: {domain: " + std::to_string(kDomain) +
                         "}\nauth: {token_file: " + token + "}\nthreads: 1\njobs: " +
                         std::to_string(worker_jobs_) + "\nwork_dir: " + dir + "/work\n",
                     error);
  }

  // Waits until `path` (a log) contains `text`.
  static bool WaitForLog(const std::string& path, const std::string& text,
                         std::chrono::seconds limit) {
    const auto deadline = Clock::now() + limit;
    while (Clock::now() < deadline) {
      if (ReadText(path).find(text) != std::string::npos) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return false;
  }

  bench::Run Burst(int workers) const {
    bench::Run run;
    run.workers = workers;
    std::vector<testing::SiteHostSpec> hosts;
    for (int i = 0; i < stations_; ++i) hosts.push_back({"st" + std::to_string(i), station_cpu_});
    for (int j = 0; j < workers; ++j) hosts.push_back({"wk" + std::to_string(j), worker_cpu_});
    hosts.push_back({"client", 0});
    const std::size_t client = hosts.size() - 1;
    std::string why;
    auto site = SiteNetwork::Create(hosts, &why);
    if (!site) {
      run.ok = false;
      run.error = "cannot make the site's hosts: " + why;
      return run;
    }
    // Declared after the site: killed before its hosts go.
    std::vector<std::unique_ptr<ChildProcess>> processes;
    const auto start = [&](std::size_t host, std::vector<std::string> argv,
                           const std::string& log) {
      processes.push_back(std::make_unique<ChildProcess>());
      HostCommand command{std::move(argv), {}, log, ""};
      return site->Start(host, command, processes.back().get(), &why);
    };
    const auto fail = [&](const std::string& message) {
      run.ok = false;
      run.error = message + (why.empty() ? "" : ": " + why);
      return run;
    };
    const std::string root = site->work_dir();
    for (int i = 0; i < stations_; ++i) {
      const std::string dir = root + "/st" + std::to_string(i);
      if (!PrepareStation(dir, i, workers > 0, &why)) return fail("station " + std::to_string(i));
      if (!start(i, {testing::CraftscandPath(), "--config", dir + "/craftscand.yaml"},
                 dir + "/craftscand.log"))
        return fail("starting craftscand");
    }
    for (int j = 0; j < workers; ++j) {
      const std::string dir = root + "/wk" + std::to_string(j);
      if (!PrepareWorker(dir, j, &why)) return fail("worker " + std::to_string(j));
      if (!start(stations_ + j, {WorkerPath(), "--config", dir + "/craftscan-worker.yaml"},
                 dir + "/worker.log"))
        return fail("starting craftscan-worker");
    }
    const auto ctl = [&](int station, std::vector<std::string> args) {
      std::vector<std::string> argv = {testing::CraftscanctlPath(),
                                       "--station",
                                       "st" + std::to_string(station),
                                       "--domain",
                                       std::to_string(kDomain),
                                       "--dds-config",
                                       site->DdsConfig(client),
                                       "--timeout",
                                       "30",
                                       "--token",
                                       kToken};
      argv.insert(argv.end(), args.begin(), args.end());
      return argv;
    };
    for (int i = 0; i < stations_; ++i) {
      std::string out;
      bool up = false;
      for (int attempt = 0; attempt < 6 && !up; ++attempt)
        up = site->Run(client, ctl(i, {"status"}), &out, std::chrono::seconds(40)) == 0;
      if (!up) return fail("station st" + std::to_string(i) + " does not answer: " + out);
    }
    for (int j = 0; j < workers; ++j) {
      if (!WaitForLog(root + "/wk" + std::to_string(j) + "/worker.log", "waiting for jobs",
                      std::chrono::seconds(60)))
        return fail("worker wk" + std::to_string(j) + " did not start");
    }
    std::this_thread::sleep_for(
        std::chrono::seconds(2));  // the workers' status reaches the stations

    const auto t0 = Clock::now();
    std::vector<std::unique_ptr<ChildProcess>> scans;
    for (int i = 0; i < stations_; ++i) {
      scans.push_back(std::make_unique<ChildProcess>());
      HostCommand command{ctl(i, {"scan", "--object", "box", "--views", std::to_string(views_),
                                  "--step", std::to_string(360.0 / views_), "--json"}),
                          {},
                          root + "/scan" + std::to_string(i) + ".json",
                          root + "/scan" + std::to_string(i) + ".err"};
      if (!site->Start(client, command, scans.back().get(), &why)) return fail("starting a scan");
    }
    for (int i = 0; i < stations_; ++i) {
      if (!scans[i]->WaitForExit(std::chrono::minutes(30)))
        return fail("scan of st" + std::to_string(i) + " did not end in 30 min");
      json job =
          json::parse(ReadText(root + "/scan" + std::to_string(i) + ".json"), nullptr, false);
      if (!job.is_object() || job.value("state", "") != "done")
        return fail("scan of st" + std::to_string(i) +
                    " failed: " + ReadText(root + "/scan" + std::to_string(i) + ".err"));
      run.jobs.push_back(std::move(job));
    }
    run.burst_s = std::chrono::duration<double>(Clock::now() - t0).count();
    if (!keep_dir_.empty()) {
      const std::string kept = keep_dir_ + "/" + std::to_string(workers) + "w";
      std::error_code ec;
      std::filesystem::create_directories(kept, ec);
      for (const auto& entry : std::filesystem::recursive_directory_iterator(root, ec)) {
        const std::string name = entry.path().filename().string();
        if (name.ends_with(".log") || name.rfind("scan", 0) == 0) {
          const std::string relative = std::filesystem::relative(entry.path(), root).string();
          std::string flat = relative;
          std::replace(flat.begin(), flat.end(), '/', '_');
          std::filesystem::copy_file(entry.path(), kept + "/" + flat,
                                     std::filesystem::copy_options::overwrite_existing, ec);
        }
      }
    }
    for (int i = 0; i < static_cast<int>(processes.size()); ++i) {
      const double cpu = CpuSeconds(*processes[static_cast<std::size_t>(i)]->pid_slot());
      (i < stations_ ? run.station_cpu_s : run.worker_cpu_s) += cpu;
    }
    return run;
  }

  int Report(const std::vector<bench::Run>& runs, int paper_stations, int paper_workers) const {
    json out = {{"stations", stations_},     {"views", views_},
                {"image_size", image_size_}, {"station_cpu", station_cpu_},
                {"worker_cpu", worker_cpu_}, {"worker_jobs", worker_jobs_},
                {"runs", json::array()}};
    double base = 0;
    std::printf("\n%8s %10s %10s %9s %12s %12s %8s\n", "workers", "burst s", "scans/h", "speed-up",
                "MB to worker", "MB back", "remote");
    for (const bench::Run& r : runs) {
      if (r.workers == 0) base = r.burst_s;
      double fetched = 0, back = 0;
      int remote = 0;
      json jobs = json::array();
      for (const json& job : r.jobs) {
        const json result = job.value("result", json::object());
        const json handed = result.value("remote", json::object());
        if (handed.value("outcome", "") == "done") {
          ++remote;
          fetched += result.value("bytes_fetched", 0.0);
          back += handed.value("bytes_back", 0.0);
        }
        jobs.push_back({{"session", result.value("session", "")},
                        {"worker", handed.value("worker", "")},
                        {"outcome", handed.value("outcome", "local")},
                        {"capture_ms", result.value("capture_ms", 0.0)},
                        {"match_ms", result.value("match_ms", 0.0)},
                        {"reconstruct_ms", result.value("reconstruct_ms", 0.0)},
                        {"worker_ms", result.value("worker_ms", 0.0)},
                        {"bytes_fetched", result.value("bytes_fetched", 0.0)},
                        {"bytes_back", handed.value("bytes_back", 0.0)}});
      }
      const double speedup = base > 0 ? base / r.burst_s : 0;
      std::printf("%8d %10.1f %10.1f %9.2f %12.1f %12.1f %5d/%d\n", r.workers, r.burst_s,
                  stations_ * 3600.0 / r.burst_s, speedup, remote ? fetched / remote / 1e6 : 0.0,
                  remote ? back / remote / 1e6 : 0.0, remote, static_cast<int>(r.jobs.size()));
      out["runs"].push_back({{"workers", r.workers},
                             {"burst_s", r.burst_s},
                             {"station_cpu_s", r.station_cpu_s},
                             {"worker_cpu_s", r.worker_cpu_s},
                             {"scans_per_hour", stations_ * 3600.0 / r.burst_s},
                             {"speedup", speedup},
                             {"jobs", jobs}});
    }
    // On paper, from the CPU seconds each kind of host spent per scan (the
    // processes' own counters over the burst): a station alone spends
    // c_local per scan at its share s, one with workers c_station; a worker
    // c_worker per job at its share w. A site of S stations and W workers
    // then makes min(S·s/c_station, W·w/c_worker) scans a second against
    // S·s/c_local alone, and a burst of one scan per station takes about
    // max(c_station/s, S·c_worker/(W·w)) against c_local/s.
    // The costs with workers come from a burst whose jobs were all remote
    // (one reconstructed at its station would count as a station's cost).
    double c_local = 0, c_station = 0, c_worker = 0;
    for (const bench::Run& r : runs) {
      if (r.workers == 0 && !r.jobs.empty()) c_local = r.station_cpu_s / r.jobs.size();
      const bool all_remote =
          !r.jobs.empty() && std::all_of(r.jobs.begin(), r.jobs.end(), [](const json& job) {
            const json result = job.value("result", json::object());
            return result.value("remote", json::object()).value("outcome", "") == "done";
          });
      if (r.workers > 0 && c_worker == 0 && all_remote) {
        c_station = r.station_cpu_s / r.jobs.size();
        c_worker = r.worker_cpu_s / r.jobs.size();
      }
    }
    if (c_local > 0 && c_worker == 0)
      std::printf("\nno figure on paper: no burst with workers had all its jobs done remotely\n");
    if (c_local > 0 && c_station > 0 && c_worker > 0) {
      const double s = station_cpu_, w = worker_cpu_;
      const int n = paper_stations, k = paper_workers;
      const double alone_rate = n * s / c_local;
      const double rate = k > 0 ? std::min(n * s / c_station, k * w / c_worker) : alone_rate;
      const double alone_burst = c_local / s;
      const double burst = k > 0 ? std::max(c_station / s, n * c_worker / (k * w)) : alone_burst;
      std::printf(
          "\nCPU per scan (measured): a station alone %.1f s; with workers a station %.1f s and "
          "a worker %.1f s\non paper, %d stations (%.2f core) and %d workers (%.2f core): a burst "
          "%.0f s vs %.0f s alone (%.2fx), steady %.0f vs %.0f scans/h (%.2fx)\n",
          c_local, c_station, c_worker, n, s, k, w, burst, alone_burst, alone_burst / burst,
          rate * 3600, alone_rate * 3600, rate / alone_rate);
      out["paper"] = {{"stations", n},
                      {"workers", k},
                      {"cpu_s_per_scan_alone", c_local},
                      {"cpu_s_per_scan_station", c_station},
                      {"cpu_s_per_scan_worker", c_worker},
                      {"burst_s", burst},
                      {"burst_alone_s", alone_burst},
                      {"scans_per_hour", rate * 3600},
                      {"scans_per_hour_alone", alone_rate * 3600}};
    }
    if (!json_path_.empty()) {
      std::string error;
      if (!WriteText(json_path_, out.dump(2) + "\n", &error)) {
        std::cerr << "craftscan-bench site: " << error << "\n";
        return kExitDataError;
      }
    }
    return kExitOk;
  }

  static std::string WorkerPath() { return CRAFTSCAN_WORKER_BINARY; }

  static constexpr int kDomain = 17;
  int stations_ = 3;
  std::vector<int> workers_ = {0, 1, 2};
  int views_ = 6;
  std::string image_size_ = "640x512";
  double station_cpu_ = 0.3;
  double worker_cpu_ = 0.5;
  int worker_jobs_ = 2;
  std::string paper_ = "10x4";
  std::string json_path_;
  std::string keep_dir_;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeSiteCommand() { return std::make_unique<SiteCommand>(); }

}  // namespace craftscan::bench
