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

bool SetError(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
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

std::unique_ptr<SessionStore> SessionStore::Open(const std::string& data_dir, std::string* error) {
  struct stat st {};
  if (data_dir.empty()) {
    SetError(error, "data dir is empty");
    return nullptr;
  }
  if (::stat(data_dir.c_str(), &st) != 0) {
    SetError(error, "data dir '" + data_dir + "': " + std::strerror(errno));
    return nullptr;
  }
  if (!S_ISDIR(st.st_mode)) {
    SetError(error, "data dir '" + data_dir + "' is not a directory");
    return nullptr;
  }
  std::error_code ec;
  const fs::path absolute = fs::absolute(data_dir, ec);
  const std::string sessions =
      ((ec ? fs::path(data_dir) : absolute).lexically_normal() / "sessions").string();
  std::string why;
  if (!internal::MakeDurableDir(sessions, &why)) {
    SetError(error, "data dir '" + data_dir + "' is not usable: " + why);
    return nullptr;
  }
  // Probe: can a file be created? (access(2) says yes to root on 0555 and
  // cannot see a full disk; a real create answers both read-only and EACCES.)
  std::string probe = sessions + "/.probe.tmp-XXXXXX";
  const int fd = ::mkstemp(probe.data());
  if (fd < 0) {
    SetError(error, "data dir '" + data_dir + "': '" + sessions +
                        "' is not writable: " + std::strerror(errno));
    return nullptr;
  }
  ::close(fd);
  ::unlink(probe.c_str());
  return std::unique_ptr<SessionStore>(new SessionStore(sessions));
}

std::unique_ptr<Session> SessionStore::Create(std::string_view object_name, std::string_view job,
                                              const nlohmann::json& params,
                                              std::chrono::system_clock::time_point now,
                                              std::string* error) {
  if (!IsJobVerb(job)) {
    SetError(error, "job verb '" + std::string(job.substr(0, 40)) +
                        "' is not a lower-case word ([a-z_], 1 to 32 characters)");
    return nullptr;
  }
  if (!params.is_object()) {
    SetError(error, "job parameters must be a JSON object, got " + std::string(params.type_name()));
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
    SetError(error,
             "cannot create a session folder in '" + sessions_dir_ + "': " + std::strerror(errno));
    return nullptr;
  }
  auto lock = std::make_unique<Session::Lock>();
  std::string why;
  bool ok = ::chmod(tmp.c_str(), 0777 & ~ProcessUmask()) == 0;  // mkdtemp gives 0700
  if (!ok) why = "'" + tmp + "': cannot set permissions: " + std::strerror(errno);
  ok = ok && lock->dir.Acquire(tmp, nullptr, &why);
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
    ok = WriteFileAtomically(tmp + "/" + internal::kManifestJson, ManifestToJson(m), &why);
    if (!ok) break;
    if (::renameat2(AT_FDCWD, tmp.c_str(), AT_FDCWD, dir.c_str(), RENAME_NOREPLACE) == 0) {
      ok = internal::FsyncDir(sessions_dir_, &why);
      if (!ok) break;
      return MakeSession(id, dir, std::move(lock), error);
    }
    if (errno != EEXIST && errno != ENOTEMPTY) {
      why = "cannot rename '" + tmp + "' to '" + dir + "': " + std::strerror(errno);
      ok = false;
    }
  }
  if (ok)
    why = "all ids '" + base + "' to '" + base + "-" + std::to_string(kMaxIdSuffix) + "' are taken";
  std::error_code ec;
  fs::remove_all(tmp, ec);
  SetError(error, "cannot create a session for '" + m.object + "': " + why);
  return nullptr;
}

std::unique_ptr<Session> SessionStore::MakeSession(const std::string& id, const std::string& dir,
                                                   std::unique_ptr<Session::Lock> lock,
                                                   std::string* error) {
  Manifest manifest;
  std::string why;
  if (!internal::ReadManifest(dir, id, &manifest, &why)) {
    SetError(error, "session " + id + " is corrupt: " + why);
    return nullptr;
  }
  return std::unique_ptr<Session>(new Session(id, dir, std::move(lock), std::move(manifest)));
}

std::unique_ptr<Session> SessionStore::OpenSession(const std::string& id, std::string* error) {
  if (!IsValidSessionId(id)) {
    SetError(error, "invalid session id " + Quoted(id) + " (expected YYYYMMDD-HHMMSS-<name>)");
    return nullptr;
  }
  const std::string dir = sessions_dir_ + "/" + id;
  struct stat st {};
  if (::stat(dir.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
    SetError(error, "unknown session " + id + " (no folder '" + dir + "')");
    return nullptr;
  }
  auto lock = std::make_unique<Session::Lock>();
  bool busy = false;
  std::string why;
  if (!lock->dir.Acquire(dir, &busy, &why)) {
    SetError(error, busy
                        ? "session " + id + " is open elsewhere (a job or another process holds it)"
                        : "session " + id + ": " + why);
    return nullptr;
  }
  return MakeSession(id, dir, std::move(lock), error);
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
      bool busy = false;
      if (lock.Acquire(dir, &busy, nullptr) || (!busy && !fs::is_directory(dir, ec))) {
        fs::remove_all(dir, ec);
      }
      continue;
    }
    if (!IsValidSessionId(name)) continue;
    auto lock = std::make_unique<Session::Lock>();
    bool busy = false;
    std::string why;
    if (!lock->dir.Acquire(dir, &busy, &why)) {
      if (!busy && problems) problems->push_back("session " + name + ": " + why);
      continue;  // busy: a live job holds it
    }
    internal::RemoveTemporaries(dir);
    auto session = MakeSession(name, dir, std::move(lock), &why);
    if (!session) {
      if (problems) problems->push_back(why);
      continue;
    }
    const SessionState state = session->state();
    if (!IsActive(state)) continue;
    if (!session->SetState(
            SessionState::kInterrupted,
            std::string("craftscand stopped while the session was ") + ToString(state), &why)) {
      if (problems) problems->push_back(why);
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
    std::string why;
    if (!IsValidSessionId(name)) {
      s.state = "corrupt";
      s.problem = "folder name is not a session id";
    } else if (!internal::ReadManifest(it->path().string(), name, &m, &why)) {
      s.state = "corrupt";
      s.problem = why;
    } else {
      s.object_name = m.object_name;
      s.job = m.job;
      s.state = ToString(m.state);
      s.views_captured = static_cast<int>(m.CapturedViews().size());
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
  std::string why;
  if (!internal::ReadManifest(dir, id, &manifest, &why)) {
    result.problems.push_back(why);
    return result;
  }
  result.manifest_ok = true;
  internal::VerifyFiles(dir, manifest, &result, nullptr);
  return result;
}

}  // namespace craftscan::daemon
