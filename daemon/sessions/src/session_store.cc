#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "craftscan/pipeline/common/atomic_file.h"
#include "session_internal.h"

namespace craftscan::daemon {
namespace {

namespace fs = std::filesystem;

// Collision suffixes "-2" .. "-999" (IsValidSessionId allows 4 bytes).
constexpr int kMaxIdSuffix = 999;

// Stores `status` in *out (may be null); for the functions returning null.
void SetStatus(Status* out, Status status) {
  if (out) *out = std::move(status);
}

// An id as a client sent it, quoted and escaped for an error message.
std::string Quoted(const std::string& id) {
  return nlohmann::json(id.substr(0, 100))
      .dump(-1, ' ', true, nlohmann::json::error_handler_t::replace);
}

bool IsJobVerb(std::string_view job) {
  return !job.empty() && job.size() <= 32 && std::all_of(job.begin(), job.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || c == '_';
  });
}

}  // namespace

std::unique_ptr<SessionStore> SessionStore::Open(const std::string& data_dir, Status* status) {
  struct stat st {};
  if (data_dir.empty()) {
    SetStatus(status, Status(ErrorCode::kInvalidArgument, "data dir is empty"));
    return nullptr;
  }
  if (::stat(data_dir.c_str(), &st) != 0) {
    SetStatus(status, Status::FromErrno(errno, "data dir '" + data_dir + "'"));
    return nullptr;
  }
  if (!S_ISDIR(st.st_mode)) {
    SetStatus(status, Status(ErrorCode::kInvalidArgument,
                             "data dir '" + data_dir + "' is not a directory"));
    return nullptr;
  }
  std::error_code ec;
  const fs::path absolute = fs::absolute(data_dir, ec);
  const std::string sessions =
      ((ec ? fs::path(data_dir) : absolute).lexically_normal() / "sessions").string();
  if (Status made = internal::MakeDurableDir(sessions); !made.ok()) {
    SetStatus(status, made.WithContext("data dir '" + data_dir + "' is not usable"));
    return nullptr;
  }
  // Probe: can a file be created? (access(2) says yes to root on 0555 and
  // cannot see a full disk; a real create answers both read-only and EACCES.)
  std::string probe = sessions + "/.probe.tmp-XXXXXX";
  const int fd = ::mkstemp(probe.data());
  if (fd < 0) {
    SetStatus(status, Status::FromErrno(errno, "data dir '" + data_dir + "': '" + sessions +
                                                   "' is not writable"));
    return nullptr;
  }
  ::close(fd);
  ::unlink(probe.c_str());
  return std::unique_ptr<SessionStore>(new SessionStore(sessions));
}

