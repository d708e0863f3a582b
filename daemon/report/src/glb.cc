// model.glb through tinygltf (glb.h). Debian ships tinygltf as a shared
// library (libtinygltf.so, README.Debian): this file only includes its
// declarations; no TINYGLTF_IMPLEMENTATION here.
#include "craftscan/daemon/glb.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <sstream>
#include <vector>

#include <tiny_gltf.h>
#include <nlohmann/json.hpp>

namespace craftscan::daemon {
namespace {

using Json = nlohmann::json;

constexpr int kFloat = TINYGLTF_COMPONENT_TYPE_FLOAT;
constexpr int kUnsignedByte = TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE;
constexpr int kUnsignedInt = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;

// JSON (as nlohmann parses report.json) as tinygltf's extras value. Nulls,
// non-finite numbers and empty arrays/objects are left out: tinygltf would
// write them as null.
bool ToValue(const Json& j, tinygltf::Value* out) {
  switch (j.type()) {
    case Json::value_t::boolean:
      *out = tinygltf::Value(j.get<bool>());
      return true;
    case Json::value_t::number_integer:
    case Json::value_t::number_unsigned: {
      const double v = j.get<double>();
      if (std::abs(v) < 2147483647.0)
        *out = tinygltf::Value(static_cast<int>(v));
      else
        *out = tinygltf::Value(v);
      return true;
    }
    case Json::value_t::number_float: {
      const double v = j.get<double>();
      if (!std::isfinite(v)) return false;
      *out = tinygltf::Value(v);
      return true;
    }
    case Json::value_t::string:
      *out = tinygltf::Value(j.get<std::string>());
      return true;
    case Json::value_t::array: {
      tinygltf::Value::Array items;
      for (const Json& item : j) {
        tinygltf::Value v;
        if (ToValue(item, &v)) items.push_back(std::move(v));
      }
      if (items.empty()) return false;
      *out = tinygltf::Value(std::move(items));
      return true;
    }
    case Json::value_t::object: {
      tinygltf::Value::Object members;
      for (auto it = j.begin(); it != j.end(); ++it) {
        tinygltf::Value v;
        if (ToValue(it.value(), &v)) members.emplace(it.key(), std::move(v));
      }
      if (members.empty()) return false;
      *out = tinygltf::Value(std::move(members));
      return true;
    }
    default:
      return false;
  }
}

// Puts `value` under `key` unless it is "" or not finite.
void PutIfKnown(Json& j, const char* key, const std::string& value) {
  if (!value.empty()) j[key] = value;
}
void PutIfKnown(Json& j, const char* key, double value) {
  if (std::isfinite(value)) j[key] = value;
}

// The accuracy figures of report.json worth carrying with the model.
Json AccuracyFigures(const Json& report) {
  Json accuracy = Json::object();
  if (const auto q = report.find("quality"); q != report.end() && q->is_object())
    accuracy["quality"] = *q;
  if (const auto l = report.find("loop_closure"); l != report.end() && l->is_object()) {
    Json loop = Json::object();
    for (const char* key : {"ok", "model", "rms_mm", "max_mm", "axis_rms_mm"})
      if (l->contains(key)) loop[key] = (*l)[key];
    accuracy["loop_closure"] = loop;
  }
  if (const auto m = report.find("measurement"); m != report.end() && m->is_object())
    accuracy["measurement"] = *m;
  return accuracy;
}

Json ProvenanceJson(const ModelProvenance& p, ModelFrame frame, const Json& report,
                    std::size_t vertices, std::size_t triangles) {
  Json j;
  j["format"] = "craftscan-model-provenance";
  j["format_version"] = 1;
  PutIfKnown(j, "object_name", p.object_name);
  PutIfKnown(j, "session_id", p.session_id);
  PutIfKnown(j, "station", p.station);
  PutIfKnown(j, "captured_utc", p.captured_utc);
  PutIfKnown(j, "client", p.client);
  Json calibration = Json::object();
  PutIfKnown(calibration, "id", p.calibration_id);
  PutIfKnown(calibration, "rms_stereo_px", p.calibration_rms_px);
  PutIfKnown(calibration, "epipolar_mean_px", p.calibration_epipolar_mean_px);
  j["calibration"] = calibration;
  PutIfKnown(j, "software", p.software);
  PutIfKnown(j, "rights", p.rights);
  j["units"] = "m";
  j["up"] = "+Y";
  j["source_frame"] = ToString(frame);
  j["source_units"] = "mm";
  // gltf_from_model is 0.001 · a rotation: its inverse is its transpose · 10⁶.
  const cv::Matx33d gltf_from_model = GltfFromModel(frame).get_minor<3, 3>(0, 0);
  const cv::Matx33d source_from_gltf = gltf_from_model.t() * 1e6;
  Json m = Json::array();
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      const double v = r < 3 && c < 3 ? source_from_gltf(r, c) : (r == c ? 1.0 : 0.0);
      m.push_back(v == 0 ? 0.0 : v);  // no −0
    }
  }
  j["source_from_gltf"] = m;
  j["vertices"] = vertices;
  j["triangles"] = triangles;
  j["accuracy"] = AccuracyFigures(report);
  return j;
}

