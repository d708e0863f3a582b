// BagWriter: staging folder → payload hashed from disk → tag files → rename.
#include "craftscan/pipeline/common/bagit.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <vector>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/sha256.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;

constexpr const char* kBagitTxt = "BagIt-Version: 1.0\nTag-File-Character-Encoding: UTF-8\n";

// fsync of a file, or of a folder (so renames in it are durable).
Status SyncPath(const std::string& path, int flags = 0) {
  // (Built with append: GCC 12 warns falsely on `"'" + string`, PR 105651.)
  std::string context("'");
  context.append(path).append("'");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | flags);
  if (fd < 0) return Status::FromErrno(errno, context);
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  return rc == 0 ? Status::Ok() : Status::FromErrno(err, context + ": fsync");
}

Status SyncDir(const std::string& dir) { return SyncPath(dir, O_DIRECTORY); }

// A manifest path as RFC 8493 §2.1.3 wants it: CR, LF and '%' percent-encoded.
std::string EncodePath(const std::string& path) {
  std::string out;
  for (const char c : path) {
    if (c == '%') {
      out += "%25";
    } else if (c == '\r') {
      out += "%0D";
    } else if (c == '\n') {
      out += "%0A";
    } else {
      out.push_back(c);
    }
  }
  return out;
}

std::string TodayUtc() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&now, &tm);
  char text[16];
  std::strftime(text, sizeof text, "%Y-%m-%d", &tm);
  return text;
}

bool IsDate(const std::string& text) {
  if (text.size() != 10 || text[4] != '-' || text[7] != '-') return false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (i != 4 && i != 7 && (text[i] < '0' || text[i] > '9')) return false;
  }
  const int month = std::stoi(text.substr(5, 2)), day = std::stoi(text.substr(8, 2));
  return month >= 1 && month <= 12 && day >= 1 && day <= 31;
}

}  // namespace

bool BagInfo::IsValid(std::string* why) const {
  const auto field = [&](const char* name, const std::string& value) {
    if (value.empty()) return Fail(why, std::string("bag-info ") + name + " is empty");
    if (value.find_first_of("\r\n") != std::string::npos) {
      return Fail(why, std::string("bag-info ") + name + " has a line break");
    }
    return true;
  };
  if (!field("Source-Organization", source_organization) ||
      !field("External-Identifier", external_identifier)) {
    return false;
  }
  if (!bagging_date.empty() && !IsDate(bagging_date)) {
    return Fail(why, "bag-info Bagging-Date '" + bagging_date + "' is not YYYY-MM-DD");
  }
  return true;
}

Status CheckBagTarget(const std::string& dir) {
  std::error_code ec;
  const fs::file_status st = fs::symlink_status(dir, ec);
  if (!fs::exists(st)) return Status::Ok();
  if (!fs::is_directory(st)) {
    return Status(ErrorCode::kAlreadyExists, "bag folder '" + dir + "' exists and is not a folder");
  }
  if (!fs::is_empty(dir, ec) || ec) {
    return Status(ErrorCode::kAlreadyExists,
                  "bag folder '" + dir +
                      "' exists and is not empty: a bag is written only to a new or empty folder");
  }
  return Status::Ok();
}

BagWriter::BagWriter(std::string bag_dir, std::string staging_dir)
    : bag_dir_(std::move(bag_dir)),
      staging_dir_(std::move(staging_dir)),
      data_dir_(staging_dir_ + "/data") {}

BagWriter::~BagWriter() {
  if (finished_) return;
  std::error_code ec;
  fs::remove_all(staging_dir_, ec);
}

std::unique_ptr<BagWriter> BagWriter::Start(const std::string& bag_dir, Status* status) {
  const auto fail = [&](Status s) {
    *status = std::move(s);
    return nullptr;
  };
  if (bag_dir.empty()) return fail(Status(ErrorCode::kInvalidArgument, "empty bag folder"));
  fs::path target = fs::path(bag_dir).lexically_normal();
  if (target.filename().empty()) target = target.parent_path();  // "bag/" → "bag"
  if (Status free = CheckBagTarget(target.string()); !free.ok()) return fail(free);
  std::error_code ec;
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  fs::create_directories(parent, ec);
  if (ec) {
    return fail(Status(ErrorCodeFromErrno(ec.value()),
                       "cannot create '" + parent.string() + "': " + ec.message()));
  }
  // (Built with append: GCC 12 warns falsely on `"." + string`, PR 105651.)
  std::string name(".");
  name.append(target.filename().string()).append(".bagit-XXXXXX");
  std::string staging = (parent / name).string();
  if (!::mkdtemp(staging.data())) {
    return fail(
        Status::FromErrno(errno, "cannot create a staging folder in '" + parent.string() + "'"));
  }
  std::unique_ptr<BagWriter> writer(new BagWriter(target.string(), staging));
  // mkdtemp makes it 0700; a bag is read by others like any output.
  fs::permissions(staging, static_cast<fs::perms>(0777 & ~ProcessUmask()), ec);
  fs::create_directory(writer->data_dir_, ec);
  if (ec) {
    return fail(Status(ErrorCodeFromErrno(ec.value()),
                       "cannot create '" + writer->data_dir_ + "': " + ec.message()));
  }
  *status = Status::Ok();
  return writer;
}

