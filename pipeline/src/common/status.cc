#include "craftscan/pipeline/common/status.h"

#include <cerrno>
#include <cstring>

namespace craftscan {

std::string_view ToString(ErrorCode code) {
  switch (code) {
    case ErrorCode::kOk:
      return "ok";
    case ErrorCode::kInvalidArgument:
      return "invalid_argument";
    case ErrorCode::kNotFound:
      return "not_found";
    case ErrorCode::kAlreadyExists:
      return "already_exists";
    case ErrorCode::kCorrupt:
      return "corrupt";
    case ErrorCode::kCancelled:
      return "cancelled";
    case ErrorCode::kDiskFull:
      return "disk_full";
    case ErrorCode::kReadOnly:
      return "read_only";
    case ErrorCode::kPermissionDenied:
      return "permission_denied";
    case ErrorCode::kIoError:
      return "io_error";
    case ErrorCode::kFailedPrecondition:
      return "failed_precondition";
    case ErrorCode::kUnavailable:
      return "unavailable";
    case ErrorCode::kDeviceLost:
      return "device_lost";
    case ErrorCode::kTimeout:
      return "timeout";
    case ErrorCode::kInternal:
      return "internal";
  }
  return "unknown";
}

ErrorCode ErrorCodeFromErrno(int errnum) {
  switch (errnum) {
    case 0:
      return ErrorCode::kOk;
    case ENOSPC:
    case EDQUOT:
      return ErrorCode::kDiskFull;
    case EROFS:
      return ErrorCode::kReadOnly;
    case EACCES:
    case EPERM:
      return ErrorCode::kPermissionDenied;
    case ENOENT:
      return ErrorCode::kNotFound;
    case EEXIST:
      return ErrorCode::kAlreadyExists;
    default:
      return ErrorCode::kIoError;
  }
}

Status Status::FromErrno(int errnum, std::string_view context) {
  return Status(ErrorCodeFromErrno(errnum), std::string(context) + ": " + std::strerror(errnum));
}

Status Status::WithContext(std::string_view context) const {
  if (ok()) return *this;
  return Status(code_, std::string(context) + ": " + message_);
}

std::string Status::ToString() const {
  if (ok()) return "ok";
  return std::string(craftscan::ToString(code_)) + ": " + message_;
}

}  // namespace craftscan