// Appends `bytes` to the buffer as a new view (4-byte aligned); its index.
int AddView(tinygltf::Model& model, const void* bytes, std::size_t size, int target,
            int stride = 0) {
  std::vector<unsigned char>& data = model.buffers[0].data;
  data.resize((data.size() + 3) / 4 * 4, 0);
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = data.size();
  view.byteLength = size;
  view.byteStride = static_cast<std::size_t>(stride);
  view.target = target;
  const auto* begin = static_cast<const unsigned char*>(bytes);
  data.insert(data.end(), begin, begin + size);
  model.bufferViews.push_back(std::move(view));
  return static_cast<int>(model.bufferViews.size()) - 1;
}

int AddAccessor(tinygltf::Model& model, int view, int component, int type, std::size_t count,
                bool normalized = false) {
  tinygltf::Accessor a;
  a.bufferView = view;
  a.componentType = component;
  a.type = type;
  a.count = count;
  a.normalized = normalized;
  model.accessors.push_back(std::move(a));
  return static_cast<int>(model.accessors.size()) - 1;
}

// Min and max per component of `values` (3 per element), as the validator
// wants them: exactly the stored values.
void SetBounds(tinygltf::Accessor& a, const std::vector<float>& xyz) {
  a.minValues.assign(3, std::numeric_limits<double>::infinity());
  a.maxValues.assign(3, -std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < xyz.size(); ++i) {
    a.minValues[i % 3] = std::min(a.minValues[i % 3], static_cast<double>(xyz[i]));
    a.maxValues[i % 3] = std::max(a.maxValues[i % 3], static_cast<double>(xyz[i]));
  }
}

bool Fail(std::string* error, const std::string& why) {
  if (error) *error = "glb: " + why;
  return false;
}

}  // namespace

const char* ToString(ModelFrame frame) {
  return frame == ModelFrame::kView0 ? "view0" : "turntable";
}

cv::Matx44d GltfFromModel(ModelFrame frame) {
  constexpr double s = 0.001;  // m per mm
  if (frame == ModelFrame::kView0) {
    return {s, 0, 0, 0, 0, -s, 0, 0, 0, 0, -s, 0, 0, 0, 0, 1};
  }
  return {s, 0, 0, 0, 0, 0, s, 0, 0, -s, 0, 0, 0, 0, 0, 1};
}

