// Child processes in tests: a program spawned with its output in files, and
// a handle that kills and reaps it if it still runs when the handle goes.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace craftscan::testing {

// A spawned child's pid, killed (SIGKILL) and reaped on destruction if still
// running. Not copyable.
class ChildProcess {
 public:
  ChildProcess() = default;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ~ChildProcess() { Kill(); }

  // For posix_spawn: where it writes the pid (set -1 on failure).
  pid_t* pid_slot() { return &pid_; }
  // Started and not reaped yet.
  bool started() const { return pid_ > 0; }
  void Signal(int signal) {
    if (pid_ > 0) ::kill(pid_, signal);
  }
  // Kills (SIGKILL) and reaps it if it still runs.
  void Kill() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, &status_, 0);
      pid_ = -1;
    }
  }

  // Whether it still runs; reaps it (keeping its wait status) once it exited.
  bool Running() {
    if (pid_ <= 0) return false;
    if (::waitpid(pid_, &status_, WNOHANG) != pid_) return true;
    pid_ = -1;
    exited_ = true;
    return false;
  }

  // True once it has exited (then status() is its wait status), false if it
  // still runs after `timeout` or never started.
  bool WaitForExit(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (Running()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return exited_;
  }
  int status() const { return status_; }

  // The exit code (128 + signal if killed by one), or −1 if it did not exit
  // within `timeout` (it keeps running; the destructor kills it).
  int Wait(std::chrono::milliseconds timeout) {
    if (!WaitForExit(timeout)) return -1;
    return WIFEXITED(status_) ? WEXITSTATUS(status_) : 128 + WTERMSIG(status_);
  }

 private:
  pid_t pid_ = -1;
  int status_ = 0;
  bool exited_ = false;
};

// Where a spawned child's standard streams go ("" = inherited).
struct SpawnOptions {
  std::string stdin_path;         // opened read-only
  std::string stdout_path;        // created or truncated
  std::string stderr_path;        // created or truncated
  bool stderr_to_stdout = false;  // stderr into stdout's file instead
  char** envp = environ;          // the child's environment
};

// Starts argv[0] (a path) with `argv`; true if it started (child->started()).
inline bool Spawn(const std::vector<std::string>& argv, const SpawnOptions& options,
                  ChildProcess* child) {
  std::vector<char*> args;
  for (const std::string& arg : argv) args.push_back(const_cast<char*>(arg.c_str()));
  args.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  if (!options.stdin_path.empty()) {
    posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, options.stdin_path.c_str(), O_RDONLY,
                                     0);
  }
  if (!options.stdout_path.empty()) {
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, options.stdout_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
  }
  if (options.stderr_to_stdout) {
    posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  } else if (!options.stderr_path.empty()) {
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, options.stderr_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
  }
  const int rc =
      posix_spawn(child->pid_slot(), argv[0].c_str(), &actions, nullptr, args.data(), options.envp);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) *child->pid_slot() = -1;
  return child->started();
}

}  // namespace craftscan::testing
