#include "craftscan/record/archive.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <list>
#include <map>
#include <mutex>
#include <regex>
#include <set>
#include <tuple>
#include <unordered_map>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/pfm.h"

namespace craftscan::record {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;  // keeps the index's field order

constexpr std::size_t kMaxWireNameBytes = 200;
constexpr int kMaxPfmSide = 32768;  // what WritePfm accepts
constexpr const char* kStagingDir = ".staging";
constexpr const char* kLockFile = ".lock";
constexpr const char* kIndexFile = "index.jsonl";

bool SetError(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

std::string ErrnoText(const std::string& what) { return what + ": " + std::strerror(errno); }

// fsync of a folder makes renames and new entries in it durable.
bool FsyncDir(const fs::path& dir, std::string* error) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return SetError(error, ErrnoText("cannot open folder '" + dir.string() + "'"));
  const int rc = ::fsync(fd);
  ::close(fd);
  if (rc != 0) return SetError(error, ErrnoText("cannot fsync folder '" + dir.string() + "'"));
  return true;
}

// The data files the archive writes (and rotates), by name.
bool IsDataFileName(const std::string& name) {
  static const std::regex pattern(
      R"((view_[0-9]{3,}_(left|right)\.png)|(cloud_[0-9]{3,}\.ply)|(fused\.ply)|(disparity_[0-9]{3,}\.pfm)|(mesh\.glb))");
  return std::regex_match(name, pattern);
}

std::string ViewNumber(int32_t view_index) {
  char text[16];
  std::snprintf(text, sizeof(text), "%03d", static_cast<int>(view_index));
  return text;
}

std::string UtcNow() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()) % 1000;
  std::tm utc{};
  gmtime_r(&seconds, &utc);
  char text[40];
  const std::size_t n = std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%S", &utc);
  std::snprintf(text + n, sizeof(text) - n, ".%03dZ", static_cast<int>(ms.count()));
  return text;
}

bool WritePng(const std::string& path, const cv::Mat& image, std::string* error) {
  std::vector<uchar> bytes;
  try {
    if (!cv::imencode(".png", image, bytes)) return SetError(error, "PNG encoding failed");
  } catch (const cv::Exception& e) {
    return SetError(error, std::string("PNG encoding failed: ") + e.what());
  }
  return WriteFileAtomically(
      path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()), error);
}

// One file of an item: its name in the session folder, its index kind, how
// to write it, and the extra index fields.
struct FileJob {
  std::string name;
  std::string kind;
  std::function<bool(const std::string& path, std::string* error)> write;
  Json extra = Json::object();
};

struct StagedFile {
  FileJob job;
  fs::path staged;
  uint64_t bytes = 0;
};

struct Entry {
  std::string folder;  // "<station>/<session>"
  std::string name;
  uint64_t bytes = 0;
};

// A session's index.jsonl: one (file name, JSON line) per data file.
struct SessionIndex {
  bool loaded = false;
  std::vector<std::pair<std::string, std::string>> lines;
};

StoreResult Outcome(StoreStatus status, std::string message) {
  StoreResult result;
  result.status = status;
  result.message = std::move(message);
  return result;
}

}  // namespace

struct Archive::State {
  ArchiveOptions options;
  fs::path out, staging;
  int lock_fd = -1;
  std::atomic<uint64_t> staging_counter{0};

  mutable std::mutex mutex;                                             // guards everything below
  std::list<Entry> entries;                                             // oldest first
  std::unordered_map<std::string, std::list<Entry>::iterator> by_path;  // folder + "/" + name
  std::map<std::string, uint64_t> files_per_folder;
  std::map<std::string, SessionIndex> indexes;
  std::set<std::string> folders_stored;  // "<station>/<session>" stored into by this run
  ArchiveTotals totals;
  bool full = false;
  std::string full_message;

  bool Fits(uint64_t files, uint64_t bytes) const {
    return (options.max_files == 0 || files <= options.max_files) &&
           (options.max_bytes == 0 || bytes <= options.max_bytes);
  }

  std::string Limits() const {
    std::string text;
    if (options.max_files > 0) text += "--max-files " + std::to_string(options.max_files);
    if (options.max_bytes > 0) {
      text += (text.empty() ? "" : ", ") + std::string("--max-bytes ") +
              std::to_string(options.max_bytes);
    }
    return text;
  }

