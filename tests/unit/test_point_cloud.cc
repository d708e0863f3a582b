#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <opencv2/core.hpp>
#include <random>
#include <string>
#include <vector>

#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "craftscan/pipeline/registration/scan_dataset.h"
#include "test_util.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
// Checks that `text` contains `part`, printing both otherwise.
#define EXPECT_CONTAINS(text, part)                          \
  EXPECT_NE(std::string(text).find(part), std::string::npos) \
      << "message: " << (text) << "\nexpected to contain: " << (part)

class PlyFiles : public testing::TempDirTest {
 protected:
  // Expects ReadPly to fail with a message naming the file and containing
  // `what`, leaving the cloud empty.
  void ExpectReadFails(const std::string& path, const std::string& what) const {
    PointCloud cloud;
    cloud.points_mm.assign(3, cv::Vec3f(1, 2, 3));
    std::string error;
    EXPECT_FALSE(ReadPly(path, &cloud, &error)) << path;
    EXPECT_CONTAINS(error, (path));
    EXPECT_CONTAINS(error, (what));
    EXPECT_TRUE(cloud.empty());
  }
};

// Binary encoder for hand-written PLY data in either byte order.
class Bytes {
 public:
  explicit Bytes(bool little) : little_(little) {}
  template <typename T>
  Bytes& Put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (!little_) std::reverse(b, b + sizeof(T));
    out_.append(b, sizeof(T));
    return *this;
  }
  const std::string& str() const { return out_; }

 private:
  bool little_;
  std::string out_;
};

PointCloud MakeCloud(int n, bool normals, bool colors, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-500.0f, 500.0f);
  PointCloud cloud;
  for (int i = 0; i < n; ++i) {
    cloud.points_mm.emplace_back(u(rng), u(rng) * 1e-3f, u(rng) * 1e4f);
    if (normals) {
      cv::Vec3f v(u(rng), u(rng), u(rng));
      cloud.normals.push_back(v / static_cast<float>(cv::norm(v)));
    }
    if (colors) {
      cloud.colors_rgb.emplace_back(static_cast<uchar>(rng() & 255),
                                    static_cast<uchar>(rng() & 255),
                                    static_cast<uchar>(rng() & 255));
    }
  }
  return cloud;
}

bool BitwiseEqual(const std::vector<cv::Vec3f>& a, const std::vector<cv::Vec3f>& b) {
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0);
}

// --- round trips ---------------------------------------------------------------

TEST_F(PlyFiles, RoundTripsAsciiAndBinaryBitExactly) {
  for (bool binary : {false, true}) {
    for (int variant = 0; variant < 4; ++variant) {
      const bool normals = variant & 1, colors = variant & 2;
      SCOPED_TRACE(::testing::Message() << "binary " << binary << " variant " << variant);
      const PointCloud cloud = MakeCloud(200, normals, colors, 7 + variant);
      const std::string path = Path("cloud.ply");
      std::string error;
      ASSERT_TRUE(WritePly(path, cloud, binary, &error)) << error;
      PointCloud back;
      ASSERT_TRUE(ReadPly(path, &back, &error)) << error;
      EXPECT_TRUE(BitwiseEqual(back.points_mm, cloud.points_mm));
      EXPECT_TRUE(BitwiseEqual(back.normals, cloud.normals));
      EXPECT_EQ(back.HasNormals(), normals);
      EXPECT_EQ(back.HasColors(), colors);
      EXPECT_TRUE(back.colors_rgb == cloud.colors_rgb);
    }
  }
}

TEST_F(PlyFiles, EncodersGiveTheBytesTheWritersWrite) {
  const auto read_all = [](const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  };
  const PointCloud cloud = MakeCloud(50, true, true, 3);
  TriangleMesh mesh;
  mesh.vertices_mm = cloud.points_mm;
  mesh.faces = {{0, 1, 2}, {2, 3, 4}};
  std::string error;
  for (bool binary : {false, true}) {
    SCOPED_TRACE(::testing::Message() << "binary " << binary);
    ASSERT_TRUE(WritePly(Path("c.ply"), cloud, binary, &error)) << error;
    EXPECT_EQ(EncodePly(cloud, binary), read_all(Path("c.ply")));
    ASSERT_TRUE(WriteMeshPly(Path("m.ply"), mesh, binary, &error)) << error;
    EXPECT_EQ(EncodeMeshPly(mesh, binary), read_all(Path("m.ply")));
  }
  // Invalid input gives no bytes (and no out-of-range read).
  PointCloud bad = cloud;
  bad.normals.pop_back();
  EXPECT_EQ(EncodePly(bad, true), "");
  TriangleMesh bad_mesh = mesh;
  bad_mesh.faces.push_back({0, 1, 50});
  EXPECT_EQ(EncodeMeshPly(bad_mesh, false), "");
}

