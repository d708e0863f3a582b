// PluginLoader with real shared objects: the sim plugin is accepted; a wrong
// ABI version, a .so without the entry symbol, a text file named like a
// plugin and a missing plugin are refused with messages naming the file.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "craftscan/drivers/plugin_loader.h"
#include "fake_host.h"
#include "test_paths.h"

namespace craftscan::drivers {
namespace {

const std::string kPluginDir = ::craftscan::testing::PluginDir();
const std::string kBadDir = ::craftscan::testing::BadPluginDir();

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(PluginLoader, SplitsTheSearchPath) {
  PluginLoader loader(":/a::/b/c:");
  EXPECT_EQ(loader.directories(), (std::vector<std::string>{"/a", "/b/c"}));
}

TEST(PluginLoader, LoadsTheSimPluginAndCreatesDevices) {
  PluginLoader loader(kBadDir + ":" + kPluginDir);
  std::shared_ptr<const Plugin> plugin;
  DriverStatus status = loader.Load("sim", &plugin);
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(plugin->name(), "sim");
  EXPECT_EQ(plugin->kinds(), kCraftscanDriverCamera | kCraftscanDriverTurntable);
  EXPECT_FALSE(plugin->description().empty());
  EXPECT_TRUE(Contains(plugin->path(), "craftscan-driver-sim.so"));

  std::shared_ptr<const Plugin> again;
  ASSERT_TRUE(loader.Load("sim", &again).ok());
  EXPECT_EQ(again, plugin);

  test::FakeHost fake;
  std::unique_ptr<DriverInstance> instance;
  status = plugin->CreateInstance({{"image_size", "64x48"}}, fake.services(), &instance);
  ASSERT_TRUE(status.ok()) << status.ToString();
  auto camera = instance->CreateCamera(&status);
  ASSERT_TRUE(camera) << status.ToString();
  auto turntable = instance->CreateTurntable(&status);
  ASSERT_TRUE(turntable) << status.ToString();
  instance.reset();  // devices may outlive their instance
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  EXPECT_TRUE(camera->Open().ok());
  EXPECT_EQ(fake.event_kinds(), (std::vector<DeviceEvent>{DeviceEvent::kConnected}));
  EXPECT_EQ(turntable->Status().state, TurntableState::kClosed);
}

TEST(PluginLoader, FactoryRefusesABadConfigNamingTheKey) {
  PluginLoader loader(kPluginDir);
  std::shared_ptr<const Plugin> plugin;
  ASSERT_TRUE(loader.Load("sim", &plugin).ok());
  std::unique_ptr<DriverInstance> instance;
  DriverStatus status = plugin->CreateInstance({{"colour", "red"}}, {}, &instance);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(status.message, "'colour'")) << status.message;
  EXPECT_TRUE(Contains(status.message, "sim")) << status.message;
  EXPECT_FALSE(instance);
  status = plugin->CreateInstance({{"threads", "many"}}, {}, &instance);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(status.message, "threads")) << status.message;
}

TEST(PluginLoader, RefusesAWrongAbiVersion) {
  PluginLoader loader(kBadDir);
  std::shared_ptr<const Plugin> plugin;
  const DriverStatus status = loader.Load("badabi", &plugin);  // its factory would abort()
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_FALSE(plugin);
  EXPECT_TRUE(Contains(status.message, kBadDir + "/craftscan-driver-badabi.so")) << status.message;
  EXPECT_TRUE(Contains(status.message, "ABI version 99")) << status.message;
  EXPECT_TRUE(Contains(status.message, "needs 1")) << status.message;
}

TEST(PluginLoader, RefusesASharedObjectWithoutTheEntrySymbol) {
  PluginLoader loader(kBadDir);
  std::shared_ptr<const Plugin> plugin;
  const DriverStatus status = loader.Load("nosymbol", &plugin);
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_FALSE(plugin);
  EXPECT_TRUE(Contains(status.message, "craftscan-driver-nosymbol.so")) << status.message;
  EXPECT_TRUE(Contains(status.message, "does not export craftscan_driver_info_v1"))
      << status.message;
}

TEST(PluginLoader, RefusesATextFileNamedLikeAPlugin) {
  PluginLoader loader(kBadDir);
  std::shared_ptr<const Plugin> plugin;
  const DriverStatus status = loader.Load("text", &plugin);
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_FALSE(plugin);
  EXPECT_TRUE(Contains(status.message, "craftscan-driver-text.so")) << status.message;
  EXPECT_TRUE(Contains(status.message, "not a loadable shared object")) << status.message;
}

TEST(PluginLoader, ReportsAMissingPluginWithTheSearchPath) {
  PluginLoader loader(kPluginDir + ":" + kBadDir);
  std::shared_ptr<const Plugin> plugin;
  const DriverStatus status = loader.Load("nonesuch", &plugin);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(status.message, "craftscan-driver-nonesuch.so")) << status.message;
  EXPECT_TRUE(Contains(status.message, kBadDir)) << status.message;
}

TEST(PluginLoader, RefusesAPluginWhoseNameDoesNotMatchItsFile) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(::testing::TempDir()) / "craftscan_renamed_plugin";
  fs::remove_all(dir);
  fs::create_directories(dir);
  fs::copy_file(kPluginDir + "/craftscan-driver-sim.so", dir / "craftscan-driver-other.so");
  PluginLoader loader(dir.string());
  std::shared_ptr<const Plugin> plugin;
  const DriverStatus status = loader.Load("other", &plugin);
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_FALSE(plugin);
  EXPECT_TRUE(Contains(status.message, "declares the name 'sim'")) << status.message;
  fs::remove_all(dir);
}

TEST(PluginLoader, ListsAvailablePluginsWithoutLoading) {
  PluginLoader loader(kPluginDir + ":" + kBadDir);
  const std::vector<std::string> names = loader.Available();
  for (const char* name : {"sim", "badabi", "nosymbol", "text"}) {
    EXPECT_NE(std::find(names.begin(), names.end(), name), names.end()) << name;
  }
}

}  // namespace
}  // namespace craftscan::drivers