Status BagWriter::AddFile(const std::string& source, const std::string& relative) {
  const fs::path rel(relative);
  if (relative.empty() || rel.is_absolute()) {
    return Status(ErrorCode::kInvalidArgument, "payload path '" + relative + "' is not relative");
  }
  for (const fs::path& part : rel) {
    if (part == "." || part == "..") {
      return Status(ErrorCode::kInvalidArgument,
                    "payload path '" + relative + "' has a '.' or '..' component");
    }
  }
  const fs::path target = fs::path(data_dir_) / rel;
  std::error_code ec;
  fs::create_directories(target.parent_path(), ec);
  if (!ec) fs::copy_file(source, target, fs::copy_options::overwrite_existing, ec);
  if (ec) {
    return Status(ErrorCodeFromErrno(ec.value()),
                  "cannot copy '" + source + "' into the bag: " + ec.message());
  }
  return SyncPath(target.string());
}

Status BagWriter::Finish(const BagInfo& info,
                         const std::map<std::string, std::string>& expected_sha256,
                         BagSummary* summary) {
  if (finished_) return Status(ErrorCode::kFailedPrecondition, "the bag is already finished");
  std::string why;
  if (!info.IsValid(&why)) return Status(ErrorCode::kInvalidArgument, why);
  // The payload, sorted by path (a stable, diffable manifest).
  std::map<std::string, std::string> payload;  // relative to data/ → absolute
  std::error_code ec;
  for (fs::recursive_directory_iterator it(data_dir_, ec), end; !ec && it != end;
       it.increment(ec)) {
    const fs::file_status st = it->symlink_status(ec);
    if (ec) break;
    if (fs::is_directory(st)) continue;
    const std::string relative = fs::relative(it->path(), data_dir_).generic_string();
    if (!fs::is_regular_file(st)) {
      return Status(ErrorCode::kInvalidArgument,
                    "payload 'data/" + relative + "' is not a regular file");
    }
    payload[relative] = it->path().string();
  }
  if (ec) return Status(ErrorCodeFromErrno(ec.value()), "'" + data_dir_ + "': " + ec.message());
  if (payload.empty()) return Status(ErrorCode::kInvalidArgument, "the bag's payload is empty");

  std::string manifest;
  BagSummary totals;
  totals.path = bag_dir_;
  for (const auto& [relative, path] : payload) {
    std::string hex;
    std::uint64_t size = 0;
    if (Status hashed = Sha256OfFile(path, &hex, &size); !hashed.ok()) return hashed;
    const auto expected = expected_sha256.find(relative);
    if (expected != expected_sha256.end() && expected->second != hex) {
      return Status(ErrorCode::kCorrupt, "payload 'data/" + relative + "': SHA-256 " + hex +
                                             " differs from the expected " + expected->second);
    }
    manifest += hex + "  data/" + EncodePath(relative) + "\n";
    totals.payload_bytes += size;
    ++totals.payload_files;
  }
  const std::string bag_info =
      "Source-Organization: " + info.source_organization +
      "\nExternal-Identifier: " + info.external_identifier +
      "\nBagging-Date: " + (info.bagging_date.empty() ? TodayUtc() : info.bagging_date) +
      "\nPayload-Oxum: " + std::to_string(totals.payload_bytes) + "." +
      std::to_string(totals.payload_files) + "\n";
  // Tag files, then the tag manifest over them (sorted by name).
  const std::map<std::string, std::string> tags = {
      {"bag-info.txt", bag_info}, {"bagit.txt", kBagitTxt}, {"manifest-sha256.txt", manifest}};
  std::string tag_manifest;
  for (const auto& [name, text] : tags) {
    if (Status written = WriteFileAtomically(staging_dir_ + "/" + name, text); !written.ok()) {
      return written;
    }
    tag_manifest += Sha256Hex(text) + "  " + name + "\n";
  }
  if (Status written = WriteFileAtomically(staging_dir_ + "/tagmanifest-sha256.txt", tag_manifest);
      !written.ok()) {
    return written;
  }
  // The payload's folders, so their entries are durable before the rename.
  for (fs::recursive_directory_iterator it(data_dir_, ec), end; !ec && it != end;
       it.increment(ec)) {
    if (it->is_directory(ec)) {
      if (Status synced = SyncDir(it->path().string()); !synced.ok()) return synced;
    }
  }
  if (Status synced = SyncDir(data_dir_); !synced.ok()) return synced;
  // rename(2) replaces an empty folder at the target; anything else there
  // now (made since Start) makes it fail rather than mix.
  if (::rename(staging_dir_.c_str(), bag_dir_.c_str()) != 0) {
    return Status::FromErrno(
        errno, "cannot rename the finished bag '" + staging_dir_ + "' to '" + bag_dir_ + "'");
  }
  finished_ = true;
  const fs::path parent =
      fs::path(bag_dir_).has_parent_path() ? fs::path(bag_dir_).parent_path() : fs::path(".");
  if (Status synced = SyncDir(parent.string()); !synced.ok()) return synced;
  if (summary) *summary = totals;
  return Status::Ok();
}

}  // namespace craftscan