TEST_F(PlyFiles, RoundTripsAnEmptyCloudAndSpecialValues) {
  std::string error;
  PointCloud empty;
  ASSERT_TRUE(WritePly(Path("empty.ply"), empty, false, &error)) << error;
  PointCloud back;
  ASSERT_TRUE(ReadPly(Path("empty.ply"), &back, &error)) << error;
  EXPECT_TRUE(back.empty());

  PointCloud special;
  special.points_mm = {
      {0.0f, -0.0f, std::numeric_limits<float>::denorm_min()},
      {std::numeric_limits<float>::max(), std::numeric_limits<float>::lowest(), 1e-30f}};
  for (bool binary : {false, true}) {
    ASSERT_TRUE(WritePly(Path("special.ply"), special, binary, &error)) << error;
    ASSERT_TRUE(ReadPly(Path("special.ply"), &back, &error)) << error;
    EXPECT_TRUE(BitwiseEqual(back.points_mm, special.points_mm)) << "binary " << binary;
  }
}

TEST_F(PlyFiles, WriteIsAtomicReplacesAndLeavesNoTemporaries) {
  std::string error;
  const std::string path = Path("out.ply");
  ASSERT_TRUE(WritePly(path, MakeCloud(10, false, false, 1), true, &error)) << error;
  ASSERT_TRUE(WritePly(path, MakeCloud(3, true, false, 2), false, &error)) << error;
  PointCloud back;
  ASSERT_TRUE(ReadPly(path, &back, &error)) << error;
  EXPECT_EQ(back.size(), 3u);
  EXPECT_TRUE(back.HasNormals());
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    ++files;
    EXPECT_EQ(entry.path().filename(), "out.ply");
  }
  EXPECT_EQ(files, 1);
  EXPECT_EQ(fs::status(path).permissions() & fs::perms::others_read, fs::perms::others_read);
}

TEST_F(PlyFiles, WriteRejectsInvalidCloudsAndBadFolders) {
  std::string error;
  PointCloud bad = MakeCloud(5, true, true, 3);
  bad.normals.pop_back();
  EXPECT_FALSE(WritePly(Path("bad.ply"), bad, false, &error));
  EXPECT_CONTAINS(error, ("normals"));
  bad = MakeCloud(5, false, true, 3);
  bad.colors_rgb.push_back({});
  EXPECT_FALSE(WritePly(Path("bad.ply"), bad, true, &error));
  EXPECT_CONTAINS(error, ("colours"));
  EXPECT_FALSE(fs::exists(Path("bad.ply")));

  const std::string nowhere = Path("no/such/folder/x.ply");
  EXPECT_FALSE(WritePly(nowhere, MakeCloud(5, false, false, 3), false, &error));
  EXPECT_CONTAINS(error, ("x.ply"));
  EXPECT_FALSE(WritePly("", MakeCloud(5, false, false, 3), false, &error));
}

// --- hand-written files -----------------------------------------------------------

