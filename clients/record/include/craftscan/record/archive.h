// The on-disk archive craftscan-record writes: captures as PNG, clouds as
// PLY, disparity maps as PFM, one folder per station and session, with an
// index and an optional size/count limit (stop, or rotate out the oldest).
//
//   <out>/<station>/<session>/view_NNN_left.png, view_NNN_right.png
//                             cloud_NNN.ply, fused.ply, disparity_NNN.pfm
//                             mesh.glb (the station's model, --what models)
//                             index.jsonl   one JSON object per data file
//   <out>/.lock                             held (flock) while a recorder writes
//   <out>/.staging/                         files being written (emptied on open)
//
// NNN is the view index, at least 3 digits. Every file reaches its folder
// complete: it is written and fsync'ed in .staging, then renamed in (same
// file system) and the folder fsync'ed; index.jsonl is replaced the same way.
// A kill at any moment leaves only whole files in the session folders (the
// index may then lack the item that was being stored; its files still count).
//
// An index line: {"time": recording time, UTC ISO 8601; "station";
// "session": the folder name; "session_raw": as received, if different;
// "view": −1 for fused; "kind": left|right|cloud|fused|disparity; "file";
// "bytes"; "stamp_ns": the sample's stamp} plus, for images, "angle_deg",
// "width", "height", "encoding"; for clouds "points", "has_colors",
// "has_normals", "world_from_view" (16 numbers, row-major, mm); for
// disparity maps "width", "height".
//
// Names received from the network (session, station) pass SanitizeWireName
// before they become folder names, so they cannot leave <out>.
//
// Limits count the data files (PNG, PLY, PFM) in the archive, including those
// recorded by earlier runs (found when the archive is opened); index.jsonl
// files (~200 bytes per data file) are not counted. An item (a capture's two
// images, a cloud, a disparity map) is stored whole or not at all. Rotation
// deletes the oldest data files of the whole archive (any station or
// session; earlier runs' files by modification time, then in recording
// order) and removes session folders it empties. An item that arrives again
// (same station, session, view and kind) replaces its files.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core/mat.hpp>
#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/bagit.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan::record {

// Parses a byte count "N", "NK", "NM" or "NG" (binary multiples: K = 1024;
// suffix case-insensitive, an optional trailing "B"/"iB" accepted, e.g.
// "512M", "2GiB"). N is a whole number ≥ 1. False with *why (may be null)
// for anything else or an overflow. Pure; thread-safe.
bool ParseByteSize(std::string_view text, uint64_t* bytes, std::string* why);

// Turns a name received from the network into a folder name that stays where
// it is joined: every byte outside [A-Za-z0-9._-] becomes '_'. Refused
// (false, *why says why; *safe untouched) when the name is empty, longer than
// 200 bytes, starts with '.' (hidden, ".", "..") or contains "..". `safe` must
// not be null; why may be. Pure; thread-safe.
bool SanitizeWireName(std::string_view raw, std::string* safe, std::string* why);

// `raw` made safe to print in one log line: non-printable bytes as \xNN,
// quotes and backslashes escaped, cut to 80 bytes with "..." appended. Pure.
std::string PrintableForLog(std::string_view raw);

// What happens when storing an item would exceed a limit.
enum class LimitPolicy {
  kStop,    // refuse the item (nothing written) and report the archive full
  kRotate,  // delete the oldest recorded files until the item fits
};

struct ArchiveOptions {
  std::string out_dir;     // the archive's root; created if missing
  uint64_t max_bytes = 0;  // bytes of data files; 0 = no limit
  uint64_t max_files = 0;  // number of data files; 0 = no limit
  LimitPolicy on_limit = LimitPolicy::kStop;

  // False with *why (may be null) for an empty out_dir.
  bool IsValid(std::string* why) const;
};

// A received item's identity.
struct ItemInfo {
  std::string station;     // station id (as in the topic name)
  std::string session;     // as received; sanitised by the archive
  int32_t view_index = 0;  // ≥ 0; −1 only for a fused cloud
  int64_t stamp_ns = 0;    // the sample's own time stamp (wall clock, ns)
};