  SessionIndex& Index(const std::string& folder) {
    SessionIndex& index = indexes[folder];
    if (index.loaded) return index;
    index.loaded = true;
    std::ifstream in(out / folder / kIndexFile);
    std::string line;
    while (std::getline(in, line)) {
      // Keep the lines of files still in the archive; skip anything else
      // (e.g. a line for a file deleted by hand, or a foreign line).
      const Json parsed = Json::parse(line, nullptr, false);
      if (parsed.is_discarded() || !parsed.is_object() || !parsed.contains("file") ||
          !parsed["file"].is_string()) {
        continue;
      }
      const std::string name = parsed["file"].get<std::string>();
      if (by_path.count(folder + "/" + name)) index.lines.emplace_back(name, line);
    }
    return index;
  }

  // Moves `staged` into folder/name and fsyncs the folder.
  bool MoveIn(const fs::path& staged, const fs::path& target, std::string* error) {
    if (::rename(staged.c_str(), target.c_str()) != 0) {
      return SetError(
          error, ErrnoText("cannot move '" + staged.string() + "' to '" + target.string() + "'"));
    }
    return true;
  }

  // Replaces folder/index.jsonl with the index's lines (removes it and, if
  // then empty and `remove_empty`, the folder when no data file is left).
  bool WriteIndex(const std::string& folder, bool remove_empty, std::string* error) {
    SessionIndex& index = Index(folder);
    const fs::path dir = out / folder;
    if (index.lines.empty()) {
      std::error_code ignored;
      fs::remove(dir / kIndexFile, ignored);
      if (remove_empty && files_per_folder[folder] == 0) {
        fs::remove(dir, ignored);  // only if empty: foreign files stay
        files_per_folder.erase(folder);
        indexes.erase(folder);
      }
      return true;
    }
    std::string text;
    for (const auto& [name, line] : index.lines) text += line + "\n";
    const fs::path staged = staging / (std::to_string(staging_counter++) + "-" + kIndexFile);
    if (!WriteFileAtomically(staged.string(), text, error)) return false;
    if (!MoveIn(staged, dir / kIndexFile, error)) {
      std::error_code ignored;
      fs::remove(staged, ignored);
      return false;
    }
    return FsyncDir(dir, error);
  }

  void RemoveIndexLine(const std::string& folder, const std::string& name) {
    auto& lines = Index(folder).lines;
    std::erase_if(lines, [&](const auto& line) { return line.first == name; });
  }

  void Forget(std::list<Entry>::iterator entry) {
    totals.files -= 1;
    totals.bytes -= entry->bytes;
    files_per_folder[entry->folder] -= 1;
    by_path.erase(entry->folder + "/" + entry->name);
    entries.erase(entry);
  }

  // Deletes the oldest files until `files` more files of `bytes` (replacing
  // the ones in `replaced`) fit. False with *error if a file cannot be
  // deleted.
  bool Rotate(uint64_t files, uint64_t bytes, const std::set<std::string>& replaced,
              const std::string& keep_folder, StoreResult* result, std::string* error) {
    uint64_t replaced_files = 0, replaced_bytes = 0;
    for (const std::string& path : replaced) {
      replaced_files += 1;
      replaced_bytes += by_path.at(path)->bytes;
    }
    std::set<std::string> touched;
    bool ok = true;
    while (ok && !entries.empty() &&
           !Fits(totals.files - replaced_files + files, totals.bytes - replaced_bytes + bytes)) {
      const auto oldest = entries.begin();
      const std::string path = oldest->folder + "/" + oldest->name;
      if (::unlink((out / path).c_str()) != 0 && errno != ENOENT) {
        ok = SetError(error, ErrnoText("cannot delete the oldest file '" + (out / path).string() +
                                       "' to make room"));
        break;
      }
      if (replaced.count(path)) {
        replaced_files -= 1;
        replaced_bytes -= oldest->bytes;
      }
      result->rotated_files += 1;
      result->rotated_bytes += oldest->bytes;
      RemoveIndexLine(oldest->folder, oldest->name);
      touched.insert(oldest->folder);
      Forget(oldest);
    }
    for (const std::string& folder : touched) {
      if (folder == keep_folder) continue;  // rewritten by the commit
      std::string index_error;
      if (!WriteIndex(folder, true, &index_error) && ok) ok = SetError(error, index_error);
    }
    return ok;
  }

