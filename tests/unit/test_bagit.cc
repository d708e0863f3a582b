// SHA-256 (the fixity hash every manifest shares) and BagWriter (RFC 8493
// bags), the bags checked by sha256sum and bagit_check.h, not by craftscan.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "bagit_check.h"
#include "craftscan/pipeline/common/bagit.h"
#include "craftscan/pipeline/common/sha256.h"
#include "file_util.h"
#include "test_util.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
using Bag = testing::TempDirTest;

TEST(Sha256, MatchesFips180Vectors) {
  EXPECT_EQ(Sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(Sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  // In pieces, and the hasher starts over after a digest.
  Sha256Hasher hasher;
  hasher.Update("a", 1);
  hasher.Update("bc", 2);
  EXPECT_EQ(hasher.HexDigest(), Sha256Hex("abc"));
  EXPECT_EQ(hasher.HexDigest(), Sha256Hex(""));
  EXPECT_TRUE(IsSha256Hex(Sha256Hex("x")));
  EXPECT_FALSE(IsSha256Hex("E3B0C44298FC1C149AFBF4C8996FB92427AE41E4649B934CA495991B7852B855"));
  EXPECT_FALSE(IsSha256Hex("e3b0"));
}

TEST_F(Bag, FileHashEqualsBytesHashAndMissingFileIsNamed) {
  const std::string bytes(3 << 20, 'q');  // more than one 1 MiB read block
  std::string hex;
  std::uint64_t size = 0;
  ASSERT_TRUE(Sha256OfFile(WriteBytes("big.bin", bytes), &hex, &size).ok());
  EXPECT_EQ(hex, Sha256Hex(bytes));
  EXPECT_EQ(size, bytes.size());
  const Status missing = Sha256OfFile(Path("nope.bin"), &hex, &size);
  EXPECT_EQ(missing.code(), ErrorCode::kNotFound);
  EXPECT_NE(missing.message().find("nope.bin"), std::string::npos) << missing.message();
}

TEST_F(Bag, WritesAnRfc8493BagThatSha256sumAccepts) {
  Status status;
  const std::string bag_dir = Path("out/bag");
  std::unique_ptr<BagWriter> bag = BagWriter::Start(bag_dir, &status);
  ASSERT_TRUE(bag) << status.ToString();
  fs::create_directories(bag->data_dir() + "/previews");
  std::ofstream(bag->data_dir() + "/fused.ply") << "ply\nformat ascii 1.0\n";
  std::ofstream(bag->data_dir() + "/previews/a 100%.png") << "png";
  EXPECT_FALSE(fs::exists(bag_dir)) << "the bag appears only when finished";
  BagSummary summary;
  status = bag->Finish({"Museum of Crafts", "20240501-093000-egg", ""},
                       {{"fused.ply", Sha256Hex("ply\nformat ascii 1.0\n")}}, &summary);
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(summary.path, bag_dir);
  EXPECT_EQ(summary.payload_files, 2u);
  EXPECT_EQ(summary.payload_bytes, 21u + 3u);
  std::string out;
  EXPECT_EQ(testing::RunSha256sumCheck(bag_dir, "tagmanifest-sha256.txt", &out), 0) << out;
  // RFC 8493's percent-encoding of '%' (sha256sum -c would read "%25"
  // literally, so only the tag manifest is checked by it here).
  EXPECT_NE(testing::ReadFile(bag_dir + "/manifest-sha256.txt").find("data/previews/a 100%25.png"),
            std::string::npos);
  EXPECT_EQ(testing::BagStructureProblems(bag_dir, "Museum of Crafts", "20240501-093000-egg"),
            std::vector<std::string>{});
  // Nothing but the bag beside it (the staging folder was renamed).
  EXPECT_EQ(std::distance(fs::directory_iterator(Path("out")), fs::directory_iterator()), 1);
}

TEST_F(Bag, PlainNamesPassEveryStructureRuleAndAFlippedByteFails) {
  Status status;
  const std::string bag_dir = Path("bag");
  fs::create_directories(bag_dir);  // an empty folder is taken
  std::unique_ptr<BagWriter> bag = BagWriter::Start(bag_dir, &status);
  ASSERT_TRUE(bag) << status.ToString();
  std::ofstream(bag->data_dir() + "/mesh.obj") << "v 0 0 0\n";
  ASSERT_TRUE(bag->Finish({"Org", "id-1", ""}, {}, nullptr).ok());
  EXPECT_TRUE(testing::BagStructureProblems(bag_dir, "Org", "id-1").empty());
  std::string out;
  EXPECT_EQ(testing::RunSha256sumCheck(bag_dir, "manifest-sha256.txt", &out), 0) << out;
  EXPECT_EQ(testing::RunSha256sumCheck(bag_dir, "tagmanifest-sha256.txt", &out), 0) << out;
  std::ofstream(bag_dir + "/data/mesh.obj") << "v 0 0 1\n";
  EXPECT_NE(testing::RunSha256sumCheck(bag_dir, "manifest-sha256.txt", &out), 0) << out;
  EXPECT_NE(out.find("data/mesh.obj: FAILED"), std::string::npos) << out;
}

TEST_F(Bag, RefusesANonEmptyTargetAndLeavesItAlone) {
  WriteBytes("keep.txt", "mine");
  Status status;
  EXPECT_FALSE(BagWriter::Start(dir_.string(), &status));
  EXPECT_EQ(status.code(), ErrorCode::kAlreadyExists);
  EXPECT_NE(status.message().find("exists and is not empty"), std::string::npos)
      << status.message();
  EXPECT_FALSE(BagWriter::Start(Path("keep.txt"), &status));
  EXPECT_NE(status.message().find("is not a folder"), std::string::npos) << status.message();
  EXPECT_EQ(testing::ReadFile(Path("keep.txt")), "mine");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir_), fs::directory_iterator()), 1);
}

TEST_F(Bag, AMismatchOrAnAbandonedBagLeavesNothingThatLooksLikeABag) {
  Status status;
  {
    std::unique_ptr<BagWriter> bag = BagWriter::Start(Path("bag"), &status);
    ASSERT_TRUE(bag);
    std::ofstream(bag->data_dir() + "/fused.ply") << "damaged";
    status = bag->Finish({"Org", "id", ""}, {{"fused.ply", Sha256Hex("original")}}, nullptr);
    EXPECT_EQ(status.code(), ErrorCode::kCorrupt);
    EXPECT_NE(status.message().find("data/fused.ply"), std::string::npos) << status.message();
  }
  {
    std::unique_ptr<BagWriter> bag = BagWriter::Start(Path("bag"), &status);
    ASSERT_TRUE(bag);
    std::ofstream(bag->data_dir() + "/fused.ply") << "half";
    // Dropped without Finish: an interrupted run.
  }
  EXPECT_FALSE(fs::exists(Path("bag")));
  EXPECT_TRUE(fs::is_empty(dir_)) << "the staging folders are removed";
  std::unique_ptr<BagWriter> bag = BagWriter::Start(Path("bag"), &status);
  ASSERT_TRUE(bag);
  EXPECT_EQ(bag->Finish({"Org", "id", ""}, {}, nullptr).code(), ErrorCode::kInvalidArgument)
      << "an empty payload is refused";
  EXPECT_EQ(bag->Finish({"", "id", ""}, {}, nullptr).code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(bag->Finish({"Org", "id", "2024-13-01"}, {}, nullptr).code(),
            ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace craftscan
