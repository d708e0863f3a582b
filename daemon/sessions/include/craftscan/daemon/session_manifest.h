// The manifest of a session on disk (manifest.json) and the naming rules for
// session folders: what a session holds, in which state it is, which files are
// durable with their sizes and checksums, and the journal of its transitions.
//
// State machine (SessionState), checked by Session::SetState:
//
//   created ─┬─► capturing ─┬─► reconstructing ─► done
//            │              └─► done                     (capture-only job)
//            └─► reconstructing                          (offline job)
//   created | capturing | reconstructing ─► interrupted | failed
//   interrupted | failed ─► capturing | reconstructing   (resume)
//   interrupted ─► failed
//
// `done` is final for SetState; Session::ReopenForTurn alone takes a done
// scan back to capturing for another turn (the object laid in another pose).
// "Active" states (created, capturing, reconstructing) are
// the ones in which files may be stored; the daemon marks sessions left active
// by a crash or restart `interrupted` when it starts.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

namespace craftscan::daemon {

enum class SessionState { kCreated, kCapturing, kReconstructing, kDone, kInterrupted, kFailed };

// "created", "capturing", "reconstructing", "done", "interrupted", "failed".
const char* ToString(SessionState state);
// Inverse of ToString (exact, lower case); false for anything else.
bool SessionStateFromString(std::string_view text, SessionState* state);
// True for created, capturing and reconstructing (files may be stored).
bool IsActive(SessionState state);
// Whether `from` → `to` is an edge of the state machine drawn above.
bool IsAllowedTransition(SessionState from, SessionState to);

// Maps an operator-given object name to a safe folder-name part: keeps
// [A-Za-z0-9._-], maps every other byte (/, \, spaces, control characters,
// each byte of a non-ASCII character) to '_', collapses runs of '_' and of
// '.', strips leading '.', '-' and '_' (no hidden folders, no option-like
// names, no "..") and trailing '_', and keeps at most 64 bytes. An empty
// result becomes "object". Pure; thread-safe.
std::string SanitizeObjectName(std::string_view name);

// True iff `id` has the exact shape of a session id made by SessionStore:
// "YYYYMMDD-HHMMSS-<name>" where <name> is a SanitizeObjectName result,
// optionally followed by "-N" (collision suffix). Refuses path separators,
// "..", leading dots and anything longer than 84 bytes, so an id from a
// client can be joined to the sessions folder safely. Pure; thread-safe.
bool IsValidSessionId(std::string_view id);

// True iff `name` may name a session output (StoreOutput): one or more
// '/'-separated components of [A-Za-z0-9._-], each not starting with '.' or
// '-', no empty component, not absolute, at most 4 components and 200 bytes,
// and not a reserved name (manifest.json, calibration.yaml, anything under
// views/). On false, *why (may be null) says what is wrong. Thread-safe.
bool IsValidOutputName(std::string_view name, std::string* why);

// FNV-1a 64-bit hash of `bytes` (the manifest's file checksum; detects
// truncation and modification, not tampering). Pure; thread-safe.
std::uint64_t Fnv1a64(std::string_view bytes);

// One durable file: size, FNV-1a 64 and SHA-256 of its bytes as they were
// written. Manifests written before SHA-256 was added have no sha256 (empty
// here); their files are verified by size and FNV-1a 64 alone.
struct FileRecord {
  std::uint64_t size_bytes = 0;
  std::uint64_t fnv1a64 = 0;
  std::string sha256;  // 64 lower-case hex digits, or empty (an old manifest)
  bool operator==(const FileRecord&) const = default;
};

// A session folder's manifest and calibration copy.
inline constexpr const char* kManifestJson = "manifest.json";
inline constexpr const char* kCalibrationYaml = "calibration.yaml";

// File names inside views/NNN/.
inline constexpr const char* kLeftPng = "left.png";
inline constexpr const char* kRightPng = "right.png";
inline constexpr const char* kMetaJson = "meta.json";
// The texture frame (a station with a pattern projector: the left view with
// the projector off, for the model's colours); optional.
inline constexpr const char* kTexturePng = "texture.png";
inline constexpr const char* kDisparityPfm = "disparity.pfm";
inline constexpr const char* kCloudPly = "cloud.ply";
// Highest view index (views/NNN has three digits).
inline constexpr int kMaxViewIndex = 999;

struct ViewRecord {
  int index = 0;                            // 0..kMaxViewIndex, folder views/NNN
  double angle_deg = 0;                     // commanded turntable angle at capture
  std::string captured_utc;                 // ISO 8601 UTC, when the capture became durable
  std::map<std::string, FileRecord> files;  // by file name (kLeftPng, ...): durable files only