bool EncodeGlb(const TriangleMesh& mesh, const ModelProvenance& provenance, std::string* glb,
               std::string* error) {
  std::string why;
  if (mesh.empty()) return Fail(error, "the mesh has no triangles");
  if (!mesh.IsValid(&why)) return Fail(error, "invalid mesh: " + why);
  const std::size_t n = mesh.vertices_mm.size();
  // Positions and normals 12 bytes, colours 4, indices 4 per corner.
  const double bytes = 28.0 * double(n) + 12.0 * double(mesh.faces.size()) + (1 << 20);
  if (bytes > 4.0e9) return Fail(error, "the mesh is too large for a GLB (4 GiB)");
  try {
    Json report = Json::object();
    if (!provenance.scan_report_json.empty()) {
      report = Json::parse(provenance.scan_report_json, nullptr, false);
      if (!report.is_object()) report = Json::object();
    }
    const ModelFrame frame = report.value("frame", std::string()) == "view0"
                                 ? ModelFrame::kView0
                                 : ModelFrame::kTurntable;
    const cv::Matx44d gltf_from_model = GltfFromModel(frame);
    const cv::Matx33d rotation = gltf_from_model.get_minor<3, 3>(0, 0) * 1000.0;

    std::vector<float> positions(3 * n), normals;
    for (std::size_t i = 0; i < n; ++i) {
      const cv::Vec4d p =
          gltf_from_model *
          cv::Vec4d(mesh.vertices_mm[i][0], mesh.vertices_mm[i][1], mesh.vertices_mm[i][2], 1.0);
      for (int c = 0; c < 3; ++c) positions[3 * i + c] = static_cast<float>(p[c]);
    }
    if (!mesh.normals.empty()) {
      normals.resize(3 * n);
      for (std::size_t i = 0; i < n && !normals.empty(); ++i) {
        const cv::Vec3d v = rotation * cv::Vec3d(mesh.normals[i]);
        const double length = cv::norm(v);
        if (!std::isfinite(length) || length < 1e-6) {
          normals.clear();  // one unusable normal: none (the viewer computes them)
          break;
        }
        for (int c = 0; c < 3; ++c) normals[3 * i + c] = static_cast<float>(v[c] / length);
      }
    }
    std::vector<std::uint32_t> indices;
    indices.reserve(3 * mesh.faces.size());
    for (const cv::Vec3i& f : mesh.faces)
      for (int c = 0; c < 3; ++c) indices.push_back(static_cast<std::uint32_t>(f[c]));

    tinygltf::Model model;
    model.asset.version = "2.0";
    model.asset.generator = provenance.software.empty() ? "craftscan" : provenance.software;
    model.asset.copyright = provenance.rights;
    tinygltf::Value extras;
    Json provenance_json = {
        {"craftscan", ProvenanceJson(provenance, frame, report, n, mesh.faces.size())}};
    ToValue(provenance_json, &extras);
    model.asset.extras = std::move(extras);
    model.buffers.emplace_back();

    tinygltf::Primitive primitive;
    primitive.mode = TINYGLTF_MODE_TRIANGLES;
    const int position_view = AddView(model, positions.data(), positions.size() * sizeof(float),
                                      TINYGLTF_TARGET_ARRAY_BUFFER);
    const int position = AddAccessor(model, position_view, kFloat, TINYGLTF_TYPE_VEC3, n);
    SetBounds(model.accessors[static_cast<std::size_t>(position)], positions);
    primitive.attributes["POSITION"] = position;
    if (!normals.empty()) {
      const int view = AddView(model, normals.data(), normals.size() * sizeof(float),
                               TINYGLTF_TARGET_ARRAY_BUFFER);
      const int accessor = AddAccessor(model, view, kFloat, TINYGLTF_TYPE_VEC3, n);
      SetBounds(model.accessors[static_cast<std::size_t>(accessor)], normals);
      primitive.attributes["NORMAL"] = accessor;
    }
    if (!mesh.colors_rgb.empty()) {
      // RGB padded to 4 bytes: vertex attributes must be 4-byte aligned.
      std::vector<unsigned char> rgb(4 * n, 0);
      for (std::size_t i = 0; i < n; ++i) std::memcpy(&rgb[4 * i], mesh.colors_rgb[i].val, 3);
      const int view = AddView(model, rgb.data(), rgb.size(), TINYGLTF_TARGET_ARRAY_BUFFER, 4);
      primitive.attributes["COLOR_0"] =
          AddAccessor(model, view, kUnsignedByte, TINYGLTF_TYPE_VEC3, n, true);
    }
    const int index_view = AddView(model, indices.data(), indices.size() * sizeof(std::uint32_t),
                                   TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    primitive.indices =
        AddAccessor(model, index_view, kUnsignedInt, TINYGLTF_TYPE_SCALAR, indices.size());

    tinygltf::Mesh gltf_mesh;
    gltf_mesh.name = provenance.object_name.empty() ? "model" : provenance.object_name;
    gltf_mesh.primitives.push_back(std::move(primitive));
    model.meshes.push_back(std::move(gltf_mesh));
    tinygltf::Node node;
    node.mesh = 0;
    node.name = model.meshes[0].name;
    model.nodes.push_back(std::move(node));
    tinygltf::Scene scene;
    scene.nodes.push_back(0);
    model.scenes.push_back(std::move(scene));
    model.defaultScene = 0;

    std::ostringstream out;
    tinygltf::TinyGLTF writer;
    if (!writer.WriteGltfSceneToStream(&model, out, false, true) || !out)
      return Fail(error, "tinygltf could not write the model");
    *glb = std::move(out).str();
    return true;
  } catch (const std::exception& e) {
    return Fail(error, e.what());
  }
}

}  // namespace craftscan::daemon