TEST_F(PlyFiles, ReadsAsciiWithFacesExtrasAnyOrderAndCrlf) {
  const std::string text =
      "ply\r\n"
      "format ascii 1.0\r\n"
      "comment written by hand\r\n"
      "obj_info scanner 3030\r\n"
      "element face 2\r\n"
      "property list uchar int vertex_indices\r\n"
      "element vertex 3\r\n"
      "property double z\r\n"
      "property uchar red\r\n"
      "property list uchar float tags\r\n"
      "property float nx\r\n"
      "property int x\r\n"
      "property float confidence\r\n"
      "property float ny\r\n"
      "property uchar green\r\n"
      "property short y\r\n"
      "property float nz\r\n"
      "property uchar blue\r\n"
      "element edge 1\r\n"
      "property int vertex1\r\n"
      "property int vertex2\r\n"
      "end_header\r\n"
      "3 0 1 2\r\n"
      "4 0 1 2 0\r\n"
      "0.125 10 0 1 1 0.5 0 20 -3 0 30\r\n"
      "+1e2 11 2 1.5 2.5 0 2 0.5 0 21 4 1 31\r\n"
      "-7.5 12 1 9 0 -5 0.1 -1 22 5 0 32\r\n"
      "0 1\r\n";
  PointCloud cloud;
  std::string error;
  ASSERT_TRUE(ReadPly(WriteBytes("hand.ply", text), &cloud, &error, 2.0)) << error;
  ASSERT_EQ(cloud.size(), 3u);
  ASSERT_TRUE(cloud.HasNormals());
  ASSERT_TRUE(cloud.HasColors());
  EXPECT_EQ(cloud.points_mm[0], cv::Vec3f(2, -6, 0.25f));
  EXPECT_EQ(cloud.points_mm[1], cv::Vec3f(4, 8, 200));
  EXPECT_EQ(cloud.points_mm[2], cv::Vec3f(-10, 10, -15));
  EXPECT_EQ(cloud.normals[0], cv::Vec3f(1, 0, 0));  // normals are not scaled
  EXPECT_EQ(cloud.normals[1], cv::Vec3f(0, 0, 1));
  EXPECT_EQ(cloud.normals[2], cv::Vec3f(0, -1, 0));
  EXPECT_EQ(cloud.colors_rgb[0], cv::Vec3b(10, 20, 30));
  EXPECT_EQ(cloud.colors_rgb[1], cv::Vec3b(11, 21, 31));
  EXPECT_EQ(cloud.colors_rgb[2], cv::Vec3b(12, 22, 32));
}

TEST_F(PlyFiles, FloatColoursAreScaledAndPartialGroupsIgnored) {
  const std::string text =
      "ply\nformat ascii 1.0\nelement vertex 1\n"
      "property float x\nproperty float y\nproperty float z\n"
      "property float red\nproperty float green\nproperty float blue\n"
      "property float nx\nproperty float ny\n"
      "end_header\n1 2 3 1.0 0.5 2.0 7 8\n";
  PointCloud cloud;
  std::string error;
  ASSERT_TRUE(ReadPly(WriteBytes("c.ply", text), &cloud, &error)) << error;
  ASSERT_TRUE(cloud.HasColors());
  EXPECT_EQ(cloud.colors_rgb[0], cv::Vec3b(255, 128, 255));
  EXPECT_FALSE(cloud.HasNormals());  // nz missing
}

// Writes a binary PLY with faces before and after the vertices, doubles,
// mixed integer types and a list property inside the vertex element.
std::string HandBinary(bool little) {
  const std::string format = little ? "binary_little_endian" : "binary_big_endian";
  std::string text = "ply\nformat " + format +
                     " 1.0\n"
                     "comment faces first\n"
                     "element face 2\n"
                     "property list uchar int vertex_indices\n"
                     "property uchar flags\n"
                     "element vertex 2\n"
                     "property uchar blue\n"
                     "property double x\n"
                     "property short y\n"
                     "property list ushort uint ids\n"
                     "property float z\n"
                     "property uchar green\n"
                     "property int8 red\n"
                     "property double nz\n"
                     "property float ny\n"
                     "property float nx\n"
                     "element face_after 1\n"
                     "property list int short idx\n"
                     "end_header\n";
  Bytes b(little);
  b.Put<std::uint8_t>(3).Put<std::int32_t>(0).Put<std::int32_t>(1).Put<std::int32_t>(1);
  b.Put<std::uint8_t>(9);
  b.Put<std::uint8_t>(0).Put<std::uint8_t>(9);  // empty list
  // vertex 0
  b.Put<std::uint8_t>(200).Put<double>(1.25).Put<std::int16_t>(-300);
  b.Put<std::uint16_t>(2).Put<std::uint32_t>(7).Put<std::uint32_t>(8);
  b.Put<float>(3.5f).Put<std::uint8_t>(100).Put<std::int8_t>(-4);
  b.Put<double>(1.0).Put<float>(0.0f).Put<float>(0.0f);
  // vertex 1
  b.Put<std::uint8_t>(1).Put<double>(-1e-3).Put<std::int16_t>(32767);
  b.Put<std::uint16_t>(0);
  b.Put<float>(-2.0f).Put<std::uint8_t>(2).Put<std::int8_t>(127);
  b.Put<double>(0.0).Put<float>(1.0f).Put<float>(0.25f);
  // face_after
  b.Put<std::int32_t>(3).Put<std::int16_t>(1).Put<std::int16_t>(2).Put<std::int16_t>(3);
  return text + b.str();
}

