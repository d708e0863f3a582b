// craftscan-turntable-emulator: a GRBL 1.1 turntable on a pseudo-terminal.
// Prints the PTY slave path on the first line of stdout, then serves until
// SIGINT/SIGTERM or "quit". Faults on demand through a control FIFO (one
// command per line) or signals.
#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>

#include "turntable_emulator.h"

namespace {

volatile std::sig_atomic_t g_quit = 0;
volatile std::sig_atomic_t g_hangup = 0;

constexpr const char* kUsage = R"(usage: craftscan-turntable-emulator [options]
  --link PATH          keep a symlink PATH pointing at the PTY slave
  --homing-ms N        duration of $H (default 100)
  --no-homing          $H answers error:5 (turntable without a limit switch)
  --no-banner          no banner on start (only after a soft reset, 0x18)
  --start-in-alarm     start locked in the Alarm state, like GRBL with homing enabled
  --start-deg D        machine position at start (default 0)
  --hold-decel A       feed-hold deceleration in deg/s^2 (default 3600)
  --version V          version in the banner (default 1.1h)
  --control-fifo PATH  create FIFO PATH and read commands from it:
                         garbage TEXT | silent on|off | alarm N | offset DEG | hangup | quit
Signals: SIGINT/SIGTERM quit; SIGUSR1 hangs up (closes the PTY master).
)";

void OnSignal(int sig) {
  if (sig == SIGUSR1) {
    g_hangup = 1;
  } else {
    g_quit = 1;
  }
}

// Runs one control command; false for "quit".
bool Control(craftscan::testing::TurntableEmulator& emu, const std::string& line) {
  std::istringstream in(line);
  std::string cmd;
  in >> cmd;
  if (cmd == "garbage") {
    std::string rest;
    std::getline(in, rest);
    emu.InjectGarbage(rest.empty() ? std::string("\xff\xfe#garbage") : rest.substr(1));
  } else if (cmd == "silent") {
    std::string on;
    in >> on;
    emu.SetSilent(on != "off");
  } else if (cmd == "alarm") {
    int code = 1;
    in >> code;
    emu.RaiseAlarm(code);
  } else if (cmd == "offset") {
    double deg = 0;
    in >> deg;
    emu.SetPositionOffset(deg);
  } else if (cmd == "hangup") {
    emu.HangUp();
  } else if (cmd == "quit") {
    return false;
  } else if (!cmd.empty()) {
    std::cerr << "turntable-emulator: unknown control command '" << cmd << "'\n";
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  craftscan::testing::EmulatorOptions options;
  std::string fifo_path;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&](const char* name) -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "missing value for " << name << "\n" << kUsage;
        std::exit(2);
      }
      return argv[++i];
    };
    if (arg == "--link") {
      options.link_path = value("--link");
    } else if (arg == "--homing-ms") {
      options.homing_time = std::chrono::milliseconds(std::atoi(value("--homing-ms").c_str()));
    } else if (arg == "--no-homing") {
      options.homing_enabled = false;
    } else if (arg == "--no-banner") {
      options.banner_on_start = false;
    } else if (arg == "--start-in-alarm") {
      options.start_in_alarm = true;
    } else if (arg == "--start-deg") {
      options.start_position_deg = std::atof(value("--start-deg").c_str());
    } else if (arg == "--hold-decel") {
      options.hold_decel_deg_s2 = std::atof(value("--hold-decel").c_str());
      if (!(options.hold_decel_deg_s2 > 0)) {
        std::fprintf(stderr, "--hold-decel: expected a deceleration > 0 deg/s^2\n");
        return 2;
      }
    } else if (arg == "--version") {
      options.version = value("--version");
    } else if (arg == "--control-fifo") {
      fifo_path = value("--control-fifo");
    } else if (arg == "-h" || arg == "--help") {
      std::cout << kUsage;
      return 0;
    } else {
      std::cerr << "unknown argument '" << arg << "'\n" << kUsage;
      return 2;
    }
  }

  std::string error;
  auto emu = craftscan::testing::TurntableEmulator::Start(options, &error);
  if (!emu) {
    std::cerr << "turntable-emulator: " << error << "\n";
    return 1;
  }
  int fifo = -1;
  if (!fifo_path.empty()) {
    ::unlink(fifo_path.c_str());
    // O_RDWR: the FIFO never reports end-of-file when a writer goes away.
    if (::mkfifo(fifo_path.c_str(), 0600) != 0 ||
        (fifo = ::open(fifo_path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC)) < 0) {
      std::cerr << "turntable-emulator: cannot create FIFO " << fifo_path << ": "
                << std::strerror(errno) << "\n";
      return 1;
    }
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnSignal);
  std::cout << emu->slave_path() << std::endl;

  std::string pending;
  bool running = true;
  while (running && !g_quit) {
    if (g_hangup) {
      g_hangup = 0;
      emu->HangUp();
    }
    pollfd pfd{fifo, POLLIN, 0};
    int r = ::poll(&pfd, fifo >= 0 ? 1 : 0, 100);
    if (r > 0 && (pfd.revents & POLLIN)) {
      char buf[256];
      ssize_t n = ::read(fifo, buf, sizeof(buf));
      if (n > 0) pending.append(buf, static_cast<std::size_t>(n));
      std::size_t eol;
      while (running && (eol = pending.find('\n')) != std::string::npos) {
        running = Control(*emu, pending.substr(0, eol));
        pending.erase(0, eol + 1);
      }
    }
  }
  emu->Stop();
  if (fifo >= 0) {
    ::close(fifo);
    ::unlink(fifo_path.c_str());
  }
  return 0;
}
