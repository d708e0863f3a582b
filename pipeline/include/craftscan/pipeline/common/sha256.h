// SHA-256 (FIPS 180-4) for fixity: the session manifests' checksums, the
// file transfer's end-to-end check and BagIt manifests (RFC 8493). One
// implementation (OpenSSL's EVP) shared by the daemon and every client.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

// SHA-256 over data given in pieces. Not thread-safe (one per thread).
class Sha256Hasher {
 public:
  Sha256Hasher();
  ~Sha256Hasher();
  Sha256Hasher(Sha256Hasher&&) noexcept;
  Sha256Hasher& operator=(Sha256Hasher&&) noexcept;

  void Update(const void* data, std::size_t size);
  void Update(std::string_view bytes) { Update(bytes.data(), bytes.size()); }
  // The digest of everything given so far as 64 lower-case hex digits; the
  // hasher then starts over (empty input).
  std::string HexDigest();

 private:
  struct Impl;  // holds the OpenSSL context (no OpenSSL type in this header)
  std::unique_ptr<Impl> impl_;
};

// SHA-256 of `bytes` as 64 lower-case hex digits. Pure; thread-safe.
std::string Sha256Hex(std::string_view bytes);

// True iff `text` is exactly 64 lower-case hex digits (the form every
// craftscan manifest and BagIt's sha256sum-style manifests use).
bool IsSha256Hex(std::string_view text);

// SHA-256 and size of the file at `path`, read in 1 MiB blocks. A failed
// Status naming the path (kNotFound, kPermissionDenied, kIoError...) if it
// cannot be read. Thread-safe.
Status Sha256OfFile(const std::string& path, std::string* hex, std::uint64_t* size_bytes);

}  // namespace craftscan