TEST_F(PlyFiles, ReadsBinaryBothEndiannessesWithFacesAndMixedTypes) {
  for (bool little : {true, false}) {
    SCOPED_TRACE(little ? "little endian" : "big endian");
    PointCloud cloud;
    std::string error;
    ASSERT_TRUE(ReadPly(WriteBytes("bin.ply", HandBinary(little)), &cloud, &error)) << error;
    ASSERT_EQ(cloud.size(), 2u);
    EXPECT_EQ(cloud.points_mm[0], cv::Vec3f(1.25f, -300, 3.5f));
    EXPECT_EQ(cloud.points_mm[1], cv::Vec3f(-1e-3f, 32767, -2));
    EXPECT_EQ(cloud.normals[0], cv::Vec3f(0, 0, 1));
    EXPECT_EQ(cloud.normals[1], cv::Vec3f(0.25f, 1, 0));
    EXPECT_EQ(cloud.colors_rgb[0], cv::Vec3b(0, 100, 200));  // red −4 clamps to 0
    EXPECT_EQ(cloud.colors_rgb[1], cv::Vec3b(127, 2, 1));
  }
}

// --- errors -------------------------------------------------------------------

TEST_F(PlyFiles, FailsClearlyOnBadFiles) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  ExpectReadFails(Path("missing.ply"), "no such file");
  fs::create_directories(Path("a_folder.ply"));
  ExpectReadFails(Path("a_folder.ply"), "no such file");
  ExpectReadFails(WriteBytes("empty.ply", ""), "not a PLY");
  ExpectReadFails(WriteBytes("png.ply", "\x89PNG\r\n\x1a\n rest"), "not a PLY");
  ExpectReadFails(WriteBytes("plyx.ply", "plyx\nformat ascii 1.0\n"), "not a PLY");
  ExpectReadFails(WriteBytes("fmt.ply", "ply\nformat binary_middle_endian 1.0\nelement vertex 0\n" +
                                            xyz + "end_header\n"),
                  "unsupported format 'binary_middle_endian'");
  ExpectReadFails(WriteBytes("ver.ply", "ply\nformat ascii 2.0\nend_header\n"), "version");
  ExpectReadFails(WriteBytes("nofmt.ply", "ply\nelement vertex 0\n" + xyz + "end_header\n"),
                  "no 'format'");
  ExpectReadFails(WriteBytes("noend.ply", "ply\nformat ascii 1.0\nelement vertex 1\n" + xyz),
                  "end_header");
  ExpectReadFails(WriteBytes("novertex.ply",
                             "ply\nformat ascii 1.0\nelement face 0\n"
                             "property list uchar int v\nend_header\n"),
                  "no 'vertex' element");
  ExpectReadFails(WriteBytes("noz.ply",
                             "ply\nformat ascii 1.0\nelement vertex 1\n"
                             "property float x\nproperty float y\nend_header\n1 2\n"),
                  "no 'z' property");
  ExpectReadFails(WriteBytes("listx.ply",
                             "ply\nformat ascii 1.0\nelement vertex 1\n"
                             "property list uchar float x\nproperty float y\n"
                             "property float z\nend_header\n1 1 2 3\n"),
                  "'x' is a list");
  ExpectReadFails(WriteBytes("type.ply",
                             "ply\nformat ascii 1.0\nelement vertex 1\n"
                             "property float128 x\nend_header\n"),
                  "unknown property type 'float128'");
  ExpectReadFails(WriteBytes("kw.ply", "ply\nformat ascii 1.0\nbanana\nend_header\n"),
                  "unknown keyword 'banana'");
  ExpectReadFails(
      WriteBytes("count.ply", "ply\nformat ascii 1.0\nelement vertex -3\n" + xyz + "end_header\n"),
      "bad count '-3'");
  ExpectReadFails(WriteBytes("orphan.ply",
                             "ply\nformat ascii 1.0\nproperty float x\n"
                             "end_header\n"),
                  "property before any element");
}