enum class StoreStatus {
  kStored,        // all files of the item are in the archive
  kRefused,       // bad name, view index or data: nothing written
  kLimitReached,  // kStop policy: the item would exceed a limit; nothing
                  // written, and every later Store returns this too
  kTooLarge,      // kRotate policy: the item alone exceeds a limit; skipped
  kFailed,        // I/O error (disk full, permissions): nothing written
};
std::string_view ToString(StoreStatus status);  // "stored", "refused", ...

struct StoreResult {
  StoreStatus status = StoreStatus::kFailed;
  std::string message;         // why, for anything but kStored
  uint64_t files = 0;          // data files stored (2 for a capture)
  uint64_t bytes = 0;          // their bytes
  uint64_t rotated_files = 0;  // oldest files deleted to make room
  uint64_t rotated_bytes = 0;
};

// What the archive holds now (data files only).
struct ArchiveTotals {
  uint64_t files = 0;
  uint64_t bytes = 0;
};

// The archive of one --out folder. Thread-safe: the Store* functions may run
// concurrently (encoding and writing happen in parallel; the commit into the
// archive is serialised).
class Archive {
 public:
  // Creates out_dir if needed, takes its lock (fails if another process
  // holds it), empties .staging and indexes the data files already there
  // (oldest first by modification time, for rotation). Null with *error
  // (may be null) for invalid options, an unwritable folder or a held lock.
  static std::unique_ptr<Archive> Open(const ArchiveOptions& options, std::string* error);
  ~Archive();  // releases the lock, removes .staging
  Archive(const Archive&) = delete;
  Archive& operator=(const Archive&) = delete;

  // A stereo pair as view_NNN_left.png / view_NNN_right.png (lossless; 8-bit
  // grey for CV_8UC1, colour for CV_8UC3 given in BGR order as OpenCV
  // keeps it). Both images non-empty, same size and type, CV_8UC1 or CV_8UC3,
  // else kRefused. `angle_deg` goes to the index.
  StoreResult StoreCapture(const ItemInfo& item, const cv::Mat& left, const cv::Mat& right,
                           double angle_deg);

  // A cloud as binary little-endian PLY (WritePly: float x y z in mm, normals
  // and colours when present): cloud_NNN.ply, or fused.ply for view −1. The
  // cloud must pass IsValid. `world_from_view` (4×4, mm) goes to the index.
  StoreResult StoreCloud(const ItemInfo& item, const PointCloud& cloud,
                         const cv::Matx44d& world_from_view);

  // A CV_32FC1 disparity map (NaN = invalid, kept) as disparity_NNN.pfm;
  // sides 1..32768 px, else kRefused.
  StoreResult StoreDisparity(const ItemInfo& item, const cv::Mat& disparity);

  // A session's model as the station stored it (its mesh.glb, fetched with
  // `get`), byte for byte, as mesh.glb (index kind "model"). Empty bytes or
  // a view index other than −1: kRefused.
  StoreResult StoreModel(const ItemInfo& item, const std::string& glb);

  ArchiveTotals totals() const;
  const ArchiveOptions& options() const;

  // Writes every session folder this Archive stored an item in (this run
  // only; folders rotation emptied are skipped) as a BagIt 1.0 bag (RFC
  // 8493, pipeline/common/bagit.h) at <bag_root>/<station>/<session>: its
  // data files and index.jsonl copied under data/, External-Identifier =
  // the session folder name, Source-Organization = `source_organization`.
  // `bag_root` must be missing or an empty folder. Call once recording has
  // stopped. Stops at the first failure (bags finished before it stay);
  // *bags lists the finished ones.
  Status WriteBags(const std::string& bag_root, const std::string& source_organization,
                   std::vector<BagSummary>* bags) const;

  struct State;  // implementation (archive.cc)

 private:
  explicit Archive(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

}  // namespace craftscan::record
