// mesh.glb (craftscan/daemon/glb.h): a small mesh written as GLB and read
// back with tinygltf's loader, field by field: positions in metres with +Y
// up, normals turned with them, colours, indices, accessor bounds, and the
// provenance in asset.extras; the bad inputs refused with a message.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>

#include <tiny_gltf.h>

#include "craftscan/daemon/glb.h"

namespace craftscan::daemon {
namespace {

using ::testing::HasSubstr;

// A tetrahedron with distinct coordinates (mm), unit normals and colours.
TriangleMesh Tetrahedron() {
  TriangleMesh mesh;
  mesh.vertices_mm = {{10, 20, 30}, {-40, 5, 0.5f}, {7, -60, 12}, {0, 0, 90}};
  for (const cv::Vec3f& v : mesh.vertices_mm) mesh.normals.push_back(cv::normalize(v));
  mesh.colors_rgb = {{255, 0, 0}, {0, 128, 0}, {1, 2, 3}, {200, 100, 50}};
  mesh.faces = {{0, 1, 2}, {0, 3, 1}, {1, 3, 2}, {2, 3, 0}};
  return mesh;
}

ModelProvenance Provenance(const std::string& frame = "turntable") {
  ModelProvenance p;
  p.object_name = "carved box «linden»";
  p.session_id = "20261203-190000-carved_box";
  p.station = "station1";
  p.captured_utc = "2026-12-03T19:00:01.250Z";
  p.client = "craftscanctl@host";
  p.calibration_id = "20261203-180000";
  p.calibration_rms_px = 0.21;
  p.calibration_epipolar_mean_px = 0.05;
  p.software = "craftscan 0.1.0";
  p.rights = "© 2026 Museum X, CC BY 4.0";
  p.scan_report_json = R"({"frame": ")" + frame + R"(",
    "quality": {"p95_to_mesh_mm": 0.42, "holes": 2},
    "loop_closure": {"ok": true, "model": "turntable_axis", "rms_mm": 0.3, "max_mm": 0.9,
                     "axis_rms_mm": 0.1, "angles_deg": [0, 60]},
    "measurement": {"units": "mm", "oriented_box": {"extents_mm": [60, 40, 30]}}})";
  return p;
}

tinygltf::Model Load(const std::string& glb) {
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  const bool ok = loader.LoadBinaryFromMemory(&model, &error, &warning,
                                              reinterpret_cast<const unsigned char*>(glb.data()),
                                              static_cast<unsigned>(glb.size()));
  EXPECT_TRUE(ok) << error;
  EXPECT_EQ(warning, "");
  return model;
}

// The accessor's elements as `T` (tightly packed or with the view's stride).
template <typename T>
std::vector<T> Read(const tinygltf::Model& model, int accessor_index, int components) {
  const tinygltf::Accessor& a = model.accessors.at(static_cast<std::size_t>(accessor_index));
  const tinygltf::BufferView& v = model.bufferViews.at(static_cast<std::size_t>(a.bufferView));
  const std::vector<unsigned char>& data = model.buffers.at(0).data;
  const std::size_t element = sizeof(T) * static_cast<std::size_t>(components);
  const std::size_t stride = v.byteStride ? v.byteStride : element;
  std::vector<T> out(a.count * static_cast<std::size_t>(components));
  for (std::size_t i = 0; i < a.count; ++i) {
    const std::size_t at = v.byteOffset + a.byteOffset + i * stride;
    EXPECT_LE(at + element, data.size());
    std::memcpy(&out[i * static_cast<std::size_t>(components)], &data[at], element);
  }
  return out;
}

const tinygltf::Value& Key(const tinygltf::Value& v, const std::string& key) {
  EXPECT_TRUE(v.Has(key)) << key;
  return v.Get(key);
}
// The float a coordinate in metres is stored as: the bounds are exactly those.
double F(double metres) { return static_cast<double>(static_cast<float>(metres)); }
double Number(const tinygltf::Value& v) { return v.IsInt() ? v.Get<int>() : v.Get<double>(); }

