// StoreMeshObjFromPly (scan_outputs.h): a worker's outputs come without
// mesh.obj, and the station writes it from the mesh.ply it stored. The OBJ
// must be the one the station would have made of the mesh itself, byte for
// byte; a mesh.ply that cannot be read is a resumable error naming it; a
// session without mesh.ply, or with its mesh.obj already, is left alone.
#include <gtest/gtest.h>

#include <string>

#include <opencv2/core.hpp>

#include "../sessions/session_test_util.h"
#include "craftscan/daemon/scan_outputs.h"
#include "craftscan/daemon/scan_turns.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::daemon {
namespace {

using testing::ReadAll;
using testing::SessionFiles;

// A tetrahedron with normals and colours whose floats print with many
// digits (the OBJ is text: every bit of each float must come through PLY).
TriangleMesh OddMesh() {
  TriangleMesh mesh;
  mesh.vertices_mm = {{0.1f, -12.345678f, 3e-5f},
                      {101.00001f, 0.3333333f, -7.25f},
                      {-0.0f, 55.5555f, 1.0f / 3.0f},
                      {12.0f, 13.0f, 1e7f / 3.0f}};
  for (const cv::Vec3f& v : mesh.vertices_mm)
    mesh.normals.push_back(cv::normalize(v + cv::Vec3f(1, 2, 3)));
  mesh.colors_rgb = {{0, 1, 2}, {255, 128, 7}, {33, 66, 99}, {254, 253, 252}};
  mesh.faces = {{0, 1, 2}, {0, 3, 1}, {1, 3, 2}, {2, 3, 0}};
  return mesh;
}

class ScanOutputFiles : public SessionFiles {};

TEST_F(ScanOutputFiles, TheObjWrittenFromAWorkersMeshPlyIsTheStationsOwnByteForByte) {
  auto session = NewCapturing("box");
  ASSERT_NE(session, nullptr);
  const TriangleMesh mesh = OddMesh();
  std::string error;
  ASSERT_TRUE(
      ::craftscan::testing::Ok(session->StoreOutput("mesh.ply", EncodeMeshPly(mesh, true)), &error))
      << error;
  const StageOutcome outcome = StoreMeshObjFromPly(*session);
  ASSERT_TRUE(outcome.ok()) << outcome.message;
  ASSERT_TRUE(session->manifest().outputs.count("mesh.obj"));
  const std::string obj = ReadAll(session->dir() + "/mesh.obj");
  EXPECT_FALSE(obj.empty());
  EXPECT_TRUE(obj == EncodeMeshObj(mesh)) << obj;
}

TEST_F(ScanOutputFiles, AnUnreadableMeshPlyIsAResumableErrorNamingIt) {
  auto session = NewCapturing("box");
  ASSERT_NE(session, nullptr);
  std::string error;
  ASSERT_TRUE(::craftscan::testing::Ok(
      session->StoreOutput("mesh.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"), &error))
      << error;
  const StageOutcome outcome = StoreMeshObjFromPly(*session);
  EXPECT_FALSE(outcome.ok());
  EXPECT_TRUE(outcome.resumable);
  EXPECT_NE(outcome.message.find("mesh.obj from mesh.ply"), std::string::npos) << outcome.message;
  EXPECT_NE(outcome.message.find("mesh.ply"), std::string::npos) << outcome.message;
  EXPECT_FALSE(session->manifest().outputs.count("mesh.obj"));
}

TEST_F(ScanOutputFiles, WithoutMeshPlyOrWithItsObjNothingIsWritten) {
  auto session = NewCapturing("box");
  ASSERT_NE(session, nullptr);
  EXPECT_TRUE(StoreMeshObjFromPly(*session).ok());
  EXPECT_FALSE(session->manifest().outputs.count("mesh.obj"));

  // A station's own outputs (or an older worker's) carry mesh.obj: kept as it is.
  const TriangleMesh mesh = OddMesh();
  std::string error;
  ASSERT_TRUE(
      ::craftscan::testing::Ok(session->StoreOutput("mesh.ply", EncodeMeshPly(mesh, true)), &error))
      << error;
  ASSERT_TRUE(::craftscan::testing::Ok(session->StoreOutput("mesh.obj", "# kept\n"), &error))
      << error;
  EXPECT_TRUE(StoreMeshObjFromPly(*session).ok());
  EXPECT_EQ(ReadAll(session->dir() + "/mesh.obj"), "# kept\n");
}

// How a join is told to people (scan_turns.h): report.json's "held" and
// the one line craftscanctl and the progress topic show.
TEST(TurnJoinSummary, SaysWhenTheJoinIsHeldWeakly) {
  ScanResult result;
  EXPECT_TRUE(TurnJoinJson(result).is_null());
  TurnJoinResult& j = result.turn_join.emplace();
  j.status = TurnJoinResult::Status::kJoined;
  j.overlap = 0.726;
  j.rmse_mm = 0.21;
  j.constraint = 0.18;
  nlohmann::json json = TurnJoinJson(result);
  EXPECT_EQ(json.value("held", ""), "firmly");
  EXPECT_EQ(TurnJoinSummary(json), "joined (fit 72.6 %, RMSE 0.21 mm, no rival)");
  j.constraint = 0.015;
  j.held_weakly = true;
  json = TurnJoinJson(result);
  EXPECT_EQ(json.value("held", ""), "weakly");
  EXPECT_EQ(TurnJoinSummary(json), "joined (fit 72.6 %, RMSE 0.21 mm, no rival, held weakly)");
  j.ambiguity = 0.5;
  EXPECT_EQ(TurnJoinSummary(TurnJoinJson(result)),
            "joined (fit 72.6 %, RMSE 0.21 mm, rival fits 50 % as well, held weakly)");
  j.status = TurnJoinResult::Status::kRefusedAmbiguous;
  j.message = "the turns cannot be joined unambiguously";
  json = TurnJoinJson(result);
  EXPECT_EQ(json.value("held", ""), "not joined");
  EXPECT_EQ(TurnJoinSummary(json), "refused_ambiguous: the turns cannot be joined unambiguously");
}

}  // namespace
}  // namespace craftscan::daemon
