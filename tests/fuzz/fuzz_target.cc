#include "fuzz_target.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <system_error>

namespace craftscan::fuzz {
namespace {

std::string_view current_input;  // fuzz targets run one input at a time

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

void SetCurrentInput(const std::uint8_t* data, std::size_t size) {
  current_input = std::string_view(reinterpret_cast<const char*>(data), size);
}

bool Outcome(bool accepted, const std::string& error) {
  static const bool verbose = std::getenv("CRAFTSCAN_FUZZ_VERBOSE") != nullptr;
  if (verbose) {
    std::fprintf(stderr, "%s%s\n",
                 accepted ? "accepted" : "refused: ", accepted ? "" : error.c_str());
  }
  if (accepted) return true;
  CRAFTSCAN_FUZZ_CHECK(!error.empty());
  for (const std::string_view marker : {"bad_alloc", "Insufficient memory"}) {
    if (error.find(marker) != std::string::npos &&
        current_input.find(marker) == std::string_view::npos) {
      CheckFailed("the error is not a failed allocation", __FILE__, __LINE__);
    }
  }
  return false;
}

std::string WriteTempFile(const std::string& name, std::string_view bytes) {
  static const TempFolder folder;
  const std::string path = folder.path() + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) CheckFailed("the temp file can be opened", __FILE__, __LINE__);
  const bool written = std::fwrite(bytes.data(), 1, bytes.size(), file) == bytes.size();
  if (std::fclose(file) != 0 || !written)
    CheckFailed("the temp file is written", __FILE__, __LINE__);
  return path;
}

}  // namespace craftscan::fuzz