TEST_F(PlyFiles, FailsOnTruncatedData) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list uchar int v\nend_header\n";
  ExpectReadFails(WriteBytes("t1.ply", header + "1 2 3\n4 5 6\n7 8\n"), "truncated");
  ExpectReadFails(WriteBytes("t2.ply", header + "1 2 3\n4 5 6\n7 8 9\n3 0 1\n"), "truncated");
  ExpectReadFails(WriteBytes("t2.ply", header + "1 2 3\n4 5 6\n7 8 9\n3 0 1\n"), "'face'");

  // Every proper prefix of a valid binary file fails cleanly; the whole file reads.
  const std::string full = HandBinary(true);
  const std::size_t header_size = full.find("end_header\n") + 11;
  for (std::size_t n = 0; n < full.size(); ++n) {
    PointCloud cloud;
    std::string error;
    EXPECT_FALSE(ReadPly(WriteBytes("prefix.ply", full.substr(0, n)), &cloud, &error)) << n;
    EXPECT_FALSE(error.empty());
    if (n > header_size) {
      EXPECT_CONTAINS(error, "truncated") << n;
    }
  }
  PointCloud cloud;
  std::string error;
  EXPECT_TRUE(ReadPly(WriteBytes("whole.ply", full), &cloud, &error)) << error;
}

TEST_F(PlyFiles, FailsOnAbsurdCountsWithoutAllocating) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  ExpectReadFails(WriteBytes("huge_a.ply", "ply\nformat ascii 1.0\nelement vertex 1000000000000\n" +
                                               xyz + "end_header\n1 2 3\n"),
                  "claims 1000000000000");
  ExpectReadFails(WriteBytes("huge_b.ply",
                             "ply\nformat binary_little_endian 1.0\nelement vertex "
                             "1000000000000\n" +
                                 xyz + "end_header\n" + std::string(12, '\0')),
                  "claims 1000000000000");
  ExpectReadFails(WriteBytes("huge_f.ply",
                             "ply\nformat binary_big_endian 1.0\n"
                             "element face 18446744073709551615\n"
                             "property list uchar int v\n"
                             "element vertex 1\n" +
                                 xyz + "end_header\n" + std::string(12, '\0')),
                  "'face' claims");
  ExpectReadFails(WriteBytes("overflow.ply",
                             "ply\nformat ascii 1.0\nelement vertex "
                             "99999999999999999999999\n" +
                                 xyz + "end_header\n"),
                  "bad count");
  // A huge list length inside the data is bounded by the file size too.
  Bytes b(true);
  b.Put<float>(1).Put<float>(2).Put<float>(3).Put<std::uint32_t>(4000000000u);
  ExpectReadFails(WriteBytes("huge_list.ply",
                             "ply\nformat binary_little_endian 1.0\n"
                             "element vertex 1\n" +
                                 xyz + "property list uint double junk\nend_header\n" + b.str()),
                  "truncated");
  // Property-less elements with huge counts carry no data and do not hang.
  PointCloud cloud;
  std::string error;
  EXPECT_TRUE(ReadPly(WriteBytes("empty_el.ply",
                                 "ply\nformat ascii 1.0\nelement nothing "
                                 "1000000000000\nelement vertex 1\n" +
                                     xyz + "end_header\n1 2 3\n"),
                      &cloud, &error))
      << error;
}

TEST_F(PlyFiles, FailsOnNonNumericAsciiValues) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
      "property float y\nproperty float z\nproperty uchar red\n"
      "property uchar green\nproperty uchar blue\nend_header\n";
  ExpectReadFails(WriteBytes("nn1.ply", header + "1 2 3 0 0 0\n4 five 6 0 0 0\n"),
                  "'five' is not a number");
  ExpectReadFails(WriteBytes("nn1.ply", header + "1 2 3 0 0 0\n4 five 6 0 0 0\n"), "entry 1");
  ExpectReadFails(WriteBytes("nn2.ply", header + "1 2 3 0 0 0\n4 5 6 1.5 0 0\n"),
                  "'1.5' is not an integer");
  ExpectReadFails(WriteBytes("nn3.ply", header + "1 2 3 0 0 0\n4 5 6 256 0 0\n"), "out of range");
  ExpectReadFails(WriteBytes("nn4.ply", header + "1 2 3 0 0 0\n4 5 6e 0 0 0\n"), "not a number");
  ExpectReadFails(
      WriteBytes("nn5.ply", header + "1 2 3 0 0 0\n4 5 " + std::string(500, '7') + " 0 0 0\n"),
      "too long");
}

