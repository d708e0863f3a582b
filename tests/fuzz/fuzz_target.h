// Shared plumbing of the fuzz targets (tests/fuzz/fuzz_<name>.cc).
//
// Each target is written once, as
//
//   CRAFTSCAN_FUZZ_TARGET(ply) { ...; return 0; }
//
// which defines craftscan::fuzz::ply::TestOneInput(data, size) running the
// body. In a fuzzer
// build (CRAFTSCAN_FUZZER defined, linked with -fsanitize=fuzzer) it also
// defines libFuzzer's LLVMFuzzerTestOneInput; the replay test
// (test_fuzz_replay, normal builds) links every target and calls the
// TestOneInput functions on the checked-in corpus and regression inputs.
//
// A target's properties are checked with CRAFTSCAN_FUZZ_CHECK: a violation
// prints the condition and aborts, which libFuzzer reports as a crash (and
// saves the input) and which fails the replay test.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan::fuzz {

// Prints "fuzz check failed: <what> at <file>:<line>" and aborts.
[[noreturn]] void CheckFailed(const char* what, const char* file, int line);

// Checks a parser's outcome: a refusal must come with a message that names
// the problem and is not a failed allocation (std::bad_alloc, OpenCV's
// "Insufficient memory"): a small input must never make a parser ask for
// gigabytes (libFuzzer's malloc limit catches such requests directly;
// test_fuzz_replay limits the address space so that they fail and show
// here). With CRAFTSCAN_FUZZ_VERBOSE set in the environment, also prints
// "accepted" or the message to stderr, to see what an input exercises.
// (A message that only quotes the input, e.g. a keyword "bad_alloc" in a
// PLY header, is no failed allocation: markers found in the input are
// ignored.) Returns `accepted`.
bool Outcome(bool accepted, const std::string& error);

// Records the input being run, for Outcome (CRAFTSCAN_FUZZ_TARGET does this).
void SetCurrentInput(const std::uint8_t* data, std::size_t size);

// A file path for parsers that take one: `bytes` are written to
// <per-process temp folder>/<name> (replacing it) and its path returned. The
// folder (under /dev/shm when present, else $TMPDIR or /tmp) is made on
// first use and removed at normal exit. Aborts if the file cannot be written.
// Not thread-safe (fuzz targets run one input at a time).
std::string WriteTempFile(const std::string& name, std::string_view bytes);

// Consumes fuzz bytes as structured values. Every read succeeds: past the
// end, integers read as 0 and strings as empty, so any input decodes to
// something.
class FuzzInput {
 public:
  FuzzInput(const std::uint8_t* data, std::size_t size) : data_(data), size_(size) {}

  std::size_t remaining() const { return size_ - pos_; }

  // The next sizeof(T) bytes, little endian (missing bytes are 0).
  template <typename T>
  T Integral() {
    T value = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) {
      const T byte = pos_ < size_ ? static_cast<T>(data_[pos_++]) : T{0};
      value = static_cast<T>(value | static_cast<T>(byte << (8 * i)));
    }
    return value;
  }

  // One byte, reduced to 0..max.
  std::uint32_t Small(std::uint32_t max) { return Integral<std::uint8_t>() % (max + 1); }

  // A length byte (reduced to 0..max_bytes) and that many bytes.
  std::string String(std::size_t max_bytes) {
    std::size_t n = Small(static_cast<std::uint32_t>(max_bytes));
    if (n > remaining()) n = remaining();
    std::string text(reinterpret_cast<const char*>(data_ + pos_), n);
    pos_ += n;
    return text;
  }

  // All bytes left.
  std::vector<std::uint8_t> Rest() {
    std::vector<std::uint8_t> rest(data_ + pos_, data_ + size_);
    pos_ = size_;
    return rest;
  }

 private:
  const std::uint8_t* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
};

}  // namespace craftscan::fuzz

#define CRAFTSCAN_FUZZ_CHECK(condition)                                               \
  do {                                                                                \
    if (!(condition)) ::craftscan::fuzz::CheckFailed(#condition, __FILE__, __LINE__); \
  } while (false)

#ifdef CRAFTSCAN_FUZZER
#define CRAFTSCAN_FUZZ_ENTRY_(name)                                                   \
  extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) { \
    return ::craftscan::fuzz::name::TestOneInput(data, size);                         \
  }
#else
#define CRAFTSCAN_FUZZ_ENTRY_(name)
#endif

// Defines craftscan::fuzz::<name>::TestOneInput, which records the input
// (SetCurrentInput) and runs the body that follows the macro, and, in fuzzer
// builds, LLVMFuzzerTestOneInput calling it. The body returns 0.
#define CRAFTSCAN_FUZZ_TARGET(name)                              \
  namespace craftscan::fuzz::name {                              \
  int Body(const std::uint8_t* data, std::size_t size);          \
  int TestOneInput(const std::uint8_t* data, std::size_t size) { \
    ::craftscan::fuzz::SetCurrentInput(data, size);              \
    return Body(data, size);                                     \
  }                                                              \
  }                                                              \
  CRAFTSCAN_FUZZ_ENTRY_(name)                                    \
  int craftscan::fuzz::name::Body(const std::uint8_t* data, std::size_t size)
