// The station's side of a reconstruction handed to a worker (remote_jobs.h).
#include "craftscan/daemon/remote_jobs.h"

#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <utility>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/site.h"
#include "craftscan/pipeline/common/sha256.h"

namespace craftscan::daemon {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// Report pages are stored when they can be; everything else is the model.
bool IsRequiredOutput(const std::string& name) {
  return name != "report.html" && name.rfind("previews/", 0) != 0;
}

struct WorkerSeen {
  bool alive = false;
  std::string state, job_id;
  uint32_t grant = 0;
};

// One file of a result as it arrives.
struct Incoming {
  std::string name, sha256, bytes;
  uint64_t total = 0;
  bool complete = false;
};

}  // namespace

struct RemoteJobs::Impl {
  std::shared_ptr<dds::Participant> participant;
  std::string site, station;
  const TokenAuthority* tokens = nullptr;
  LogFn log;
  std::unique_ptr<dds::Writer<dds::msg::JobOffer>> offers;
  std::unique_ptr<dds::Reader<dds::msg::JobClaim>> claims;
  std::unique_ptr<dds::Reader<dds::msg::JobResult>> results;
  std::unique_ptr<dds::Reader<dds::msg::WorkerStatus>> workers;
  std::mutex workers_mutex;  // guards `seen` and taking from `workers`
  std::map<std::string, WorkerSeen> seen;
  std::set<std::string> late_logged;  // "job|worker|grant" already logged as dropped

  void Log(drivers::LogLevel level, const std::string& message) const {
    if (log) log(level, message);
  }

  // Takes every WorkerStatus sample: the workers alive now and what they do.
  void PollWorkers() {
    dds::Sample<dds::msg::WorkerStatus> sample;
    dds::SampleState state;
    std::string error;
    while (workers->TakeWithInfo(milliseconds(0), &sample, &state, &error) ==
           dds::TakeStatus::kOk) {
      const std::string name(dds::View(sample->worker));
      if (name.empty()) continue;
      WorkerSeen& w = seen[name];
      w.alive = state.instance == dds::InstanceState::kAlive;
      if (state.valid_data) {
        w.state = dds::View(sample->state);
        w.job_id = dds::View(sample->job_id);
        w.grant = sample->grant;
      }
    }
  }
  bool Alive(const std::string& worker) {
    std::lock_guard lock(workers_mutex);
    PollWorkers();
    const auto it = seen.find(worker);
    return it != seen.end() && it->second.alive;
  }

  // Whether `token` may take jobs: listed with role operator or admin.
  std::optional<Identity> Trusted(std::string_view token) const {
    if (tokens == nullptr) return std::nullopt;
    std::optional<Identity> identity = tokens->Authenticate(token);
    if (!identity || !Satisfies(identity->role, Role::kOperator)) return std::nullopt;
    return identity;
  }

  void DropLate(const dds::msg::JobResult& chunk, const std::string& why) {
    const std::string key = std::string(dds::View(chunk.job_id)) + "|" +
                            std::string(dds::View(chunk.worker)) + "|" +
                            std::to_string(chunk.grant);
    if (!late_logged.insert(key).second) return;
    Log(drivers::LogLevel::kWarning, "dropped a result of job " +
                                         std::string(dds::View(chunk.job_id)) + " from worker " +
                                         std::string(dds::View(chunk.worker)) + " (grant " +
                                         std::to_string(chunk.grant) + "): " + why);
  }
};

void RemoteJobFeed::Add(std::vector<RemoteInput> inputs, int views_ready) {
  std::lock_guard lock(mutex_);
  for (RemoteInput& input : inputs) inputs_.push_back(std::move(input));
  views_ready_ = views_ready;
  changed_ = true;
}

void RemoteJobFeed::Close() {
  std::lock_guard lock(mutex_);
  closed_ = true;
  changed_ = true;
}

bool RemoteJobFeed::Take(std::vector<RemoteInput>* inputs, int* views_ready, bool* closed) {
  std::lock_guard lock(mutex_);
  if (!changed_) return false;
  changed_ = false;
  *inputs = inputs_;
  *views_ready = views_ready_;
  *closed = closed_;
  return true;
}

