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

// "'<path>': <what>: <strerror(errno)>" in *error; false.
bool FailErrno(std::string* error, const std::string& what, const std::string& path) {
  if (error) *error = "'" + path + "': " + what + ": " + std::strerror(errno);
  return false;
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

bool WriteFileAtomically(const std::string& path, std::string_view bytes, std::string* error) {
  return NoThrowBool("WriteFileAtomically", error, [&]() -> bool {
    namespace fs = std::filesystem;
    if (path.empty()) {
      if (error) *error = "empty path";
      return false;
    }
    const fs::path target(path);
    const fs::path folder = target.has_parent_path() ? target.parent_path() : fs::path(".");
    // Hidden temporary beside the target: same file system, so rename is atomic.
    // (Built with append: GCC 12 warns falsely on `"." + string`, PR 105651.)
    std::string tmp_name(".");
    tmp_name.append(target.filename().string()).append(".tmp-XXXXXX");
    std::string tmp = (folder / tmp_name).string();
    const int fd = ::mkstemp(tmp.data());
    if (fd < 0) return FailErrno(error, "cannot create a temporary file", tmp);

    // Each step runs only if the ones before succeeded; the descriptor is
    // closed either way.
    const char* failed = nullptr;
    if (!WriteAll(fd, bytes)) {
      failed = "cannot write";
    } else if (::fchmod(fd, 0666 & ~ProcessUmask()) != 0) {  // mkstemp creates 0600
      failed = "cannot set permissions";
    } else if (::fsync(fd) != 0) {
      failed = "cannot fsync";
    }
    if (failed) FailErrno(error, failed, tmp);
    if (::close(fd) != 0 && !failed) {
      failed = "cannot close";
      FailErrno(error, failed, tmp);
    }
    if (!failed && ::rename(tmp.c_str(), path.c_str()) != 0) {
      failed = "cannot rename the temporary file to it";
      FailErrno(error, failed, path);
    }
    const bool ok = failed == nullptr;
    if (!ok) {
      ::unlink(tmp.c_str());
      return false;
    }
    const int dir_fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY);
    if (dir_fd >= 0) {
      const int rc = ::fsync(dir_fd);
      ::close(dir_fd);
      if (rc != 0) return FailErrno(error, "cannot fsync the folder of", path);
    }
    return true;
  });
}

}  // namespace craftscan
