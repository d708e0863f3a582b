// PluginLoader: finds driver plugins on a plugin path, loads them with
// dlopen, checks their ABI before creating anything, and creates driver
// instances.
//
//   PluginLoader loader("/usr/lib/craftscan/drivers:/opt/site/drivers");
//   std::shared_ptr<const Plugin> sim;
//   DriverStatus s = loader.Load("sim", &sim);   // craftscan-driver-sim.so
//   std::unique_ptr<DriverInstance> instance;
//   s = sim->CreateInstance({{"object", "egg"}}, host, &instance);
//   std::unique_ptr<StereoCamera> camera = instance->CreateCamera(&s);
//
// Refusals (each message names the file): a file that is not a loadable
// shared object, a missing `craftscan_driver_info_v1` symbol, a null info, an
// ABI version other than CRAFTSCAN_DRIVER_ABI_VERSION, a name that does not
// match the file name, a missing factory. Accepted modules stay loaded for
// the life of the process (RTLD_NODELETE), so devices may outlive the loader.
//
// Thread safety: a PluginLoader is not thread-safe; Plugin is immutable and
// CreateInstance may be called from any thread.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/drivers/plugin.h"

namespace craftscan::drivers {

// A loaded, ABI-checked driver module.
class Plugin {
 public:
  const std::string& name() const { return name_; }
  const std::string& description() const { return description_; }
  const std::string& path() const { return path_; }
  std::uint32_t kinds() const { return kinds_; }  // CraftscanDriverKind flags

  // Creates a driver instance; on failure *instance stays null and the status
  // (from the driver, prefixed with the driver's name) says why.
  DriverStatus CreateInstance(const DriverConfig& config, const HostServices& host,
                              std::unique_ptr<DriverInstance>* instance) const;

 private:
  friend class PluginLoader;
  std::string name_, description_, path_;
  std::uint32_t kinds_ = 0;
  CraftscanDriverCreateFn create_ = nullptr;
};

class PluginLoader {
 public:
  // search_path: directories separated by ':' (empty entries ignored),
  // searched in order.
  explicit PluginLoader(std::string_view search_path);

  const std::vector<std::string>& directories() const { return directories_; }

  // Loads craftscan-driver-<name>.so from the first directory that has it.
  // kInvalidArgument if none has it (the message lists the path), kIoError
  // for a file that is not a valid plugin. Loading a name twice returns the
  // same Plugin.
  DriverStatus Load(std::string_view name, std::shared_ptr<const Plugin>* plugin);
  // Loads one file (any name) and checks it.
  DriverStatus LoadFile(const std::string& path, std::shared_ptr<const Plugin>* plugin);
  // Names of the plugins on the path (files craftscan-driver-*.so), sorted,
  // without loading them.
  std::vector<std::string> Available() const;

 private:
  std::vector<std::string> directories_;
  std::vector<std::shared_ptr<const Plugin>> loaded_;
};

}  // namespace craftscan::drivers