std::unique_ptr<Session> SessionStore::Create(std::string_view object_name, std::string_view job,
                                              const nlohmann::json& params,
                                              std::chrono::system_clock::time_point now,
                                              Status* status) {
  if (!IsJobVerb(job)) {
    SetStatus(status, Status(ErrorCode::kInvalidArgument,
                             "job verb '" + std::string(job.substr(0, 40)) +
                                 "' is not a lower-case word ([a-z_], 1 to 32 characters)"));
    return nullptr;
  }
  if (!params.is_object()) {
    SetStatus(status,
              Status(ErrorCode::kInvalidArgument, "job parameters must be a JSON object, got " +
                                                      std::string(params.type_name())));
    return nullptr;
  }
  Manifest m;
  m.object_name = std::string(object_name);
  m.object = SanitizeObjectName(object_name);
  m.job = std::string(job);
  m.params = params;
  m.state = SessionState::kCreated;
  m.created_utc = internal::IsoUtc(now);
  const std::string base = internal::IdTimeUtc(now) + "-" + m.object;

  // The folder is populated under a hidden temporary name, locked so that a
  // concurrent MarkInterrupted leaves it alone, then renamed into place
  // without replacing anything (RENAME_NOREPLACE: ids never collide, even
  // across processes).
  std::string tmp = sessions_dir_ + "/." + base + ".tmp-XXXXXX";
  if (::mkdtemp(tmp.data()) == nullptr) {
    SetStatus(status, Status::FromErrno(
                          errno, "cannot create a session folder in '" + sessions_dir_ + "'"));
    return nullptr;
  }
  auto lock = std::make_unique<Session::Lock>();
  Status why;                                               // the first failure, with its code
  if (::chmod(tmp.c_str(), 0777 & ~ProcessUmask()) != 0) {  // mkdtemp gives 0700
    why = Status::FromErrno(errno, "'" + tmp + "': cannot set permissions");
  }
  if (why.ok()) why = lock->dir.Acquire(tmp);
  bool ok = why.ok();
  std::string id;
  for (int n = 1; ok && n <= kMaxIdSuffix; ++n) {
    id = n == 1 ? base : base + "-" + std::to_string(n);
    const std::string dir = sessions_dir_ + "/" + id;
    if (::access(dir.c_str(), F_OK) == 0) continue;
    m.id = id;
    m.updated_utc = internal::IsoUtc(std::chrono::system_clock::now());
    m.journal = {{m.updated_utc, "created",
                  m.job + " of '" + m.object_name + "' (" +
                      params.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + ")"}};
    why = WriteFileAtomically(tmp + "/" + internal::kManifestJson, ManifestToJson(m));
    ok = why.ok();
    if (!ok) break;
    if (::renameat2(AT_FDCWD, tmp.c_str(), AT_FDCWD, dir.c_str(), RENAME_NOREPLACE) == 0) {
      why = internal::FsyncDir(sessions_dir_);
      ok = why.ok();
      if (!ok) break;
      return MakeSession(id, dir, std::move(lock), status);
    }
    const int err = errno;
    if (err != EEXIST && err != ENOTEMPTY) {
      why = Status::FromErrno(err, "cannot rename '" + tmp + "' to '" + dir + "'");
      ok = false;
    }
  }
  if (ok) {
    why = Status(ErrorCode::kAlreadyExists, "all ids '" + base + "' to '" + base + "-" +
                                                std::to_string(kMaxIdSuffix) + "' are taken");
  }
  std::error_code ec;
  fs::remove_all(tmp, ec);
  SetStatus(status, why.WithContext("cannot create a session for '" + m.object + "'"));
  return nullptr;
}

std::unique_ptr<Session> SessionStore::MakeSession(const std::string& id, const std::string& dir,
                                                   std::unique_ptr<Session::Lock> lock,
                                                   Status* status) {
  Manifest manifest;
  if (Status read = internal::ReadManifest(dir, id, &manifest); !read.ok()) {
    // Unreadable or invalid: either way the session cannot be used as it is.
    // An invalid manifest is kCorrupt; a read error keeps the errno's code.
    SetStatus(status, read.WithContext("session " + id + " is corrupt"));
    return nullptr;
  }
  return std::unique_ptr<Session>(new Session(id, dir, std::move(lock), std::move(manifest)));
}

