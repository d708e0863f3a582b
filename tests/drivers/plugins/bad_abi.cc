// A test plugin declaring an ABI version this host does not speak; its
// factory must never be called.
#include <cstdlib>

#include "craftscan/drivers/plugin.h"

namespace {
craftscan::drivers::DriverInstance* Create(const craftscan::drivers::DriverConfig&,
                                           const craftscan::drivers::HostServices&,
                                           craftscan::drivers::DriverStatus*) noexcept {
  std::abort();  // the loader must refuse the module before creating anything
}
}  // namespace

extern "C" __attribute__((visibility("default"))) const CraftscanDriverInfo*
craftscan_driver_info_v1() {
  static const CraftscanDriverInfo info{CRAFTSCAN_DRIVER_ABI_VERSION + 98, "badabi",
                                        kCraftscanDriverCamera, "wrong ABI version", Create};
  return &info;
}
