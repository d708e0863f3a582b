// FileAssembler on its own: in-order chunks become verified files written
// atomically; lost, reordered, contradictory or damaged data fails with a
// clear message and leaves no partial file behind.
#include <gtest/gtest.h>

#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/client/file_assembler.h"
#include "file_util.h"

namespace craftscan::client {
namespace {

namespace fs = std::filesystem;

class FileReassembly : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_FALSE(dir_.empty()); }

  static std::uint64_t Hash(const std::string& bytes) {
    Fnv1a64Hasher h;
    h.Update(bytes.data(), bytes.size());
    return h.value();
  }
  // The chunks of `content` as file `index` of `count`, `size` bytes each.
  // The chunks point into `name` and `content`: views, so that a literal
  // passed here outlives the loop (a std::string parameter made from one
  // died before the range-for's body ran; ASan's stack-use-after-scope).
  static std::vector<FileChunk> Chunks(std::string_view name, std::string_view content,
                                       std::uint32_t index, std::uint32_t count, std::size_t size) {
    std::vector<FileChunk> chunks;
    std::size_t offset = 0;
    do {
      FileChunk c;
      c.name = name;
      c.file_index = index;
      c.file_count = count;
      c.total_size = content.size();
      c.offset = offset;
      c.size = std::min(size, content.size() - offset);
      c.data = reinterpret_cast<const std::uint8_t*>(content.data()) + offset;
      offset += c.size;
      c.last = offset == content.size();
      chunks.push_back(c);
    } while (offset < content.size());
    return chunks;
  }
  std::string Read(const std::string& name) const { return testing::ReadFile(dir_ + "/" + name); }
  // Every regular file under dir_ (relative), hidden ones included.
  std::vector<std::string> Files() const {
    std::vector<std::string> names;
    for (const auto& e : fs::recursive_directory_iterator(dir_)) {
      if (e.is_regular_file()) names.push_back(fs::relative(e.path(), dir_).string());
    }
    std::sort(names.begin(), names.end());
    return names;
  }

  const testing::TempDir temp_{"craftscan-assembler"};  // removed after each test
  const std::string dir_ = temp_.path();
  const std::string ply_ = std::string(10000, 'p') + "end";
  const std::string png_ = "\x89PNG small";
};

TEST_F(FileReassembly, WritesVerifiedFilesWhetherTheListComesFirstOrLast) {
  for (const bool list_first : {true, false}) {
    const std::string out = dir_ + (list_first ? "/first" : "/last");
    {
      FileAssembler assembler(out);
      const std::vector<ExpectedFile> expected = {{"fused.ply", ply_.size(), Hash(ply_)},
                                                  {"previews/a.png", png_.size(), Hash(png_)},
                                                  {"empty.json", 0, Hash("")}};
      std::string error;
      if (list_first) {
        ASSERT_TRUE(assembler.SetExpected(expected, &error)) << error;
      }
      for (const FileChunk& c : Chunks("fused.ply", ply_, 0, 3, 4096)) {
        ASSERT_TRUE(assembler.Accept(c, &error)) << error;
      }
      for (const FileChunk& c : Chunks("previews/a.png", png_, 1, 3, 4096)) {
        ASSERT_TRUE(assembler.Accept(c, &error)) << error;
      }
      const std::vector<FileChunk> empty = Chunks("empty.json", "", 2, 3, 4096);
      ASSERT_EQ(empty.size(), 1u);
      ASSERT_TRUE(assembler.Accept(empty[0], &error)) << error;
      EXPECT_EQ(assembler.Complete(), list_first);
      if (!list_first) {
        ASSERT_TRUE(assembler.SetExpected(expected, &error)) << error;
      }
      EXPECT_TRUE(assembler.Complete());
      ASSERT_EQ(assembler.files().size(), 3u);
      EXPECT_EQ(assembler.files()[1].path, out + "/previews/a.png");
      EXPECT_EQ(assembler.bytes_received(), ply_.size() + png_.size());
    }
    const std::string prefix = list_first ? "first/" : "last/";
    EXPECT_EQ(Read(prefix + "fused.ply"), ply_);
    EXPECT_EQ(Read(prefix + "previews/a.png"), png_);
    EXPECT_TRUE(fs::exists(dir_ + "/" + prefix + "empty.json"));
  }
  EXPECT_EQ(Files().size(), 6u) << "no temporaries left";
}

TEST_F(FileReassembly, ALostChunkFailsAndLeavesNoPartialFile) {
  FileAssembler assembler(dir_);
  std::string error;
  ASSERT_TRUE(assembler.SetExpected({{"fused.ply", ply_.size(), Hash(ply_)}}, &error));
  std::vector<FileChunk> chunks = Chunks("fused.ply", ply_, 0, 1, 1000);
  ASSERT_TRUE(assembler.Accept(chunks[0], &error)) << error;
  EXPECT_FALSE(assembler.Accept(chunks[2], &error));
  EXPECT_NE(error.find("lost"), std::string::npos) << error;
  EXPECT_TRUE(assembler.failed());
  EXPECT_FALSE(assembler.Accept(chunks[1], &error)) << "a failed transfer stays failed";
  EXPECT_TRUE(Files().empty());
}

TEST_F(FileReassembly, AChecksumMismatchIsRefused) {
  FileAssembler assembler(dir_);
  std::string error;
  std::string damaged = ply_;
  damaged[5000] ^= 1;
  for (const FileChunk& c : Chunks("fused.ply", damaged, 0, 1, 4096)) {
    ASSERT_TRUE(assembler.Accept(c, &error)) << error;
  }
  EXPECT_FALSE(assembler.SetExpected({{"fused.ply", ply_.size(), Hash(ply_)}}, &error));
  EXPECT_NE(error.find("checksum"), std::string::npos) << error;
  EXPECT_TRUE(Files().empty());
}

