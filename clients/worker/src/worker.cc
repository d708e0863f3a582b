// craftscan-worker's job loop (worker.h; the protocol in craftscan/dds/site.h).
#include "craftscan/worker/worker.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/client/station_client.h"
#include "craftscan/daemon/config.h"
#include "craftscan/daemon/report.h"
#include "craftscan/daemon/scan_outputs.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/site.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/pfm.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/sha256.h"
#include "craftscan/pipeline/surface/visibility.h"

namespace craftscan::worker {

bool WorkerOptions::IsValid(std::string* why) const {
  const auto fail = [&](const std::string& message) {
    if (why) *why = message;
    return false;
  };
  std::string reason;
  if (!dds::IsValidWorkerId(worker_id, &reason)) return fail("worker: " + reason);
  if (!dds::IsValidSiteId(site, &reason)) return fail("site: " + reason);
  if (domain > dds::kMaxDomainId)
    return fail("dds.domain: must be 0.." + std::to_string(dds::kMaxDomainId) + ", got " +
                std::to_string(domain));
  if (threads < 1 || threads > 256)
    return fail("threads: must be 1..256, got " + std::to_string(threads));
  if (work_dir.empty() || work_dir.front() != '/')
    return fail("work_dir: must be an absolute path, got '" + work_dir + "'");
  if (jobs < 1 || jobs > 16) return fail("jobs: must be 1..16, got " + std::to_string(jobs));
  if (token.size() > 128) return fail("token: longer than 128 bytes");
  return true;
}

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr auto kRenewEvery = milliseconds(dds::kWorkerLeaseMs / 4);
constexpr auto kClaimEvery = milliseconds(1000);
constexpr std::size_t kChunkBytes = std::size_t{1} << 20;
constexpr std::size_t kAckEveryBytes = std::size_t{8} << 20;
constexpr int kFetchAttempts = 3;

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

double LoadPerCore() {
  double load[1] = {0};
  if (getloadavg(load, 1) != 1) return 0;
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  return load[0] / cores;
}

struct Offer {
  std::string job_id, station, session, state, worker;
  uint32_t grant = 0;
  std::string inputs, parameters;
  int64_t offered_ns = 0;
  int views_ready = 0, views_total = 0;
};

// One granted job, run on a thread of its own while the loop renews the lease.
struct Job {
  Offer offer;   // as granted
  Offer latest;  // as last written by its station (guarded by Loop::mutex)
  std::atomic<bool> abort{false};
  std::atomic<bool> finished{false};
  std::string phase = "fetching";  // guarded by Loop::mutex
  std::thread thread;
  std::set<std::string> fetched;  // its files fetched so far (its thread only)
  std::uint64_t fetched_bytes = 0;
};

class Loop {
 public:
  Loop(const WorkerOptions& options, const WorkerHooks& hooks) : o_(options), hooks_(hooks) {}

  bool Open(std::string* error) {
    dds::ParticipantOptions p;
    p.domain_id = o_.domain;
    p.config = o_.dds_config;
    participant_ = dds::Participant::Create(p, error);
    if (!participant_) return false;
    status_ = dds::Writer<dds::msg::WorkerStatus>::Create(participant_,
                                                          dds::WorkerStatusTopic(o_.site), error);
    claims_ = status_ ? dds::Writer<dds::msg::JobClaim>::Create(participant_,
                                                                dds::JobClaimTopic(o_.site), error)
                      : nullptr;
    results_ = claims_ ? dds::Writer<dds::msg::JobResult>::Create(
                             participant_, dds::JobResultTopic(o_.site), error)
                       : nullptr;
    offers_ = results_ ? dds::Reader<dds::msg::JobOffer>::Create(participant_,
                                                                 dds::JobOfferTopic(o_.site), error)
                       : nullptr;
    return offers_ != nullptr;
  }

