// FileAssembler: in-order chunks → hidden temporaries → checked → renamed.
#include "craftscan/client/file_assembler.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <set>
#include <utility>

namespace craftscan::client {
namespace {

namespace fs = std::filesystem;

bool IsNameChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
         c == '_' || c == '-';
}

bool WriteAll(int fd, const std::uint8_t* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

// fsync of a folder, so a rename in it is durable.
void SyncDir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

void Fnv1a64Hasher::Update(const void* data, std::size_t size) {
  const auto* p = static_cast<const std::uint8_t*>(data);
  std::uint64_t h = hash_;
  for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 1099511628211ull;
  hash_ = h;
}

std::optional<std::uint64_t> ParseHex64(std::string_view text) {
  std::uint64_t value = 0;
  if (text.size() != 16 || text.find_first_not_of("0123456789abcdef") != std::string_view::npos ||
      std::from_chars(text.data(), text.data() + text.size(), value, 16).ec != std::errc()) {
    return std::nullopt;
  }
  return value;
}

std::string Hex64(std::uint64_t value) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(value));
  return text;
}

bool IsSafeFileName(std::string_view name, std::string* why) {
  auto fail = [&](const std::string& message) {
    if (why) *why = message;
    return false;
  };
  if (name.empty() || name.size() > 200) return fail("file name must be 1..200 bytes");
  int components = 0;
  std::size_t start = 0;
  while (start <= name.size()) {
    const std::size_t end = std::min(name.find('/', start), name.size());
    const std::string_view part = name.substr(start, end - start);
    if (part.empty()) return fail("file name '" + std::string(name) + "' has an empty component");
    if (part.front() == '.' || part.front() == '-') {
      return fail("file name '" + std::string(name) + "' has a component starting with '" +
                  part.front() + "'");
    }
    for (char c : part) {
      if (!IsNameChar(c)) {
        return fail("file name '" + std::string(name) +
                    "' has a character other than A-Z a-z 0-9 . _ - /");
      }
    }
    if (++components > 4) return fail("file name '" + std::string(name) + "' is nested too deep");
    start = end + 1;
  }
  return true;
}

FileAssembler::FileAssembler(std::string out_dir) : out_dir_(std::move(out_dir)) {}

FileAssembler::~FileAssembler() {
  CloseCurrent();
  if (!current_finished_ && !temp_path_.empty()) ::unlink(temp_path_.c_str());
  for (const Pending& p : pending_) ::unlink(p.temp_path.c_str());
}

void FileAssembler::CloseCurrent() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

bool FileAssembler::Fail(std::string message, std::string* error) {
  failed_ = true;
  CloseCurrent();
  if (!current_finished_ && !temp_path_.empty()) ::unlink(temp_path_.c_str());
  temp_path_.clear();
  for (const Pending& p : pending_) ::unlink(p.temp_path.c_str());
  pending_.clear();
  if (error) *error = std::move(message);
  return false;
}

bool FileAssembler::FailLocally(std::string message, std::string* error) {
  failed_locally_ = true;
  return Fail(std::move(message), error);
}

std::uint64_t FileAssembler::bytes_expected() const {
  std::uint64_t total = 0;
  if (expected_) {
    for (const ExpectedFile& f : *expected_) total += f.size_bytes;
  }
  return total;
}

bool FileAssembler::Complete() const {
  return !failed_ && expected_ && done_.size() == expected_->size();
}

bool FileAssembler::SetExpected(std::vector<ExpectedFile> files, std::string* error) {
  if (failed_) return Fail("the transfer already failed", error);
  if (files.empty()) return Fail("the station listed no files", error);
  std::set<std::string> names;
  for (const ExpectedFile& f : files) {
    std::string why;
    if (!IsSafeFileName(f.name, &why)) return Fail("the station listed an unsafe " + why, error);
    if (!names.insert(f.name).second)
      return Fail("the station listed '" + f.name + "' twice", error);
    if (!f.sha256.empty() && !IsSha256Hex(f.sha256)) {
      return Fail("the station listed '" + f.name + "' with a malformed SHA-256", error);
    }
  }
  if (file_count_ != 0 && file_count_ != files.size()) {
    return Fail("the station announced " + std::to_string(files.size()) +
                    " files but its chunks say " + std::to_string(file_count_),
                error);
  }
  if (index_ >= 0 && (static_cast<std::size_t>(index_) >= files.size() ||
                      files[static_cast<std::size_t>(index_)].name != name_)) {
    return Fail("the chunks received do not match the station's list", error);
  }
  expected_ = std::move(files);
  return Settle(error);
}

bool FileAssembler::StartFile(const FileChunk& chunk, std::string* error) {
  std::string why;
  if (!IsSafeFileName(chunk.name, &why)) return Fail("the station sent an unsafe " + why, error);
  const fs::path target = fs::path(out_dir_) / std::string(chunk.name);
  const fs::path folder = target.parent_path();
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) return FailLocally("cannot create '" + folder.string() + "': " + ec.message(), error);
  // (Built with append: GCC 12 warns falsely on `"." + string`, PR 105651.)
  std::string temp_name(".");
  temp_name.append(target.filename().string()).append(".tmp-XXXXXX");
  std::string temp = (folder / temp_name).string();
  const int fd = ::mkstemp(temp.data());
  if (fd < 0) {
    return FailLocally("cannot create a file in '" + folder.string() + "': " + std::strerror(errno),
                       error);
  }
  ::fcntl(fd, F_SETFD, FD_CLOEXEC);
  fd_ = fd;
  temp_path_ = temp;
  index_ = chunk.file_index;
  name_ = std::string(chunk.name);
  total_ = chunk.total_size;
  offset_ = 0;
  current_finished_ = false;
  hash_ = Fnv1a64Hasher();
  sha256_ = Sha256Hasher();
  return true;
}

