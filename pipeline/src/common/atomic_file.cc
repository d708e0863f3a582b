#include "craftscan/pipeline/common/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

// "'<path>': <what>: <strerror(errnum)>" with the errno's code.
Status ErrnoStatus(int errnum, const std::string& what, const std::string& path) {
  return Status::FromErrno(errnum, "'" + path + "': " + what);
}

bool WriteAll(int fd, std::string_view bytes) {
  const char* p = bytes.data();
  std::size_t left = bytes.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  return true;
}

}  // namespace

unsigned ProcessUmask() {
  static const unsigned umask = [] {
    std::ifstream status("/proc/self/status");
    for (std::string line; std::getline(status, line);) {
      if (line.rfind("Umask:", 0) == 0)
        return static_cast<unsigned>(std::strtoul(line.c_str() + 6, nullptr, 8)) & 0777;
    }
    return 022u;
  }();
  return umask;
}

Status WriteFileAtomically(const std::string& path, std::string_view bytes) {
  try {
    namespace fs = std::filesystem;
    if (path.empty()) return Status(ErrorCode::kInvalidArgument, "empty path");
    const fs::path target(path);
    const fs::path folder = target.has_parent_path() ? target.parent_path() : fs::path(".");
    // Hidden temporary beside the target: same file system, so rename is atomic.
    // (Built with append: GCC 12 warns falsely on `"." + string`, PR 105651.)
    std::string tmp_name(".");
    tmp_name.append(target.filename().string()).append(".tmp-XXXXXX");
    std::string tmp = (folder / tmp_name).string();
    const int fd = ::mkstemp(tmp.data());
    if (fd < 0) return ErrnoStatus(errno, "cannot create a temporary file", tmp);

    // Each step runs only if the ones before succeeded; the descriptor is
    // closed either way. The errno is taken right after the failing call:
    // close() and unlink() below may change it.
    Status failed;
    if (!WriteAll(fd, bytes)) {
      failed = ErrnoStatus(errno, "cannot write", tmp);
    } else if (::fchmod(fd, 0666 & ~ProcessUmask()) != 0) {  // mkstemp creates 0600
      failed = ErrnoStatus(errno, "cannot set permissions", tmp);
    } else if (::fsync(fd) != 0) {
      failed = ErrnoStatus(errno, "cannot fsync", tmp);
    }
    if (::close(fd) != 0 && failed.ok()) failed = ErrnoStatus(errno, "cannot close", tmp);
    if (failed.ok() && ::rename(tmp.c_str(), path.c_str()) != 0)
      failed = ErrnoStatus(errno, "cannot rename the temporary file to it", path);
    if (!failed.ok()) {
      ::unlink(tmp.c_str());
      return failed;
    }
    const int dir_fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY);
    if (dir_fd >= 0) {
      const int rc = ::fsync(dir_fd);
      const int fsync_errno = errno;
      ::close(dir_fd);
      if (rc != 0) return ErrnoStatus(fsync_errno, "cannot fsync the folder of", path);
    }
    return Status::Ok();
  } catch (const std::exception& e) {
    return Status(ErrorCode::kInternal, std::string("WriteFileAtomically: ") + e.what());
  } catch (...) {
    return Status(ErrorCode::kInternal, "WriteFileAtomically: unknown exception");
  }
}

bool WriteFileAtomically(const std::string& path, std::string_view bytes, std::string* error) {
  const Status status = WriteFileAtomically(path, bytes);
  if (status.ok()) return true;
  return Fail(error, status.message());
}

}  // namespace craftscan
