// BagIt 1.0 bags (RFC 8493) of a session's files, for archives that take
// fixity-checked packages. Shared by `craftscanctl get --bagit` and
// `craftscan-record --bagit`. A finished bag is
//
//   <bag>/bagit.txt               "BagIt-Version: 1.0\nTag-File-Character-Encoding: UTF-8\n"
//   <bag>/data/...                the payload
//   <bag>/bag-info.txt            Source-Organization, External-Identifier,
//                                 Bagging-Date (YYYY-MM-DD), Payload-Oxum (octets.count)
//   <bag>/manifest-sha256.txt     "<sha256>  data/<path>" for every payload file
//   <bag>/tagmanifest-sha256.txt  the same for the three tag files above
//
// in the `sha256sum -c` format (two spaces; paths with '/', '%', CR and LF
// percent-encoded as RFC 8493 §2.1.3 asks), sorted by path, LF line ends.
//
// Crash safety: the bag is built in a hidden staging folder beside <bag>
// (".<name>.bagit-XXXXXX", same file system); every file is fsync'ed and the
// staging folder is renamed to <bag> only once complete, so an interrupted
// run never leaves a half bag at <bag> (at most a hidden staging folder,
// removed by the BagWriter's destructor when it runs).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

struct BagInfo {
  std::string source_organization;  // bag-info.txt Source-Organization (required)
  std::string external_identifier;  // bag-info.txt External-Identifier: the session id (required)
  std::string bagging_date;         // YYYY-MM-DD; empty: today (UTC)

  // False with *why (may be null) for a missing field, a line break in one,
  // or a malformed date.
  bool IsValid(std::string* why) const;
};

// What a finished bag holds.
struct BagSummary {
  std::string path;                 // the bag folder
  std::uint64_t payload_bytes = 0;  // Payload-Oxum's octets
  std::uint64_t payload_files = 0;  // Payload-Oxum's count
};

// Ok if `dir` does not exist or is an empty folder; else a kAlreadyExists
// Status saying what is there (a bag never mixes with other files).
Status CheckBagTarget(const std::string& dir);

// Not thread-safe.
class BagWriter {
 public:
  // Checks that `bag_dir` does not exist or is an empty folder (else a
  // kAlreadyExists Status saying so: a bag never mixes with other files) and
  // creates the staging folder with its data/ beside it (parents of
  // `bag_dir` created). Null with *status set on failure.
  static std::unique_ptr<BagWriter> Start(const std::string& bag_dir, Status* status);
  // Removes the staging folder unless Finish succeeded.
  ~BagWriter();
  BagWriter(const BagWriter&) = delete;
  BagWriter& operator=(const BagWriter&) = delete;

  // Where the caller puts the payload (any tree of regular files; the caller
  // fsyncs them). Under the staging folder.
  const std::string& data_dir() const { return data_dir_; }

  // Copies the regular file `source` to data/<relative> (folders created)
  // and fsyncs it. `relative` is a '/'-separated path without "." or ".."
  // components. A failed Status naming the file on any error.
  Status AddFile(const std::string& source, const std::string& relative);

  // Hashes every regular file under data_dir() as it is on disk, checks it
  // against `expected_sha256` (payload path relative to data/ → hex) where
  // listed — a mismatch is a kCorrupt Status naming the file — writes the tag
  // files, fsyncs and renames the staging folder to the bag folder. A failed
  // Status (nothing at the bag folder) on any error, for an empty payload or
  // anything in data/ that is not a regular file or folder.
  Status Finish(const BagInfo& info, const std::map<std::string, std::string>& expected_sha256,
                BagSummary* summary);

 private:
  BagWriter(std::string bag_dir, std::string staging_dir);

  std::string bag_dir_, staging_dir_, data_dir_;
  bool finished_ = false;
};

}  // namespace craftscan
