#include "craftscan/pipeline/common/pfm.h"

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/status.h"

#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <fstream>
#include <sstream>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace craftscan {
namespace {

// Per side; far above any stereo image we handle, low enough that width ×
// height × 3 × 4 bytes cannot overflow and a corrupt header cannot ask for
// tens of gigabytes.
constexpr int kMaxPfmSide = 1 << 15;
// A header token longer than this is garbage, not a number.
constexpr std::size_t kMaxTokenLength = 64;

std::uint32_t ByteSwap32(std::uint32_t v) {
  return ((v & 0x000000FFu) << 24) | ((v & 0x0000FF00u) << 8) | ((v & 0x00FF0000u) >> 8) |
         ((v & 0xFF000000u) >> 24);
}

void ByteSwapFloats(float* data, std::size_t count) {
  for (std::size_t i = 0; i < count; ++i) {
    std::uint32_t bits;
    std::memcpy(&bits, &data[i], sizeof(bits));
    bits = ByteSwap32(bits);
    std::memcpy(&data[i], &bits, sizeof(bits));
  }
}

// Reads one whitespace-delimited header token. On success the single
// whitespace byte that ends the token has been consumed too, so after the
// scale token the stream is at the first data byte.
bool ReadToken(std::istream& in, std::string* token) {
  token->clear();
  int c = in.get();
  while (c != EOF && std::isspace(c)) c = in.get();
  while (c != EOF && !std::isspace(c)) {
    if (token->size() >= kMaxTokenLength) return false;
    token->push_back(static_cast<char>(c));
    c = in.get();
  }
  return !token->empty() && c != EOF;
}

bool ParseInt(const std::string& text, long* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  *value = std::strtol(text.c_str(), &end, 10);
  return errno == 0 && end == text.c_str() + text.size();
}

bool ParseDouble(const std::string& text, double* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  *value = std::strtod(text.c_str(), &end);
  return errno == 0 && end == text.c_str() + text.size() && std::isfinite(*value);
}

bool ReadPfmImpl(const std::string& path, cv::Mat* image, std::string* error) {
  const std::string where = "PFM '" + path + "': ";
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(error, where + "cannot open file (missing or unreadable)");

  std::string magic;
  if (!ReadToken(in, &magic) || (magic != "Pf" && magic != "PF")) {
    return Fail(error, where + "bad magic (expected 'Pf' or 'PF')");
  }
  const int channels = magic == "PF" ? 3 : 1;

  std::string width_text, height_text, scale_text;
  long width = 0, height = 0;
  if (!ReadToken(in, &width_text) || !ReadToken(in, &height_text) ||
      !ParseInt(width_text, &width) || !ParseInt(height_text, &height)) {
    return Fail(error, where + "malformed width/height in header");
  }
  if (width <= 0 || height <= 0 || width > kMaxPfmSide || height > kMaxPfmSide) {
    return Fail(error, where + "bad dimensions " + width_text + "x" + height_text +
                           " (each side must be in 1.." + std::to_string(kMaxPfmSide) + ")");
  }
  double scale = 0;
  if (!ReadToken(in, &scale_text) || !ParseDouble(scale_text, &scale) || scale == 0) {
    return Fail(error, where + "malformed scale in header (need a finite non-zero number)");
  }
  const bool file_little_endian = scale < 0;

  const std::size_t row_floats = static_cast<std::size_t>(width) * channels;
  const std::size_t total_floats = row_floats * static_cast<std::size_t>(height);
  // Check the size before allocating: a 30-byte file claiming 32768 × 32768
  // × 3 would otherwise ask for 12 GiB first (found by tests/fuzz).
  const std::uint64_t needed = total_floats * sizeof(float);
  const std::streampos data_start = in.tellg();
  if (data_start != std::streampos(-1)) {
    in.seekg(0, std::ios::end);
    const std::streampos end = in.tellg();
    in.clear();
    in.seekg(data_start);
    if (end != std::streampos(-1) && end - data_start < static_cast<std::streamoff>(needed)) {
      return Fail(error, where + "truncated data: expected " + std::to_string(needed) +
                             " bytes, found " + std::to_string(end - data_start));
    }
  }
  std::vector<float> data(total_floats);
  in.read(reinterpret_cast<char*>(data.data()),
          static_cast<std::streamsize>(total_floats * sizeof(float)));
  if (static_cast<std::size_t>(in.gcount()) != total_floats * sizeof(float)) {
    return Fail(error, where + "truncated data: expected " +
                           std::to_string(total_floats * sizeof(float)) + " bytes, found " +
                           std::to_string(in.gcount()));
  }
  const bool host_little_endian = std::endian::native == std::endian::little;
  if (file_little_endian != host_little_endian) ByteSwapFloats(data.data(), total_floats);

  // Rows are stored bottom-to-top; colour is stored RGB, OpenCV's order is BGR.
  cv::Mat out(static_cast<int>(height), static_cast<int>(width), CV_MAKETYPE(CV_32F, channels));
  for (int y = 0; y < out.rows; ++y) {
    const float* src = data.data() + static_cast<std::size_t>(out.rows - 1 - y) * row_floats;
    std::memcpy(out.ptr<float>(y), src, row_floats * sizeof(float));
  }
  if (channels == 3) cv::cvtColor(out, out, cv::COLOR_RGB2BGR);
  *image = std::move(out);
  return true;
}

// `where` starts each message ("PFM '<path>': " or "PFM: ").
bool EncodePfmImpl(const cv::Mat& image, const std::string& where, std::string* bytes,
                   std::string* error) {
  if (image.empty()) return Fail(error, where + "cannot write an empty image");
  if (image.type() != CV_32FC1 && image.type() != CV_32FC3) {
    return Fail(error, where + "image must be CV_32FC1 or CV_32FC3");
  }
  if (image.cols > kMaxPfmSide || image.rows > kMaxPfmSide) {
    return Fail(error, where + "image too large for PFM I/O");
  }
  cv::Mat rgb;  // must not share the caller's buffer: cvtColor would write into it
  if (image.channels() == 3) {
    cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
  } else {
    rgb = image;
  }

  std::ostringstream out(std::ios::binary);
  out << (rgb.channels() == 3 ? "PF" : "Pf") << '\n'
      << rgb.cols << ' ' << rgb.rows << '\n'
      << "-1.0\n";  // negative scale = little endian
  const std::size_t row_floats = static_cast<std::size_t>(rgb.cols) * rgb.channels();
  std::vector<float> row(row_floats);
  const bool host_little_endian = std::endian::native == std::endian::little;
  for (int y = rgb.rows - 1; y >= 0; --y) {
    std::memcpy(row.data(), rgb.ptr<float>(y), row_floats * sizeof(float));
    if (!host_little_endian) ByteSwapFloats(row.data(), row_floats);
    out.write(reinterpret_cast<const char*>(row.data()),
              static_cast<std::streamsize>(row_floats * sizeof(float)));
  }
  *bytes = std::move(out).str();
  return true;
}

bool WritePfmImpl(const std::string& path, const cv::Mat& image, std::string* error) {
  std::string bytes;
  if (!EncodePfmImpl(image, "PFM '" + path + "': ", &bytes, error)) return false;
  const Status status = WriteFileAtomically(path, bytes);
  if (!status.ok()) return Fail(error, "PFM " + status.message());
  return true;
}

}  // namespace

bool ReadPfm(const std::string& path, cv::Mat* image, std::string* error) {
  if (image == nullptr) return Fail(error, "ReadPfm: image is null");
  try {
    return ReadPfmImpl(path, image, error);
  } catch (const std::exception& e) {  // bad_alloc, cv::Exception: report, never throw
    return Fail(error, "PFM '" + path + "': " + e.what());
  }
}

bool EncodePfm(const cv::Mat& image, std::string* bytes, std::string* error) {
  if (bytes == nullptr) return Fail(error, "EncodePfm: bytes is null");
  bytes->clear();
  try {
    return EncodePfmImpl(image, "PFM: ", bytes, error);
  } catch (const std::exception& e) {
    bytes->clear();
    return Fail(error, std::string("PFM: ") + e.what());
  }
}

bool WritePfm(const std::string& path, const cv::Mat& image, std::string* error) {
  try {
    return WritePfmImpl(path, image, error);
  } catch (const std::exception& e) {
    return Fail(error, "PFM '" + path + "': " + e.what());
  }
}

}  // namespace craftscan
