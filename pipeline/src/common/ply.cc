#include "craftscan/pipeline/common/ply.h"

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/status.h"
#include "craftscan/pipeline/common/triangle_mesh.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <string_view>
#include <system_error>
#include <utility>

namespace craftscan {
namespace {

// A header longer than this is not a PLY header but garbage.
constexpr std::size_t kMaxHeaderBytes = 1 << 20;
// Far above any scan we handle (a 16k × 16k range image); a sanity bound on
// top of the "does the data fit in the file" check.
constexpr std::uint64_t kMaxVertices = std::uint64_t{1} << 28;
// Token length limit for ASCII values; longer is garbage, not a number.
constexpr std::size_t kMaxTokenLength = 64;
// A face with more corners than this is garbage, not a polygon.
constexpr double kMaxPolygonCorners = 1e6;

enum class Format { kAscii, kBinaryLittle, kBinaryBig };

enum class ScalarType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

std::optional<ScalarType> ParseScalarType(std::string_view name) {
  if (name == "char" || name == "int8") return ScalarType::kInt8;
  if (name == "uchar" || name == "uint8") return ScalarType::kUint8;
  if (name == "short" || name == "int16") return ScalarType::kInt16;
  if (name == "ushort" || name == "uint16") return ScalarType::kUint16;
  if (name == "int" || name == "int32") return ScalarType::kInt32;
  if (name == "uint" || name == "uint32") return ScalarType::kUint32;
  if (name == "float" || name == "float32") return ScalarType::kFloat32;
  if (name == "double" || name == "float64") return ScalarType::kFloat64;
  return std::nullopt;
}

std::size_t SizeOf(ScalarType t) {
  switch (t) {
    case ScalarType::kInt8:
    case ScalarType::kUint8:
      return 1;
    case ScalarType::kInt16:
    case ScalarType::kUint16:
      return 2;
    case ScalarType::kInt32:
    case ScalarType::kUint32:
    case ScalarType::kFloat32:
      return 4;
    case ScalarType::kFloat64:
      return 8;
  }
  return 1;
}

bool IsFloating(ScalarType t) { return t == ScalarType::kFloat32 || t == ScalarType::kFloat64; }

struct Property {
  std::string name;
  bool is_list = false;
  ScalarType type = ScalarType::kFloat32;      // value type (item type for lists)
  ScalarType count_type = ScalarType::kUint8;  // list length type
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> properties;
};

struct Header {
  Format format = Format::kAscii;
  std::vector<Element> elements;
  std::size_t data_offset = 0;  // first byte after "end_header\n"
};

std::vector<std::string_view> SplitWords(std::string_view line) {
  std::vector<std::string_view> words;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    const std::size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) words.push_back(line.substr(start, i - start));
  }
  return words;
}