TEST(Glb, TurntableMeshReadsBackInMetresWithYUp) {
  const TriangleMesh mesh = Tetrahedron();
  std::string glb, error;
  ASSERT_TRUE(EncodeGlb(mesh, Provenance(), &glb, &error)) << error;
  ASSERT_GE(glb.size(), 12u);
  EXPECT_EQ(glb.substr(0, 4), "glTF");
  std::uint32_t length = 0;
  std::memcpy(&length, glb.data() + 8, 4);
  EXPECT_EQ(length, glb.size());
  EXPECT_EQ(glb.size() % 4, 0u);

  const tinygltf::Model model = Load(glb);
  EXPECT_EQ(model.asset.version, "2.0");
  EXPECT_EQ(model.asset.generator, "craftscan 0.1.0");
  EXPECT_EQ(model.asset.copyright, "© 2026 Museum X, CC BY 4.0");
  ASSERT_EQ(model.scenes.size(), 1u);
  EXPECT_EQ(model.defaultScene, 0);
  ASSERT_EQ(model.nodes.size(), 1u);
  EXPECT_EQ(model.nodes[0].mesh, 0);
  EXPECT_TRUE(model.nodes[0].matrix.empty());  // vertices converted, no node transform
  ASSERT_EQ(model.meshes.size(), 1u);
  ASSERT_EQ(model.meshes[0].primitives.size(), 1u);
  const tinygltf::Primitive& prim = model.meshes[0].primitives[0];
  EXPECT_EQ(prim.mode, TINYGLTF_MODE_TRIANGLES);

  // Positions: (x, z, −y) / 1000.
  const int pos = prim.attributes.at("POSITION");
  const tinygltf::Accessor& pa = model.accessors[static_cast<std::size_t>(pos)];
  EXPECT_EQ(pa.componentType, TINYGLTF_COMPONENT_TYPE_FLOAT);
  EXPECT_EQ(pa.type, TINYGLTF_TYPE_VEC3);
  ASSERT_EQ(pa.count, 4u);
  const std::vector<float> p = Read<float>(model, pos, 3);
  for (std::size_t i = 0; i < 4; ++i) {
    const cv::Vec3f& v = mesh.vertices_mm[i];
    EXPECT_NEAR(p[3 * i + 0], v[0] / 1000.0, 1e-7) << i;
    EXPECT_NEAR(p[3 * i + 1], v[2] / 1000.0, 1e-7) << i;
    EXPECT_NEAR(p[3 * i + 2], -v[1] / 1000.0, 1e-7) << i;
  }
  // The top vertex (z = 90 mm in the turntable) is the highest in glTF's Y.
  EXPECT_NEAR(p[3 * 3 + 1], 0.090, 1e-7);
  ASSERT_EQ(pa.minValues.size(), 3u);
  ASSERT_EQ(pa.maxValues.size(), 3u);
  EXPECT_DOUBLE_EQ(pa.minValues[0], F(-40.0 / 1000.0));
  EXPECT_DOUBLE_EQ(pa.maxValues[0], F(10.0 / 1000.0));
  EXPECT_DOUBLE_EQ(pa.minValues[1], F(0.5 / 1000.0));
  EXPECT_DOUBLE_EQ(pa.maxValues[1], F(90.0 / 1000.0));
  EXPECT_DOUBLE_EQ(pa.minValues[2], F(-20.0 / 1000.0));
  EXPECT_DOUBLE_EQ(pa.maxValues[2], F(60.0 / 1000.0));

  // Normals turned the same way, unit length.
  const std::vector<float> n = Read<float>(model, prim.attributes.at("NORMAL"), 3);
  for (std::size_t i = 0; i < 4; ++i) {
    const cv::Vec3f& v = mesh.normals[i];
    EXPECT_NEAR(n[3 * i + 0], v[0], 1e-6);
    EXPECT_NEAR(n[3 * i + 1], v[2], 1e-6);
    EXPECT_NEAR(n[3 * i + 2], -v[1], 1e-6);
  }

  // Colours: normalized unsigned bytes, RGB in a 4-byte stride.
  const int col = prim.attributes.at("COLOR_0");
  const tinygltf::Accessor& ca = model.accessors[static_cast<std::size_t>(col)];
  EXPECT_EQ(ca.componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE);
  EXPECT_EQ(ca.type, TINYGLTF_TYPE_VEC3);
  EXPECT_TRUE(ca.normalized);
  EXPECT_EQ(model.bufferViews[static_cast<std::size_t>(ca.bufferView)].byteStride, 4u);
  const std::vector<std::uint8_t> c = Read<std::uint8_t>(model, col, 3);
  for (std::size_t i = 0; i < 4; ++i)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(c[3 * i + k], mesh.colors_rgb[i][k]) << i << "," << k;

  // Indices: the faces, 32-bit.
  const tinygltf::Accessor& ia = model.accessors[static_cast<std::size_t>(prim.indices)];
  EXPECT_EQ(ia.componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT);
  const std::vector<std::uint32_t> idx = Read<std::uint32_t>(model, prim.indices, 1);
  ASSERT_EQ(idx.size(), 12u);
  for (std::size_t f = 0; f < 4; ++f)
    for (int k = 0; k < 3; ++k)
      EXPECT_EQ(idx[3 * f + k], static_cast<std::uint32_t>(mesh.faces[f][k]));

  // Provenance.
  const tinygltf::Value& prov = Key(model.asset.extras, "craftscan");
  EXPECT_EQ(Key(prov, "format").Get<std::string>(), "craftscan-model-provenance");
  EXPECT_EQ(Number(Key(prov, "format_version")), 1);
  EXPECT_EQ(Key(prov, "object_name").Get<std::string>(), "carved box «linden»");
  EXPECT_EQ(Key(prov, "session_id").Get<std::string>(), "20261203-190000-carved_box");
  EXPECT_EQ(Key(prov, "station").Get<std::string>(), "station1");
  EXPECT_EQ(Key(prov, "captured_utc").Get<std::string>(), "2026-12-03T19:00:01.250Z");
  EXPECT_EQ(Key(prov, "client").Get<std::string>(), "craftscanctl@host");
  const tinygltf::Value& cal = Key(prov, "calibration");
  EXPECT_EQ(Key(cal, "id").Get<std::string>(), "20261203-180000");
  EXPECT_DOUBLE_EQ(Number(Key(cal, "rms_stereo_px")), 0.21);
  EXPECT_DOUBLE_EQ(Number(Key(cal, "epipolar_mean_px")), 0.05);
  EXPECT_EQ(Key(prov, "software").Get<std::string>(), "craftscan 0.1.0");
  EXPECT_EQ(Key(prov, "rights").Get<std::string>(), "© 2026 Museum X, CC BY 4.0");
  EXPECT_EQ(Key(prov, "units").Get<std::string>(), "m");
  EXPECT_EQ(Key(prov, "up").Get<std::string>(), "+Y");
  EXPECT_EQ(Key(prov, "source_frame").Get<std::string>(), "turntable");
  EXPECT_EQ(Key(prov, "source_units").Get<std::string>(), "mm");
  EXPECT_EQ(Number(Key(prov, "vertices")), 4);
  EXPECT_EQ(Number(Key(prov, "triangles")), 4);
  // source_from_gltf takes every stored position back to the mesh's mm.
  const tinygltf::Value& m = Key(prov, "source_from_gltf");
  ASSERT_EQ(m.ArrayLen(), 16u);
  cv::Matx44d source_from_gltf;
  for (int i = 0; i < 16; ++i) source_from_gltf.val[i] = Number(m.Get(i));
  for (std::size_t i = 0; i < 4; ++i) {
    const cv::Vec4d back = source_from_gltf * cv::Vec4d(p[3 * i], p[3 * i + 1], p[3 * i + 2], 1);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(back[k], mesh.vertices_mm[i][k], 1e-4) << i;
    EXPECT_DOUBLE_EQ(back[3], 1);
  }
  const tinygltf::Value& acc = Key(prov, "accuracy");
  EXPECT_DOUBLE_EQ(Number(Key(Key(acc, "quality"), "p95_to_mesh_mm")), 0.42);
  EXPECT_EQ(Number(Key(Key(acc, "quality"), "holes")), 2);
  const tinygltf::Value& loop = Key(acc, "loop_closure");
  EXPECT_DOUBLE_EQ(Number(Key(loop, "rms_mm")), 0.3);
  EXPECT_DOUBLE_EQ(Number(Key(loop, "max_mm")), 0.9);
  EXPECT_DOUBLE_EQ(Number(Key(loop, "axis_rms_mm")), 0.1);
  EXPECT_FALSE(loop.Has("angles_deg"));
  const tinygltf::Value& extents = Key(Key(Key(acc, "measurement"), "oriented_box"), "extents_mm");
  ASSERT_EQ(extents.ArrayLen(), 3u);
  EXPECT_EQ(Number(extents.Get(0)), 60);
}