TEST_F(PlyFiles, SurvivesRandomCorruption) {
  const std::string good = HandBinary(false);
  std::mt19937 rng(42);
  for (int trial = 0; trial < 500; ++trial) {
    std::string bad = good;
    const int flips = 1 + static_cast<int>(rng() % 4);
    for (int f = 0; f < flips; ++f) bad[rng() % bad.size()] = static_cast<char>(rng() & 255);
    PointCloud cloud;
    std::string error;
    if (!ReadPly(WriteBytes("fuzz.ply", bad), &cloud, &error)) {
      EXPECT_FALSE(error.empty());
      EXPECT_TRUE(cloud.empty());
    }
  }
}

TEST_F(PlyFiles, RejectsBadScaleAndNullOutput) {
  const std::string path = WriteBytes("ok.ply",
                                      "ply\nformat ascii 1.0\nelement vertex 1\n"
                                      "property float x\nproperty float y\n"
                                      "property float z\nend_header\n1 2 3\n");
  PointCloud cloud;
  std::string error;
  EXPECT_FALSE(ReadPly(path, &cloud, &error, 0.0));
  EXPECT_CONTAINS(error, ("scale_to_mm"));
  EXPECT_FALSE(ReadPly(path, &cloud, &error, std::nan("")));
  EXPECT_FALSE(ReadPly(path, nullptr, &error));
  EXPECT_FALSE(ReadPly(Path("missing.ply"), &cloud, nullptr));  // null error is fine
  ASSERT_TRUE(ReadPly(path, &cloud, &error, 1000.0)) << error;
  EXPECT_EQ(cloud.points_mm[0], cv::Vec3f(1000, 2000, 3000));
}

// --- pose metrics -------------------------------------------------------------

cv::Matx44d Pose(const cv::Matx33d& r, const cv::Vec3d& t) {
  cv::Matx44d m = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m(i, j) = r(i, j);
    m(i, 3) = t[i];
  }
  return m;
}

cv::Matx33d AxisAngle(cv::Vec3d axis, double deg) {
  axis *= 1.0 / cv::norm(axis);
  const double half = deg * M_PI / 360.0;
  return RotationFromQuaternion(std::cos(half), axis[0] * std::sin(half), axis[1] * std::sin(half),
                                axis[2] * std::sin(half));
}

TEST(PoseMetrics, QuaternionRotationIsActiveHamilton) {
  // 90° about z maps x to y.
  const cv::Matx33d r = AxisAngle({0, 0, 1}, 90);
  const cv::Vec3d y = r * cv::Vec3d(1, 0, 0);
  EXPECT_NEAR(y[0], 0, 1e-12);
  EXPECT_NEAR(y[1], 1, 1e-12);
  EXPECT_NEAR(cv::determinant(r), 1.0, 1e-12);
  EXPECT_EQ(RotationFromQuaternion(0, 0, 0, 0), cv::Matx33d::eye());
  // Unnormalised input is normalised.
  EXPECT_LT(cv::norm(RotationFromQuaternion(2, 0, 0, 2) - AxisAngle({0, 0, 1}, 90)), 1e-12);
}

TEST(PoseMetrics, RotationAndTranslationErrors) {
  const cv::Matx44d a = Pose(AxisAngle({1, 2, 3}, 20), {10, 20, 30});
  for (double deg : {0.0, 1e-4, 0.1, 34.3, 90.0, 179.0, 180.0}) {
    const cv::Matx44d b =
        Pose(AxisAngle({1, 2, 3}, 20) * AxisAngle({-1, 0.5, 2}, deg), {13, 24, 30});
    EXPECT_NEAR(RotationErrorDeg(a, b), deg, 1e-9 + deg * 1e-9) << deg;
    EXPECT_NEAR(RotationErrorDeg(b, a), deg, 1e-9 + deg * 1e-9) << deg;
    EXPECT_NEAR(TranslationErrorMm(a, b), 5.0, 1e-12);
  }
}