  void Run(const std::atomic<bool>& stop) {
    WriteStatus();
    if (hooks_.ready) hooks_.ready();
    Log(1, "worker " + o_.worker_id + " on site " + o_.site + ": waiting for jobs");
    auto renewed = Clock::now();
    while (!stop.load()) {
      TakeOffers();
      EndFinishedJobs();
      if (static_cast<int>(jobs_.size()) < std::max(1, o_.jobs)) ClaimOrStart();
      if (Clock::now() - renewed >= kRenewEvery) {
        WriteStatus();
        renewed = Clock::now();
      }
      if (hooks_.alive) hooks_.alive();
    }
    for (auto& job : jobs_) job->abort = true;
    for (auto& job : jobs_) job->finished.wait(false);
    EndFinishedJobs();
    std::string error;
    dds::Outgoing<dds::msg::WorkerStatus> gone;
    gone.msg().worker = gone.Keep(o_.worker_id);
    status_->Dispose(gone.msg(), &error);
  }

 private:
  void Log(int level, const std::string& message) const {
    if (hooks_.log) hooks_.log(level, message);
  }
  void Status(const std::string& line) const {
    if (hooks_.status) hooks_.status(line);
  }

  // The lease renewal: what the worker is doing, at least every lease/4.
  void WriteStatus() {
    dds::Outgoing<dds::msg::WorkerStatus> s;
    dds::msg::WorkerStatus& m = s.msg();
    m.worker = s.Keep(o_.worker_id);
    {
      // The first job held (and how many more) or idle.
      std::lock_guard lock(mutex_);
      const Job* first = jobs_.empty() ? nullptr : jobs_.front().get();
      m.state =
          s.Keep(!first ? std::string("idle")
                        : first->phase + (jobs_.size() > 1
                                              ? " (+" + std::to_string(jobs_.size() - 1) + " more)"
                                              : std::string()));
      m.job_id = s.Keep(first ? first->offer.job_id : std::string());
      m.station = s.Keep(first ? first->offer.station : std::string());
      m.grant = first ? first->offer.grant : 0;
    }
    m.cores = static_cast<uint32_t>(o_.threads);
    m.load = LoadPerCore();
    m.jobs_done = jobs_done_;
    m.stamp_ns = NowNs();
    std::string error;
    if (!status_->Write(m, &error)) Log(2, "status: " + error);
  }

  // Offers as they change; a job in hand whose offer no longer grants it to
  // this worker (disposed, station gone, granted again elsewhere) is dropped.
  void TakeOffers() {
    dds::Sample<dds::msg::JobOffer> sample;
    dds::SampleState state;
    std::string error;
    while (offers_->TakeWithInfo(milliseconds(100), &sample, &state, &error) ==
           dds::TakeStatus::kOk) {
      const std::string id(dds::View(sample->job_id));
      if (state.instance != dds::InstanceState::kAlive) {
        offers_seen_.erase(id);
        Job* job = FindJob(id);
        if (job && !job->abort.exchange(true)) {
          Log(2, "job " + id + ": withdrawn by its station (" +
                     (state.instance == dds::InstanceState::kDisposed ? "ended" : "station gone") +
                     "): abandoned");
        }
        continue;
      }
      if (!state.valid_data) continue;
      Offer o;
      o.job_id = id;
      o.station = dds::View(sample->station);
      o.session = dds::View(sample->session);
      o.state = dds::View(sample->state);
      o.worker = dds::View(sample->worker);
      o.grant = sample->grant;
      o.inputs = dds::View(sample->inputs);
      o.parameters = dds::View(sample->parameters);
      o.offered_ns = sample->offered_ns;
      o.views_ready = sample->views_ready;
      o.views_total = sample->views_total;
      Job* job = FindJob(id);
      if (job) {
        std::lock_guard lock(mutex_);
        job->latest = o;
      }
      if (job && (o.worker != o_.worker_id || o.grant != job->offer.grant) &&
          !job->abort.exchange(true)) {
        Log(2, "job " + id + ": granted again (to " + (o.worker.empty() ? "nobody yet" : o.worker) +
                   ", grant " + std::to_string(o.grant) + "): abandoned");
      }
      offers_seen_[id] = std::move(o);
    }
  }

