#include "fs_util.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <system_error>
#include <vector>

namespace craftscan::daemon::internal {
namespace {

// "'<path>': <what>: <strerror(err)>" with err's code.
Status Fail(const std::string& path, const char* what, int err) {
  return Status::FromErrno(err, "'" + path + "': " + what);
}

std::tm UtcTm(std::chrono::system_clock::time_point t) {
  const std::time_t seconds = std::chrono::system_clock::to_time_t(t);
  std::tm tm{};
  gmtime_r(&seconds, &tm);
  return tm;
}

}  // namespace

Status ReadFileBytes(const std::string& path, std::string* bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Fail(path, "cannot open", errno);
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    ::close(fd);
    return Fail(path, "cannot stat", err);
  }
  bytes->clear();
  bytes->reserve(static_cast<std::size_t>(st.st_size));
  char buffer[1 << 16];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      ::close(fd);
      return Fail(path, "cannot read", err);
    }
    if (n == 0) break;
    bytes->append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return Status::Ok();
}

Status FsyncDir(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return Fail(path, "cannot open the folder", errno);
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) return Fail(path, "cannot fsync the folder", err);
  return Status::Ok();
}

Status MakeDurableDir(const std::string& path) {
  if (::mkdir(path.c_str(), 0755) != 0) {
    const int err = errno;
    struct stat st {};
    if (err != EEXIST || ::stat(path.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
      return Fail(path, "cannot create the folder", err);
    }
  }
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  return FsyncDir(parent.empty() ? std::string(".") : parent.string());
}

Status DirLock::Acquire(const std::string& path) {
  fd_ = ::open(path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd_ < 0) return Fail(path, "cannot open the folder", errno);
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    if (err == EWOULDBLOCK) {
      return Status(ErrorCode::kFailedPrecondition,
                    "'" + path + "' is open elsewhere (locked by another session object)");
    }
    return Fail(path, "cannot lock the folder", err);
  }
  return Status::Ok();
}

DirLock::~DirLock() {
  if (fd_ >= 0) ::close(fd_);
}

std::string IsoUtc(std::chrono::system_clock::time_point t) {
  const std::tm tm = UtcTm(t);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(t.time_since_epoch()).count() % 1000;
  char text[96];
  std::snprintf(text, sizeof text, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec,
                static_cast<int>(ms < 0 ? ms + 1000 : ms));
  return text;
}

std::string IdTimeUtc(std::chrono::system_clock::time_point t) {
  const std::tm tm = UtcTm(t);
  char text[96];
  std::snprintf(text, sizeof text, "%04d%02d%02d-%02d%02d%02d", tm.tm_year + 1900, tm.tm_mon + 1,
                tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec);
  return text;
}

bool IsTemporaryName(const std::string& file_name) {
  // ".<name>.tmp-XXXXXX": hidden, and ".tmp-" followed by exactly 6 characters.
  const std::size_t at = file_name.rfind(".tmp-");
  return file_name.size() > 12 && file_name[0] == '.' && at != std::string::npos && at > 1 &&
         file_name.size() - at == 11;
}

int RemoveTemporaries(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::vector<fs::path> stale;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (IsTemporaryName(it->path().filename().string())) {
      stale.push_back(it->path());
      if (it->is_directory(ec)) it.disable_recursion_pending();
    }
  }
  int removed = 0;
  for (const auto& path : stale) {
    if (fs::remove_all(path, ec) > 0 && !ec) ++removed;
  }
  return removed;
}

}  // namespace craftscan::daemon::internal
