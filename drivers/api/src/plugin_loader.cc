// dlopen-based driver plugin loading with ABI checks before any creation.
#include "craftscan/drivers/plugin_loader.h"

#include <dlfcn.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <system_error>
#include <utility>

namespace craftscan::drivers {
namespace {

namespace fs = std::filesystem;
constexpr std::string_view kPrefix = "craftscan-driver-";
constexpr std::string_view kSuffix = ".so";

std::string FileNameFor(std::string_view name) {
  return std::string(kPrefix) + std::string(name) + std::string(kSuffix);
}

DriverStatus Refuse(const std::string& path, const std::string& why) {
  return DriverStatus::Error(StatusCode::kIoError, "driver plugin " + path + ": " + why);
}

std::string DlError() {
  const char* error = dlerror();
  return error ? error : "unknown dlopen error";
}

}  // namespace

DriverStatus Plugin::CreateInstance(const DriverConfig& config, const HostServices& host,
                                    std::unique_ptr<DriverInstance>* instance) const {
  instance->reset();
  DriverStatus status;
  DriverInstance* created = create_(config, host, &status);
  if (!created) {
    if (status.ok()) {
      status = DriverStatus::Error(StatusCode::kFault, "factory returned no instance");
    }
    status.message = name_ + ": " + status.message;
    return status;
  }
  instance->reset(created);
  return DriverStatus::Ok();
}

PluginLoader::PluginLoader(std::string_view search_path) {
  std::size_t start = 0;
  while (start <= search_path.size()) {
    std::size_t end = search_path.find(':', start);
    if (end == std::string_view::npos) end = search_path.size();
    if (end > start) directories_.emplace_back(search_path.substr(start, end - start));
    start = end + 1;
  }
}

DriverStatus PluginLoader::Load(std::string_view name, std::shared_ptr<const Plugin>* plugin) {
  plugin->reset();
  for (const auto& loaded : loaded_) {
    if (loaded->name() == name) {
      *plugin = loaded;
      return DriverStatus::Ok();
    }
  }
  const std::string file = FileNameFor(name);
  for (const std::string& dir : directories_) {
    const fs::path path = fs::path(dir) / file;
    std::error_code error;
    if (fs::is_regular_file(path, error)) return LoadFile(path.string(), plugin);
  }
  std::string searched;
  for (const std::string& dir : directories_) searched += (searched.empty() ? "" : ":") + dir;
  return DriverStatus::Error(StatusCode::kInvalidArgument,
                             "no driver plugin " + file + " on the plugin path '" + searched + "'");
}

DriverStatus PluginLoader::LoadFile(const std::string& path,
                                    std::shared_ptr<const Plugin>* plugin) {
  plugin->reset();
  dlerror();  // clear
  // RTLD_LOCAL: a plugin's symbols never satisfy another plugin's references.
  void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!handle) return Refuse(path, "not a loadable shared object: " + DlError());
  auto close = [&] { dlclose(handle); };

  dlerror();
  void* symbol = dlsym(handle, CRAFTSCAN_DRIVER_INFO_SYMBOL);
  if (!symbol) {
    const std::string error = DlError();
    close();
    return Refuse(path, "does not export " + std::string(CRAFTSCAN_DRIVER_INFO_SYMBOL) +
                            " (not a craftscan driver): " + error);
  }
  const auto info_fn = reinterpret_cast<CraftscanDriverInfoFn>(symbol);
  const CraftscanDriverInfo* info = info_fn();
  if (!info) {
    close();
    return Refuse(path, std::string(CRAFTSCAN_DRIVER_INFO_SYMBOL) + " returned null");
  }
  // The version is checked before any other member is read.
  if (info->abi_version != CRAFTSCAN_DRIVER_ABI_VERSION) {
    const std::string message = "driver ABI version " + std::to_string(info->abi_version) +
                                ", this host needs " +
                                std::to_string(CRAFTSCAN_DRIVER_ABI_VERSION) + "; rebuild it";
    close();
    return Refuse(path, message);
  }
  if (!info->name || !info->create) {
    close();
    return Refuse(path, "info has no name or no factory");
  }
  const std::string name = info->name;
  const std::string file_name = fs::path(path).filename().string();
  if (file_name.starts_with(kPrefix) && file_name != FileNameFor(name)) {
    close();
    return Refuse(path, "declares the name '" + name + "', expected " + file_name);
  }
  for (const auto& loaded : loaded_) {
    if (loaded->name() == name) {
      close();
      if (fs::path(loaded->path()) == fs::path(path)) {
        *plugin = loaded;
        return DriverStatus::Ok();
      }
      return Refuse(path, "driver '" + name + "' is already loaded from " + loaded->path());
    }
  }
  // Accepted: pin the module so devices created from it may outlive the loader.
  if (void* pinned = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_NOLOAD | RTLD_NODELETE)) {
    dlclose(pinned);
  }
  auto loaded = std::make_shared<Plugin>();
  loaded->name_ = name;
  loaded->description_ = info->description ? info->description : "";
  loaded->path_ = path;
  loaded->kinds_ = info->kinds;
  loaded->create_ = info->create;
  loaded_.push_back(loaded);
  *plugin = loaded;
  return DriverStatus::Ok();
}

std::vector<std::string> PluginLoader::Available() const {
  std::vector<std::string> names;
  for (const std::string& dir : directories_) {
    std::error_code error;
    for (const auto& entry : fs::directory_iterator(dir, error)) {
      const std::string file = entry.path().filename().string();
      if (file.size() > kPrefix.size() + kSuffix.size() && file.starts_with(kPrefix) &&
          file.ends_with(kSuffix)) {
        names.push_back(file.substr(kPrefix.size(), file.size() - kPrefix.size() - kSuffix.size()));
      }
    }
  }
  std::sort(names.begin(), names.end());
  names.erase(std::unique(names.begin(), names.end()), names.end());
  return names;
}

}  // namespace craftscan::drivers
