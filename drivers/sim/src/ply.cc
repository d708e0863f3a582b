#include "craftscan/sim/ply.h"

#include "craftscan/pipeline/common/atomic_file.h"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string_view>

namespace craftscan::sim {
namespace {

enum class Scalar { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParseScalar(std::string_view name, Scalar* type) {
  struct Entry {
    std::string_view name;
    Scalar type;
  };
  static constexpr Entry kTypes[] = {
      {"char", Scalar::kInt8},       {"int8", Scalar::kInt8},       {"uchar", Scalar::kUint8},
      {"uint8", Scalar::kUint8},     {"short", Scalar::kInt16},     {"int16", Scalar::kInt16},
      {"ushort", Scalar::kUint16},   {"uint16", Scalar::kUint16},   {"int", Scalar::kInt32},
      {"int32", Scalar::kInt32},     {"uint", Scalar::kUint32},     {"uint32", Scalar::kUint32},
      {"float", Scalar::kFloat32},   {"float32", Scalar::kFloat32}, {"double", Scalar::kFloat64},
      {"float64", Scalar::kFloat64},
  };
  for (const Entry& e : kTypes) {
    if (e.name == name) {
      *type = e.type;
      return true;
    }
  }
  return false;
}

int SizeOf(Scalar t) {
  switch (t) {
    case Scalar::kInt8:
    case Scalar::kUint8:
      return 1;
    case Scalar::kInt16:
    case Scalar::kUint16:
      return 2;
    case Scalar::kInt32:
    case Scalar::kUint32:
    case Scalar::kFloat32:
      return 4;
    case Scalar::kFloat64:
      return 8;
  }
  return 1;
}

// Little-endian value at p (the host is little-endian x86-64/ARM64).
double ReadBinary(const char* p, Scalar t) {
  switch (t) {
    case Scalar::kInt8: {
      std::int8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case Scalar::kUint8: {
      std::uint8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case Scalar::kInt16: {
      std::int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case Scalar::kUint16: {
      std::uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case Scalar::kInt32: {
      std::int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case Scalar::kUint32: {
      std::uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case Scalar::kFloat32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case Scalar::kFloat64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
  }
  return 0;
}

struct Property {
  std::string name;
  bool is_list = false;
  Scalar count_type = Scalar::kUint8;  // lists only
  Scalar type = Scalar::kFloat32;      // the value or list entry type
};

struct Element {
  std::string name;
  std::size_t count = 0;
  std::vector<Property> properties;
};

std::vector<std::string_view> Split(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
    std::size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r') ++j;
    if (j > i) out.push_back(line.substr(i, j - i));
    i = j;
  }
  return out;
}

// Reads the next whitespace-separated number of an ASCII body.
class AsciiReader {
 public:
  AsciiReader(const char* begin, const char* end) : p_(begin), end_(end) {}
  bool Next(double* value) {
    while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r' || *p_ == '\n')) ++p_;
    if (p_ >= end_) return false;
    const auto [ptr, ec] = std::from_chars(p_, end_, *value);
    if (ec != std::errc() || ptr == p_) {
      bad_ = true;
      return false;
    }
    p_ = ptr;
    return true;
  }
  bool bad() const { return bad_; }

 private:
  const char* p_;
  const char* end_;
  bool bad_ = false;
};

class BinaryReader {
 public:
  BinaryReader(const char* begin, const char* end) : p_(begin), end_(end) {}
  bool Next(Scalar t, double* value) {
    const int size = SizeOf(t);
    if (end_ - p_ < size) return false;
    *value = ReadBinary(p_, t);
    p_ += size;
    return true;
  }

 private:
  const char* p_;
  const char* end_;
};

}  // namespace

bool LoadPly(const std::string& path, TriangleMesh* mesh, std::string* error) {
  auto fail = [&](const std::string& message) {
    if (error) *error = "'" + path + "': " + message;
    return false;
  };
  std::ifstream file(path, std::ios::binary);
  if (!file) return fail("cannot open file");
  const std::string data((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  if (file.bad()) return fail("read error");

  // Header.
  std::size_t pos = 0;
  int line_number = 0;
  auto next_line = [&](std::string_view* line) {
    if (pos >= data.size()) return false;
    std::size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) eol = data.size();
    *line = std::string_view(data).substr(pos, eol - pos);
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    pos = eol + 1;
    ++line_number;
    return true;
  };
  std::string_view line;
  if (!next_line(&line) || line != "ply") {
    return fail("not a PLY file (the first line must be 'ply')");
  }
  bool binary = false, have_format = false, have_end = false;
  std::vector<Element> elements;
  while (next_line(&line)) {
    const std::vector<std::string_view> tokens = Split(line);
    const std::string where = "header line " + std::to_string(line_number) + ": ";
    if (tokens.empty() || tokens[0] == "comment" || tokens[0] == "obj_info") continue;
    if (tokens[0] == "end_header") {
      have_end = true;
      break;
    }
    if (tokens[0] == "format") {
      if (tokens.size() != 3) return fail(where + "malformed format line");
      if (tokens[1] == "ascii") {
        binary = false;
      } else if (tokens[1] == "binary_little_endian") {
        binary = true;
      } else {
        return fail(where + "unsupported format '" + std::string(tokens[1]) +
                    "' (supported: ascii, binary_little_endian)");
      }
      have_format = true;
    } else if (tokens[0] == "element") {
      if (tokens.size() != 3) return fail(where + "malformed element line");
      Element e;
      e.name = tokens[1];
      std::uint64_t count = 0;
      const auto [ptr, ec] =
          std::from_chars(tokens[2].data(), tokens[2].data() + tokens[2].size(), count);
      if (ec != std::errc() || ptr != tokens[2].data() + tokens[2].size() || count > (1u << 31)) {
        return fail(where + "bad element count '" + std::string(tokens[2]) + "'");
      }
      e.count = count;
      elements.push_back(std::move(e));
    } else if (tokens[0] == "property") {
      if (elements.empty()) return fail(where + "property before any element");
      Property p;
      if (tokens.size() == 5 && tokens[1] == "list") {
        p.is_list = true;
        if (!ParseScalar(tokens[2], &p.count_type) || !ParseScalar(tokens[3], &p.type)) {
          return fail(where + "unknown list type in '" + std::string(line) + "'");
        }
        if (p.count_type == Scalar::kFloat32 || p.count_type == Scalar::kFloat64) {
          return fail(where + "list count type must be an integer type");
        }
        p.name = tokens[4];
      } else if (tokens.size() == 3) {
        if (!ParseScalar(tokens[1], &p.type)) {
          return fail(where + "unknown property type '" + std::string(tokens[1]) + "'");
        }
        p.name = tokens[2];
      } else {
        return fail(where + "malformed property line");
      }
      elements.back().properties.push_back(std::move(p));
    } else {
      return fail(where + "unknown keyword '" + std::string(tokens[0]) + "'");
    }
  }
  if (!have_end) return fail("header has no 'end_header'");
  if (!have_format) return fail("header has no 'format' line");

  // Where x, y, z and the face indices are.
  int vertex_element = -1, face_element = -1;
  int ix = -1, iy = -1, iz = -1, iface = -1;
  for (std::size_t i = 0; i < elements.size(); ++i) {
    const Element& e = elements[i];
    if (e.name == "vertex") {
      vertex_element = static_cast<int>(i);
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const Property& p = e.properties[k];
        if (p.is_list) continue;
        if (p.name == "x") ix = static_cast<int>(k);
        if (p.name == "y") iy = static_cast<int>(k);
        if (p.name == "z") iz = static_cast<int>(k);
      }
    } else if (e.name == "face") {
      face_element = static_cast<int>(i);
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const Property& p = e.properties[k];
        if (p.is_list && (p.name == "vertex_indices" || p.name == "vertex_index")) {
          iface = static_cast<int>(k);
        }
      }
    }
  }
  if (vertex_element < 0) return fail("no 'vertex' element");
  if (ix < 0 || iy < 0 || iz < 0) return fail("element 'vertex' lacks property x, y or z");
  if (face_element < 0 || elements[static_cast<std::size_t>(face_element)].count == 0) {
    return fail("no faces (a point cloud is not a mesh)");
  }
  if (iface < 0) return fail("element 'face' has no list property 'vertex_indices'");

  TriangleMesh out;
  const std::size_t num_vertices = elements[static_cast<std::size_t>(vertex_element)].count;
  out.vertices.reserve(num_vertices);
  const char* body = data.data() + std::min(pos, data.size());
  const char* end = data.data() + data.size();
  AsciiReader ascii(body, end);
  BinaryReader bin(body, end);
  auto read = [&](Scalar t, double* v) { return binary ? bin.Next(t, v) : ascii.Next(v); };
  auto truncated = [&](const Element& e, std::size_t item) {
    if (!binary && ascii.bad()) {
      return fail("malformed number in element '" + e.name + "' item " + std::to_string(item));
    }
    return fail("truncated: element '" + e.name + "' item " + std::to_string(item) + " of " +
                std::to_string(e.count) + " is incomplete");
  };
  std::vector<int> polygon;
  for (std::size_t ei = 0; ei < elements.size(); ++ei) {
    const Element& e = elements[ei];
    for (std::size_t item = 0; item < e.count; ++item) {
      double xyz[3] = {0, 0, 0};
      polygon.clear();
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const Property& p = e.properties[k];
        if (!p.is_list) {
          double v;
          if (!read(p.type, &v)) return truncated(e, item);
          if (static_cast<int>(ei) == vertex_element) {
            if (static_cast<int>(k) == ix) xyz[0] = v;
            if (static_cast<int>(k) == iy) xyz[1] = v;
            if (static_cast<int>(k) == iz) xyz[2] = v;
          }
          continue;
        }
        double count;
        if (!read(p.count_type, &count)) return truncated(e, item);
        if (!(count >= 0) || count > 1e6 || count != std::floor(count)) {
          return fail("element '" + e.name + "' item " + std::to_string(item) +
                      ": bad list length");
        }
        const bool is_face = static_cast<int>(ei) == face_element && static_cast<int>(k) == iface;
        for (int j = 0; j < static_cast<int>(count); ++j) {
          double v;
          if (!read(p.type, &v)) return truncated(e, item);
          if (is_face) {
            if (!(v >= 0) || v >= static_cast<double>(num_vertices) || v != std::floor(v)) {
              return fail("face " + std::to_string(item) + " refers to vertex " +
                          std::to_string(static_cast<long long>(v)) + " but there are " +
                          std::to_string(num_vertices) + " vertices");
            }
            polygon.push_back(static_cast<int>(v));
          }
        }
        if (is_face && polygon.size() < 3) {
          return fail("face " + std::to_string(item) + " has " + std::to_string(polygon.size()) +
                      " vertices (need at least 3)");
        }
      }
      if (static_cast<int>(ei) == vertex_element) {
        if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) {
          return fail("vertex " + std::to_string(item) + " is not finite");
        }
        out.vertices.emplace_back(xyz[0], xyz[1], xyz[2]);
      } else if (static_cast<int>(ei) == face_element) {
        for (std::size_t j = 1; j + 1 < polygon.size(); ++j) {
          out.triangles.emplace_back(polygon[0], polygon[j], polygon[j + 1]);
        }
      }
    }
  }
  *mesh = std::move(out);
  return true;
}

bool SavePly(const std::string& path, const TriangleMesh& mesh, bool binary, std::string* error) {
  std::ostringstream out(std::ios::binary);
  out << "ply\nformat " << (binary ? "binary_little_endian" : "ascii") << " 1.0\n"
      << "comment craftscan sim\n"
      << "element vertex " << mesh.vertices.size() << "\n"
      << "property float x\nproperty float y\nproperty float z\n"
      << "element face " << mesh.triangles.size() << "\n"
      << "property list uchar int vertex_indices\nend_header\n";
  if (binary) {
    for (const cv::Vec3d& v : mesh.vertices) {
      const float f[3] = {static_cast<float>(v[0]), static_cast<float>(v[1]),
                          static_cast<float>(v[2])};
      out.write(reinterpret_cast<const char*>(f), sizeof(f));
    }
    for (const cv::Vec3i& t : mesh.triangles) {
      const std::uint8_t n = 3;
      const std::int32_t idx[3] = {t[0], t[1], t[2]};
      out.write(reinterpret_cast<const char*>(&n), 1);
      out.write(reinterpret_cast<const char*>(idx), sizeof(idx));
    }
  } else {
    out.precision(9);
    for (const cv::Vec3d& v : mesh.vertices) out << v[0] << ' ' << v[1] << ' ' << v[2] << '\n';
    for (const cv::Vec3i& t : mesh.triangles)
      out << "3 " << t[0] << ' ' << t[1] << ' ' << t[2] << '\n';
  }
  return WriteFileAtomically(path, out.view(), error);
}

}  // namespace craftscan::sim