  StoreResult Store(const ItemInfo& item, std::vector<FileJob> jobs);
  StoreResult Commit(const ItemInfo& item, const std::string& session,
                     std::vector<StagedFile>* staged);
};

namespace {

void DiscardStaged(const std::vector<StagedFile>& staged) {
  for (const StagedFile& file : staged) {
    std::error_code ignored;
    fs::remove(file.staged, ignored);
  }
}

}  // namespace

StoreResult Archive::State::Store(const ItemInfo& item, std::vector<FileJob> jobs) {
  std::string station, session, why;
  if (!SanitizeWireName(item.station, &station, &why) || station != item.station) {
    return Outcome(StoreStatus::kRefused,
                   "station '" + PrintableForLog(item.station) + "' is not a valid folder name");
  }
  if (!SanitizeWireName(item.session, &session, &why)) {
    return Outcome(StoreStatus::kRefused, "session " + why);
  }
  if (item.view_index < -1) {
    return Outcome(StoreStatus::kRefused,
                   "view index " + std::to_string(item.view_index) + " is negative");
  }
  {
    std::lock_guard lock(mutex);
    if (full) return Outcome(StoreStatus::kLimitReached, full_message);
  }

  // Encode and write outside the lock: other items are written meanwhile.
  std::vector<StagedFile> staged;
  for (FileJob& job : jobs) {
    StagedFile file;
    file.staged = staging / (std::to_string(staging_counter++) + "-" + job.name);
    std::string error;
    const bool written = job.write(file.staged.string(), &error);
    std::error_code size_error;
    if (written) file.bytes = fs::file_size(file.staged, size_error);
    file.job = std::move(job);
    staged.push_back(std::move(file));
    if (!written || size_error) {
      DiscardStaged(staged);
      return Outcome(StoreStatus::kFailed, "cannot write " + staged.back().job.name + ": " +
                                               (written ? size_error.message() : error));
    }
  }
  StoreResult result = Commit(item, session, &staged);
  if (result.status != StoreStatus::kStored) DiscardStaged(staged);
  return result;
}

