// WriteFileAtomically: the crash-safe write every craftscan writer uses.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "craftscan/pipeline/common/atomic_file.h"
#include "file_util.h"
#include "test_util.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
using AtomicFile = testing::TempDirTest;

using testing::ReadFile;

TEST_F(AtomicFile, WritesAndReplacesLeavingNoTemporary) {
  std::string error;
  const std::string path = Path("a.bin");
  ASSERT_TRUE(WriteFileAtomically(path, std::string("first\0x", 7), &error)) << error;
  EXPECT_EQ(ReadFile(path), std::string("first\0x", 7));
  ASSERT_TRUE(WriteFileAtomically(path, "second", &error)) << error;
  EXPECT_EQ(ReadFile(path), "second");
  EXPECT_EQ(fs::status(path).permissions() & fs::perms::all,
            fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read |
                fs::perms::others_read);
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) files += entry.is_regular_file() ? 1 : 0;
  EXPECT_EQ(files, 1);
}

TEST_F(AtomicFile, FailureNamesThePathAndKeepsWhatWasThere) {
  std::string error;
  EXPECT_FALSE(WriteFileAtomically(Path("no/such/folder/x"), "data", &error));
  EXPECT_NE(error.find("no/such/folder"), std::string::npos) << error;
  EXPECT_NE(error.find("cannot create a temporary file"), std::string::npos) << error;

  // The target is a non-empty folder: the rename fails, the folder and its
  // content survive and no temporary is left behind.
  const std::string target = Path("taken");
  fs::create_directories(target);
  WriteBytes("taken/keep.txt", "kept");
  EXPECT_FALSE(WriteFileAtomically(target, "data", &error));
  EXPECT_NE(error.find("cannot rename"), std::string::npos) << error;
  EXPECT_EQ(ReadFile(Path("taken/keep.txt")), "kept");
  int entries = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir_)) ++entries;
  EXPECT_EQ(entries, 1);

  EXPECT_FALSE(WriteFileAtomically("", "data", &error));
  EXPECT_NE(error.find("empty path"), std::string::npos) << error;
}

TEST_F(AtomicFile, StatusCarriesTheCodeOfTheFailingCall) {
  EXPECT_TRUE(WriteFileAtomically(Path("ok.bin"), "data").ok());
  const Status missing = WriteFileAtomically(Path("no/such/folder/x"), "data");
  EXPECT_EQ(missing.code(), ErrorCode::kNotFound) << missing.ToString();
  EXPECT_NE(missing.message().find("cannot create a temporary file"), std::string::npos)
      << missing.message();
  // rename(2) over a non-empty folder: EISDIR, an I/O error, not the unlink's errno.
  fs::create_directories(Path("taken"));
  WriteBytes("taken/keep.txt", "kept");
  const Status taken = WriteFileAtomically(Path("taken"), "data");
  EXPECT_EQ(taken.code(), ErrorCode::kIoError) << taken.ToString();
  EXPECT_NE(taken.message().find("cannot rename"), std::string::npos) << taken.message();
  EXPECT_EQ(WriteFileAtomically("", "data").code(), ErrorCode::kInvalidArgument);
  // The text version reports the Status's message.
  std::string error;
  EXPECT_FALSE(WriteFileAtomically(Path("taken"), "data", &error));
  EXPECT_EQ(error, taken.message());
}

}  // namespace
}  // namespace craftscan