TEST_F(FileReassembly, Sha256IsCheckedWhereListedAndReportedForEveryFile) {
  // Listed and right: the file is in place with the SHA-256 of its bytes.
  {
    FileAssembler assembler(dir_ + "/ok");
    std::string error;
    ASSERT_TRUE(assembler.SetExpected({{"fused.ply", ply_.size(), Hash(ply_), Sha256Hex(ply_)},
                                       {"a.png", png_.size(), Hash(png_)}},
                                      &error))
        << error;
    for (const FileChunk& c : Chunks("fused.ply", ply_, 0, 2, 4096)) {
      ASSERT_TRUE(assembler.Accept(c, &error)) << error;
    }
    for (const FileChunk& c : Chunks("a.png", png_, 1, 2, 4096)) {
      ASSERT_TRUE(assembler.Accept(c, &error)) << error;
    }
    ASSERT_TRUE(assembler.Complete());
    EXPECT_EQ(assembler.files()[0].sha256, Sha256Hex(ply_));
    EXPECT_EQ(assembler.files()[1].sha256, Sha256Hex(png_)) << "computed even when not listed";
  }
  // Listed and wrong (the FNV-1a 64 agrees): refused naming SHA-256.
  FileAssembler assembler(dir_ + "/bad");
  std::string error;
  ASSERT_TRUE(
      assembler.SetExpected({{"fused.ply", ply_.size(), Hash(ply_), Sha256Hex("other")}}, &error));
  bool accepted = true;
  for (const FileChunk& c : Chunks("fused.ply", ply_, 0, 1, 4096)) {
    accepted = assembler.Accept(c, &error);
  }
  EXPECT_FALSE(accepted);
  EXPECT_NE(error.find("'fused.ply': SHA-256 checksum " + Sha256Hex(ply_) + " differs"),
            std::string::npos)
      << error;
  EXPECT_FALSE(fs::exists(dir_ + "/bad/fused.ply"));
  // A malformed SHA-256 in the list is refused up front.
  FileAssembler malformed(dir_ + "/malformed");
  EXPECT_FALSE(malformed.SetExpected({{"fused.ply", 1, 1, "ABC"}}, &error));
  EXPECT_NE(error.find("malformed SHA-256"), std::string::npos) << error;
}

TEST_F(FileReassembly, StationErrorsUnsafeNamesAndContradictionsFail) {
  std::string error;
  {
    FileAssembler assembler(dir_);
    FileChunk c;
    c.name = "mesh.ply";
    c.file_count = 1;
    c.last = true;
    c.error = "cannot open it: No such file or directory";
    EXPECT_FALSE(assembler.Accept(c, &error));
    EXPECT_NE(error.find("No such file"), std::string::npos) << error;
  }
  for (const char* name : {"../escape", "/etc/passwd", "a//b", ".hidden", "a/../../b", "-rf"}) {
    FileAssembler assembler(dir_);
    EXPECT_FALSE(assembler.Accept(Chunks(name, png_, 0, 1, 4096)[0], &error)) << name;
    EXPECT_FALSE(assembler.SetExpected({{name, 1, 0}}, &error)) << name;
  }
  {
    FileAssembler assembler(dir_);
    std::vector<FileChunk> chunks = Chunks("fused.ply", ply_, 0, 1, 100000);
    chunks[0].last = false;  // claims more data than total_size allows
    EXPECT_FALSE(assembler.Accept(chunks[0], &error));
  }
  {
    FileAssembler assembler(dir_);
    ASSERT_TRUE(assembler.SetExpected({{"report.json", 4, Hash("abcd")}}, &error));
    EXPECT_FALSE(assembler.Accept(Chunks("fused.ply", ply_, 0, 1, 4096)[0], &error));
    EXPECT_NE(error.find("report.json"), std::string::npos) << error;
  }
  {
    FileAssembler assembler(dir_);
    EXPECT_FALSE(assembler.Accept(Chunks("fused.ply", ply_, 1, 2, 4096)[0], &error))
        << "the start of the transfer is missing";
  }
  EXPECT_TRUE(Files().empty());
}

TEST_F(FileReassembly, AnUnfinishedFileIsRemovedWithTheAssembler) {
  {
    FileAssembler assembler(dir_);
    std::string error;
    ASSERT_TRUE(assembler.Accept(Chunks("fused.ply", ply_, 0, 1, 1000)[0], &error)) << error;
    EXPECT_EQ(Files().size(), 1u) << "the hidden temporary";
  }
  EXPECT_TRUE(Files().empty());
}

TEST(FileAssemblerHelpers, HexAndHash) {
  EXPECT_EQ(Hex64(0x0123456789abcdefull), "0123456789abcdef");
  EXPECT_EQ(ParseHex64("0123456789abcdef"), 0x0123456789abcdefull);
  EXPECT_FALSE(ParseHex64("0123456789ABCDEF"));
  EXPECT_FALSE(ParseHex64("123"));
  Fnv1a64Hasher whole, pieces;
  whole.Update("hello world", 11);
  pieces.Update("hello", 5);
  pieces.Update(" world", 6);
  EXPECT_EQ(whole.value(), pieces.value());
  EXPECT_EQ(Fnv1a64Hasher().value(), 14695981039346656037ull);
  std::string why;
  EXPECT_TRUE(IsSafeFileName("previews/view_003.png", &why)) << why;
  EXPECT_FALSE(IsSafeFileName("a/b/c/d/e", &why));
}

}  // namespace
}  // namespace craftscan::client