bool ParseHeader(const std::string& data, const std::string& where, Header* header,
                 std::string* error) {
  std::size_t pos = 0;
  int line_number = 0;
  bool have_format = false;
  auto next_line = [&](std::string_view* line) {
    if (pos >= data.size()) return false;
    std::size_t end = data.find('\n', pos);
    if (end == std::string::npos) return false;  // a header always ends in a newline
    *line = std::string_view(data).substr(pos, end - pos);
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    pos = end + 1;
    ++line_number;
    return true;
  };

  std::string_view line;
  if (data.size() < 4 || data.compare(0, 3, "ply") != 0 || (data[3] != '\n' && data[3] != '\r')) {
    return Fail(error, where + "not a PLY file (does not start with a 'ply' line)");
  }
  next_line(&line);
  while (true) {
    if (pos > kMaxHeaderBytes) {
      return Fail(error, where + "no 'end_header' within the first " +
                             std::to_string(kMaxHeaderBytes) + " bytes");
    }
    if (!next_line(&line)) return Fail(error, where + "header ends without 'end_header'");
    const std::string at = where + "header line " + std::to_string(line_number) + ": ";
    const std::vector<std::string_view> w = SplitWords(line);
    if (w.empty()) continue;
    if (w[0] == "comment" || w[0] == "obj_info") continue;
    if (w[0] == "end_header") break;
    if (w[0] == "format") {
      if (w.size() != 3) return Fail(error, at + "expected 'format <type> 1.0'");
      if (w[1] == "ascii") {
        header->format = Format::kAscii;
      } else if (w[1] == "binary_little_endian") {
        header->format = Format::kBinaryLittle;
      } else if (w[1] == "binary_big_endian") {
        header->format = Format::kBinaryBig;
      } else {
        return Fail(error, at + "unsupported format '" + std::string(w[1]) +
                               "' (expected ascii, binary_little_endian or binary_big_endian)");
      }
      if (w[2] != "1.0" && w[2] != "1") {
        return Fail(error, at + "unsupported PLY version '" + std::string(w[2]) + "'");
      }
      have_format = true;
    } else if (w[0] == "element") {
      if (w.size() != 3) return Fail(error, at + "expected 'element <name> <count>'");
      Element e;
      e.name = std::string(w[1]);
      const auto r = std::from_chars(w[2].data(), w[2].data() + w[2].size(), e.count);
      if (r.ec != std::errc() || r.ptr != w[2].data() + w[2].size()) {
        return Fail(error,
                    at + "bad count '" + std::string(w[2]) + "' for element '" + e.name + "'");
      }
      header->elements.push_back(std::move(e));
    } else if (w[0] == "property") {
      if (header->elements.empty()) return Fail(error, at + "property before any element");
      Property p;
      if (w.size() == 5 && w[1] == "list") {
        const auto count_type = ParseScalarType(w[2]);
        const auto item_type = ParseScalarType(w[3]);
        if (!count_type || !item_type || IsFloating(*count_type)) {
          return Fail(error, at + "bad list property types '" + std::string(w[2]) + " " +
                                 std::string(w[3]) + "'");
        }
        p.is_list = true;
        p.count_type = *count_type;
        p.type = *item_type;
        p.name = std::string(w[4]);
      } else if (w.size() == 3) {
        const auto type = ParseScalarType(w[1]);
        if (!type) return Fail(error, at + "unknown property type '" + std::string(w[1]) + "'");
        p.type = *type;
        p.name = std::string(w[2]);
      } else {
        return Fail(error, at + "expected 'property <type> <name>' or "
                                "'property list <count type> <item type> <name>'");
      }
      header->elements.back().properties.push_back(std::move(p));
    } else {
      return Fail(error, at + "unknown keyword '" + std::string(w[0]) + "'");
    }
  }
  if (!have_format) return Fail(error, where + "header has no 'format' line");
  header->data_offset = pos;
  return true;
}

// Reads scalar values from the data section, ASCII or binary.
class DataReader {
 public:
  DataReader(const std::string& data, std::size_t offset, Format format)
      : data_(data), pos_(offset), format_(format) {}

  std::size_t Remaining() const { return data_.size() - pos_; }

  // Reads one value of type `t` as a double. On failure sets *why.
  bool Read(ScalarType t, double* value, std::string* why) {
    if (format_ == Format::kAscii) return ReadAscii(t, value, why);
    return ReadBinary(t, value, why);
  }

  // Skips `n` values of type `t`.
  bool Skip(ScalarType t, std::uint64_t n, std::string* why) {
    if (format_ != Format::kAscii) {
      const std::size_t size = SizeOf(t);
      if (n > Remaining() / size) return Truncated(why);
      pos_ += static_cast<std::size_t>(n) * size;
      return true;
    }
    double ignored;
    for (std::uint64_t i = 0; i < n; ++i) {
      if (!ReadAscii(t, &ignored, why)) return false;
    }
    return true;
  }

 private:
  bool Truncated(std::string* why) {
    *why = "unexpected end of data (truncated file)";
    return false;
  }

