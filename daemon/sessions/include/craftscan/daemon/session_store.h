// Sessions on disk (DESIGN.md "Sessions on disk"): every capture, disparity
// map, view cloud and output of a job is kept in its own folder, written
// crash-safely, with a manifest that says what is durable.
//
//   <data_dir>/sessions/<YYYYMMDD-HHMMSS>-<object>/
//     manifest.json     state journal (session_manifest.h)
//     calibration.yaml  the calibration used (copied in, never referenced)
//     views/NNN/left.png right.png meta.json [texture.png] disparity.pfm cloud.ply
//     fused.ply mesh.ply report.json report.html previews/*.png
//
// Durability: every file is written to a hidden temporary beside it, fsync'ed
// and renamed (WriteFileAtomically), and new folders are fsync'ed into their
// parent; the manifest is rewritten (atomically) only after the files it
// lists are durable. So a Store* call that returned ok survives a crash or
// power loss, and after any crash the manifest lists only intact files.
// Leftover temporaries (".<name>.tmp-XXXXXX") are ignored by every reader and
// removed by SessionStore::MarkInterrupted.
//
// Typical use in the daemon:
//   auto store = SessionStore::Open(config.data_dir, &status);  // refuses a bad dir
//   store->MarkInterrupted();                                   // once, at start
//   auto s = store->Create("carved egg", "scan", {{"views", 24}}, now, &status);
//   s->CopyCalibration(calibration_path, "rig-a");
//   s->SetState(SessionState::kCapturing, "");
//   Status stored = s->StoreCapture(0, 0.0, left, right, meta);  // ok = acknowledged
//   ...
//   resume: s = store->OpenSession(id, &status); s->GetResumePoint(true) ...
//
// Errors: the calls that write (and Open, Create, OpenSession) return a
// craftscan::Status whose code comes from the errno of the failing system
// call (kDiskFull for ENOSPC/EDQUOT, kReadOnly for EROFS, kPermissionDenied
// for EACCES/EPERM, kIoError, ...) or names the refusal (kInvalidArgument,
// kFailedPrecondition for a forbidden transition, a busy file or a session
// held elsewhere, kNotFound, kCorrupt); the message says which file and why,
// ending in strerror for system errors. Callers branch on the code. The
// Load* calls read only and report text (bool + *error).
//
// A Session holds an exclusive lock (flock) on its folder: one Session object
// per session at a time, in this or any other process. A SIGKILL releases it.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core/mat.hpp>

#include "craftscan/daemon/session_manifest.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan::daemon {

// Outcome of checking a session's files against its manifest.
struct VerifyResult {
  bool manifest_ok = false;           // manifest.json read and valid
  std::vector<std::string> problems;  // one line per missing/truncated/modified file
  int files_checked = 0;              // files listed by the manifest and read
  std::uint64_t bytes_checked = 0;
  bool IsIntact() const { return manifest_ok && problems.empty(); }
};

// Where a resumed job continues: nothing durable is redone.
struct ResumePoint {
  int planned_views = -1;  // params["views"] when a non-negative integer, else -1
  // Lowest view index in [0, planned_views) without a durable capture
  // (planned_views when all are captured; with planned_views unknown: the
  // lowest index not captured).
  int next_capture = 0;
  std::vector<int> to_capture;    // planned views without a durable capture, ascending
  std::vector<int> to_match;      // captured views without a durable disparity map
  std::vector<int> to_reproject;  // views with a disparity map but no durable cloud
  // With verification: files that failed it ("views/003/left.png: ..."); the
  // step that wrote each of them is listed above as not durable.
  std::vector<std::string> damaged;
  bool CapturesComplete() const { return planned_views >= 0 && to_capture.empty(); }
};

