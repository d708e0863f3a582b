// Replays every checked-in fuzz input (tests/fuzz/corpus/<target>/ and
// tests/fuzz/regression/<target>/) through the fuzz targets' entry
// functions, built without libFuzzer: the crashes the fuzzers once found stay
// regression tests in the normal (gcc) test suite. A crash or a broken
// property aborts the test process, which fails the target's test; the
// input's path is printed before it runs.
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <ostream>
#include <set>
#include <string>
#include <vector>
#include "test_paths.h"

#define CRAFTSCAN_DECLARE_FUZZ_TARGET(name)                     \
  namespace craftscan::fuzz::name {                             \
  int TestOneInput(const std::uint8_t* data, std::size_t size); \
  }
CRAFTSCAN_DECLARE_FUZZ_TARGET(ply)
CRAFTSCAN_DECLARE_FUZZ_TARGET(pfm)
CRAFTSCAN_DECLARE_FUZZ_TARGET(calibration)
CRAFTSCAN_DECLARE_FUZZ_TARGET(config)
CRAFTSCAN_DECLARE_FUZZ_TARGET(auth)
CRAFTSCAN_DECLARE_FUZZ_TARGET(grbl)
CRAFTSCAN_DECLARE_FUZZ_TARGET(commands)
CRAFTSCAN_DECLARE_FUZZ_TARGET(manifest)
CRAFTSCAN_DECLARE_FUZZ_TARGET(dds_convert)
#undef CRAFTSCAN_DECLARE_FUZZ_TARGET

// A parser must not ask for gigabytes on a small input. libFuzzer catches
// such requests with its malloc limit; here the process's address space is
// limited instead, so they fail (and the targets check that no error reports
// a failed allocation). Sanitizer runtimes reserve terabytes of address space
// and cannot run under such a limit: ASan gets a largest-allocation limit
// instead, TSan none.
#if defined(__SANITIZE_ADDRESS__)
#define CRAFTSCAN_REPLAY_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define CRAFTSCAN_REPLAY_ASAN 1
#endif
#endif
#if defined(__SANITIZE_THREAD__)
#define CRAFTSCAN_REPLAY_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define CRAFTSCAN_REPLAY_TSAN 1
#endif
#endif

#if defined(CRAFTSCAN_REPLAY_ASAN)
extern "C" const char* __asan_default_options() {
  return "allocator_may_return_null=1:max_allocation_size_mb=2048";
}
#endif

namespace {

namespace fs = std::filesystem;

// Far above what the test needs (a few hundred MB of mappings), far below
// the gigabytes a bad size field asks for.
constexpr rlim_t kAddressSpaceLimitBytes = rlim_t{6} << 30;

#if !defined(CRAFTSCAN_REPLAY_ASAN) && !defined(CRAFTSCAN_REPLAY_TSAN)
const bool kAddressSpaceLimited = [] {
  rlimit limit{};
  if (getrlimit(RLIMIT_AS, &limit) != 0) return false;
  if (limit.rlim_cur != RLIM_INFINITY && limit.rlim_cur <= kAddressSpaceLimitBytes) return true;
  limit.rlim_cur = kAddressSpaceLimitBytes;
  return setrlimit(RLIMIT_AS, &limit) == 0;
}();
#endif

struct Target {
  const char* name;
  int (*run)(const std::uint8_t* data, std::size_t size);
};

const std::vector<Target>& Targets() {
  static const std::vector<Target> targets = {
      {"ply", craftscan::fuzz::ply::TestOneInput},
      {"pfm", craftscan::fuzz::pfm::TestOneInput},
      {"calibration", craftscan::fuzz::calibration::TestOneInput},
      {"config", craftscan::fuzz::config::TestOneInput},
      {"auth", craftscan::fuzz::auth::TestOneInput},
      {"grbl", craftscan::fuzz::grbl::TestOneInput},
      {"commands", craftscan::fuzz::commands::TestOneInput},
      {"manifest", craftscan::fuzz::manifest::TestOneInput},
      {"dds_convert", craftscan::fuzz::dds_convert::TestOneInput},
  };
  return targets;
}

// The files in `folder`, sorted; none if it does not exist.
std::vector<fs::path> Inputs(const fs::path& folder) {
  std::vector<fs::path> files;
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return files;
  for (const fs::directory_entry& entry : fs::directory_iterator(folder)) {
    if (entry.is_regular_file()) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Runs every input of `folder` through `target`; returns how many ran.
std::size_t Replay(const Target& target, const fs::path& folder) {
  std::size_t count = 0;
  for (const fs::path& input : Inputs(folder)) {
    const std::string bytes = ReadAll(input);
    std::fprintf(stderr, "replaying %s (%zu bytes)\n", input.c_str(), bytes.size());
    const int rc = target.run(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
    EXPECT_EQ(rc, 0) << input;
    ++count;
  }
  return count;
}

void PrintTo(const Target& target, std::ostream* out) { *out << target.name; }

class FuzzReplay : public testing::TestWithParam<Target> {};

TEST_P(FuzzReplay, CorpusAndRegressionInputsPass) {
  const fs::path root = ::craftscan::testing::FuzzDir();
  const std::size_t seeds = Replay(GetParam(), root / "corpus" / GetParam().name);
  EXPECT_GE(seeds, 3u) << "corpus/" << GetParam().name << " needs seed inputs";
  Replay(GetParam(), root / "regression" / GetParam().name);
}

INSTANTIATE_TEST_SUITE_P(Targets, FuzzReplay, testing::ValuesIn(Targets()),
                         [](const testing::TestParamInfo<Target>& info) {
                           return std::string(info.param.name);
                         });

// The memory limit is in place, and every folder under corpus/ and
// regression/ belongs to a target (a typo in a folder name would otherwise
// silently skip its inputs).
TEST(FuzzReplaySetup, MemoryLimitedAndEveryInputFolderNamesATarget) {
#if !defined(CRAFTSCAN_REPLAY_ASAN) && !defined(CRAFTSCAN_REPLAY_TSAN)
  EXPECT_TRUE(kAddressSpaceLimited) << "cannot limit the address space (RLIMIT_AS)";
#endif
  std::set<std::string> names;
  for (const Target& target : Targets()) names.insert(target.name);
  const fs::path root = ::craftscan::testing::FuzzDir();
  for (const char* kind : {"corpus", "regression"}) {
    for (const fs::directory_entry& entry : fs::directory_iterator(root / kind)) {
      EXPECT_TRUE(entry.is_directory() && names.count(entry.path().filename().string()) == 1)
          << entry.path() << " is not a fuzz target's folder";
    }
  }
}

}  // namespace