  void ClaimOrStart() {
    // A grant to this worker not yet worked on starts the job.
    for (const auto& [id, o] : offers_seen_) {
      if (o.state == "granted" && o.worker == o_.worker_id && done_grants_[id] < o.grant) {
        StartJob(o);
        return;
      }
    }
    // Else claim the oldest open offer (again every second while it is open).
    const Offer* best = nullptr;
    for (const auto& [id, o] : offers_seen_) {
      if (o.state != "offered" || FindJob(id)) continue;
      if (!best || o.offered_ns < best->offered_ns) best = &o;
    }
    if (!best) return;
    auto& last = claimed_at_[best->job_id];
    if (Clock::now() - last < kClaimEvery) return;
    last = Clock::now();
    dds::Outgoing<dds::msg::JobClaim> c;
    c.msg().job_id = c.Keep(best->job_id);
    c.msg().worker = c.Keep(o_.worker_id);
    c.msg().token = c.Keep(o_.token);
    c.msg().cores = static_cast<uint32_t>(o_.threads);
    c.msg().load = LoadPerCore();
    c.msg().stamp_ns = NowNs();
    std::string error;
    if (!claims_->Write(c.msg(), &error)) Log(2, "claim: " + error);
  }

  void StartJob(const Offer& offer) {
    done_grants_[offer.job_id] = offer.grant;
    auto job = std::make_unique<Job>();
    job->offer = offer;
    job->latest = offer;
    Job* raw = job.get();
    {
      std::lock_guard lock(mutex_);
      jobs_.push_back(std::move(job));
    }
    Log(1, "job " + offer.job_id + ": granted (grant " + std::to_string(offer.grant) + ")");
    WriteStatus();
    raw->thread = std::thread([this, raw] {
      // Below the loop and DDS's own threads (nice 10, inherited by the
      // pipeline's thread pools): on a small CPU share two jobs' meshing
      // starved the lease renewals and Cyclone's participant liveliness
      // (a live worker lost both its grants).
      ::setpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)), 10);
      try {
        Work(*raw);
      } catch (const std::exception& e) {
        Log(3, "job " + raw->offer.job_id + ": " + e.what());
      }
      raw->finished = true;
      raw->finished.notify_all();
    });
  }

  Job* FindJob(const std::string& id) const {
    for (const auto& job : jobs_)
      if (job->offer.job_id == id) return job.get();
    return nullptr;
  }

  void EndFinishedJobs() {
    for (std::size_t i = 0; i < jobs_.size();) {
      Job& job = *jobs_[i];
      if (!job.finished.load()) {
        ++i;
        continue;
      }
      if (job.thread.joinable()) job.thread.join();
      std::error_code ec;
      std::filesystem::remove_all(JobDir(job.offer), ec);
      {
        std::lock_guard lock(mutex_);
        jobs_.erase(jobs_.begin() + static_cast<std::ptrdiff_t>(i));
      }
      if (jobs_.empty()) Status("idle");
    }
  }

  std::string JobDir(const Offer& offer) const {
    std::string name = offer.job_id;
    for (char& c : name)
      if (c == '/') c = '_';
    return o_.work_dir + "/" + name;
  }

  void Phase(Job& job, const std::string& phase) {
    {
      std::lock_guard lock(mutex_);
      job.phase = phase;
    }
    Status("job " + job.offer.job_id + ": " + phase);
    WriteStatus();
  }

  // Fetch, reconstruct, return.
  // The job's offer as the station last wrote it (views are added to it).
  Offer Latest(Job& job) {
    std::lock_guard lock(mutex_);
    return job.latest;
  }

  // Fetches `names` of the job's session into its folder, each checked
  // against the offer's SHA-256; "" when fine, else why not.
  std::string FetchInputs(Job& job, client::StationClient& station,
                          const std::vector<std::string>& names,
                          const std::map<std::string, std::string>& sha256) {
    client::FetchRequest fetch;
    fetch.session = job.offer.session;
    fetch.out_dir = JobDir(job.offer);
    fetch.cancel = &job.abort;
    fetch.files = names;
    // A transfer that lost chunks or stalled is asked for again: right after
    // a station restarts, its file writer may match this worker's reader
    // part way through the first transfer (in 11 of 20 restarts the job
    // went back to the station for that alone).
    client::FetchResult fetched;
    for (int attempt = 1; attempt <= kFetchAttempts; ++attempt) {
      fetched = station.Fetch(fetch);
      if (job.abort.load()) return "abandoned";
      const bool transient = fetched.status == client::FetchStatus::kTransferFailed ||
                             fetched.status == client::FetchStatus::kUnreachable;
      if (!transient || attempt == kFetchAttempts) break;
      Log(2, "job " + job.offer.job_id + ": fetching the inputs (attempt " +
                 std::to_string(attempt) + " of " + std::to_string(kFetchAttempts) +
                 "): " + fetched.message + "; asking again");
    }
    if (fetched.status != client::FetchStatus::kOk)
      return "fetching the inputs: " + fetched.message;
    for (const client::FetchedFile& f : fetched.files) {
      const auto expected = sha256.find(f.name);
      if (expected != sha256.end() && !expected->second.empty() && expected->second != f.sha256)
        return f.name + ": SHA-256 differs from the offer's";
      job.fetched_bytes += f.size_bytes;
    }
    return {};
  }

  // Fetch the calibration, then each view as the station lists it and add
  // it to the scan (registration while the station still captures), then
  // finish, make the outputs and return them.
  void Work(Job& job) {
    const Offer& offer = job.offer;
    const std::string dir = JobDir(offer);
    const nlohmann::json params = nlohmann::json::parse(offer.parameters, nullptr, false);
    if (!params.is_object()) return Fail(job, "the offer's parameters are not JSON");

    Phase(job, "fetching");
    client::ConnectOptions connect;
    connect.station = offer.station;
    connect.domain_id = o_.domain;
    // No dds_config: the site participant made this process's domain with
    // the worker's config (its DDS Security identity, role worker, too); a
    // further participant joins that domain, which only an empty config may.
    connect.token = o_.token;
    connect.client_name = "craftscan-worker@" + o_.worker_id;
    std::string error;
    client::StationClient* station = nullptr;
    {
      std::lock_guard lock(stations_mutex_);
      std::unique_ptr<client::StationClient>& client = stations_[offer.station];
      if (!client) client = client::StationClient::Connect(connect, &error);
      station = client.get();
    }
    if (!station) return Fail(job, "cannot reach station " + offer.station + ": " + error);
    const auto start = Clock::now();
    daemon::DaemonConfig config;
    if (!daemon::ParseDaemonConfig(params.value("config", std::string()), {}, &config, &error))
      return Fail(job, "the station's settings: " + error);
    std::map<std::string, std::string> sha256;
    const auto list = [&](const Offer& o) {
      std::vector<nlohmann::json> entries;
      const nlohmann::json inputs = nlohmann::json::parse(o.inputs, nullptr, false);
      if (!inputs.is_array()) return entries;
      for (const nlohmann::json& input : inputs) {
        sha256[input.value("name", std::string())] = input.value("sha256", std::string());
        entries.push_back(input);
      }
      return entries;
    };
    list(offer);
    if (std::string why = FetchInputs(job, *station, {"calibration.yaml"}, sha256); !why.empty())
      return job.abort.load() ? void() : Fail(job, why);
    StereoCalibration calibration;
    if (!LoadCalibration(dir + "/calibration.yaml", &calibration, &error))
      return Fail(job, "calibration.yaml: " + error);
    ScanOptions scan = daemon::ReconstructionOptions(config.pipeline);
    scan.num_threads = o_.threads;
    scan.camera = RectifiedLeftCamera(calibration);
    IncrementalScan incremental(calibration.turntable, scan);
    std::string captured_utc;
    int added = 0;
    const int total = std::max(offer.views_total, 0);
    while (added < total) {
      if (job.abort.load()) return;
      const Offer latest = Latest(job);
      std::vector<std::string> names;
      std::vector<std::pair<std::string, double>> clouds;  // in view order
      for (const nlohmann::json& input : list(latest)) {
        const int view = input.value("view", -1);
        const std::string name = input.value("name", std::string());
        if (name == "calibration.yaml" || job.fetched.count(name)) continue;
        names.push_back(name);
        if (view >= 0) {
          clouds.emplace_back(name, input.value("angle_deg", 0.0));
          if (captured_utc.empty()) captured_utc = input.value("captured_utc", std::string());
        }
      }
      if (names.empty()) {
        std::this_thread::sleep_for(milliseconds(50));
        continue;
      }
      Phase(job, "reconstructing " + std::to_string(added) + "/" + std::to_string(total));
      if (std::string why = FetchInputs(job, *station, names, sha256); !why.empty())
        return job.abort.load() ? void() : Fail(job, why);
      for (const std::string& name : names) job.fetched.insert(name);
      for (const auto& [name, angle] : clouds) {
        ScanView view;
        view.commanded_angle_rad = angle * CV_PI / 180;
        if (!ReadPly(dir + "/" + name, &view.cloud_in_rig, &error))
          return Fail(job, name + ": " + error);
        incremental.Add(std::move(view));
        ++added;
      }
    }
    Phase(job, "reconstructing");
    const ScanResult r = incremental.Finish();
    if (job.abort.load()) return;
    if (!r.IsUsable()) return Fail(job, "reconstruction: " + r.message);
    const auto view_file = [&](int index, const char* file) {
      char folder[16];
      std::snprintf(folder, sizeof folder, "views/%03d/", index);
      return dir + "/" + folder + file;
    };

    daemon::ScanOutputContext c;
    c.session_id = params.value("session", std::string());
    c.object_name = params.value("object_name", std::string());
    c.created_utc = params.value("created_utc", std::string());
    c.captured_utc = captured_utc;
    c.client = params.value("client", std::string());
    c.calibration_id = params.value("calibration_id", std::string());
    c.calibration = &calibration;
    c.station = params.value("station", std::string());
    c.software = params.value("software", std::string());
    c.rights = params.value("rights", std::string());
    for (const nlohmann::json& v : params.value("report_views", nlohmann::json::array()))
      if (v.is_array() && v.size() == 2)
        c.report_views.emplace_back(v[0].get<int>(), v[1].get<double>());
    c.min_disparity = params.value("min_disparity", 0);
    c.num_disparities = params.value("num_disparities", 0);
    c.load_disparity = [&](int index, cv::Mat* disparity) {
      return ReadPfm(view_file(index, "disparity.pfm"), disparity, nullptr);
    };
    if (params.value("report", false)) c.report = daemon::MakeReportFiles;
    c.mesh_obj = false;  // the station writes it from mesh.ply: half the bytes back
    c.log = [this](drivers::LogLevel level, std::string_view message) {
      Log(static_cast<int>(level), std::string(message));
    };
    daemon::ScanOutputs outputs = daemon::MakeScanOutputs(r, ScanReportJson(r), c);
    outputs.result["worker"] = o_.worker_id;
    outputs.result["worker_ms"] =
        std::chrono::duration<double, std::milli>(Clock::now() - start).count();
    outputs.result["bytes_fetched"] = job.fetched_bytes;
    if (job.abort.load()) return;

    Phase(job, "returning");
    if (Send(job, outputs)) {
      ++jobs_done_;
      Log(1, "job " + offer.job_id + ": result sent (" + std::to_string(outputs.files.size()) +
                 " files)");
    }
  }

  // The outputs as JobResult chunks of this grant; false when abandoned.
  bool Send(Job& job, const daemon::ScanOutputs& outputs) {
    std::string error;
    const std::string result = outputs.result.dump();
    std::size_t since_ack = 0;
    for (std::size_t i = 0; i < outputs.files.size(); ++i) {
      const daemon::ScanOutputFile& file = outputs.files[i];
      const std::string sha = Sha256Hex(file.bytes);
      std::size_t offset = 0;
      do {
        if (job.abort.load()) return false;
        const std::size_t n = std::min(kChunkBytes, file.bytes.size() - offset);
        const bool last = offset + n == file.bytes.size();
        dds::Outgoing<dds::msg::JobResult> chunk;
        Fill(job, &chunk);
        dds::msg::JobResult& m = chunk.msg();
        m.name = chunk.Keep(file.name);
        m.file_index = static_cast<uint32_t>(i);
        m.file_count = static_cast<uint32_t>(outputs.files.size());
        m.total_size = file.bytes.size();
        m.offset = offset;
        dds::Borrow(&m.data, reinterpret_cast<const uint8_t*>(file.bytes.data()) + offset, n);
        m.last = last;
        m.sha256 = chunk.Keep(sha);
        if (last && i + 1 == outputs.files.size()) m.result = chunk.Keep(result);
        if (!results_->Write(m, &error)) {
          Log(2, "job " + job.offer.job_id + ": " + error);
          return false;
        }
        offset += n;
        since_ack += n;
        if (since_ack >= kAckEveryBytes) {
          results_->WaitForAcks(milliseconds(30000), &error);
          since_ack = 0;
        }
      } while (offset < file.bytes.size());
    }
    return results_->WaitForAcks(milliseconds(30000), &error);
  }

  void Fill(const Job& job, dds::Outgoing<dds::msg::JobResult>* chunk) {
    chunk->msg().job_id = chunk->Keep(job.offer.job_id);
    chunk->msg().worker = chunk->Keep(o_.worker_id);
    chunk->msg().token = chunk->Keep(o_.token);
    chunk->msg().grant = job.offer.grant;
  }

  // Tells the station this grant's job failed here (it reconstructs itself).
  void Fail(Job& job, const std::string& why) {
    Log(3, "job " + job.offer.job_id + ": " + why);
    if (job.abort.load()) return;
    dds::Outgoing<dds::msg::JobResult> chunk;
    Fill(job, &chunk);
    chunk.msg().error = chunk.Keep(why);
    chunk.msg().last = true;
    std::string error;
    if (!results_->Write(chunk.msg(), &error)) Log(2, "job " + job.offer.job_id + ": " + error);
  }

  const WorkerOptions& o_;
  const WorkerHooks& hooks_;
  std::shared_ptr<dds::Participant> participant_;
  std::unique_ptr<dds::Writer<dds::msg::WorkerStatus>> status_;
  std::unique_ptr<dds::Writer<dds::msg::JobClaim>> claims_;
  std::unique_ptr<dds::Writer<dds::msg::JobResult>> results_;
  std::unique_ptr<dds::Reader<dds::msg::JobOffer>> offers_;
  std::map<std::string, Offer> offers_seen_;
  // One client per station, kept: its reader stays matched between jobs.
  std::map<std::string, std::unique_ptr<client::StationClient>> stations_;
  std::map<std::string, Clock::time_point> claimed_at_;
  std::map<std::string, uint32_t> done_grants_;  // the last grant worked on, per job
  std::mutex mutex_;  // guards jobs_ (changed by the loop) and Job::phase/latest
  std::vector<std::unique_ptr<Job>> jobs_;
  std::mutex stations_mutex_;  // guards stations_ (each client serves one job at a time)
  std::atomic<uint64_t> jobs_done_{0};
};

}  // namespace

int RunWorker(const WorkerOptions& options, const std::atomic<bool>& stop, const WorkerHooks& hooks,
              std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) {
    if (error) *error = why;
    return 1;
  }
  std::error_code ec;
  std::filesystem::create_directories(options.work_dir, ec);
  if (ec) {
    if (error) *error = "work_dir " + options.work_dir + ": " + ec.message();
    return 1;
  }
  Loop loop(options, hooks);
  if (!loop.Open(&why)) {
    if (error) *error = "dds: " + why;
    return 1;
  }
  loop.Run(stop);
  return 0;
}

}  // namespace craftscan::worker