StoreResult Archive::State::Commit(const ItemInfo& item, const std::string& session,
                                   std::vector<StagedFile>* staged) {
  const std::string folder = item.station + "/" + session;
  std::lock_guard lock(mutex);
  if (full) return Outcome(StoreStatus::kLimitReached, full_message);
  uint64_t files = 0, bytes = 0;
  std::set<std::string> replaced;  // files of this item already in the archive
  for (const StagedFile& file : *staged) {
    files += 1;
    bytes += file.bytes;
    if (by_path.count(folder + "/" + file.job.name)) replaced.insert(folder + "/" + file.job.name);
  }
  StoreResult result;
  uint64_t replaced_files = 0, replaced_bytes = 0;
  for (const std::string& path : replaced) {
    replaced_files += 1;
    replaced_bytes += by_path.at(path)->bytes;
  }
  if (!Fits(totals.files - replaced_files + files, totals.bytes - replaced_bytes + bytes)) {
    const std::string what =
        std::to_string(files) + " file(s) of " + std::to_string(bytes) + " bytes (" + folder + ")";
    if (options.on_limit == LimitPolicy::kStop) {
      full = true;
      full_message = "archive limit reached (" + Limits() + "): it holds " +
                     std::to_string(totals.files) + " files, " + std::to_string(totals.bytes) +
                     " bytes; " + what + " would exceed it";
      return Outcome(StoreStatus::kLimitReached, full_message);
    }
    if (!Fits(files, bytes)) {
      return Outcome(StoreStatus::kTooLarge,
                     what + " exceed the limit (" + Limits() + ") on their own; skipped");
    }
    std::string error;
    if (!Rotate(files, bytes, replaced, folder, &result, &error)) {
      return Outcome(StoreStatus::kFailed, error);
    }
  }

  // Folders: new ones (and their parents' entries) made durable.
  const fs::path dir = out / folder;
  std::error_code ignored, fs_error;
  const bool station_existed = fs::is_directory(out / item.station, ignored);
  const bool session_existed = fs::is_directory(dir, ignored);
  fs::create_directories(dir, fs_error);
  std::string error;
  if (fs_error) {
    return Outcome(StoreStatus::kFailed,
                   "cannot create folder '" + dir.string() + "': " + fs_error.message());
  }
  if ((!session_existed && !FsyncDir(out / item.station, &error)) ||
      (!station_existed && !FsyncDir(out, &error))) {
    return Outcome(StoreStatus::kFailed, error);
  }

  std::size_t moved = 0;
  for (; moved < staged->size(); ++moved) {
    if (!MoveIn((*staged)[moved].staged, dir / (*staged)[moved].job.name, &error)) break;
  }
  if (moved < staged->size() || !FsyncDir(dir, &error)) {
    // Whole items only: take back what was moved in. (A replaced file is
    // lost here; the message says so.)
    for (std::size_t i = 0; i < moved; ++i) {
      fs::remove(dir / (*staged)[i].job.name, ignored);
      const auto old = by_path.find(folder + "/" + (*staged)[i].job.name);
      if (old != by_path.end()) {
        RemoveIndexLine(folder, (*staged)[i].job.name);
        Forget(old->second);
      }
    }
    return Outcome(StoreStatus::kFailed, error);
  }

  // Accounting and index.
  SessionIndex& index = Index(folder);
  const std::string now = UtcNow();
  for (const StagedFile& file : *staged) {
    const auto old = by_path.find(folder + "/" + file.job.name);
    if (old != by_path.end()) Forget(old->second);
    RemoveIndexLine(folder, file.job.name);
    entries.push_back({folder, file.job.name, file.bytes});
    by_path[folder + "/" + file.job.name] = std::prev(entries.end());
    files_per_folder[folder] += 1;
    folders_stored.insert(folder);
    totals.files += 1;
    totals.bytes += file.bytes;

    Json line = Json::object();
    line["time"] = now;
    line["station"] = item.station;
    line["session"] = session;
    if (session != item.session) line["session_raw"] = item.session;
    line["view"] = item.view_index;
    line["kind"] = file.job.kind;
    line["file"] = file.job.name;
    line["bytes"] = file.bytes;
    line["stamp_ns"] = item.stamp_ns;
    for (const auto& [key, value] : file.job.extra.items()) line[key] = value;
    // Invalid UTF-8 from the wire becomes U+FFFD rather than an exception.
    index.lines.emplace_back(file.job.name,
                             line.dump(-1, ' ', false, Json::error_handler_t::replace));
    result.files += 1;
    result.bytes += file.bytes;
  }
  if (!WriteIndex(folder, false, &error)) {
    result.status = StoreStatus::kFailed;
    result.message = "stored " + std::to_string(result.files) + " file(s) in '" + dir.string() +
                     "' but could not update " + kIndexFile + ": " + error;
    staged->clear();  // moved in: nothing left to discard
    return result;
  }
  staged->clear();
  result.status = StoreStatus::kStored;
  return result;
}

// --- Public functions ------------------------------------------------------

bool ParseByteSize(std::string_view text, uint64_t* bytes, std::string* why) {
  const std::string quoted = "'" + PrintableForLog(text) + "'";
  std::size_t digits = 0;
  while (digits < text.size() && std::isdigit(static_cast<unsigned char>(text[digits]))) ++digits;
  if (digits == 0) return SetError(why, quoted + " is not a byte count (e.g. 500M, 2G, 1048576)");
  uint64_t value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + digits, value);
  if (ec != std::errc() || end != text.data() + digits) {
    return SetError(why, quoted + " is too large");
  }
  std::string suffix;
  for (char c : text.substr(digits))
    suffix += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  uint64_t multiplier = 0;
  if (suffix.empty() || suffix == "b") {
    multiplier = 1;
  } else {
    static const std::pair<char, uint64_t> kUnits[] = {
        {'k', 1ull << 10}, {'m', 1ull << 20}, {'g', 1ull << 30}, {'t', 1ull << 40}};
    for (const auto& [unit, factor] : kUnits) {
      if (suffix[0] == unit &&
          (suffix.size() == 1 || suffix.substr(1) == "b" || suffix.substr(1) == "ib")) {
        multiplier = factor;
      }
    }
  }
  if (multiplier == 0) {
    return SetError(why, quoted + ": unknown unit (use K, M, G or T, binary multiples)");
  }
  if (value == 0) return SetError(why, quoted + " must be at least 1 byte");
  if (value > std::numeric_limits<uint64_t>::max() / multiplier) {
    return SetError(why, quoted + " is too large");
  }
  *bytes = value * multiplier;
  return true;
}