TEST(Glb, View0MeshFlipsYAndZ) {
  const TriangleMesh mesh = Tetrahedron();
  std::string glb, error;
  ASSERT_TRUE(EncodeGlb(mesh, Provenance("view0"), &glb, &error)) << error;
  const tinygltf::Model model = Load(glb);
  const tinygltf::Primitive& prim = model.meshes.at(0).primitives.at(0);
  const std::vector<float> p = Read<float>(model, prim.attributes.at("POSITION"), 3);
  for (std::size_t i = 0; i < 4; ++i) {
    const cv::Vec3f& v = mesh.vertices_mm[i];
    EXPECT_NEAR(p[3 * i + 0], v[0] / 1000.0, 1e-7);
    EXPECT_NEAR(p[3 * i + 1], -v[1] / 1000.0, 1e-7);
    EXPECT_NEAR(p[3 * i + 2], -v[2] / 1000.0, 1e-7);
  }
  EXPECT_EQ(Key(Key(model.asset.extras, "craftscan"), "source_frame").Get<std::string>(), "view0");
}

TEST(Glb, UnknownFiguresAndEmptyStringsAreLeftOut) {
  TriangleMesh mesh = Tetrahedron();
  mesh.colors_rgb.clear();
  mesh.normals[2] = {0, 0, 0};  // one unusable normal: no NORMAL at all
  ModelProvenance p;            // nothing known
  std::string glb, error;
  ASSERT_TRUE(EncodeGlb(mesh, p, &glb, &error)) << error;
  const tinygltf::Model model = Load(glb);
  const tinygltf::Primitive& prim = model.meshes.at(0).primitives.at(0);
  EXPECT_EQ(prim.attributes.count("COLOR_0"), 0u);
  EXPECT_EQ(prim.attributes.count("NORMAL"), 0u);
  EXPECT_EQ(model.asset.copyright, "");
  EXPECT_EQ(model.asset.generator, "craftscan");
  const tinygltf::Value& prov = Key(model.asset.extras, "craftscan");
  EXPECT_FALSE(prov.Has("rights"));
  EXPECT_FALSE(prov.Has("client"));
  EXPECT_FALSE(prov.Has("calibration"));  // no id, no RMS: nothing to say
  EXPECT_EQ(Key(prov, "source_frame").Get<std::string>(), "turntable");
}

TEST(Glb, BadMeshesAreRefusedWithAMessage) {
  std::string glb = "untouched", error;
  EXPECT_FALSE(EncodeGlb(TriangleMesh{}, Provenance(), &glb, &error));
  EXPECT_THAT(error, HasSubstr("glb: the mesh has no triangles"));
  TriangleMesh bad = Tetrahedron();
  bad.faces.push_back({0, 1, 9});
  EXPECT_FALSE(EncodeGlb(bad, Provenance(), &glb, &error));
  EXPECT_THAT(error, HasSubstr("glb: invalid mesh"));
  bad = Tetrahedron();
  bad.colors_rgb.pop_back();
  EXPECT_FALSE(EncodeGlb(bad, Provenance(), &glb, &error));
  EXPECT_THAT(error, HasSubstr("glb: invalid mesh"));
  EXPECT_EQ(glb, "untouched");
}

}  // namespace
}  // namespace craftscan::daemon