// One line of SessionStore::List.
struct SessionSummary {
  std::string id;
  std::string object_name;  // as the operator gave it ("" when corrupt)
  std::string job;          // job verb ("" when corrupt)
  std::string state;        // ToString(SessionState) or "corrupt"
  std::string problem;      // why it is corrupt; "" otherwise
  int views_captured = 0;   // views with a durable capture
  std::string created_utc;  // ISO 8601 UTC ("" when corrupt)
  std::string updated_utc;
  // A scan with turns added (scan_turns.h in the service): params.turns as
  // recorded; null otherwise.
  nlohmann::json turns;
};

// Writes one output file at `path` (a path inside the session folder chosen
// by the store); must write atomically (e.g. WriteFileAtomically with the
// bytes of EncodePly / EncodeMeshPly) and return a failed Status, with the
// errno's code, on failure.
using OutputWriter = std::function<Status(const std::string& path)>;

class Session {
 public:
  ~Session();  // releases the folder lock; nothing else is written
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  const std::string& id() const { return id_; }
  // Absolute path of the session folder.
  const std::string& dir() const { return dir_; }
  // A copy of the manifest as last written to disk. Thread-safe.
  Manifest manifest() const;
  SessionState state() const;
  nlohmann::json params() const;
  // Views whose capture is durable, ascending. Thread-safe.
  std::vector<int> DurableViews() const;
  // Absolute path of calibration.yaml, or "" before CopyCalibration.
  std::string CalibrationPath() const;

  // Moves to `state` (see the state machine in session_manifest.h) and
  // appends a journal entry {now, ToString(state), detail}. For failed and
  // interrupted, `detail` becomes the manifest's error; other states clear
  // it. A failed Status (kFailedPrecondition) for a transition the machine
  // forbids ("session X: cannot go from done to capturing") or an I/O
  // failure (the errno's code), in which case the state on disk and in
  // memory is unchanged.
  Status SetState(SessionState state, const std::string& detail);

  // Replaces the job parameters (a JSON object; e.g. a scan's `turns`) and
  // appends a journal entry {now, "params", detail}. Any state. Errors as
  // SetState's (kInvalidArgument for a non-object).
  Status SetParams(const nlohmann::json& params, const std::string& detail);
  // Another turn of a finished scan (the object laid in another pose): the
  // only way out of `done`, to capturing, with the new `params` in the same
  // manifest write and a journal entry {now, "capturing", detail}. Files
  // already listed stay listed. kFailedPrecondition unless the session is done.
  Status ReopenForTurn(const nlohmann::json& params, const std::string& detail);

  // Copies the calibration file at `source_path` into calibration.yaml and
  // records `calibration_id` (free text, e.g. the calibration's name or date).
  // Requires an active state. Errors name the file and strerror.
  Status CopyCalibration(const std::string& source_path, const std::string& calibration_id);

  // Stores view `view` (0..999): left.png and right.png (lossless PNG; 8- or
  // 16-bit, 1, 3 or 4 channels, OpenCV BGR order), meta.json (`meta` as
  // given, must be a JSON object), then the manifest entry with
  // `angle_deg`. Returns ok only once all of it is durable: that is the
  // acknowledgement a client may be given. Storing a view again replaces it
  // and drops its disparity and cloud from the manifest (they are stale).
  // Requires an active state. On failure (the message: which file, path,
  // strerror, e.g. "No space left on device"; the code: kDiskFull) the files this call wrote are
  // removed and every other listed file is untouched.
  //
  // Replacing (all Store* calls): files the manifest lists are first taken
  // off it (one manifest rewrite), then replaced; so a failed or interrupted
  // replacement leaves the old version unlisted, never a listed file with a
  // wrong checksum. If that first rewrite fails nothing is touched.
  // `texture_left` (optional; StereoFrame::texture_left) is stored with them
  // as texture.png, in the same step.
  Status StoreCapture(int view, double angle_deg, const cv::Mat& left, const cv::Mat& right,
                      const nlohmann::json& meta, const cv::Mat& texture_left = cv::Mat());
  // Stores the view's disparity map (CV_32FC1, pixels) as disparity.pfm.
  // Requires a durable capture of the view and an active state; storing again
  // drops the view's cloud from the manifest.
  Status StoreDisparity(int view, const cv::Mat& disparity_px);
  // Stores the view's cloud (mm) as binary PLY cloud.ply. Requires a durable
  // capture of the view and an active state.
  Status StoreCloud(int view, const PointCloud& cloud);
  // Stores an output ("fused.ply", "report.json", "previews/view003.png", ...;
  // see IsValidOutputName), creating its folders. Requires an active state.
  Status StoreOutput(const std::string& name, std::string_view bytes);
  // The same with the bytes written by `writer` at the output's path.
  Status StoreOutputWith(const std::string& name, const OutputWriter& writer);

