// Runs the real craftscanctl binary as a child process for the CLI tests:
// its exit code, stdout and stderr (through files, so no pipe can fill up),
// with a bound on how long it may run.
#pragma once

#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <string>
#include <vector>

#include "file_util.h"
#include "process_util.h"
#include "test_paths.h"

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
    std::vector<std::string> argv = {::craftscan::testing::CraftscanctlPath()};
    argv.insert(argv.end(), args.begin(), args.end());
    std::vector<char*> envp;
    for (std::string& v : environment) envp.push_back(v.data());
    envp.push_back(nullptr);
    SpawnOptions options;
    options.stdin_path = "/dev/null";
    options.stdout_path = out_path_;
    options.stderr_path = err_path_;
    options.envp = envp.data();
    start_ = std::chrono::steady_clock::now();
    Spawn(argv, options, &child_);
  }
  CtlProcess(const CtlProcess&) = delete;
  CtlProcess& operator=(const CtlProcess&) = delete;

  // Whether it is still running.
  bool Running() {
    if (child_.Running()) return true;
    Collect();
    return false;
  }

  // What it wrote to stdout so far.
  std::string Output() const { return ReadFile(out_path_); }
  // Sends `signal` if it runs.
  void Signal(int signal) { child_.Signal(signal); }

  // Waits up to `timeout` for the exit (then kills it: exit_code −1).
  CtlRun Wait(std::chrono::seconds timeout) {
    if (child_.WaitForExit(timeout)) {
      Collect();
    } else if (child_.started()) {
      child_.Kill();
      run_.exit_code = -1;
    }
    run_.out = ReadFile(out_path_);
    run_.err = ReadFile(err_path_);
    return run_;
  }

 private:
  // Once it has exited (and was reaped): its exit code and run time, once.
  void Collect() {
    if (collected_ || !child_.WaitForExit(std::chrono::milliseconds(0))) return;
    collected_ = true;
    run_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    run_.exit_code = WIFEXITED(child_.status()) ? WEXITSTATUS(child_.status()) : -1;
  }

  std::string out_path_, err_path_;
  ChildProcess child_;  // killed if still running
  std::chrono::steady_clock::time_point start_;
  CtlRun run_;
  bool collected_ = false;
};

}  // namespace craftscan::testing