  bool ReadBinary(ScalarType t, double* value, std::string* why) {
    const std::size_t size = SizeOf(t);
    if (Remaining() < size) return Truncated(why);
    std::array<unsigned char, 8> b{};
    std::memcpy(b.data(), data_.data() + pos_, size);
    pos_ += size;
    const bool file_little = format_ == Format::kBinaryLittle;
    if (file_little != (std::endian::native == std::endian::little)) {
      std::reverse(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(size));
    }
    switch (t) {
      case ScalarType::kInt8:
        *value = Load<std::int8_t>(b);
        break;
      case ScalarType::kUint8:
        *value = Load<std::uint8_t>(b);
        break;
      case ScalarType::kInt16:
        *value = Load<std::int16_t>(b);
        break;
      case ScalarType::kUint16:
        *value = Load<std::uint16_t>(b);
        break;
      case ScalarType::kInt32:
        *value = Load<std::int32_t>(b);
        break;
      case ScalarType::kUint32:
        *value = Load<std::uint32_t>(b);
        break;
      case ScalarType::kFloat32:
        *value = Load<float>(b);
        break;
      case ScalarType::kFloat64:
        *value = Load<double>(b);
        break;
    }
    return true;
  }

  template <typename T>
  static double Load(const std::array<unsigned char, 8>& b) {
    T v;
    std::memcpy(&v, b.data(), sizeof(T));
    return static_cast<double>(v);
  }

  bool ReadAscii(ScalarType t, double* value, std::string* why) {
    while (pos_ < data_.size() && std::isspace(static_cast<unsigned char>(data_[pos_]))) ++pos_;
    if (pos_ >= data_.size()) return Truncated(why);
    const std::size_t start = pos_;
    while (pos_ < data_.size() && !std::isspace(static_cast<unsigned char>(data_[pos_]))) ++pos_;
    std::string_view token(data_.data() + start, pos_ - start);
    const std::string shown(token.substr(0, kMaxTokenLength));
    if (token.size() > kMaxTokenLength) {
      *why = "value '" + shown + "...' is too long to be a number";
      return false;
    }
    std::string_view digits = token;
    if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
    const char* begin = digits.data();
    const char* end = digits.data() + digits.size();
    if (IsFloating(t)) {
      // float32 is parsed as float, not double-then-float: no double rounding,
      // so shortest-form text written by WritePly round-trips bit-exactly.
      std::from_chars_result r;
      if (t == ScalarType::kFloat32) {
        float f = 0.0f;
        r = std::from_chars(begin, end, f);
        *value = f;
      } else {
        r = std::from_chars(begin, end, *value);
      }
      if (r.ec != std::errc() || r.ptr != end) {
        *why = "value '" + shown + "' is not a number (or out of range)";
        return false;
      }
      return true;
    }
    std::int64_t v = 0;
    const auto r = std::from_chars(begin, end, v);
    if (r.ec != std::errc() || r.ptr != end) {
      *why = "value '" + shown + "' is not an integer";
      return false;
    }
    static constexpr std::array<std::pair<std::int64_t, std::int64_t>, 6> kRanges = {{
        {INT8_MIN, INT8_MAX},
        {0, UINT8_MAX},
        {INT16_MIN, INT16_MAX},
        {0, UINT16_MAX},
        {INT32_MIN, INT32_MAX},
        {0, UINT32_MAX},
    }};
    const auto [lo, hi] = kRanges[static_cast<std::size_t>(t)];
    if (v < lo || v > hi) {
      *why = "value '" + shown + "' is out of range for its integer type";
      return false;
    }
    *value = static_cast<double>(v);
    return true;
  }

  const std::string& data_;
  std::size_t pos_;
  Format format_;
};

// Smallest number of data bytes one instance of `e` can occupy: a guard
// against headers claiming more entries than the file can hold.
std::size_t MinBytesPerInstance(const Element& e, Format format) {
  std::size_t bytes = 0;
  for (const Property& p : e.properties) {
    if (format == Format::kAscii) {
      bytes += 2;  // at least one character and one separator (lists: the count)
    } else {
      bytes += p.is_list ? SizeOf(p.count_type) : SizeOf(p.type);
    }
  }
  return bytes;
}

