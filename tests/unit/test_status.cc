// craftscan::Status: the errno → code mapping, FromErrno and WithContext.
#include <gtest/gtest.h>

#include <cerrno>
#include <cstring>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {
namespace {

TEST(StatusCodes, ErrorCodeFromErrnoMapsTheStorageErrors) {
  EXPECT_EQ(ErrorCodeFromErrno(0), ErrorCode::kOk);
  EXPECT_EQ(ErrorCodeFromErrno(ENOSPC), ErrorCode::kDiskFull);
  EXPECT_EQ(ErrorCodeFromErrno(EDQUOT), ErrorCode::kDiskFull);
  EXPECT_EQ(ErrorCodeFromErrno(EROFS), ErrorCode::kReadOnly);
  EXPECT_EQ(ErrorCodeFromErrno(EACCES), ErrorCode::kPermissionDenied);
  EXPECT_EQ(ErrorCodeFromErrno(EPERM), ErrorCode::kPermissionDenied);
  EXPECT_EQ(ErrorCodeFromErrno(ENOENT), ErrorCode::kNotFound);
  EXPECT_EQ(ErrorCodeFromErrno(EEXIST), ErrorCode::kAlreadyExists);
  EXPECT_EQ(ErrorCodeFromErrno(EIO), ErrorCode::kIoError);
  EXPECT_EQ(ErrorCodeFromErrno(EBADF), ErrorCode::kIoError);
  EXPECT_TRUE(IsStorageError(ErrorCodeFromErrno(ENOSPC)));
  EXPECT_TRUE(IsStorageError(ErrorCodeFromErrno(EROFS)));
  EXPECT_TRUE(IsStorageError(ErrorCodeFromErrno(EACCES)));
  EXPECT_TRUE(IsStorageError(ErrorCodeFromErrno(EIO)));
  EXPECT_FALSE(IsStorageError(ErrorCodeFromErrno(ENOENT)));
  EXPECT_FALSE(IsStorageError(ErrorCode::kOk));
}

TEST(StatusCodes, FromErrnoCarriesTheCodeAndTheStrerrorText) {
  const Status full = Status::FromErrno(ENOSPC, "'/data/x': cannot write");
  EXPECT_FALSE(full.ok());
  EXPECT_FALSE(static_cast<bool>(full));
  EXPECT_EQ(full.code(), ErrorCode::kDiskFull);
  EXPECT_EQ(full.message(), std::string("'/data/x': cannot write: ") + std::strerror(ENOSPC));
  EXPECT_EQ(full.ToString(), "disk_full: " + full.message());

  const Status read_only = Status::FromErrno(EROFS, "probe");
  EXPECT_EQ(read_only.code(), ErrorCode::kReadOnly);
  EXPECT_EQ(read_only.message(), std::string("probe: ") + std::strerror(EROFS));
}

TEST(StatusCodes, WithContextKeepsTheCodeAndPrefixesTheMessage) {
  const Status denied = Status::FromErrno(EACCES, "'/data/s'");
  const Status wrapped = denied.WithContext("session 1");
  EXPECT_EQ(wrapped.code(), ErrorCode::kPermissionDenied);
  EXPECT_EQ(wrapped.message(), "session 1: " + denied.message());
  // An ok status stays ok, without text.
  const Status ok = Status::Ok().WithContext("ignored");
  EXPECT_TRUE(ok.ok());
  EXPECT_TRUE(static_cast<bool>(ok));
  EXPECT_EQ(ok.message(), "");
  EXPECT_EQ(ok.ToString(), "ok");
  EXPECT_EQ(ToString(ErrorCode::kDiskFull), "disk_full");
  EXPECT_EQ(ToString(ErrorCode::kPermissionDenied), "permission_denied");
}

}  // namespace
}  // namespace craftscan