  // left.png, right.png and meta.json are all durable.
  bool HasCapture() const;
  bool HasDisparity() const { return files.count(kDisparityPfm) > 0; }
  bool HasCloud() const { return files.count(kCloudPly) > 0; }
};

struct JournalEntry {
  std::string time_utc;  // ISO 8601 UTC with milliseconds
  std::string event;     // a state name ("capturing", ...) or "calibration", "output"
  std::string detail;    // free text for people
};

// The whole manifest. Every change is written as a complete new manifest.json
// (atomic rewrite); see ManifestToJson for the exact format.
struct Manifest {
  static constexpr int kFormatVersion = 1;
  int format_version = kFormatVersion;
  std::string id;                                    // folder name under sessions/
  std::string object_name;                           // as the operator gave it
  std::string object;                                // SanitizeObjectName(object_name)
  std::string job;                                   // job verb: "scan", "capture", ...
  nlohmann::json params = nlohmann::json::object();  // job parameters: views, step_deg, ...
  SessionState state = SessionState::kCreated;
  std::string error;                          // last failure/interruption reason; "" otherwise
  std::string created_utc;                    // ISO 8601 UTC
  std::string updated_utc;                    // ISO 8601 UTC, time of the last rewrite
  std::string calibration_id;                 // as given to CopyCalibration
  std::optional<FileRecord> calibration;      // calibration.yaml, once durable
  std::map<int, ViewRecord> views;            // by view index
  std::map<std::string, FileRecord> outputs;  // by relative name: "fused.ply", "previews/a.png"
  std::vector<JournalEntry> journal;          // oldest first

  // Indices of views whose capture is durable, ascending.
  std::vector<int> CapturedViews() const;
};

// The manifest as JSON (keys in a fixed, readable order), e.g.
//   {"format": "craftscan-session", "format_version": 1,
//    "id": "20240501-093000-egg", "object": {"name": "egg", "sanitized": "egg"},
//    "job": "scan", "params": {"views": 24, "step_deg": 15.0},
//    "state": "capturing", "error": "",
//    "created": "2024-05-01T09:30:00.000Z", "updated": "2024-05-01T09:30:07.412Z",
//    "calibration": {"id": "rig-a", "file": "calibration.yaml", "size": 2210,
//                    "fnv1a64": "9ae16a3b2f90404f", "sha256": "64 hex digits"},
//                                                             (null before CopyCalibration)
//    "views": [{"index": 0, "angle_deg": 0.0, "captured": "2024-05-01T09:30:03.101Z",
//               "files": {"left.png": {"size": 812345, "fnv1a64": "…", "sha256": "…"},
//                         "right.png": …, "meta.json": …, "disparity.pfm": …,
//                         "cloud.ply": …}}],
//    "outputs": {"fused.ply": {"size": …, "fnv1a64": "…", "sha256": "…"}, "report.json": …},
//    "journal": [{"time": "…", "event": "created", "detail": "scan of 'egg'"}, …]}
// fnv1a64 is 16 lower-case hex digits (a JSON number cannot hold 64 bits in
// every reader); sha256 is 64 lower-case hex digits, written when the record
// has one (every record made since SHA-256 was added) and optional when
// read, so manifests from before load unchanged (same format_version: the
// field is an addition older readers ignore). Pure; thread-safe.
std::string ManifestToJson(const Manifest& manifest);

// Parses and validates manifest.json text: format name and version, every
// field's type, state names, view indices in range and unique, file names
// known, output names valid (IsValidOutputName), checksums as hex (sha256
// optional, 64 lower-case hex digits when present). Returns
// false with *error (may be null) naming the first field that is wrong; never
// throws.
bool ManifestFromJson(std::string_view text, Manifest* manifest, std::string* error);

}  // namespace craftscan::daemon
