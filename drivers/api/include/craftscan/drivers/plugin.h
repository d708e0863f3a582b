// The driver plugin ABI. A driver is a shared object
// `craftscan-driver-<name>.so` exporting ONE C symbol:
//
//   extern "C" const CraftscanDriverInfo* craftscan_driver_info_v1(void);
//
// returning a static, versioned info struct. The host (PluginLoader) reads
// abi_version first and refuses the module unless it equals
// CRAFTSCAN_DRIVER_ABI_VERSION; only then does it read the rest or create
// anything. A driver is written as one DriverInstance subclass plus one
// registration line:
//
//   CRAFTSCAN_DRIVER_PLUGIN("sim", kCraftscanDriverCamera | kCraftscanDriverTurntable,
//                           "simulated stereo rig and turntable", CreateSimInstance);
//
// where `DriverInstance* CreateSimInstance(const DriverConfig&, const
// HostServices&, DriverStatus*) noexcept` returns null and sets the status on
// failure. No exception crosses the boundary: every entry point is noexcept.
// Host and plugins must be built with the same compiler and C++ standard
// library (the ABI passes C++ types); bump the version on any change to this
// file, camera.h, turntable.h, host.h or status.h.
#pragma once

#include <cstdint>
#include <memory>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/drivers/status.h"
#include "craftscan/drivers/turntable.h"

#define CRAFTSCAN_DRIVER_ABI_VERSION 1u
#define CRAFTSCAN_DRIVER_INFO_SYMBOL "craftscan_driver_info_v1"

namespace craftscan::drivers {

// One configured instance of a driver (e.g. one rig, one serial port). The
// devices it creates share its resources (the sim camera and turntable share
// one scene) and may outlive it. A driver kind it does not provide returns
// null with kUnsupported.
class DriverInstance {
 public:
  virtual ~DriverInstance() = default;
  virtual std::unique_ptr<StereoCamera> CreateCamera(DriverStatus* status) noexcept = 0;
  virtual std::unique_ptr<Turntable> CreateTurntable(DriverStatus* status) noexcept = 0;
};

}  // namespace craftscan::drivers

enum CraftscanDriverKind : std::uint32_t {
  kCraftscanDriverCamera = 1u << 0,
  kCraftscanDriverTurntable = 1u << 1,
};

using CraftscanDriverCreateFn =
    craftscan::drivers::DriverInstance* (*)(const craftscan::drivers::DriverConfig& config,
                                            const craftscan::drivers::HostServices& host,
                                            craftscan::drivers::DriverStatus* status) noexcept;

extern "C" {
struct CraftscanDriverInfo {
  std::uint32_t abi_version;  // CRAFTSCAN_DRIVER_ABI_VERSION; always the first member
  const char* name;           // "<name>" of craftscan-driver-<name>.so
  std::uint32_t kinds;        // CraftscanDriverKind flags
  const char* description;    // one line for listings
  CraftscanDriverCreateFn create;
};
using CraftscanDriverInfoFn = const CraftscanDriverInfo* (*)();
}

// Defines the exported entry point of a driver plugin (use once per .so).
#define CRAFTSCAN_DRIVER_PLUGIN(name, kinds, description, create_fn)                              \
  extern "C" __attribute__((visibility("default"))) const CraftscanDriverInfo*                    \
  craftscan_driver_info_v1() {                                                                    \
    static const CraftscanDriverInfo info{CRAFTSCAN_DRIVER_ABI_VERSION, name, kinds, description, \
                                          create_fn};                                             \
    return &info;                                                                                 \
  }