bool FileAssembler::Accept(const FileChunk& chunk, std::string* error) {
  if (failed_) return Fail("the transfer already failed", error);
  if (!chunk.error.empty()) {
    return Fail(
        "the station could not send '" + std::string(chunk.name) + "': " + std::string(chunk.error),
        error);
  }
  if (chunk.file_count == 0 || chunk.file_index >= chunk.file_count) {
    return Fail("malformed chunk: file " + std::to_string(chunk.file_index) + " of " +
                    std::to_string(chunk.file_count),
                error);
  }
  if (file_count_ == 0) file_count_ = chunk.file_count;
  if (chunk.file_count != file_count_ || (expected_ && chunk.file_count != expected_->size())) {
    return Fail("malformed chunk: the file count changed during the transfer", error);
  }
  // In order: continue the current file, or start the next one after the
  // current one ended.
  const bool continues =
      !current_finished_ && chunk.file_index == index_ && chunk.offset == offset_;
  const bool next = current_finished_ && chunk.file_index == index_ + 1 && chunk.offset == 0;
  if (!continues && !next) {
    const std::string want =
        current_finished_
            ? "file " + std::to_string(index_ + 1) + " from offset 0"
            : "file " + std::to_string(index_) + " at offset " + std::to_string(offset_);
    return Fail("chunks were lost: expected " + want + ", got file " +
                    std::to_string(chunk.file_index) + " at offset " +
                    std::to_string(chunk.offset) +
                    " (the receiver fell behind or the network dropped data; try again)",
                error);
  }
  if (expected_) {
    const ExpectedFile& e = (*expected_)[chunk.file_index];
    if (chunk.name != e.name || chunk.total_size != e.size_bytes) {
      return Fail("chunk of '" + std::string(chunk.name) + "' (" +
                      std::to_string(chunk.total_size) + " bytes) does not match the listed '" +
                      e.name + "' (" + std::to_string(e.size_bytes) + " bytes)",
                  error);
    }
  }
  if (next && !StartFile(chunk, error)) return false;
  if (chunk.name != name_ || chunk.total_size != total_) {
    return Fail("malformed chunk: name or size changed within '" + name_ + "'", error);
  }
  if (chunk.size > total_ - offset_) {
    return Fail("malformed chunk: data past the end of '" + name_ + "'", error);
  }
  if (chunk.size > 0 && !WriteAll(fd_, chunk.data, chunk.size)) {
    return FailLocally("cannot write '" + temp_path_ + "': " + std::strerror(errno), error);
  }
  hash_.Update(chunk.data, chunk.size);
  sha256_.Update(chunk.data, chunk.size);
  offset_ += chunk.size;
  bytes_received_ += chunk.size;
  if (chunk.last != (offset_ == total_)) {
    return Fail(chunk.last ? "'" + name_ + "' ended after " + std::to_string(offset_) + " of " +
                                 std::to_string(total_) + " bytes"
                           : "'" + name_ + "' has more data than announced",
                error);
  }
  if (chunk.last) return FinishFile(error);
  return true;
}

bool FileAssembler::FinishFile(std::string* error) {
  if (::fchmod(fd_, 0644) != 0 || ::fsync(fd_) != 0) {
    return FailLocally("cannot fsync '" + temp_path_ + "': " + std::strerror(errno), error);
  }
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0)
    return FailLocally("cannot close '" + temp_path_ + "': " + std::strerror(errno), error);
  pending_.push_back({static_cast<std::uint32_t>(index_), name_, temp_path_, total_, hash_.value(),
                      sha256_.HexDigest()});
  current_finished_ = true;
  temp_path_.clear();
  return Settle(error);
}

bool FileAssembler::Settle(std::string* error) {
  if (!expected_) return true;
  std::vector<Pending> batch = std::move(pending_);
  pending_.clear();
  for (std::size_t i = 0; i < batch.size(); ++i) {
    const Pending& p = batch[i];
    const ExpectedFile& e = (*expected_)[p.index];
    std::string problem;
    bool local = false;
    const std::string final_path = (fs::path(out_dir_) / p.name).string();
    if (p.name != e.name || p.size_bytes != e.size_bytes) {
      problem = "'" + p.name + "' does not match the station's list";
    } else if (!e.sha256.empty() && p.sha256 != e.sha256) {
      problem = "'" + p.name + "': SHA-256 checksum " + p.sha256 +
                " differs from the station's manifest (" + e.sha256 +
                "): damaged in transit or on the station";
    } else if (p.fnv1a64 != e.fnv1a64) {
      problem = "'" + p.name + "': checksum " + Hex64(p.fnv1a64) +
                " differs from the station's manifest (" + Hex64(e.fnv1a64) +
                "): damaged in transit or on the station";
    } else if (::rename(p.temp_path.c_str(), final_path.c_str()) != 0) {
      problem =
          "cannot rename '" + p.temp_path + "' to '" + final_path + "': " + std::strerror(errno);
      local = true;
    }
    if (!problem.empty()) {
      for (std::size_t j = i; j < batch.size(); ++j) ::unlink(batch[j].temp_path.c_str());
      return local ? FailLocally(problem, error) : Fail(problem, error);
    }
    SyncDir(fs::path(final_path).parent_path().string());
    done_.push_back({p.name, final_path, p.size_bytes, p.fnv1a64, p.sha256});
  }
  return true;
}

}  // namespace craftscan::client