  // Load*: read a durable file back, checking its size and checksum against
  // the manifest first; bit-exact with what was stored. False with *error
  // ("session X: view 3 has no durable disparity.pfm", "...: checksum
  // differs from the manifest (modified or corrupt)", a decoding error)
  // when the file is not listed, damaged or undecodable. *meta may be null.
  // *texture_left (may be null) is the stored texture frame, or empty when
  // the view has none.
  bool LoadCapture(int view, cv::Mat* left, cv::Mat* right, nlohmann::json* meta,
                   std::string* error, cv::Mat* texture_left = nullptr) const;
  bool LoadDisparity(int view, cv::Mat* disparity_px, std::string* error) const;
  bool LoadCloud(int view, PointCloud* cloud, std::string* error) const;
  bool LoadOutput(const std::string& name, std::string* bytes, std::string* error) const;

  // Where a resumed job continues. With `verify_files`, every listed file is
  // read and checked (Verify) and damaged ones count as not durable.
  ResumePoint GetResumePoint(bool verify_files) const;
  // Checks every file the manifest lists: exists, size, checksum. Reads
  // them all (about 150 MB for 6 views of 5 MP with disparity maps); a file
  // being replaced by a concurrent Store* call may show as a problem.
  VerifyResult Verify() const;

  // Thread-safety: all methods may be called from several threads. Store*
  // calls for distinct views (and for outputs) run concurrently; the
  // manifest rewrite is serialised by one mutex. A Store* call for a view or
  // output that another call is still storing fails with "... is being
  // stored by another call" (kFailedPrecondition). SetState may run concurrently with Store*.

 private:
  friend class SessionStore;
  struct Lock;
  Session(std::string id, std::string dir, std::unique_ptr<Lock> lock, Manifest manifest);

  // One file-storing step (see Store).
  struct StoreStep {
    std::string key;                        // busy key: "views/003" or the output name
    std::string what;                       // for messages: "capture of view 3"
    std::vector<std::string> paths;         // files the step writes
    std::function<bool(Manifest*)> unlist;  // drops stale records; true if any
    std::function<Status()> write;          // writes the files durably
    std::function<Status(Manifest*)> list;  // records the new files
  };
  // Writes `next` as the manifest and keeps it if that succeeded; mutex_ held.
  Status WriteLocked(Manifest next);
  // Runs `change` on a copy of the manifest, writes it, and keeps it only if
  // the write succeeded.
  Status Commit(const std::function<Status(Manifest*)>& change);
  // The same for removals; writes nothing when `remove` returns false.
  Status Unlist(const std::function<bool(Manifest*)>& remove);
  // Checks the state allows stores and marks `key` busy (released by Release).
  Status Claim(const std::string& key);
  void Release(const std::string& key);
  // Claim, unlist, write, list; on failure removes what it wrote.
  Status Store(const StoreStep& step);
  Status CheckView(int view, const std::string& what, bool needs_capture) const;
  Status StoreViewFile(int view, const char* file, const OutputWriter& writer);
  bool LoadVerified(const std::string& relative, const FileRecord& record, std::string* bytes,
                    std::string* error) const;
  bool FindViewFile(int view, const char* file, FileRecord* record, std::string* error) const;
  std::string Prefix() const { return "session " + id_ + ": "; }