bool SanitizeWireName(std::string_view raw, std::string* safe, std::string* why) {
  const auto refuse = [&](const std::string& reason) {
    return SetError(why, "name '" + PrintableForLog(raw) + "' " + reason);
  };
  if (raw.empty()) return refuse("is empty");
  if (raw.size() > kMaxWireNameBytes) {
    return refuse("is longer than " + std::to_string(kMaxWireNameBytes) + " bytes");
  }
  if (raw.front() == '.') return refuse("starts with '.'");
  if (raw.find("..") != std::string_view::npos) return refuse("contains '..'");
  std::string result(raw);
  for (char& c : result) {
    const bool allowed =
        std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-';
    if (!allowed || static_cast<unsigned char>(c) >= 0x80) c = '_';
  }
  *safe = std::move(result);
  return true;
}

std::string PrintableForLog(std::string_view raw) {
  constexpr std::size_t kMaxShown = 80;
  std::string text;
  for (std::size_t i = 0; i < raw.size() && i < kMaxShown; ++i) {
    const unsigned char c = static_cast<unsigned char>(raw[i]);
    if (c == '\\' || c == '\'' || c == '"') {
      text += '\\';
      text += static_cast<char>(c);
    } else if (c < 0x20 || c >= 0x7f) {
      char hex[8];
      std::snprintf(hex, sizeof(hex), "\\x%02x", c);
      text += hex;
    } else {
      text += static_cast<char>(c);
    }
  }
  if (raw.size() > kMaxShown) text += "...";
  return text;
}

std::string_view ToString(StoreStatus status) {
  switch (status) {
    case StoreStatus::kStored:
      return "stored";
    case StoreStatus::kRefused:
      return "refused";
    case StoreStatus::kLimitReached:
      return "limit_reached";
    case StoreStatus::kTooLarge:
      return "too_large";
    case StoreStatus::kFailed:
      return "failed";
  }
  return "unknown";
}

bool ArchiveOptions::IsValid(std::string* why) const {
  if (out_dir.empty()) return SetError(why, "out_dir is empty");
  return true;
}

