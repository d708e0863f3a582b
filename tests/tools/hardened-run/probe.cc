// hardened-probe: tries the operations a sandbox should refuse (and a few it
// should allow) and prints one line per action, "ACTION RESULT", where
// RESULT is "OK" or the errno name (EPERM, EROFS, ...). Run under
// hardened-run by the daemon's hardening test; every action is harmless when
// it succeeds outside a sandbox (it restores or only touches its own
// process or a file it created).
//
//   hardened-probe write:PATH ... mprotect-exec socket:packet status
//
// Actions:
//   write:PATH          create PATH (O_EXCL), write, unlink
//   openw:PATH          open an existing file for writing, close
//   stat:PATH           stat
//   list:DIR            prints "N entries" or the errno name
//   socket:FAMILY       unix, inet, inet6, netlink, packet, bluetooth, can, vsock
//   mmap-wx             anonymous mapping PROT_WRITE|PROT_EXEC
//   mprotect-exec       anonymous RW mapping made PROT_READ|PROT_EXEC
//   setuid-self         setuid(getuid()) (a no-op change)
//   sethostname-same    sethostname with the current name
//   personality         personality(PER_LINUX32), then back
//   sched-fifo          SCHED_FIFO priority 1, then back to SCHED_OTHER
//   chmod-suid:PATH     create PATH, chmod 04750, unlink
//   unshare-user        unshare(CLONE_NEWUSER) (the probe's own)
//   clone3              clone3 with a null argument (EFAULT/EINVAL if it reaches the kernel)
//   syslog              klogctl(SYSLOG_ACTION_SIZE_BUFFER)
//   status              the Cap*, NoNewPrivs, Seccomp and Umask lines of /proc/self/status
// Exit status 0, or 2 for an unknown action.
#include <dirent.h>
#include <fcntl.h>
#include <sched.h>
#include <sys/klog.h>
#include <sys/mman.h>
#include <sys/personality.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>

namespace {

std::string Result(bool ok) {
  if (ok) return "OK";
  const char* name = strerrorname_np(errno);
  if (name != nullptr) return name;
  char number[32];
  std::snprintf(number, sizeof number, "errno %d", errno);
  return number;
}

int Family(const std::string& name) {
  if (name == "unix") return AF_UNIX;
  if (name == "inet") return AF_INET;
  if (name == "inet6") return AF_INET6;
  if (name == "netlink") return AF_NETLINK;
  if (name == "packet") return AF_PACKET;
  if (name == "bluetooth") return AF_BLUETOOTH;
  if (name == "can") return AF_CAN;
  if (name == "vsock") return AF_VSOCK;
  return -1;
}

bool Write(const std::string& path) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0640);
  if (fd < 0) return false;
  const bool ok = ::write(fd, "probe\n", 6) == 6;
  const int e = errno;
  ::close(fd);
  ::unlink(path.c_str());
  errno = e;
  return ok;
}

std::string List(const std::string& dir) {
  DIR* d = ::opendir(dir.c_str());
  if (d == nullptr) return Result(false);
  int n = 0;
  errno = 0;
  while (const dirent* e = ::readdir(d))
    if (std::strcmp(e->d_name, ".") != 0 && std::strcmp(e->d_name, "..") != 0) ++n;
  const bool ok = errno == 0;
  ::closedir(d);
  return ok ? std::to_string(n) + " entries" : Result(false);
}

bool MapAndProtect(bool mprotect_exec) {
  const std::size_t size = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  const int prot = mprotect_exec ? PROT_READ | PROT_WRITE : PROT_WRITE | PROT_EXEC;
  void* p = ::mmap(nullptr, size, prot, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) return false;
  bool ok = true;
  if (mprotect_exec) ok = ::mprotect(p, size, PROT_READ | PROT_EXEC) == 0;
  const int e = errno;
  ::munmap(p, size);
  errno = e;
  return ok;
}

std::string Status() {
  std::ifstream in("/proc/self/status");
  std::string out, line;
  for (const char* key : {"CapInh:", "CapPrm:", "CapEff:", "CapBnd:", "CapAmb:", "NoNewPrivs:",
                          "Seccomp:", "Umask:"}) {
    in.clear();
    in.seekg(0);
    while (std::getline(in, line)) {
      if (line.rfind(key, 0) == 0) {
        std::string value = line.substr(std::strlen(key));
        value.erase(0, value.find_first_not_of(" \t"));
        out += std::string(out.empty() ? "" : " ") + key + value;
      }
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string action = argv[i];
    const auto colon = action.find(':');
    const std::string verb = action.substr(0, colon);
    const std::string arg = colon == std::string::npos ? "" : action.substr(colon + 1);
    std::string result;
    if (verb == "write") {
      result = Result(Write(arg));
    } else if (verb == "openw") {
      const int fd = ::open(arg.c_str(), O_WRONLY | O_CLOEXEC);
      result = Result(fd >= 0);
      if (fd >= 0) ::close(fd);
    } else if (verb == "stat") {
      struct stat st {};
      result = Result(::stat(arg.c_str(), &st) == 0);
    } else if (verb == "list") {
      result = List(arg);
    } else if (verb == "socket") {
      const int family = Family(arg);
      if (family < 0) {
        std::fprintf(stderr, "hardened-probe: unknown family %s\n", arg.c_str());
        return 2;
      }
      const int fd = ::socket(family, SOCK_DGRAM | SOCK_CLOEXEC, 0);
      result = Result(fd >= 0);
      if (fd >= 0) ::close(fd);
    } else if (verb == "mmap-wx") {
      result = Result(MapAndProtect(false));
    } else if (verb == "mprotect-exec") {
      result = Result(MapAndProtect(true));
    } else if (verb == "setuid-self") {
      result = Result(::setuid(::getuid()) == 0);
    } else if (verb == "sethostname-same") {
      char name[256] = {};
      ::gethostname(name, sizeof name - 1);
      result = Result(::sethostname(name, std::strlen(name)) == 0);
    } else if (verb == "personality") {
      const int old = ::personality(0xffffffff);
      const bool ok = ::personality(PER_LINUX32) != -1;
      const int e = errno;
      if (ok) ::personality(static_cast<unsigned long>(old));
      errno = e;
      result = Result(ok);
    } else if (verb == "sched-fifo") {
      sched_param rt{};
      rt.sched_priority = 1;
      const bool ok = ::sched_setscheduler(0, SCHED_FIFO, &rt) == 0;
      const int e = errno;
      sched_param other{};
      if (ok) ::sched_setscheduler(0, SCHED_OTHER, &other);
      errno = e;
      result = Result(ok);
    } else if (verb == "chmod-suid") {
      const int fd = ::open(arg.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0640);
      if (fd < 0) {
        result = "create:" + Result(false);
      } else {
        ::close(fd);
        result = Result(::chmod(arg.c_str(), 04750) == 0);
        ::unlink(arg.c_str());
      }
    } else if (verb == "unshare-user") {
      result = Result(::unshare(CLONE_NEWUSER) == 0);
    } else if (verb == "clone3") {
      result = Result(::syscall(SYS_clone3, nullptr, 0) == 0);
    } else if (verb == "syslog") {
      result = Result(::klogctl(10, nullptr, 0) >= 0);
    } else if (verb == "status") {
      result = Status();
    } else {
      std::fprintf(stderr, "hardened-probe: unknown action %s\n", action.c_str());
      return 2;
    }
    std::printf("%s %s\n", action.c_str(), result.c_str());
  }
  return 0;
}