  const std::string id_;
  const std::string dir_;
  const std::unique_ptr<Lock> lock_;
  mutable std::mutex mutex_;
  Manifest manifest_;           // guarded by mutex_
  std::set<std::string> busy_;  // guarded by mutex_: files being stored
};

class SessionStore {
 public:
  // Opens the store at `data_dir` (an existing directory), creating
  // data_dir/sessions if missing and probing that a file can be created
  // there. Returns null with *status (may be null) naming the path and the
  // reason ("... is not a directory" kInvalidArgument, "... is not
  // writable: Read-only file system" kReadOnly, ...). Thread-safe.
  static std::unique_ptr<SessionStore> Open(const std::string& data_dir, Status* status);

  // Absolute path of data_dir/sessions.
  const std::string& sessions_dir() const { return sessions_dir_; }

  // Daemon start: every session in an active state (created, capturing,
  // reconstructing) that no one holds open becomes `interrupted` with a
  // journal entry; stale temporaries left by a crash are removed from it, and
  // half-created session folders (".<id>.tmp-XXXXXX") are deleted. Returns
  // the ids marked, ascending. Sessions that cannot be marked (corrupt
  // manifest, I/O error) are left as they are and described in *problems
  // (may be null). Call once before any job runs.
  std::vector<std::string> MarkInterrupted(std::vector<std::string>* problems = nullptr);

  // Creates a session for `object_name` (sanitised into the id), job verb
  // `job` (non-empty [a-z_]) and `params` (a JSON object) with id
  // "<YYYYMMDD-HHMMSS>-<object>" (time `now` in UTC), suffixed "-2", "-3", ...
  // when taken. The folder appears atomically with its manifest in state
  // created (journal: "created"). Returns null with *status (may be null)
  // on invalid arguments (kInvalidArgument) or an I/O failure (the errno's
  // code; nothing is left behind). Thread-safe,
  // also across processes (ids never collide).
  std::unique_ptr<Session> Create(std::string_view object_name, std::string_view job,
                                  const nlohmann::json& params,
                                  std::chrono::system_clock::time_point now, Status* status);

  // Every session folder, sorted by id (oldest first). A folder whose
  // manifest is missing, unreadable or invalid is listed with state "corrupt"
  // and the reason; hidden entries (temporaries) are skipped. Thread-safe.
  std::vector<SessionSummary> List() const;

  // Opens an existing session for writing or reading (takes its lock).
  // Returns null with *status (may be null) for an invalid id
  // (IsValidSessionId; kInvalidArgument), an unknown id (kNotFound), a
  // corrupt manifest (kCorrupt, with the reason), a session held open
  // elsewhere (kFailedPrecondition) or an I/O error (the errno's code).
  // Thread-safe.
  std::unique_ptr<Session> OpenSession(const std::string& id, Status* status);

  // Moves session `id` out of the store into <data_dir>/trash/<id> (with
  // "-2", "-3"... when that is taken), never deleting a byte: an admin
  // empties the trash by hand. Refused (kFailedPrecondition) while anyone
  // holds the session open (a job), kNotFound for an unknown id,
  // kInvalidArgument for an invalid one. Returns the trash path ("" on
  // failure, with *status). Thread-safe.
  std::string MoveToTrash(const std::string& id, Status* status);

  // Checks the files of session `id` against its manifest without taking its
  // lock (reads only; meaningful when no one is writing it). An invalid or
  // unknown id gives manifest_ok = false with the reason in problems.
  VerifyResult Verify(const std::string& id) const;

 private:
  explicit SessionStore(std::string sessions_dir) : sessions_dir_(std::move(sessions_dir)) {}
  // Reads the manifest of session folder `dir`, whose lock is already held.
  static std::unique_ptr<Session> MakeSession(const std::string& id, const std::string& dir,
                                              std::unique_ptr<Session::Lock> lock, Status* status);
  const std::string sessions_dir_;
};

}  // namespace craftscan::daemon