TEST(PoseMetrics, RelativePoseMapsSourceIntoTarget) {
  const cv::Matx44d world_from_target = Pose(AxisAngle({0, 1, 0}, 30), {5, -2, 100});
  const cv::Matx44d world_from_source = Pose(AxisAngle({1, 1, 0}, -70), {-40, 8, 3});
  const cv::Matx44d target_from_source = RelativePose(world_from_target, world_from_source);
  const cv::Vec4d p_source(12, -7, 300, 1);
  const cv::Vec4d p_world = world_from_source * p_source;
  const cv::Vec4d p_target = target_from_source * p_source;
  EXPECT_LT(cv::norm(world_from_target * p_target - p_world), 1e-9);
  EXPECT_LT(cv::norm(InvertRigid(world_from_target) * world_from_target - cv::Matx44d::eye()),
            1e-12);
  EXPECT_LT(cv::norm(RelativePose(world_from_source, world_from_source) - cv::Matx44d::eye()),
            1e-12);

  PointCloud cloud;
  cloud.points_mm.emplace_back(12, -7, 300);
  cloud.normals.emplace_back(0, 0, 1);
  const PointCloud moved = TransformCloud(target_from_source, cloud);
  EXPECT_LT(
      cv::norm(cv::Vec3d(moved.points_mm[0]) - cv::Vec3d(p_target[0], p_target[1], p_target[2])),
      1e-3);
  EXPECT_NEAR(cv::norm(moved.normals[0]), 1.0, 1e-6);
}

// --- Stanford scan sets -------------------------------------------------------------

class StanfordScans : public PlyFiles {
 protected:
  void WriteConf(const std::string& text) const { WriteBytes("bun.conf", text); }
  void ExpectLoadFails(const std::string& what) const {
    std::vector<RangeScan> scans(2);
    std::string error;
    EXPECT_FALSE(LoadStanfordScans(dir_.string(), &scans, &error));
    EXPECT_CONTAINS(error, (what));
    EXPECT_TRUE(scans.empty());
  }
};

TEST_F(StanfordScans, ConvertsUnitsAndUsesTheConjugateQuaternion) {
  WriteBytes("a.ply",
             "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
             "property float y\nproperty float z\nend_header\n0.1 0 0\n");
  // q = 90° about z, stored (qx qy qz qw); t in metres.
  const double s = std::sqrt(0.5);
  WriteConf("# comment\n\ncamera 0 0 -1 0 0 0 1\nbmesh a.ply 0.01 0.02 0.03 0 0 " +
            std::to_string(s) + " " + std::to_string(s) + "\r\n");
  std::vector<RangeScan> scans;
  std::string error;
  ASSERT_TRUE(LoadStanfordScans(dir_.string(), &scans, &error)) << error;
  ASSERT_EQ(scans.size(), 1u);
  EXPECT_EQ(scans[0].name, "a.ply");
  EXPECT_EQ(scans[0].cloud.points_mm[0], cv::Vec3f(100, 0, 0));
  // p_world = R(q)ᵀ p + t: Rᵀ maps x to −y.
  const cv::Vec4d p = scans[0].world_from_scan * cv::Vec4d(100, 0, 0, 1);
  EXPECT_NEAR(p[0], 10, 1e-4);
  EXPECT_NEAR(p[1], 20 - 100, 1e-4);
  EXPECT_NEAR(p[2], 30, 1e-4);
}

TEST_F(StanfordScans, FailsClearlyOnBadConfFiles) {
  ExpectLoadFails("bun.conf': no such file");
  WriteBytes("a.ply",
             "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
             "property float y\nproperty float z\nend_header\n0.1 0 0\n");
  WriteConf("camera 0 0 0 0 0 0 1\n");
  ExpectLoadFails("no 'bmesh' lines");
  WriteConf("bmesh a.ply 0 0 0 0 0 1\n");
  ExpectLoadFails("line 1: expected 'bmesh <file> tx ty tz qx qy qz qw', got 8 fields");
  WriteConf("bmesh a.ply 0 0 0 0 0 0 1\nbmesh a.ply 0 zero 0 0 0 0 1\n");
  ExpectLoadFails("line 2: value 'zero' is not a finite number");
  WriteConf("bmesh a.ply 0 0 nan 0 0 0 1\n");
  ExpectLoadFails("'nan' is not a finite number");
  WriteConf("bmesh a.ply 0 0 0 0 0 0 2\n");
  ExpectLoadFails("quaternion");
  WriteConf("camera 0 0\nbmesh a.ply 0 0 0 0 0 0 1\n");
  ExpectLoadFails("line 1: expected 'camera");
  WriteConf("mesh a.ply 0 0 0 0 0 0 1\n");
  ExpectLoadFails("unknown keyword 'mesh'");
  WriteConf("bmesh b.ply 0 0 0 0 0 0 1\n");
  ExpectLoadFails("scan 'b.ply'");
  ExpectLoadFails("no such file");
  std::string error;
  EXPECT_FALSE(LoadStanfordScans(dir_.string(), nullptr, &error));
}

