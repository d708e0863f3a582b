// Point cloud conversions: craftscan PointCloud message and ROS PointCloud2.
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <string>
#include <vector>

#include "convert_internal.h"
#include "craftscan/dds/convert.h"

namespace craftscan::dds {
namespace {

using internal::Fail;

static_assert(sizeof(cv::Vec3f) == 3 * sizeof(float), "Vec3f must be three packed floats");
static_assert(sizeof(cv::Vec3b) == 3, "Vec3b must be three packed bytes");

constexpr double kMetresPerMm = 1e-3;
constexpr double kMmPerMetre = 1e3;

std::size_t FieldTypeSize(uint8_t type) {
  switch (static_cast<PointFieldType>(type)) {
    case PointFieldType::kInt8:
    case PointFieldType::kUint8:
      return 1;
    case PointFieldType::kInt16:
    case PointFieldType::kUint16:
      return 2;
    case PointFieldType::kInt32:
    case PointFieldType::kUint32:
    case PointFieldType::kFloat32:
      return 4;
    case PointFieldType::kFloat64:
      return 8;
  }
  return 0;
}

// Where one scalar of each point sits in a PointCloud2.
struct FieldAccess {
  uint32_t offset = 0;
  PointFieldType type = PointFieldType::kFloat32;

  double Read(const uint8_t* point) const {
    if (type == PointFieldType::kFloat64) {
      double value;
      std::memcpy(&value, point + offset, sizeof value);
      return value;
    }
    float value;
    std::memcpy(&value, point + offset, sizeof value);
    return value;
  }
  uint32_t ReadBits(const uint8_t* point) const {
    uint32_t value;
    std::memcpy(&value, point + offset, sizeof value);
    return value;
  }
};

// Finds field `name` with a type in `allowed`. Returns 1 if found, 0 if
// absent, −1 (with *error) if present but unusable.
int FindField(const ros::PointCloud2& message, std::string_view name,
              std::initializer_list<PointFieldType> allowed, FieldAccess* access,
              std::string* error) {
  for (uint32_t i = 0; i < message.fields._length; ++i) {
    const ros::PointField& field = message.fields._buffer[i];
    if (View(field.name) != name) continue;
    bool type_ok = false;
    for (PointFieldType type : allowed) type_ok |= field.datatype == static_cast<uint8_t>(type);
    if (!type_ok) {
      Fail(error, "PointCloud2: field '" + std::string(name) + "' has unsupported datatype " +
                      std::to_string(field.datatype));
      return -1;
    }
    const uint64_t end = static_cast<uint64_t>(field.offset) + FieldTypeSize(field.datatype);
    if (field.count < 1 || end > message.point_step) {
      Fail(error, "PointCloud2: field '" + std::string(name) + "' (offset " +
                      std::to_string(field.offset) + ", count " + std::to_string(field.count) +
                      ") does not fit point_step " + std::to_string(message.point_step));
      return -1;
    }
    access->offset = field.offset;
    access->type = static_cast<PointFieldType>(field.datatype);
    return 1;
  }
  return 0;
}

// Finds all three of `names` (0 = none of them, 1 = all, −1 = error/partial).
int FindFields3(const ros::PointCloud2& message, const std::string_view (&names)[3],
                std::initializer_list<PointFieldType> allowed, FieldAccess (*access)[3],
                std::string* error) {
  int found = 0;
  for (int i = 0; i < 3; ++i) {
    const int rc = FindField(message, names[i], allowed, &(*access)[i], error);
    if (rc < 0) return -1;
    found += rc;
  }
  if (found == 0 || found == 3) return found / 3;
  Fail(error, "PointCloud2: has only some of the fields " + std::string(names[0]) + ", " +
                  std::string(names[1]) + ", " + std::string(names[2]));
  return -1;
}

ros::PointField Field(MessageStorage* storage, std::string_view name, uint32_t offset) {
  ros::PointField field;
  field.name = storage->Keep(name);
  field.offset = offset;
  field.datatype = static_cast<uint8_t>(PointFieldType::kFloat32);
  field.count = 1;
  return field;
}

}  // namespace

bool MakeCloud(const PointCloud& cloud, const CloudMeta& meta, Outgoing<msg::PointCloud>* out,
               std::string* error) {
  std::string why;
  if (!cloud.IsValid(&why)) return Fail(error, "cloud: " + why);
  const std::size_t n = cloud.size();
  if (n > std::numeric_limits<uint32_t>::max() / 3) {
    return Fail(error, "cloud: " + std::to_string(n) + " points are too many for one DDS sample");
  }
  *out = Outgoing<msg::PointCloud>();
  msg::PointCloud& m = out->msg();
  m.session = out->Keep(meta.session);
  m.view_index = meta.view_index;
  m.kind = out->Keep(meta.kind);
  for (int i = 0; i < 16; ++i) m.world_from_view[i] = meta.world_from_view.val[i];
  m.point_count = static_cast<uint32_t>(n);
  Borrow(&m.xyz, reinterpret_cast<const float*>(cloud.points_mm.data()), 3 * n);
  if (cloud.HasColors()) {
    Borrow(&m.rgb, reinterpret_cast<const uint8_t*>(cloud.colors_rgb.data()), 3 * n);
  }
  if (cloud.HasNormals()) {
    Borrow(&m.normals, reinterpret_cast<const float*>(cloud.normals.data()), 3 * n);
  }
  m.stamp_ns = meta.stamp_ns;
  m.frame_id = out->Keep(meta.frame_id);
  return true;
}

bool CloudFromMessage(const msg::PointCloud& message, PointCloud* cloud, CloudMeta* meta,
                      std::string* error) {
  const uint64_t n = message.point_count;
  const auto check = [&](const char* name, uint64_t length, bool optional) {
    if (length == 3 * n || (optional && length == 0)) return true;
    return Fail(error, std::string("cloud message: ") + name + " has " + std::to_string(length) +
                           " values, expected " + std::to_string(3 * n) +
                           (optional ? " or none" : "") + " for point_count " + std::to_string(n));
  };
  if (!check("xyz", message.xyz._length, false) || !check("rgb", message.rgb._length, true) ||
      !check("normals", message.normals._length, true)) {
    return false;
  }
  cloud->points_mm.resize(n);
  if (n > 0)
    std::memcpy(static_cast<void*>(cloud->points_mm.data()), message.xyz._buffer,
                n * sizeof(cv::Vec3f));
  cloud->colors_rgb.resize(message.rgb._length / 3);
  if (message.rgb._length > 0) {
    std::memcpy(static_cast<void*>(cloud->colors_rgb.data()), message.rgb._buffer,
                message.rgb._length);
  }
  cloud->normals.resize(message.normals._length / 3);
  if (message.normals._length > 0) {
    std::memcpy(static_cast<void*>(cloud->normals.data()), message.normals._buffer,
                n * sizeof(cv::Vec3f));
  }
  if (meta) {
    meta->session = View(message.session);
    meta->view_index = message.view_index;
    meta->kind = View(message.kind);
    for (int i = 0; i < 16; ++i) meta->world_from_view.val[i] = message.world_from_view[i];
    meta->stamp_ns = message.stamp_ns;
    meta->frame_id = View(message.frame_id);
  }
  return true;
}

bool MakePointCloud2(const PointCloud& cloud, int64_t stamp_ns, std::string_view frame_id,
                     Outgoing<ros::PointCloud2>* out, std::string* error) {
  std::string why;
  if (!cloud.IsValid(&why)) return Fail(error, "cloud: " + why);
  const bool colors = cloud.HasColors();
  const bool normals = cloud.HasNormals();
  const uint32_t rgb_offset = 12;
  const uint32_t normal_offset = colors ? 16 : 12;
  const uint32_t point_step = 12 + (colors ? 4 : 0) + (normals ? 12 : 0);
  const std::size_t n = cloud.size();
  if (n > std::numeric_limits<uint32_t>::max() / point_step) {
    return Fail(error, "cloud: " + std::to_string(n) + " points are too many for one DDS sample");
  }
  *out = Outgoing<ros::PointCloud2>();
  ros::PointCloud2& m = out->msg();

  std::vector<ros::PointField> fields = {Field(out, "x", 0), Field(out, "y", 4),
                                         Field(out, "z", 8)};
  if (colors) fields.push_back(Field(out, "rgb", rgb_offset));
  if (normals) {
    fields.push_back(Field(out, "normal_x", normal_offset));
    fields.push_back(Field(out, "normal_y", normal_offset + 4));
    fields.push_back(Field(out, "normal_z", normal_offset + 8));
  }
  const std::size_t field_count = fields.size();
  Borrow(&m.fields, out->Keep(std::move(fields)), field_count);

  std::vector<uint8_t> data(n * point_step);
  bool dense = true;
  for (std::size_t i = 0; i < n; ++i) {
    uint8_t* point = data.data() + i * point_step;
    const cv::Vec3f& p = cloud.points_mm[i];
    dense = dense && std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
    const float xyz_m[3] = {static_cast<float>(p[0] * kMetresPerMm),
                            static_cast<float>(p[1] * kMetresPerMm),
                            static_cast<float>(p[2] * kMetresPerMm)};
    std::memcpy(point, xyz_m, sizeof xyz_m);
    if (colors) {
      const cv::Vec3b& c = cloud.colors_rgb[i];
      const uint32_t rgb = (uint32_t{c[0]} << 16) | (uint32_t{c[1]} << 8) | uint32_t{c[2]};
      std::memcpy(point + rgb_offset, &rgb, sizeof rgb);
    }
    if (normals) std::memcpy(point + normal_offset, &cloud.normals[i], sizeof(cv::Vec3f));
  }
  const std::size_t bytes = data.size();
  Borrow(&m.data, out->Keep(std::move(data)), bytes);

  m.header.stamp = RosTimeFromNs(stamp_ns);
  m.header.frame_id = out->Keep(frame_id);
  m.height = 1;
  m.width = static_cast<uint32_t>(n);
  m.is_bigendian = false;
  m.point_step = point_step;
  m.row_step = static_cast<uint32_t>(n * point_step);
  m.is_dense = dense;
  return true;
}

bool CloudFromPointCloud2(const ros::PointCloud2& message, PointCloud* cloud, std::string* error) {
  if (message.is_bigendian) return Fail(error, "PointCloud2: big-endian data is not supported");
  if (message.point_step == 0 && message.width > 0)
    return Fail(error, "PointCloud2: point_step is 0");
  const uint64_t row_bytes = static_cast<uint64_t>(message.width) * message.point_step;
  if (message.row_step < row_bytes) {
    return Fail(error, "PointCloud2: row_step " + std::to_string(message.row_step) +
                           " < width × point_step = " + std::to_string(row_bytes));
  }
  const uint64_t expected = static_cast<uint64_t>(message.row_step) * message.height;
  if (message.data._length != expected) {
    return Fail(error, "PointCloud2: data has " + std::to_string(message.data._length) +
                           " bytes, expected row_step × height = " + std::to_string(expected));
  }
  const std::initializer_list<PointFieldType> kReal = {PointFieldType::kFloat32,
                                                       PointFieldType::kFloat64};
  FieldAccess xyz[3], normal[3], rgb;
  const int has_xyz = FindFields3(message, {"x", "y", "z"}, kReal, &xyz, error);
  if (has_xyz < 0) return false;
  if (has_xyz == 0) return Fail(error, "PointCloud2: no x, y, z fields");
  const int has_normals =
      FindFields3(message, {"normal_x", "normal_y", "normal_z"}, kReal, &normal, error);
  if (has_normals < 0) return false;
  const std::initializer_list<PointFieldType> kPacked = {PointFieldType::kFloat32,
                                                         PointFieldType::kUint32};
  int has_rgb = FindField(message, "rgb", kPacked, &rgb, error);
  if (has_rgb == 0) has_rgb = FindField(message, "rgba", kPacked, &rgb, error);
  if (has_rgb < 0) return false;

  cloud->points_mm.clear();
  cloud->normals.clear();
  cloud->colors_rgb.clear();
  const std::size_t total = static_cast<std::size_t>(message.width) * message.height;
  // No points: done, however many empty rows the header claims (walking
  // 2^31 of them took seconds; found by tests/fuzz).
  if (total == 0) return true;
  cloud->points_mm.reserve(total);
  if (has_normals) cloud->normals.reserve(total);
  if (has_rgb) cloud->colors_rgb.reserve(total);
  for (uint32_t row = 0; row < message.height; ++row) {
    const uint8_t* row_data =
        message.data._buffer + static_cast<std::size_t>(row) * message.row_step;
    for (uint32_t col = 0; col < message.width; ++col) {
      const uint8_t* point = row_data + static_cast<std::size_t>(col) * message.point_step;
      const double x = xyz[0].Read(point), y = xyz[1].Read(point), z = xyz[2].Read(point);
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
      cloud->points_mm.emplace_back(static_cast<float>(x * kMmPerMetre),
                                    static_cast<float>(y * kMmPerMetre),
                                    static_cast<float>(z * kMmPerMetre));
      if (has_normals) {
        cloud->normals.emplace_back(static_cast<float>(normal[0].Read(point)),
                                    static_cast<float>(normal[1].Read(point)),
                                    static_cast<float>(normal[2].Read(point)));
      }
      if (has_rgb) {
        const uint32_t bits = rgb.ReadBits(point);
        cloud->colors_rgb.emplace_back(static_cast<uint8_t>(bits >> 16),
                                       static_cast<uint8_t>(bits >> 8), static_cast<uint8_t>(bits));
      }
    }
  }
  return true;
}

}  // namespace craftscan::dds
