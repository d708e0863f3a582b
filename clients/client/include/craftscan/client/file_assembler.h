// Reassembles the session files a station streams in answer to `get` (the
// SessionFile chunks of craftscan.idl; protocol in the daemon's commands.h)
// into a folder: each file is written to a hidden temporary beside its final
// name as its chunks arrive (never held whole in memory), checked against
// the size and checksums the station's reply listed (SHA-256 where listed,
// and FNV-1a 64), then fsync'ed
// and renamed into place, so a file at its final name is always complete.
//
// No DDS here: StationClient::Fetch feeds it; tests feed it directly.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/pipeline/common/sha256.h"

namespace craftscan::client {

// FNV-1a 64 over data given in pieces (equal to the sessions' Fnv1a64 of the
// concatenation). Not thread-safe.
class Fnv1a64Hasher {
 public:
  void Update(const void* data, std::size_t size);
  std::uint64_t value() const { return hash_; }

 private:
  std::uint64_t hash_ = 14695981039346656037ull;
};

// "0123456789abcdef" (16 lower-case hex digits) → value; nullopt for anything else.
std::optional<std::uint64_t> ParseHex64(std::string_view text);
std::string Hex64(std::uint64_t value);  // 16 lower-case hex digits

// Whether `name` is safe to join to an output folder: 1..200 bytes of
// '/'-separated components of [A-Za-z0-9._-], none empty, none starting with
// '.' or '-' (so no "..", no hidden or absolute paths), at most 4 components.
// False with *why (may be null). Thread-safe.
bool IsSafeFileName(std::string_view name, std::string* why);

// One file the station announced in its reply.
struct ExpectedFile {
  std::string name;
  std::uint64_t size_bytes = 0;
  std::uint64_t fnv1a64 = 0;
  std::string sha256;  // 64 lower-case hex digits; empty: not listed (a station's old manifest)
};

// One chunk as received (views into the message; valid during Accept).
struct FileChunk {
  std::string_view name;
  std::uint32_t file_index = 0;
  std::uint32_t file_count = 0;
  std::uint64_t total_size = 0;  // bytes of the whole file
  std::uint64_t offset = 0;      // of data in the file
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
  bool last = false;
  std::string_view error;  // non-empty: the station could not send the file
};

// A file written to its final place.
struct FetchedFile {
  std::string name;  // as the station named it ("previews/a.png")
  std::string path;  // out_dir/name
  std::uint64_t size_bytes = 0;
  std::uint64_t fnv1a64 = 0;
  std::string sha256;  // of the bytes received (checked against the list where it had one)
};

// Not thread-safe: one thread feeds it.
class FileAssembler {
 public:
  // Files go under `out_dir` (created, with parents, when the first file
  // starts).
  explicit FileAssembler(std::string out_dir);
  // Removes the temporaries of files not finished (finished files stay).
  ~FileAssembler();
  FileAssembler(const FileAssembler&) = delete;
  FileAssembler& operator=(const FileAssembler&) = delete;

  // The station's list (from its reply). May come before or after the first
  // chunks. False with *error for an empty list, an unsafe or repeated name,
  // a sha256 that is not 64 lower-case hex digits, or a list that
  // contradicts chunks already taken; the assembler is then failed.
  bool SetExpected(std::vector<ExpectedFile> files, std::string* error);

  // Takes the next chunk of the transfer. Chunks must come in order: file 0
  // from offset 0, each next chunk at the offset where the previous ended,
  // the next file only after the previous one's last chunk. False with
  // *error — and the assembler failed for good — for an error chunk (the
  // station's reason), a gap or reordering (lost chunks), a chunk that
  // contradicts the expected list or itself (name, size, count, data past
  // total_size, last before the end), a file whose size or checksum differs
  // from the expected one, or an I/O error writing out_dir.
  bool Accept(const FileChunk& chunk, std::string* error);

  // The expected list is known and every file in it is in place.
  bool Complete() const;
  bool failed() const { return failed_; }
  // The failure was local: out_dir could not be created or written.
  bool failed_locally() const { return failed_locally_; }
  // Files in place so far, in transfer order.
  const std::vector<FetchedFile>& files() const { return done_; }
  std::uint64_t bytes_received() const { return bytes_received_; }
  std::uint64_t bytes_expected() const;  // sum of the expected sizes (0 before SetExpected)

 private:
  // A file received whole (temporary closed), waiting to be checked against
  // its expected record and renamed.
  struct Pending {
    std::uint32_t index = 0;
    std::string name, temp_path;
    std::uint64_t size_bytes = 0, fnv1a64 = 0;
    std::string sha256;
  };
  // Marks the assembler failed, removes temporaries, sets *error.
  bool Fail(std::string message, std::string* error);
  bool FailLocally(std::string message, std::string* error);
  bool StartFile(const FileChunk& chunk, std::string* error);
  bool FinishFile(std::string* error);
  // Verifies and renames finished files whose expected record is known.
  bool Settle(std::string* error);
  void CloseCurrent();

  std::string out_dir_;
  std::optional<std::vector<ExpectedFile>> expected_;
  std::uint32_t file_count_ = 0;  // from the chunks (0 until the first)
  // The file being received.
  int fd_ = -1;
  std::int64_t index_ = -1;  // its index; -1 before the first chunk
  std::string name_, temp_path_;
  std::uint64_t total_ = 0, offset_ = 0;
  bool current_finished_ = true;
  Fnv1a64Hasher hash_;
  Sha256Hasher sha256_;
  std::vector<Pending> pending_;
  std::vector<FetchedFile> done_;
  std::uint64_t bytes_received_ = 0;
  bool failed_ = false;
  bool failed_locally_ = false;
};

}  // namespace craftscan::client
