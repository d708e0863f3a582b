// Status: the typed outcome of an operation that can fail for reasons the
// caller acts on (a full disk, a read-only data directory, a missing file,
// a cancel), shared by the pipeline's file I/O and the daemon's session
// store and device manager. Callers branch on `code`, never on the text of
// `message` (DESIGN.md "Errors": no outcome is recognised by matching text).
//
// Algorithm results keep their own structs with a `status` enum, a
// `message` and quality figures (STYLE.md 10); `Failed<Result>()` below is
// the one way to build a failed one.
#pragma once

#include <exception>
#include <string>
#include <string_view>
#include <utility>

namespace craftscan {

enum class ErrorCode {
  kOk,
  kInvalidArgument,     // a bad argument, option or input (the message names it)
  kNotFound,            // a file, session or device that is not there
  kAlreadyExists,       // a name that is taken
  kCorrupt,             // a file that is there but malformed or truncated
  kCancelled,           // stopped on request (cancel, shutdown, an aborted move)
  kDiskFull,            // ENOSPC, EDQUOT
  kReadOnly,            // EROFS
  kPermissionDenied,    // EACCES, EPERM
  kIoError,             // EIO and other transport or file errors
  kFailedPrecondition,  // not now: busy, locked elsewhere, wrong state
  kUnavailable,         // a service that is not usable at the moment (no data dir)
  kDeviceLost,          // a camera or turntable that went away
  kTimeout,             // no answer in time
  kInternal,            // a bug or an unexpected exception
};
std::string_view ToString(ErrorCode code);  // "ok", "invalid_argument", "disk_full", ...

// The code for an errno value: ENOSPC/EDQUOT → kDiskFull, EROFS → kReadOnly,
// EACCES/EPERM → kPermissionDenied, ENOENT → kNotFound, EEXIST →
// kAlreadyExists, anything else → kIoError (0 → kOk).
ErrorCode ErrorCodeFromErrno(int errnum);

// True for the codes that mean "the data disk refused the write": the
// operator frees space, remounts or fixes permissions, then resumes.
inline bool IsStorageError(ErrorCode code) {
  return code == ErrorCode::kDiskFull || code == ErrorCode::kReadOnly ||
         code == ErrorCode::kPermissionDenied || code == ErrorCode::kIoError;
}

class Status {
 public:
  Status() = default;  // ok
  Status(ErrorCode code, std::string message) : code_(code), message_(std::move(message)) {}
  static Status Ok() { return {}; }
  // "<context>: <strerror(errnum)>" with the code ErrorCodeFromErrno gives.
  static Status FromErrno(int errnum, std::string_view context);

  bool ok() const { return code_ == ErrorCode::kOk; }
  explicit operator bool() const { return ok(); }
  ErrorCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // The same code with "<context>: " put before the message.
  Status WithContext(std::string_view context) const;
  // "disk_full: '/data/x': No space left on device"; "ok" when ok.
  std::string ToString() const;

 private:
  ErrorCode code_ = ErrorCode::kOk;
  std::string message_;
};

// For the `bool F(..., std::string* why)` functions: stores `message` in
// *why (when not null) and returns false.
inline bool Fail(std::string* why, std::string message) {
  if (why) *why = std::move(message);
  return false;
}

// The one way to build a failed algorithm result: every pipeline result
// struct has a `status` enum member and a `message`.
template <class Result>
Result Failed(decltype(Result::status) status, std::string message) {
  Result result;
  result.status = status;
  result.message = std::move(message);
  return result;
}

// The same for a result that already holds figures worth keeping on failure
// (counts, timings, the stage reached): `partial` with status and message set.
template <class Result>
Result Failed(Result partial, decltype(Result::status) status, std::string message) {
  partial.status = status;
  partial.message = std::move(message);
  return partial;
}

// For the functions documented "never throws": runs `body` (which returns
// a Result) and turns an escaping exception (std::bad_alloc, cv::Exception,
// a PCL exception) into a failed Result with "<where>: <what()>".
template <class Result, class Body>
Result NoThrow(std::string_view where, decltype(Result::status) failed_status, Body&& body) {
  try {
    return body();
  } catch (const std::exception& e) {
    return Failed<Result>(failed_status, std::string(where) + ": " + e.what());
  } catch (...) {
    return Failed<Result>(failed_status, std::string(where) + ": unknown exception");
  }
}

// The same for `bool F(..., std::string* why)` functions: the exception
// becomes false with *why set.
template <class Body>
bool NoThrowBool(std::string_view where, std::string* why, Body&& body) {
  try {
    return body();
  } catch (const std::exception& e) {
    return Fail(why, std::string(where) + ": " + e.what());
  } catch (...) {
    return Fail(why, std::string(where) + ": unknown exception");
  }
}

}  // namespace craftscan
