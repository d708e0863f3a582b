// A private mount namespace and a small tmpfs in it, for tests that fill or
// remount a data directory without touching the host (the disk-full stage
// test; test_daemon_storage.cc has its own copy, to be moved here).
#pragma once

#include <sched.h>
#include <sys/mount.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <string>

namespace craftscan::testing {

// Moves the calling thread into a private mount namespace: directly as root,
// else through a new user namespace (which needs a single-threaded process,
// as at the start of a test). Returns "" or why not (the test then skips).
inline std::string EnterPrivateMountNamespace() {
  if (::unshare(CLONE_NEWNS) != 0) {
    const uid_t uid = ::geteuid();
    const gid_t gid = ::getegid();
    if (::unshare(CLONE_NEWUSER | CLONE_NEWNS) != 0) {
      return std::string("no mount namespace (unshare: ") + std::strerror(errno) + ")";
    }
    std::ofstream("/proc/self/setgroups") << "deny";
    std::ofstream("/proc/self/uid_map") << "0 " << uid << " 1";
    std::ofstream("/proc/self/gid_map") << "0 " << gid << " 1";
  }
  // Private, so that nothing mounted here propagates to the host.
  if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
    return std::string("cannot make mounts private: ") + std::strerror(errno);
  }
  return {};
}

// A tmpfs of `size` ("16m") on `dir` (an existing folder) for the life of
// the object; unmounted lazily.
class ScopedTmpfs {
 public:
  ScopedTmpfs(std::string dir, const std::string& size) : dir_(std::move(dir)) {
    const std::string options = "size=" + size + ",mode=0755";
    if (::mount("craftscan-test", dir_.c_str(), "tmpfs", 0, options.c_str()) != 0) {
      error_ = "mount tmpfs on " + dir_ + ": " + std::strerror(errno);
      return;
    }
    mounted_ = true;
  }
  ~ScopedTmpfs() {
    if (mounted_) ::umount2(dir_.c_str(), MNT_DETACH);
  }
  ScopedTmpfs(const ScopedTmpfs&) = delete;
  ScopedTmpfs& operator=(const ScopedTmpfs&) = delete;

  const std::string& error() const { return error_; }

 private:
  std::string dir_, error_;
  bool mounted_ = false;
};

}  // namespace craftscan::testing
