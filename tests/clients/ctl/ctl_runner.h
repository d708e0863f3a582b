// Runs the real craftscanctl binary as a child process for the CLI tests:
// its exit code, stdout and stderr (through files, so no pipe can fill up),
// with a bound on how long it may run.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace craftscan::testing {

struct CtlRun {
  int exit_code = -1;  // -1: did not exit in time (killed) or could not start
  std::string out, err;
  double seconds = 0;
};

// A started craftscanctl; Wait() collects it.
class CtlProcess {
 public:
  // Starts `CRAFTSCANCTL_PATH args...` with the environment of this process
  // minus CRAFTSCAN_TOKEN and CYCLONEDDS_URI, plus `env` ("NAME=value").
  // Output goes to <dir>/<tag>.out/.err.
  CtlProcess(const std::string& dir, const std::string& tag, const std::vector<std::string>& args,
             const std::vector<std::string>& env = {})
      : out_path_(dir + "/" + tag + ".out"), err_path_(dir + "/" + tag + ".err") {
    std::vector<std::string> environment;
    for (char** e = environ; *e; ++e) {
      const std::string v = *e;
      if (v.rfind("CRAFTSCAN_TOKEN=", 0) == 0 || v.rfind("CYCLONEDDS_URI=", 0) == 0) continue;
      environment.push_back(v);
    }
    environment.insert(environment.end(), env.begin(), env.end());
    std::vector<std::string> argv_strings = {CRAFTSCANCTL_PATH};
    argv_strings.insert(argv_strings.end(), args.begin(), args.end());
    std::vector<char*> argv, envp;
    for (std::string& a : argv_strings) argv.push_back(a.data());
    argv.push_back(nullptr);
    for (std::string& v : environment) envp.push_back(v.data());
    envp.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&actions, 1, out_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                     0644);
    posix_spawn_file_actions_addopen(&actions, 2, err_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                     0644);
    start_ = std::chrono::steady_clock::now();
    if (posix_spawn(&pid_, CRAFTSCANCTL_PATH, &actions, nullptr, argv.data(), envp.data()) != 0) {
      pid_ = -1;
    }
    posix_spawn_file_actions_destroy(&actions);
  }
  ~CtlProcess() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  CtlProcess(const CtlProcess&) = delete;
  CtlProcess& operator=(const CtlProcess&) = delete;

  // Whether it is still running.
  bool Running() {
    if (pid_ <= 0) return false;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      Collect(status);
      return false;
    }
    return true;
  }

  // What it wrote to stdout so far.
  std::string Output() const { return Read(out_path_); }
  // Sends `signal` if it runs.
  void Signal(int signal) {
    if (pid_ > 0) ::kill(pid_, signal);
  }

  // Waits up to `timeout` for the exit (then kills it: exit_code −1).
  CtlRun Wait(std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (pid_ > 0) {
      int status = 0;
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        Collect(status);
        break;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
        pid_ = -1;
        run_.exit_code = -1;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    run_.out = Read(out_path_);
    run_.err = Read(err_path_);
    return run_;
  }

 private:
  void Collect(int status) {
    run_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    run_.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    pid_ = -1;
  }
  static std::string Read(const std::string& path) {
    std::ifstream in(path);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }

  std::string out_path_, err_path_;
  pid_t pid_ = -1;
  std::chrono::steady_clock::time_point start_;
  CtlRun run_;
};

}  // namespace craftscan::testing