RemoteJobs::RemoteJobs(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RemoteJobs::~RemoteJobs() = default;

std::unique_ptr<RemoteJobs> RemoteJobs::Create(std::shared_ptr<dds::Participant> participant,
                                               const std::string& site, const std::string& station,
                                               const TokenAuthority* tokens, LogFn log,
                                               std::string* error) {
  auto impl = std::make_unique<Impl>();
  impl->participant = participant;
  impl->site = site;
  impl->station = station;
  impl->tokens = tokens;
  impl->log = std::move(log);
  impl->offers =
      dds::Writer<dds::msg::JobOffer>::Create(participant, dds::JobOfferTopic(site), error);
  if (!impl->offers) return nullptr;
  impl->claims =
      dds::Reader<dds::msg::JobClaim>::Create(participant, dds::JobClaimTopic(site), error);
  if (!impl->claims) return nullptr;
  impl->results =
      dds::Reader<dds::msg::JobResult>::Create(participant, dds::JobResultTopic(site), error);
  if (!impl->results) return nullptr;
  impl->workers =
      dds::Reader<dds::msg::WorkerStatus>::Create(participant, dds::WorkerStatusTopic(site), error);
  if (!impl->workers) return nullptr;
  return std::unique_ptr<RemoteJobs>(new RemoteJobs(std::move(impl)));
}

int RemoteJobs::WorkersAlive() {
  std::lock_guard lock(impl_->workers_mutex);
  impl_->PollWorkers();
  int n = 0;
  for (const auto& [name, w] : impl_->seen) n += w.alive ? 1 : 0;
  return n;
}

int RemoteJobs::WorkersIdle() {
  std::lock_guard lock(impl_->workers_mutex);
  impl_->PollWorkers();
  int n = 0;
  for (const auto& [name, w] : impl_->seen) n += w.alive && w.state == "idle" ? 1 : 0;
  return n;
}

RemoteJobOutcome RemoteJobs::Run(
    const RemoteJobRequest& request, const std::atomic<bool>& stop, const ProgressFn& progress,
    const std::function<void(const std::string&, const std::string&)>& on_change) {
  Impl& m = *impl_;
  RemoteJobOutcome out;
  const auto started = Clock::now();
  out.job_id = m.station + "/" + request.session + "/" + std::to_string(NowNs() / 1000000);
  const auto say = [&](const std::string& message) {
    if (progress) progress("remote", out.grants, 0, message);
  };
  const auto changed = [&](const std::string& job, const std::string& worker) {
    if (on_change) on_change(job, worker);
  };

  const auto inputs_json = [](const std::vector<RemoteInput>& list) {
    nlohmann::json inputs = nlohmann::json::array();
    for (const RemoteInput& input : list) {
      nlohmann::json entry = {{"name", input.name}, {"size", input.size}, {"sha256", input.sha256}};
      if (input.view >= 0) {
        entry["view"] = input.view;
        entry["angle_deg"] = input.angle_deg;
        entry["captured_utc"] = input.captured_utc;
      }
      inputs.push_back(std::move(entry));
    }
    return inputs.dump();
  };
  std::vector<RemoteInput> inputs = request.inputs;
  const std::size_t fixed_inputs = inputs.size();
  int views_ready = request.feed ? 0 : request.views_total;
  bool closed = request.feed == nullptr;
  dds::Outgoing<dds::msg::JobOffer> offer;
  dds::msg::JobOffer& o = offer.msg();
  o.job_id = offer.Keep(out.job_id);
  o.station = offer.Keep(m.station);
  o.session = offer.Keep(request.session);
  o.kind = offer.Keep("reconstruct");
  o.lease_ms = dds::kWorkerLeaseMs;
  o.inputs = offer.Keep(inputs_json(inputs));
  o.parameters = offer.Keep(request.parameters.dump());
  o.offered_ns = NowNs();
  o.views_total = request.views_total;
  o.views_ready = views_ready;
  std::string worker;  // granted to ("" while offered)
  std::string error;
  const auto publish = [&]() {
    o.state = offer.Keep(worker.empty() ? "offered" : "granted");
    o.worker = offer.Keep(worker);
    o.grant = static_cast<uint32_t>(out.grants);
    if (!m.offers->Write(o, &error))
      m.Log(drivers::LogLevel::kWarning, "job " + out.job_id + ": " + error);
  };
  const auto end = [&](RemoteJobOutcome::Status status, const std::string& message) {
    if (request.feed) request.feed->SetEnded();
    if (!m.offers->Dispose(o, &error))
      m.Log(drivers::LogLevel::kWarning, "job " + out.job_id + ": " + error);
    out.status = status;
    out.message = message;
    out.seconds = std::chrono::duration<double>(Clock::now() - started).count();
    changed("", "");
    return out;
  };

  publish();
  changed(out.job_id, "");
  say("offered to the workers of site " + m.site);
  auto round = Clock::now();  // since the job was (again) offered
  auto granted_at = Clock::now();
  std::map<uint32_t, Incoming> files;
  uint32_t file_count = 0;
  nlohmann::json result;
  bool have_result = false;
  const auto reoffer = [&](const std::string& why) {
    m.Log(drivers::LogLevel::kWarning,
          "job " + out.job_id + ": worker " + worker + " " + why + "; offering it again");
    worker.clear();
    files.clear();
    file_count = 0;
    have_result = false;
    out.bytes_back = 0;
    publish();
    changed(out.job_id, "");
    say("offered again: the worker " + why);
    round = Clock::now();
  };

  for (;;) {
    if (stop.load()) return end(RemoteJobOutcome::Status::kCancelled, "cancelled");
    // Views as they become durable: the offer grows (the worker fetches them).
    std::vector<RemoteInput> fed;
    if (request.feed && request.feed->Take(&fed, &views_ready, &closed)) {
      inputs.resize(fixed_inputs);
      inputs.insert(inputs.end(), fed.begin(), fed.end());
      o.inputs = offer.Keep(inputs_json(inputs));
      o.views_ready = views_ready;
      publish();
      if (closed && views_ready < request.views_total)
        return end(RemoteJobOutcome::Status::kLocal,
                   "the scan ended after " + std::to_string(views_ready) + " of " +
                       std::to_string(request.views_total) + " views");
    }
    // Claims: the first trusted, alive worker is granted the job.
    dds::Sample<dds::msg::JobClaim> claim;
    while (m.claims->Take(milliseconds(0), &claim, &error) == dds::TakeStatus::kOk) {
      if (dds::View(claim->job_id) != out.job_id || !worker.empty()) continue;
      const std::string who(dds::View(claim->worker));
      if (!m.Trusted(dds::View(claim->token))) {
        m.Log(drivers::LogLevel::kWarning,
              "job " + out.job_id + ": refused the claim of worker '" + who +
                  "': its token is not in the station's tokens file with role operator or admin");
        continue;
      }
      if (!m.Alive(who)) {
        m.Log(drivers::LogLevel::kInfo, "job " + out.job_id + ": claim of worker '" + who +
                                            "' not granted: not alive on the site (yet)");
        continue;
      }
      worker = who;
      ++out.grants;
      granted_at = Clock::now();
      publish();
      changed(out.job_id, worker);
      m.Log(drivers::LogLevel::kInfo, "job " + out.job_id + ": granted to worker " + worker +
                                          " (grant " + std::to_string(out.grants) + ")");
      say("granted to worker " + worker);
    }
    // The lease and the deadlines.
    if (!worker.empty() && !m.Alive(worker)) {
      reoffer("lost its lease (no sign of life for " + std::to_string(dds::kWorkerLeaseMs) +
              " ms)");
    } else if (!worker.empty() && Clock::now() - granted_at > request.max_remote) {
      return end(RemoteJobOutcome::Status::kLocal, "worker " + worker + " did not deliver within " +
                                                       std::to_string(request.max_remote.count()) +
                                                       " s");
    } else if (worker.empty() && Clock::now() - round > request.offer_timeout) {
      return end(
          RemoteJobOutcome::Status::kLocal,
          "no worker claimed it within " + std::to_string(request.offer_timeout.count()) + " ms");
    }
    // Results: this job's current grant only, in order, checked.
    dds::Sample<dds::msg::JobResult> chunk;
    while (m.results->Take(milliseconds(50), &chunk, &error) == dds::TakeStatus::kOk) {
      const dds::msg::JobResult& c = chunk.get();
      if (dds::View(c.job_id) != out.job_id) {
        m.DropLate(c, "not a job this station has open");
        continue;
      }
      if (worker.empty() || dds::View(c.worker) != worker ||
          c.grant != static_cast<uint32_t>(out.grants)) {
        m.DropLate(c, "the job is " + (worker.empty() ? std::string("not granted now")
                                                      : "granted to " + worker + " as grant " +
                                                            std::to_string(out.grants)));
        continue;
      }
      if (!m.Trusted(dds::View(c.token))) {
        m.DropLate(c, "its token is not trusted");
        continue;
      }
      if (!std::string_view(dds::View(c.error)).empty()) {
        return end(RemoteJobOutcome::Status::kLocal,
                   "worker " + worker + " could not do it: " + std::string(dds::View(c.error)));
      }
      Incoming& file = files[c.file_index];
      file_count = c.file_count;
      if (c.offset != file.bytes.size() || file.complete) {
        reoffer("sent " + std::string(dds::View(c.name)) + " with a gap at byte " +
                std::to_string(c.offset));
        break;
      }
      file.name = dds::View(c.name);
      file.sha256 = dds::View(c.sha256);
      file.total = c.total_size;
      file.bytes.append(reinterpret_cast<const char*>(c.data._buffer), c.data._length);
      out.bytes_back += c.data._length;
      if (!std::string_view(dds::View(c.result)).empty()) {
        result = nlohmann::json::parse(dds::View(c.result), nullptr, false);
        have_result = result.is_object();
      }
      if (!c.last) continue;
      file.complete = true;
      if (file.bytes.size() != file.total || Sha256Hex(file.bytes) != file.sha256) {
        reoffer("sent " + file.name + " damaged (size or SHA-256 differs)");
        break;
      }
    }
    bool all = file_count > 0 && files.size() == file_count && have_result;
    for (const auto& [index, file] : files) all = all && file.complete;
    if (all) {
      for (auto& [index, file] : files)
        out.outputs.files.push_back(
            {file.name, std::move(file.bytes), IsRequiredOutput(file.name)});
      out.outputs.result = std::move(result);
      out.worker = worker;
      m.Log(drivers::LogLevel::kInfo, "job " + out.job_id + ": result of worker " + worker +
                                          " stored (" + std::to_string(file_count) + " files, " +
                                          std::to_string(out.bytes_back) + " bytes)");
      return end(RemoteJobOutcome::Status::kDone, "reconstructed by worker " + worker);
    }
  }
}

}  // namespace craftscan::daemon