std::unique_ptr<Archive> Archive::Open(const ArchiveOptions& options, std::string* error) {
  if (!options.IsValid(error)) return nullptr;
  auto state = std::make_unique<State>();
  state->options = options;
  state->out = fs::path(options.out_dir);
  state->staging = state->out / kStagingDir;
  const std::string where = "archive '" + options.out_dir + "'";
  std::error_code fs_error;
  fs::create_directories(state->out, fs_error);
  if (fs_error) {
    SetError(error, where + ": cannot create it: " + fs_error.message());
    return nullptr;
  }
  const fs::path lock_path = state->out / kLockFile;
  state->lock_fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (state->lock_fd < 0) {
    SetError(error, where + ": " + ErrnoText("cannot open " + lock_path.string()));
    return nullptr;
  }
  if (::flock(state->lock_fd, LOCK_EX | LOCK_NB) != 0) {
    SetError(error, where + " is in use by another craftscan-record (" +
                        ErrnoText("lock " + lock_path.string()) + ")");
    ::close(state->lock_fd);
    return nullptr;
  }
  // From here on the destructor releases the lock.
  std::unique_ptr<Archive> archive(new Archive(std::move(state)));
  State& s = *archive->state_;
  fs::remove_all(s.staging, fs_error);
  if (!fs_error) fs::create_directory(s.staging, fs_error);
  if (fs_error) {
    SetError(error, where + ": cannot prepare " + s.staging.string() + ": " + fs_error.message());
    return nullptr;
  }

  // Index what earlier runs recorded, oldest first.
  struct Found {
    int64_t mtime_ns;
    std::string folder, name;
    uint64_t bytes;
  };
  std::vector<Found> found;
  const auto is_ours = [](const fs::directory_entry& entry) {
    std::string safe;
    const std::string name = entry.path().filename().string();
    std::error_code ignored;
    return entry.is_directory(ignored) && SanitizeWireName(name, &safe, nullptr) && safe == name;
  };
  for (fs::directory_iterator station(s.out, fs_error), end; !fs_error && station != end;
       station.increment(fs_error)) {
    if (!is_ours(*station)) continue;
    std::error_code inner_error;
    for (fs::directory_iterator session(station->path(), inner_error);
         !inner_error && session != end; session.increment(inner_error)) {
      if (!is_ours(*session)) continue;
      std::error_code file_error;
      for (fs::directory_iterator file(session->path(), file_error); !file_error && file != end;
           file.increment(file_error)) {
        const std::string name = file->path().filename().string();
        struct stat info {};
        if (!IsDataFileName(name) || ::stat(file->path().c_str(), &info) != 0 ||
            !S_ISREG(info.st_mode)) {
          continue;
        }
        found.push_back(
            {int64_t{info.st_mtim.tv_sec} * 1'000'000'000 + info.st_mtim.tv_nsec,
             station->path().filename().string() + "/" + session->path().filename().string(), name,
             static_cast<uint64_t>(info.st_size)});
      }
    }
  }
  if (fs_error) {
    SetError(error, where + ": cannot list it: " + fs_error.message());
    return nullptr;
  }
  std::sort(found.begin(), found.end(), [](const Found& a, const Found& b) {
    return std::tie(a.mtime_ns, a.folder, a.name) < std::tie(b.mtime_ns, b.folder, b.name);
  });
  for (const Found& file : found) {
    s.entries.push_back({file.folder, file.name, file.bytes});
    s.by_path[file.folder + "/" + file.name] = std::prev(s.entries.end());
    s.files_per_folder[file.folder] += 1;
    s.totals.files += 1;
    s.totals.bytes += file.bytes;
  }
  return archive;
}

Archive::Archive(std::unique_ptr<State> state) : state_(std::move(state)) {}

Archive::~Archive() {
  std::error_code ignored;
  fs::remove_all(state_->staging, ignored);
  if (state_->lock_fd >= 0) ::close(state_->lock_fd);  // releases the flock
}

StoreResult Archive::StoreCapture(const ItemInfo& item, const cv::Mat& left, const cv::Mat& right,
                                  double angle_deg) {
  if (left.empty() || left.size() != right.size() || left.type() != right.type() ||
      (left.type() != CV_8UC1 && left.type() != CV_8UC3)) {
    return Outcome(StoreStatus::kRefused,
                   "a capture needs two non-empty images of the same size, both 8-bit grey or "
                   "both 8-bit BGR");
  }
  if (item.view_index < 0) {
    return Outcome(StoreStatus::kRefused,
                   "capture view index " + std::to_string(item.view_index) + " is negative");
  }
  const std::string view = ViewNumber(item.view_index);
  Json extra = Json::object();
  extra["angle_deg"] = angle_deg;
  extra["width"] = left.cols;
  extra["height"] = left.rows;
  extra["encoding"] = left.type() == CV_8UC1 ? "mono8" : "bgr8";
  std::vector<FileJob> jobs;
  jobs.push_back(
      {"view_" + view + "_left.png", "left",
       [&left](const std::string& path, std::string* error) { return WritePng(path, left, error); },
       extra});
  jobs.push_back({"view_" + view + "_right.png", "right",
                  [&right](const std::string& path, std::string* error) {
                    return WritePng(path, right, error);
                  },
                  extra});
  return state_->Store(item, std::move(jobs));
}