int FindProperty(const Element& e, std::string_view name) {
  for (std::size_t i = 0; i < e.properties.size(); ++i) {
    if (e.properties[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

std::uint8_t ToColorByte(double v, ScalarType t) {
  if (IsFloating(t)) v *= 255.0;
  if (!(v >= 0.0)) return 0;  // also NaN
  if (v >= 255.0) return 255;
  return static_cast<std::uint8_t>(std::lround(v));
}

// Where the wanted vertex and face properties are (indices into the
// element's property list; -1 when absent).
struct Layout {
  int vertex_element = -1;
  std::array<int, 3> xyz{};
  std::array<int, 3> normal{-1, -1, -1};
  std::array<int, 3> rgb{-1, -1, -1};
  int face_element = -1;
  int face_list = -1;  // the vertex_indices (or vertex_index) list
};

int FindElement(const Header& header, std::string_view name) {
  for (std::size_t i = 0; i < header.elements.size(); ++i) {
    if (header.elements[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

// Indices of three scalar properties, or all -1 unless all three are there.
std::array<int, 3> FindGroup(const Element& e, std::array<const char*, 3> names) {
  std::array<int, 3> idx{};
  for (int k = 0; k < 3; ++k) {
    idx[k] = FindProperty(e, names[k]);
    if (idx[k] < 0 || e.properties[static_cast<std::size_t>(idx[k])].is_list) {
      return std::array<int, 3>{-1, -1, -1};
    }
  }
  return idx;
}

bool FindVertexLayout(const Header& header, const std::string& where, Layout* layout,
                      std::string* error) {
  layout->vertex_element = FindElement(header, "vertex");
  if (layout->vertex_element < 0) return Fail(error, where + "no 'vertex' element in the header");
  const Element& vertex = header.elements[static_cast<std::size_t>(layout->vertex_element)];
  layout->xyz = {FindProperty(vertex, "x"), FindProperty(vertex, "y"), FindProperty(vertex, "z")};
  for (int k = 0; k < 3; ++k) {
    const char* axis[] = {"x", "y", "z"};
    if (layout->xyz[k] < 0) {
      return Fail(error, where + "vertex element has no '" + axis[k] + "' property");
    }
    if (vertex.properties[static_cast<std::size_t>(layout->xyz[k])].is_list) {
      return Fail(error, where + "vertex property '" + axis[k] + "' is a list, not a scalar");
    }
  }
  layout->normal = FindGroup(vertex, {"nx", "ny", "nz"});
  layout->rgb = FindGroup(vertex, {"red", "green", "blue"});
  if (layout->rgb[0] < 0)
    layout->rgb = FindGroup(vertex, {"diffuse_red", "diffuse_green", "diffuse_blue"});
  return true;
}

bool FindFaceLayout(const Header& header, const std::string& where, Layout* layout,
                    std::string* error) {
  layout->face_element = FindElement(header, "face");
  if (layout->face_element < 0 ||
      header.elements[static_cast<std::size_t>(layout->face_element)].count == 0) {
    return Fail(error, where + "no faces (a point cloud is not a mesh)");
  }
  const Element& face = header.elements[static_cast<std::size_t>(layout->face_element)];
  for (std::size_t k = 0; k < face.properties.size(); ++k) {
    const Property& p = face.properties[k];
    if (p.is_list && (p.name == "vertex_indices" || p.name == "vertex_index")) {
      layout->face_list = static_cast<int>(k);
    }
  }
  if (layout->face_list < 0) {
    return Fail(error, where + "element 'face' has no list property 'vertex_indices'");
  }
  return true;
}

// Every element count against the data the file holds, before allocating.
bool CheckCounts(const Header& header, std::size_t data_bytes, std::uint64_t vertex_count,
                 const std::string& where, std::string* error) {
  for (const Element& e : header.elements) {
    const std::size_t min_bytes = MinBytesPerInstance(e, header.format);
    const std::size_t slack = header.format == Format::kAscii ? 1 : 0;  // last separator
    if (min_bytes > 0 && e.count > data_bytes / min_bytes + slack) {
      return Fail(error, where + "element '" + e.name + "' claims " + std::to_string(e.count) +
                             " entries but the file has only " + std::to_string(data_bytes) +
                             " bytes of data (truncated file or corrupt header)");
    }
  }
  if (vertex_count > kMaxVertices) {
    return Fail(error, where + "absurd vertex count " + std::to_string(vertex_count) + " (limit " +
                           std::to_string(kMaxVertices) + ")");
  }
  return true;
}

// Reads one face's index list and appends its triangle fan to *faces.
bool ReadFace(DataReader* reader, const Property& p, std::uint64_t vertex_count, std::uint64_t item,
              std::vector<cv::Vec3i>* faces, std::vector<int>* polygon, std::string* why) {
  double count = 0;
  if (!reader->Read(p.count_type, &count, why)) return false;
  if (!(count >= 0) || count > kMaxPolygonCorners) {
    *why = "bad list length " + std::to_string(static_cast<long long>(count));
    return false;
  }
  polygon->clear();
  for (std::uint64_t j = 0; j < static_cast<std::uint64_t>(count); ++j) {
    double v = 0;
    if (!reader->Read(p.type, &v, why)) return false;
    if (!(v >= 0) || v >= static_cast<double>(vertex_count) || v != std::floor(v)) {
      *why = "face " + std::to_string(item) + " refers to vertex " +
             std::to_string(static_cast<long long>(v)) + " but there are " +
             std::to_string(vertex_count) + " vertices";
      return false;
    }
    polygon->push_back(static_cast<int>(v));
  }
  if (polygon->size() < 3) {
    *why = "face " + std::to_string(item) + " has " + std::to_string(polygon->size()) +
           " vertices (need at least 3)";
    return false;
  }
  for (std::size_t j = 1; j + 1 < polygon->size(); ++j) {
    faces->emplace_back((*polygon)[0], (*polygon)[j], (*polygon)[j + 1]);
  }
  return true;
}

// Reads `path` into *cloud (the vertices) and, when `faces` is not null,
// the face lists into *faces. Outputs are only set on success.
bool ReadPlyFile(const std::string& path, double scale_to_mm, PointCloud* cloud,
                 std::vector<cv::Vec3i>* faces, std::string* error) {
  const std::string where = "PLY '" + path + "': ";
  if (!std::isfinite(scale_to_mm) || scale_to_mm <= 0.0) {
    return Fail(error, where + "scale_to_mm must be finite and > 0");
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    return Fail(error, where + "no such file (or not a regular file)");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(error, where + "cannot open: " + std::strerror(errno));
  std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return Fail(error, where + "read error");

  Header header;
  if (!ParseHeader(data, where, &header, error)) return false;
  Layout layout;
  if (!FindVertexLayout(header, where, &layout, error)) return false;
  if (faces != nullptr && !FindFaceLayout(header, where, &layout, error)) return false;
  const Element& vertex = header.elements[static_cast<std::size_t>(layout.vertex_element)];
  if (!CheckCounts(header, data.size() - header.data_offset, vertex.count, where, error)) {
    return false;
  }
  const bool has_normals = layout.normal[0] >= 0;
  const bool has_colors = layout.rgb[0] >= 0;

  const std::size_t n = static_cast<std::size_t>(vertex.count);
  PointCloud out;
  out.points_mm.resize(n);
  if (has_normals) out.normals.resize(n);
  if (has_colors) out.colors_rgb.resize(n);
  std::vector<cv::Vec3i> out_faces;
  std::vector<int> polygon;

  DataReader reader(data, header.data_offset, header.format);
  std::vector<double> values;
  std::string why;
  for (std::size_t ei = 0; ei < header.elements.size(); ++ei) {
    const Element& e = header.elements[ei];
    const bool is_vertex = static_cast<int>(ei) == layout.vertex_element;
    const bool is_face = faces != nullptr && static_cast<int>(ei) == layout.face_element;
    if (e.properties.empty()) continue;  // no data, however large the count
    values.assign(e.properties.size(), 0.0);
    for (std::uint64_t i = 0; i < e.count; ++i) {
      for (std::size_t pi = 0; pi < e.properties.size(); ++pi) {
        const Property& p = e.properties[pi];
        bool ok;
        if (is_face && static_cast<int>(pi) == layout.face_list) {
          ok = ReadFace(&reader, p, vertex.count, i, &out_faces, &polygon, &why);
        } else if (p.is_list) {
          double count = 0;
          ok = reader.Read(p.count_type, &count, &why);
          if (ok && count < 0) {
            why = "negative list length " + std::to_string(static_cast<long long>(count));
            ok = false;
          }
          if (ok) ok = reader.Skip(p.type, static_cast<std::uint64_t>(count), &why);
        } else {
          ok = reader.Read(p.type, &values[pi], &why);
        }
        if (!ok) {
          return Fail(error, where + "element '" + e.name + "' entry " + std::to_string(i) +
                                 " of " + std::to_string(e.count) + ", property '" + p.name +
                                 "': " + why);
        }
      }
      if (!is_vertex) continue;
      const std::size_t v = static_cast<std::size_t>(i);
      for (int k = 0; k < 3; ++k) {
        out.points_mm[v][k] =
            static_cast<float>(values[static_cast<std::size_t>(layout.xyz[k])] * scale_to_mm);
      }
      if (has_normals) {
        for (int k = 0; k < 3; ++k) {
          out.normals[v][k] =
              static_cast<float>(values[static_cast<std::size_t>(layout.normal[k])]);
        }
      }
      if (has_colors) {
        for (int k = 0; k < 3; ++k) {
          const auto idx = static_cast<std::size_t>(layout.rgb[k]);
          out.colors_rgb[v][k] = ToColorByte(values[idx], vertex.properties[idx].type);
        }
      }
    }
    // Nothing after the vertices is needed, but a truncated face list is
    // still a broken file, so keep reading to the end for the diagnostics.
  }
  *cloud = std::move(out);
  if (faces != nullptr) *faces = std::move(out_faces);
  return true;
}

void AppendFloatText(float v, std::string* out) {
  char buffer[64];
  const auto r = std::to_chars(buffer, buffer + sizeof(buffer), v);
  out->append(buffer, r.ptr);
}

template <typename T>
void AppendLittleEndian(T v, std::string* out) {
  std::array<char, sizeof(T)> b;
  std::memcpy(b.data(), &v, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(b.begin(), b.end());
  out->append(b.data(), b.size());
}

// The vertex arrays of a cloud or a mesh (normals/colours empty or one per
// vertex: checked by the callers' IsValid).
struct Vertices {
  const std::vector<cv::Vec3f>& points_mm;
  const std::vector<cv::Vec3f>& normals;
  const std::vector<cv::Vec3b>& colors_rgb;
};

std::string FormatPly(const Vertices& vertices, const std::vector<cv::Vec3i>* faces, bool binary,
                      std::string_view comment) {
  const std::size_t n = vertices.points_mm.size();
  const bool has_normals = !vertices.normals.empty();
  const bool has_colors = !vertices.colors_rgb.empty();
  std::string text = "ply\n";
  text += binary ? "format binary_little_endian 1.0\n" : "format ascii 1.0\n";
  text += "comment ";
  text += comment;
  text += "\nelement vertex " + std::to_string(n) + "\n";
  text += "property float x\nproperty float y\nproperty float z\n";
  if (has_normals) text += "property float nx\nproperty float ny\nproperty float nz\n";
  if (has_colors) text += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (faces != nullptr) {
    text += "element face " + std::to_string(faces->size()) + "\n";
    text += "property list uchar int vertex_indices\n";
  }
  text += "end_header\n";
  const std::size_t per_vertex = binary ? 12 + (has_normals ? 12 : 0) + (has_colors ? 3 : 0) : 48;
  const std::size_t per_face = binary ? 13 : 30;
  text.reserve(text.size() + n * per_vertex + (faces ? faces->size() * per_face : 0));
  for (std::size_t i = 0; i < n; ++i) {
    if (binary) {
      for (int k = 0; k < 3; ++k) AppendLittleEndian(vertices.points_mm[i][k], &text);
      if (has_normals) {
        for (int k = 0; k < 3; ++k) AppendLittleEndian(vertices.normals[i][k], &text);
      }
      if (has_colors) {
        for (int k = 0; k < 3; ++k) text.push_back(static_cast<char>(vertices.colors_rgb[i][k]));
      }
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      if (k > 0) text.push_back(' ');
      AppendFloatText(vertices.points_mm[i][k], &text);
    }
    if (has_normals) {
      for (int k = 0; k < 3; ++k) {
        text.push_back(' ');
        AppendFloatText(vertices.normals[i][k], &text);
      }
    }
    if (has_colors) {
      for (int k = 0; k < 3; ++k) {
        text.push_back(' ');
        text += std::to_string(static_cast<int>(vertices.colors_rgb[i][k]));
      }
    }
    text.push_back('\n');
  }
  if (faces == nullptr) return text;
  for (const cv::Vec3i& f : *faces) {
    if (binary) {
      text.push_back(static_cast<char>(3));
      for (int k = 0; k < 3; ++k) AppendLittleEndian<std::int32_t>(f[k], &text);
    } else {
      text += "3 " + std::to_string(f[0]) + ' ' + std::to_string(f[1]) + ' ' +
              std::to_string(f[2]) + '\n';
    }
  }
  return text;
}

}  // namespace

bool ReadPly(const std::string& path, PointCloud* cloud, std::string* error, double scale_to_mm) {
  if (cloud == nullptr) return Fail(error, "PLY '" + path + "': null output cloud");
  *cloud = PointCloud();
  try {
    return ReadPlyFile(path, scale_to_mm, cloud, nullptr, error);
  } catch (const std::exception& e) {
    *cloud = PointCloud();
    return Fail(error, "PLY '" + path + "': " + e.what());
  }
}

bool ReadMeshPly(const std::string& path, TriangleMesh* mesh, std::string* error,
                 double scale_to_mm) {
  if (mesh == nullptr) return Fail(error, "PLY '" + path + "': null output mesh");
  *mesh = TriangleMesh();
  try {
    PointCloud vertices;
    std::vector<cv::Vec3i> faces;
    if (!ReadPlyFile(path, scale_to_mm, &vertices, &faces, error)) return false;
    TriangleMesh out;
    out.vertices_mm = std::move(vertices.points_mm);
    out.normals = std::move(vertices.normals);
    out.colors_rgb = std::move(vertices.colors_rgb);
    out.faces = std::move(faces);
    std::string why;
    if (!out.IsValid(&why)) return Fail(error, "PLY '" + path + "': " + why);
    *mesh = std::move(out);
    return true;
  } catch (const std::exception& e) {
    *mesh = TriangleMesh();
    return Fail(error, "PLY '" + path + "': " + e.what());
  }
}

std::string EncodePly(const PointCloud& cloud, bool binary) {
  if (!cloud.IsValid(nullptr)) return {};
  return FormatPly({cloud.points_mm, cloud.normals, cloud.colors_rgb}, nullptr, binary,
                   "craftscan point cloud, units mm");
}

std::string EncodeMeshPly(const TriangleMesh& mesh, bool binary) {
  if (!mesh.IsValid(nullptr)) return {};
  return FormatPly({mesh.vertices_mm, mesh.normals, mesh.colors_rgb}, &mesh.faces, binary,
                   "craftscan mesh, units mm");
}

namespace {

bool WriteBytes(const std::string& path, const std::string& bytes, std::string* error) {
  const Status status = WriteFileAtomically(path, bytes);
  if (!status.ok()) return Fail(error, "PLY " + status.message());
  return true;
}

}  // namespace

bool WritePly(const std::string& path, const PointCloud& cloud, bool binary, std::string* error) {
  try {
    std::string why;
    if (path.empty()) return Fail(error, "WritePly: empty path");
    if (!cloud.IsValid(&why)) return Fail(error, "PLY '" + path + "': invalid cloud: " + why);
    return WriteBytes(path, EncodePly(cloud, binary), error);
  } catch (const std::exception& e) {
    return Fail(error, "PLY '" + path + "': " + e.what());
  }
}

bool WriteMeshPly(const std::string& path, const TriangleMesh& mesh, bool binary,
                  std::string* error) {
  try {
    std::string why;
    if (path.empty()) return Fail(error, "WriteMeshPly: empty path");
    if (!mesh.IsValid(&why)) return Fail(error, "WriteMeshPly '" + path + "': " + why);
    return WriteBytes(path, EncodeMeshPly(mesh, binary), error);
  } catch (const std::exception& e) {
    return Fail(error, "PLY '" + path + "': " + e.what());
  }
}

}  // namespace craftscan