std::unique_ptr<Session> SessionStore::OpenSession(const std::string& id, Status* status) {
  if (!IsValidSessionId(id)) {
    SetStatus(status,
              Status(ErrorCode::kInvalidArgument,
                     "invalid session id " + Quoted(id) + " (expected YYYYMMDD-HHMMSS-<name>)"));
    return nullptr;
  }
  const std::string dir = sessions_dir_ + "/" + id;
  struct stat st {};
  if (::stat(dir.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
    SetStatus(status,
              Status(ErrorCode::kNotFound, "unknown session " + id + " (no folder '" + dir + "')"));
    return nullptr;
  }
  auto lock = std::make_unique<Session::Lock>();
  if (Status locked = lock->dir.Acquire(dir); !locked.ok()) {
    const bool busy = locked.code() == ErrorCode::kFailedPrecondition;
    SetStatus(status, busy ? Status(ErrorCode::kFailedPrecondition,
                                    "session " + id +
                                        " is open elsewhere (a job or another process holds it)")
                           : locked.WithContext("session " + id));
    return nullptr;
  }
  return MakeSession(id, dir, std::move(lock), status);
}

std::string SessionStore::MoveToTrash(const std::string& id, Status* status) {
  // Held open by no one: taking its lock proves it (and keeps a job from
  // opening it while it moves).
  std::unique_ptr<Session> session = OpenSession(id, status);
  if (!session) return "";
  const fs::path trash = fs::path(sessions_dir_).parent_path() / "trash";
  std::error_code ec;
  fs::create_directories(trash, ec);
  if (ec) {
    SetStatus(status, Status(ErrorCode::kIoError, "cannot make the trash folder '" +
                                                      trash.string() + "': " + ec.message()));
    return "";
  }
  fs::path target = trash / id;
  for (int n = 2; fs::exists(target) && n < 1000; ++n)
    target = trash / (id + "-" + std::to_string(n));
  const std::string from = sessions_dir_ + "/" + id;
  if (::rename(from.c_str(), target.c_str()) != 0) {
    SetStatus(status,
              Status(ErrorCode::kIoError, "cannot move session " + id + " to '" + target.string() +
                                              "': " + std::strerror(errno)));
    return "";
  }
  Status synced = internal::FsyncDir(sessions_dir_);
  if (synced.ok()) synced = internal::FsyncDir(trash.string());
  SetStatus(status, synced.ok() ? Status() : synced.WithContext("session " + id + " moved"));
  return target.string();
}

std::vector<std::string> SessionStore::MarkInterrupted(std::vector<std::string>* problems) {
  std::vector<std::string> marked;
  std::vector<std::string> names;
  std::error_code ec;
  for (auto it = fs::directory_iterator(sessions_dir_, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    names.push_back(it->path().filename().string());
  }
  if (ec && problems) problems->push_back("'" + sessions_dir_ + "': " + ec.message());
  std::sort(names.begin(), names.end());
  for (const std::string& name : names) {
    const std::string dir = sessions_dir_ + "/" + name;
    if (internal::IsTemporaryName(name)) {  // a Create that crashed, or the open probe
      internal::DirLock lock;
      const Status locked = lock.Acquire(dir);
      const bool busy = locked.code() == ErrorCode::kFailedPrecondition;
      if (locked.ok() || (!busy && !fs::is_directory(dir, ec))) {
        fs::remove_all(dir, ec);
      }
      continue;
    }
    if (!IsValidSessionId(name)) continue;
    auto lock = std::make_unique<Session::Lock>();
    if (Status locked = lock->dir.Acquire(dir); !locked.ok()) {
      const bool busy = locked.code() == ErrorCode::kFailedPrecondition;
      if (!busy && problems) problems->push_back("session " + name + ": " + locked.message());
      continue;  // busy: a live job holds it
    }
    internal::RemoveTemporaries(dir);
    Status why;
    auto session = MakeSession(name, dir, std::move(lock), &why);
    if (!session) {
      if (problems) problems->push_back(why.message());
      continue;
    }
    const SessionState state = session->state();
    if (!IsActive(state)) continue;
    why = session->SetState(
        SessionState::kInterrupted,
        std::string("craftscand stopped while the session was ") + ToString(state));
    if (!why.ok()) {
      if (problems) problems->push_back(why.message());
      continue;
    }
    marked.push_back(name);
  }
  return marked;
}

std::vector<SessionSummary> SessionStore::List() const {
  std::vector<SessionSummary> out;
  std::error_code ec;
  for (auto it = fs::directory_iterator(sessions_dir_, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.empty() || name[0] == '.' || !it->is_directory(ec)) continue;
    SessionSummary s;
    s.id = name;
    Manifest m;
    Status read;
    if (!IsValidSessionId(name)) {
      s.state = "corrupt";
      s.problem = "folder name is not a session id";
    } else if (read = internal::ReadManifest(it->path().string(), name, &m); !read.ok()) {
      s.state = "corrupt";
      s.problem = read.message();
    } else {
      s.object_name = m.object_name;
      s.job = m.job;
      s.state = ToString(m.state);
      s.views_captured = static_cast<int>(m.CapturedViews().size());
      if (const auto turns = m.params.find("turns"); turns != m.params.end()) s.turns = *turns;
      s.created_utc = m.created_utc;
      s.updated_utc = m.updated_utc;
    }
    out.push_back(std::move(s));
  }
  std::sort(out.begin(), out.end(),
            [](const SessionSummary& a, const SessionSummary& b) { return a.id < b.id; });
  return out;
}

VerifyResult SessionStore::Verify(const std::string& id) const {
  VerifyResult result;
  if (!IsValidSessionId(id)) {
    result.problems.push_back("invalid session id " + Quoted(id));
    return result;
  }
  const std::string dir = sessions_dir_ + "/" + id;
  Manifest manifest;
  if (Status read = internal::ReadManifest(dir, id, &manifest); !read.ok()) {
    result.problems.push_back(read.message());
    return result;
  }
  result.manifest_ok = true;
  internal::VerifyFiles(dir, manifest, &result, nullptr);
  return result;
}

}  // namespace craftscan::daemon
