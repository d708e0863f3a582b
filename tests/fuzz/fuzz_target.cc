#include "fuzz_target.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <system_error>

namespace craftscan::fuzz {
namespace {

// The per-process temp folder; removed when the process exits normally.
class TempFolder {
 public:
  TempFolder() {
    namespace fs = std::filesystem;
    std::error_code ec;
    std::string base = "/dev/shm";
    if (!fs::is_directory(base, ec)) {
      const char* tmpdir = std::getenv("TMPDIR");
      base = tmpdir != nullptr && *tmpdir != '\0' ? tmpdir : "/tmp";
    }
    std::string pattern = base + "/craftscan-fuzz-XXXXXX";
    if (mkdtemp(pattern.data()) == nullptr) {
      std::fprintf(stderr, "fuzz: cannot make a temp folder under %s\n", base.c_str());
      std::abort();
    }
    path_ = pattern;
  }
  ~TempFolder() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempFolder(const TempFolder&) = delete;
  TempFolder& operator=(const TempFolder&) = delete;

  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

}  // namespace

void CheckFailed(const char* what, const char* file, int line) {
  std::fprintf(stderr, "fuzz check failed: %s at %s:%d\n", what, file, line);
  std::fflush(stderr);
  std::abort();
}

bool IsOutOfMemoryMessage(const std::string& error) {
  return error.find("bad_alloc") != std::string::npos ||
         error.find("Insufficient memory") != std::string::npos;
}

void Report(bool accepted, const std::string& error) {
  static const bool verbose = std::getenv("CRAFTSCAN_FUZZ_VERBOSE") != nullptr;
  if (!verbose) return;
  if (accepted) {
    std::fprintf(stderr, "accepted\n");
  } else {
    std::fprintf(stderr, "refused: %s\n", error.c_str());
  }
}

std::string WriteTempFile(const std::string& name, std::string_view bytes) {
  static const TempFolder folder;
  const std::string path = folder.path() + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) CheckFailed("the temp file can be opened", __FILE__, __LINE__);
  const bool written = std::fwrite(bytes.data(), 1, bytes.size(), file) == bytes.size();
  if (std::fclose(file) != 0 || !written) CheckFailed("the temp file is written", __FILE__, __LINE__);
  return path;
}

}  // namespace craftscan::fuzz