StoreResult Archive::StoreCloud(const ItemInfo& item, const PointCloud& cloud,
                                const cv::Matx44d& world_from_view) {
  std::string why;
  if (!cloud.IsValid(&why)) return Outcome(StoreStatus::kRefused, "invalid cloud: " + why);
  if (item.view_index < -1) {
    return Outcome(StoreStatus::kRefused,
                   "cloud view index " + std::to_string(item.view_index) + " is below -1");
  }
  const bool fused = item.view_index == -1;
  Json extra = Json::object();
  extra["points"] = cloud.size();
  extra["has_colors"] = cloud.HasColors();
  extra["has_normals"] = cloud.HasNormals();
  Json pose = Json::array();
  for (int i = 0; i < 16; ++i) pose.push_back(world_from_view.val[i]);
  extra["world_from_view"] = std::move(pose);
  std::vector<FileJob> jobs;
  jobs.push_back(
      {fused ? std::string("fused.ply") : "cloud_" + ViewNumber(item.view_index) + ".ply",
       fused ? "fused" : "cloud",
       [&cloud](const std::string& path, std::string* error) {
         return WritePly(path, cloud, /*binary=*/true, error);
       },
       std::move(extra)});
  return state_->Store(item, std::move(jobs));
}

StoreResult Archive::StoreDisparity(const ItemInfo& item, const cv::Mat& disparity) {
  if (disparity.empty() || disparity.type() != CV_32FC1 || disparity.cols > kMaxPfmSide ||
      disparity.rows > kMaxPfmSide) {
    return Outcome(StoreStatus::kRefused, "a disparity map must be CV_32FC1 with sides 1.." +
                                              std::to_string(kMaxPfmSide) + " px");
  }
  if (item.view_index < 0) {
    return Outcome(StoreStatus::kRefused,
                   "disparity view index " + std::to_string(item.view_index) + " is negative");
  }
  Json extra = Json::object();
  extra["width"] = disparity.cols;
  extra["height"] = disparity.rows;
  std::vector<FileJob> jobs;
  jobs.push_back({"disparity_" + ViewNumber(item.view_index) + ".pfm", "disparity",
                  [&disparity](const std::string& path, std::string* error) {
                    return WritePfm(path, disparity, error);
                  },
                  std::move(extra)});
  return state_->Store(item, std::move(jobs));
}

StoreResult Archive::StoreModel(const ItemInfo& item, const std::string& glb) {
  if (glb.empty()) return Outcome(StoreStatus::kRefused, "an empty model");
  if (item.view_index != -1) {
    return Outcome(StoreStatus::kRefused,
                   "model view index " + std::to_string(item.view_index) + " is not -1");
  }
  Json extra = Json::object();
  extra["format"] = "glb";
  std::vector<FileJob> jobs;
  jobs.push_back({"mesh.glb", "model",
                  [&glb](const std::string& path, std::string* error) {
                    return WriteFileAtomically(path, glb, error);
                  },
                  std::move(extra)});
  return state_->Store(item, std::move(jobs));
}

ArchiveTotals Archive::totals() const {
  std::lock_guard lock(state_->mutex);
  return state_->totals;
}

const ArchiveOptions& Archive::options() const { return state_->options; }

Status Archive::WriteBags(const std::string& bag_root, const std::string& source_organization,
                          std::vector<BagSummary>* bags) const {
  std::lock_guard lock(state_->mutex);
  if (Status free = CheckBagTarget(bag_root); !free.ok()) return free;
  for (const std::string& folder : state_->folders_stored) {
    const fs::path source = state_->out / folder;
    const auto held = state_->files_per_folder.find(folder);
    if (held == state_->files_per_folder.end() || held->second == 0) continue;  // rotated out
    Status status;
    std::unique_ptr<BagWriter> bag =
        BagWriter::Start((fs::path(bag_root) / folder).string(), &status);
    if (!bag) return status;
    std::error_code ec;
    for (const fs::directory_entry& entry : fs::directory_iterator(source, ec)) {
      if (!entry.is_regular_file() || entry.path().filename().string().front() == '.') continue;
      status = bag->AddFile(entry.path().string(), entry.path().filename().string());
      if (!status.ok()) return status;
    }
    if (ec)
      return Status(ErrorCodeFromErrno(ec.value()), "'" + source.string() + "': " + ec.message());
    BagSummary summary;
    const std::string session = fs::path(folder).filename().string();
    status = bag->Finish({source_organization, session, ""}, {}, &summary);
    if (!status.ok()) return status;
    if (bags) bags->push_back(summary);
  }
  return Status::Ok();
}

}  // namespace craftscan::record
