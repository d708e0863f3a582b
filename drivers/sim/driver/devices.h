// The sim driver's devices (implementation header of the plugin).
#pragma once

#include "craftscan/drivers/plugin.h"

namespace craftscan::sim {

// Factory of the sim driver plugin: parses the config (driver_options.h) and
// builds the shared scene. Null and *status set on a bad config.
drivers::DriverInstance* CreateSimInstance(const drivers::DriverConfig& config,
                                           const drivers::HostServices& host,
                                           drivers::DriverStatus* status) noexcept;

}  // namespace craftscan::sim
