#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <utility>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/pfm.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/sha256.h"
#include "session_internal.h"

namespace craftscan::daemon {
namespace {

using internal::ViewFolder;

bool SetError(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

// A failed Status with `code` and `message`.
Status Error(ErrorCode code, std::string message) { return Status(code, std::move(message)); }

// The same code with `prefix` put before the message (no separator), as
// WritePfm and WritePly word their failures: "PFM '<path>': ...".
Status Prefixed(const char* prefix, const Status& status) {
  if (status.ok()) return status;
  return Status(status.code(), prefix + status.message());
}

std::string NowUtc() { return internal::IsoUtc(std::chrono::system_clock::now()); }

FileRecord RecordOfBytes(std::string_view bytes) {
  return FileRecord{bytes.size(), Fnv1a64(bytes), Sha256Hex(bytes)};
}

// The record of a file as it is on disk now.
Status RecordOf(const std::string& path, FileRecord* record) {
  std::string data;
  if (Status read = internal::ReadFileBytes(path, &data); !read.ok()) return read;
  *record = RecordOfBytes(data);
  return Status::Ok();
}

// Empty if the bytes match the record, else what differs: SHA-256 where the
// manifest has it, FNV-1a 64 for files listed by manifests from before.
std::string Mismatch(const std::string& bytes, const FileRecord& record) {
  if (bytes.size() != record.size_bytes) {
    return "size " + std::to_string(bytes.size()) + " bytes, the manifest says " +
           std::to_string(record.size_bytes) + " (truncated or replaced)";
  }
  if (!record.sha256.empty()) {
    const std::string sha256 = Sha256Hex(bytes);
    if (sha256 != record.sha256) {
      return "checksum differs from the manifest (SHA-256 " + sha256 + ", the manifest says " +
             record.sha256 + "): modified or corrupt";
    }
  } else if (Fnv1a64(bytes) != record.fnv1a64) {
    return "checksum differs from the manifest (FNV-1a 64; the manifest predates SHA-256): "
           "modified or corrupt";
  }
  return {};
}

bool CheckPngImage(const cv::Mat& image, const char* which, std::string* error) {
  if (image.empty()) return SetError(error, std::string(which) + " image is empty");
  const int depth = image.depth();
  const int channels = image.channels();
  if ((depth != CV_8U && depth != CV_16U) || (channels != 1 && channels != 3 && channels != 4)) {
    return SetError(error, std::string(which) + " image has type " +
                               cv::typeToString(image.type()) +
                               "; PNG stores 8- or 16-bit images with 1, 3 or 4 channels");
  }
  return true;
}

bool EncodePng(const cv::Mat& image, std::string* bytes, std::string* error) {
  try {
    std::vector<uchar> buffer;
    // Level 1: captures are acknowledged only once written, so speed beats size.
    if (!cv::imencode(".png", image, buffer, {cv::IMWRITE_PNG_COMPRESSION, 1})) {
      return SetError(error, "PNG encoding failed");
    }
    bytes->assign(buffer.begin(), buffer.end());
    return true;
  } catch (const cv::Exception& e) {
    return SetError(error, std::string("PNG encoding failed: ") + e.what());
  }
}

bool DecodePng(const std::string& bytes, cv::Mat* image, const std::string& path,
               std::string* error) {
  try {
    const cv::Mat raw(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data()));
    *image = cv::imdecode(raw, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return SetError(error, "'" + path + "': cannot decode PNG: " + e.what());
  }
  return !image->empty() || SetError(error, "'" + path + "': cannot decode PNG");
}

}  // namespace

namespace internal {

std::string ViewFolder(int view) {
  char text[32];
  std::snprintf(text, sizeof text, "views/%03d", view);
  return text;
}

Status ReadManifest(const std::string& dir, const std::string& id, Manifest* manifest) {
  std::string text;
  if (Status read = ReadFileBytes(dir + "/" + kManifestJson, &text); !read.ok()) return read;
  std::string why;
  if (!ManifestFromJson(text, manifest, &why)) {
    return Error(ErrorCode::kCorrupt, "'" + dir + "/" + kManifestJson + "': " + why);
  }
  if (manifest->id != id) {
    return Error(ErrorCode::kCorrupt, "'" + dir + "/" + kManifestJson + "': id '" + manifest->id +
                                          "' differs from the folder name '" + id + "'");
  }
  return Status::Ok();
}

void VerifyFiles(const std::string& dir, const Manifest& manifest, VerifyResult* result,
                 std::set<std::string>* damaged) {
  const auto check = [&](const std::string& relative, const FileRecord& record) {
    std::string bytes, why;
    if (Status read = ReadFileBytes(dir + "/" + relative, &bytes); !read.ok()) {
      result->problems.push_back(relative + ": " + read.message());
    } else {
      ++result->files_checked;
      result->bytes_checked += bytes.size();
      why = Mismatch(bytes, record);
      if (why.empty()) return;
      result->problems.push_back(relative + ": " + why);
    }
    if (damaged) damaged->insert(relative);
  };
  if (manifest.calibration) check(kCalibrationYaml, *manifest.calibration);
  for (const auto& [index, view] : manifest.views) {
    for (const auto& [name, record] : view.files) check(ViewFolder(index) + "/" + name, record);
  }
  for (const auto& [name, record] : manifest.outputs) check(name, record);
}

}  // namespace internal

Session::Session(std::string id, std::string dir, std::unique_ptr<Lock> lock, Manifest manifest)
    : id_(std::move(id)),
      dir_(std::move(dir)),
      lock_(std::move(lock)),
      manifest_(std::move(manifest)) {}

Session::~Session() = default;

Manifest Session::manifest() const {
  std::lock_guard lock(mutex_);
  return manifest_;
}

SessionState Session::state() const {
  std::lock_guard lock(mutex_);
  return manifest_.state;
}

nlohmann::json Session::params() const {
  std::lock_guard lock(mutex_);
  return manifest_.params;
}

std::vector<int> Session::DurableViews() const {
  std::lock_guard lock(mutex_);
  return manifest_.CapturedViews();
}

std::string Session::CalibrationPath() const {
  std::lock_guard lock(mutex_);
  return manifest_.calibration ? dir_ + "/" + internal::kCalibrationYaml : std::string();
}

Status Session::WriteLocked(Manifest next) {
  next.updated_utc = NowUtc();
  const Status written =
      WriteFileAtomically(dir_ + "/" + internal::kManifestJson, ManifestToJson(next));
  if (!written.ok()) return written.WithContext(Prefix() + "cannot update the manifest");
  manifest_ = std::move(next);
  return Status::Ok();
}

Status Session::Commit(const std::function<Status(Manifest*)>& change) {
  std::lock_guard lock(mutex_);
  Manifest next = manifest_;
  if (Status changed = change(&next); !changed.ok()) return changed;
  return WriteLocked(std::move(next));
}

Status Session::SetState(SessionState state, const std::string& detail) {
  return Commit([&](Manifest* m) {
    if (!IsAllowedTransition(m->state, state)) {
      return Error(ErrorCode::kFailedPrecondition,
                   Prefix() + "cannot go from " + ToString(m->state) + " to " + ToString(state));
    }
    m->state = state;
    m->error = state == SessionState::kFailed || state == SessionState::kInterrupted
                   ? detail
                   : std::string();
    m->journal.push_back({NowUtc(), ToString(state), detail});
    return Status::Ok();
  });
}

Status Session::SetParams(const nlohmann::json& params, const std::string& detail) {
  if (!params.is_object())
    return Error(ErrorCode::kInvalidArgument, Prefix() + "params must be a JSON object");
  return Commit([&](Manifest* m) {
    m->params = params;
    m->journal.push_back({NowUtc(), "params", detail});
    return Status::Ok();
  });
}

Status Session::ReopenForTurn(const nlohmann::json& params, const std::string& detail) {
  if (!params.is_object())
    return Error(ErrorCode::kInvalidArgument, Prefix() + "params must be a JSON object");
  return Commit([&](Manifest* m) {
    if (m->state != SessionState::kDone) {
      return Error(ErrorCode::kFailedPrecondition, Prefix() +
                                                       "a turn can be added only to a done " +
                                                       "session, not one " + ToString(m->state));
    }
    m->params = params;
    m->state = SessionState::kCapturing;
    m->error.clear();
    m->journal.push_back({NowUtc(), ToString(m->state), detail});
    return Status::Ok();
  });
}

Status Session::Unlist(const std::function<bool(Manifest*)>& remove) {
  std::lock_guard lock(mutex_);
  Manifest next = manifest_;
  // Nothing listed: nothing to write.
  if (!remove(&next)) return Status::Ok();
  return WriteLocked(std::move(next));
}

Status Session::Claim(const std::string& key) {
  std::lock_guard lock(mutex_);
  if (!IsActive(manifest_.state)) {
    return Error(ErrorCode::kFailedPrecondition,
                 Prefix() + "cannot store " + key + " in state " + ToString(manifest_.state) +
                     " (only created, capturing or reconstructing)");
  }
  if (!busy_.insert(key).second) {
    return Error(ErrorCode::kFailedPrecondition,
                 Prefix() + key + " is being stored by another call");
  }
  return Status::Ok();
}

void Session::Release(const std::string& key) {
  std::lock_guard lock(mutex_);
  busy_.erase(key);
}

Status Session::Store(const StoreStep& step) {
  if (Status claimed = Claim(step.key); !claimed.ok()) return claimed;
  // A file the manifest lists is taken off it before being replaced, so the
  // manifest never points at bytes it has no checksum for.
  if (Status unlisted = Unlist(step.unlist); !unlisted.ok()) {
    Release(step.key);
    return unlisted;
  }
  Status status = step.write();
  if (!status.ok()) {
    status = status.WithContext(Prefix() + "cannot store the " + step.what);
  } else {
    status = Commit(step.list);
  }
  if (!status.ok()) {
    // Whatever this call wrote is listed nowhere: remove it (frees a full disk).
    for (const std::string& path : step.paths) ::unlink(path.c_str());
  }
  Release(step.key);
  return status;
}

Status Session::CheckView(int view, const std::string& what, bool needs_capture) const {
  if (view < 0 || view > kMaxViewIndex) {
    return Error(ErrorCode::kInvalidArgument, Prefix() + what + ": view index " +
                                                  std::to_string(view) + " is outside 0.." +
                                                  std::to_string(kMaxViewIndex));
  }
  if (!needs_capture) return Status::Ok();
  std::lock_guard lock(mutex_);
  const auto it = manifest_.views.find(view);
  if (it != manifest_.views.end() && it->second.HasCapture()) return Status::Ok();
  return Error(ErrorCode::kFailedPrecondition,
               Prefix() + what + ": view " + std::to_string(view) + " has no durable capture");
}

Status Session::CopyCalibration(const std::string& source_path, const std::string& calibration_id) {
  std::string bytes;
  if (Status read = internal::ReadFileBytes(source_path, &bytes); !read.ok()) {
    return read.WithContext(Prefix() + "cannot copy the calibration");
  }
  const std::string path = dir_ + "/" + internal::kCalibrationYaml;
  StoreStep step;
  step.key = internal::kCalibrationYaml;
  step.what = "calibration";
  step.paths = {path};
  step.unlist = [](Manifest* m) {
    const bool listed = m->calibration.has_value();
    m->calibration.reset();
    return listed;
  };
  step.write = [&] { return WriteFileAtomically(path, bytes); };
  step.list = [&](Manifest* m) {
    m->calibration = RecordOfBytes(bytes);
    m->calibration_id = calibration_id;
    m->journal.push_back({NowUtc(), "calibration",
                          "copied from '" + source_path + "' (id '" + calibration_id + "')"});
    return Status::Ok();
  };
  return Store(step);
}

Status Session::StoreCapture(int view, double angle_deg, const cv::Mat& left, const cv::Mat& right,
                             const nlohmann::json& meta, const cv::Mat& texture_left) {
  StoreStep step;
  step.what = "capture of view " + std::to_string(view);
  if (Status checked = CheckView(view, step.what, false); !checked.ok()) return checked;
  std::string why;
  if (!CheckPngImage(left, "left", &why) || !CheckPngImage(right, "right", &why) ||
      (!texture_left.empty() && !CheckPngImage(texture_left, "texture", &why))) {
    return Error(ErrorCode::kInvalidArgument, Prefix() + step.what + ": " + why);
  }
  if (!texture_left.empty() && texture_left.size() != left.size()) {
    return Error(ErrorCode::kInvalidArgument, Prefix() + step.what + ": the texture image is " +
                                                  std::to_string(texture_left.cols) + "x" +
                                                  std::to_string(texture_left.rows) +
                                                  ", the left image " + std::to_string(left.cols) +
                                                  "x" + std::to_string(left.rows));
  }
  if (!meta.is_object()) {
    return Error(ErrorCode::kInvalidArgument, Prefix() + step.what + ": meta is not a JSON object");
  }
  // Encode before claiming: slow, and needs no lock.
  std::string files[4];
  const int count = texture_left.empty() ? 3 : 4;
  if (!EncodePng(left, &files[0], &why) || !EncodePng(right, &files[1], &why) ||
      (count == 4 && !EncodePng(texture_left, &files[3], &why))) {
    return Error(ErrorCode::kInternal, Prefix() + step.what + ": " + why);
  }
  files[2] = meta.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";

  const char* names[4] = {kLeftPng, kRightPng, kMetaJson, kTexturePng};
  step.key = ViewFolder(view);
  const std::string folder = dir_ + "/" + step.key;
  for (int i = 0; i < count; ++i) step.paths.push_back(folder + "/" + names[i]);
  // A new capture makes the view's disparity and cloud stale: all of it goes.
  step.unlist = [view](Manifest* m) { return m->views.erase(view) > 0; };
  step.write = [&] {
    Status status = internal::MakeDurableDir(dir_ + "/views");
    if (status.ok()) status = internal::MakeDurableDir(folder);
    for (int i = 0; status.ok() && i < count; ++i) {
      status = WriteFileAtomically(step.paths[i], files[i]);
    }
    return status;
  };
  step.list = [&](Manifest* m) {
    ViewRecord& v = m->views[view];
    v.index = view;
    v.angle_deg = angle_deg;
    v.captured_utc = NowUtc();
    for (int i = 0; i < count; ++i) v.files[names[i]] = RecordOfBytes(files[i]);
    return Status::Ok();
  };
  return Store(step);
}

Status Session::StoreViewFile(int view, const char* file, const OutputWriter& writer) {
  StoreStep step;
  step.what = std::string(file) + " of view " + std::to_string(view);
  if (Status checked = CheckView(view, step.what, true); !checked.ok()) return checked;
  step.key = ViewFolder(view);
  const std::string path = dir_ + "/" + step.key + "/" + file;
  step.paths = {path};
  // A new disparity map makes the view's cloud stale.
  const bool drops_cloud = std::string(file) == kDisparityPfm;
  step.unlist = [&](Manifest* m) {
    const auto it = m->views.find(view);
    if (it == m->views.end()) return false;
    const bool listed = it->second.files.erase(file) > 0;
    return (drops_cloud && it->second.files.erase(kCloudPly) > 0) || listed;
  };
  FileRecord record;
  step.write = [&] {
    Status written = writer(path);
    if (written.ok()) written = RecordOf(path, &record);
    return written;
  };
  step.list = [&](Manifest* m) {
    const auto it = m->views.find(view);
    if (it == m->views.end() || !it->second.HasCapture()) {  // a failed recapture meanwhile
      return Error(ErrorCode::kFailedPrecondition,
                   Prefix() + step.what + ": the view's capture is gone");
    }
    it->second.files[file] = record;
    return Status::Ok();
  };
  return Store(step);
}

Status Session::StoreDisparity(int view, const cv::Mat& disparity_px) {
  if (disparity_px.empty() || disparity_px.type() != CV_32FC1) {
    return Error(ErrorCode::kInvalidArgument,
                 Prefix() + "disparity of view " + std::to_string(view) + " must be " +
                     "a non-empty CV_32FC1 image, got " +
                     (disparity_px.empty() ? std::string("an empty one")
                                           : cv::typeToString(disparity_px.type())));
  }
  // Encoded here, written with the Status-returning WriteFileAtomically so
  // the errno's code reaches the caller.
  std::string bytes, why;
  if (!EncodePfm(disparity_px, &bytes, &why)) {
    return Error(ErrorCode::kInvalidArgument,
                 Prefix() + "disparity of view " + std::to_string(view) + ": " + why);
  }
  return StoreViewFile(view, kDisparityPfm, [&](const std::string& path) {
    return Prefixed("PFM ", WriteFileAtomically(path, bytes));
  });
}

Status Session::StoreCloud(int view, const PointCloud& cloud) {
  std::string why;
  if (!cloud.IsValid(&why)) {
    return Error(ErrorCode::kInvalidArgument,
                 Prefix() + "cloud of view " + std::to_string(view) + ": " + why);
  }
  std::string bytes;
  try {
    bytes = EncodePly(cloud, true);
  } catch (const std::exception& e) {  // std::bad_alloc
    return Error(ErrorCode::kInternal,
                 Prefix() + "cloud of view " + std::to_string(view) + ": " + e.what());
  }
  return StoreViewFile(view, kCloudPly, [&](const std::string& path) {
    return Prefixed("PLY ", WriteFileAtomically(path, bytes));
  });
}

Status Session::StoreOutput(const std::string& name, std::string_view bytes) {
  return StoreOutputWith(name,
                         [&](const std::string& path) { return WriteFileAtomically(path, bytes); });
}

Status Session::StoreOutputWith(const std::string& name, const OutputWriter& writer) {
  std::string why;
  if (!IsValidOutputName(name, &why)) return Error(ErrorCode::kInvalidArgument, Prefix() + why);
  StoreStep step;
  step.key = name;
  step.what = "output " + name;
  const std::string path = dir_ + "/" + name;
  step.paths = {path};
  step.unlist = [&](Manifest* m) { return m->outputs.erase(name) > 0; };
  FileRecord record;
  step.write = [&] {
    // The output's folders, outermost first.
    for (std::size_t slash = name.find('/'); slash != std::string::npos;
         slash = name.find('/', slash + 1)) {
      Status made = internal::MakeDurableDir(dir_ + "/" + name.substr(0, slash));
      if (!made.ok()) return made;
    }
    Status written = writer(path);
    if (written.ok()) written = RecordOf(path, &record);
    return written;
  };
  step.list = [&](Manifest* m) {
    m->outputs[name] = record;
    m->journal.push_back({NowUtc(), "output", name});
    return Status::Ok();
  };
  return Store(step);
}

bool Session::FindViewFile(int view, const char* file, FileRecord* record,
                           std::string* error) const {
  std::lock_guard lock(mutex_);
  const auto it = manifest_.views.find(view);
  const auto f = it == manifest_.views.end() ? nullptr : &it->second.files;
  if (!f || f->count(file) == 0) {
    return SetError(error, Prefix() + "view " + std::to_string(view) + " has no durable " + file);
  }
  *record = f->at(file);
  return true;
}

bool Session::LoadVerified(const std::string& relative, const FileRecord& record,
                           std::string* bytes, std::string* error) const {
  if (Status read = internal::ReadFileBytes(dir_ + "/" + relative, bytes); !read.ok()) {
    return SetError(error, Prefix() + read.message());
  }
  const std::string why = Mismatch(*bytes, record);
  return why.empty() || SetError(error, Prefix() + "'" + dir_ + "/" + relative + "': " + why);
}

bool Session::LoadCapture(int view, cv::Mat* left, cv::Mat* right, nlohmann::json* meta,
                          std::string* error, cv::Mat* texture_left) const {
  const std::string folder = ViewFolder(view);
  std::string bytes;
  FileRecord record;
  cv::Mat* images[2] = {left, right};
  const char* names[2] = {kLeftPng, kRightPng};
  for (int i = 0; i < 2; ++i) {
    if (!FindViewFile(view, names[i], &record, error) ||
        !LoadVerified(folder + "/" + names[i], record, &bytes, error) ||
        !DecodePng(bytes, images[i], dir_ + "/" + folder + "/" + names[i], error)) {
      return false;
    }
  }
  if (!FindViewFile(view, kMetaJson, &record, error) ||
      !LoadVerified(folder + "/" + kMetaJson, record, &bytes, error)) {
    return false;
  }
  if (meta) {
    *meta = nlohmann::json::parse(bytes, nullptr, /*allow_exceptions=*/false);
    if (meta->is_discarded()) {
      return SetError(error, Prefix() + "'" + folder + "/meta.json' is not valid JSON");
    }
  }
  if (texture_left) {
    texture_left->release();
    std::string none;
    if (FindViewFile(view, kTexturePng, &record, &none) &&
        (!LoadVerified(folder + "/" + kTexturePng, record, &bytes, error) ||
         !DecodePng(bytes, texture_left, dir_ + "/" + folder + "/" + kTexturePng, error))) {
      return false;
    }
  }
  return true;
}

bool Session::LoadDisparity(int view, cv::Mat* disparity_px, std::string* error) const {
  const std::string relative = ViewFolder(view) + "/" + kDisparityPfm;
  std::string bytes;
  FileRecord record;
  return FindViewFile(view, kDisparityPfm, &record, error) &&
         LoadVerified(relative, record, &bytes, error) &&
         ReadPfm(dir_ + "/" + relative, disparity_px, error);
}

bool Session::LoadCloud(int view, PointCloud* cloud, std::string* error) const {
  const std::string relative = ViewFolder(view) + "/" + kCloudPly;
  std::string bytes;
  FileRecord record;
  return FindViewFile(view, kCloudPly, &record, error) &&
         LoadVerified(relative, record, &bytes, error) &&
         ReadPly(dir_ + "/" + relative, cloud, error);
}

bool Session::LoadOutput(const std::string& name, std::string* bytes, std::string* error) const {
  FileRecord record;
  {
    std::lock_guard lock(mutex_);
    const auto it = manifest_.outputs.find(name);
    if (it == manifest_.outputs.end()) {
      return SetError(error, Prefix() + "no durable output named '" + name + "'");
    }
    record = it->second;
  }
  return LoadVerified(name, record, bytes, error);
}

VerifyResult Session::Verify() const {
  VerifyResult result;
  result.manifest_ok = true;
  internal::VerifyFiles(dir_, manifest(), &result, nullptr);
  return result;
}

ResumePoint Session::GetResumePoint(bool verify_files) const {
  const Manifest m = manifest();
  std::set<std::string> damaged;
  ResumePoint point;
  if (verify_files) {
    VerifyResult result;
    internal::VerifyFiles(dir_, m, &result, &damaged);
    point.damaged = result.problems;
  }
  const auto durable = [&](const ViewRecord& v, const char* file) {
    return v.files.count(file) > 0 && damaged.count(ViewFolder(v.index) + "/" + file) == 0;
  };
  std::set<int> captured;
  for (const auto& [index, v] : m.views) {
    if (!durable(v, kLeftPng) || !durable(v, kRightPng) || !durable(v, kMetaJson)) continue;
    captured.insert(index);
    if (!durable(v, kDisparityPfm)) {
      point.to_match.push_back(index);
    } else if (!durable(v, kCloudPly)) {
      point.to_reproject.push_back(index);
    }
  }
  const auto planned = m.params.find("views");
  if (planned != m.params.end() && planned->is_number_integer() && planned->get<long long>() >= 0 &&
      planned->get<long long>() <= kMaxViewIndex + 1) {
    point.planned_views = planned->get<int>();
    for (int i = 0; i < point.planned_views; ++i) {
      if (captured.count(i) == 0) point.to_capture.push_back(i);
    }
  }
  point.next_capture = 0;
  while (captured.count(point.next_capture) > 0) ++point.next_capture;
  if (point.planned_views >= 0)
    point.next_capture = std::min(point.next_capture, point.planned_views);
  return point;
}

}  // namespace craftscan::daemon