// Median and fraction-within-2-mm of nearest-neighbour distances from a
// subsample of `query` to `reference` (brute force; both in the same frame).
void NearestNeighbourStats(const std::vector<cv::Vec3f>& query,
                           const std::vector<cv::Vec3f>& reference, std::size_t stride,
                           double* median_mm, double* within_2mm) {
  std::vector<double> d;
  for (std::size_t i = 0; i < query.size(); i += stride) {
    float best = std::numeric_limits<float>::max();
    const cv::Vec3f q = query[i];
    for (const cv::Vec3f& r : reference) {
      const cv::Vec3f e = r - q;
      best = std::min(best, e.dot(e));
    }
    d.push_back(std::sqrt(best));
  }
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  *median_mm = d[d.size() / 2];
  *within_2mm =
      static_cast<double>(std::count_if(d.begin(), d.end(), [](double v) { return v < 2.0; })) /
      d.size();
}

TEST(StanfordBunny, LoadsScansWithConsistentGroundTruth) {
  const fs::path dir = craftscan::testing::SharedData() / "clouds" / "bunny";
  if (!fs::exists(dir / "bun.conf")) {
    GTEST_SKIP() << "Stanford bunny not found at " << dir << " (set -DCRAFTSCAN_SHARED_DATA=...)";
  }
  std::vector<RangeScan> scans;
  std::string error;
  ASSERT_TRUE(LoadStanfordScans(dir.string(), &scans, &error)) << error;
  ASSERT_EQ(scans.size(), 10u);
  const std::vector<std::pair<std::string, std::size_t>> expected = {
      {"bun000.ply", 40256}, {"bun045.ply", 40097},  {"bun090.ply", 30379}, {"bun180.ply", 40251},
      {"bun270.ply", 31701}, {"top2.ply", 38298},    {"top3.ply", 36023},   {"bun315.ply", 35336},
      {"chin.ply", 37738},   {"ear_back.ply", 32193}};
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(scans[i].name, expected[i].first);
    EXPECT_EQ(scans[i].cloud.size(), expected[i].second) << expected[i].first;
  }
  const RangeScan& s000 = scans[0];
  const RangeScan& s045 = scans[1];
  EXPECT_EQ(s000.world_from_scan, cv::Matx44d::eye());
  // Object ~150 mm across, in mm now.
  cv::Vec3f lo(1e9f, 1e9f, 1e9f), hi(-1e9f, -1e9f, -1e9f);
  for (const cv::Vec3f& p : s000.cloud.points_mm) {
    for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
  }
  EXPECT_GT(hi[0] - lo[0], 100.0f);
  EXPECT_LT(hi[0] - lo[0], 250.0f);

  // README: bun045 is 34.3° and ~5 cm away from bun000.
  const cv::Matx44d target_from_source = RelativePose(s000.world_from_scan, s045.world_from_scan);
  EXPECT_NEAR(RotationErrorDeg(cv::Matx44d::eye(), target_from_source), 34.3, 0.2);
  EXPECT_NEAR(TranslationErrorMm(cv::Matx44d::eye(), target_from_source), 53, 2);

  // The ground truth brings the overlap together; identity and the
  // non-conjugate quaternion do not.
  const std::vector<cv::Vec3f> ref = TransformCloud(s000.world_from_scan, s000.cloud).points_mm;
  double median = 0, within = 0;
  NearestNeighbourStats(TransformCloud(s045.world_from_scan, s045.cloud).points_mm, ref, 20,
                        &median, &within);
  EXPECT_LT(median, 1.0);
  EXPECT_GT(within, 0.85);
  RecordProperty("bun045_to_bun000_median_nn_mm", std::to_string(median));

  NearestNeighbourStats(s045.cloud.points_mm, ref, 20, &median, &within);
  EXPECT_GT(median, 10.0) << "identity pose";
  RecordProperty("identity_median_nn_mm", std::to_string(median));

  cv::Matx44d wrong = s045.world_from_scan;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) wrong(i, j) = s045.world_from_scan(j, i);
  }
  NearestNeighbourStats(TransformCloud(wrong, s045.cloud).points_mm, ref, 20, &median, &within);
  EXPECT_GT(median, 10.0) << "R(q) instead of R(q)ᵀ";
  RecordProperty("non_conjugate_median_nn_mm", std::to_string(median));
}

}  // namespace
}  // namespace craftscan
