// ROS 2 .msg texts of the types in idl/ros2/ (ROS 2 Humble's definitions,
// comments left out) and their concatenation as rosbag2 writes it.
#include "craftscan/dds/ros2_definitions.h"

#include <set>
#include <string>
#include <vector>

namespace craftscan::dds {
namespace {

struct Definition {
  std::string_view name;  // "pkg/Name"
  std::string_view text;
  std::vector<std::string_view> uses;  // in order of first use
};

const std::vector<Definition>& Definitions() {
  static const std::vector<Definition> definitions = {
      {"builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n", {}},
      {"std_msgs/Header",
       "builtin_interfaces/Time stamp\nstring frame_id\n",
       {"builtin_interfaces/Time"}},
      {"sensor_msgs/Image",
       "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
       "uint8 is_bigendian\nuint32 step\nuint8[] data\n",
       {"std_msgs/Header"}},
      {"sensor_msgs/RegionOfInterest",
       "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
       {}},
      {"sensor_msgs/CameraInfo",
       "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
       "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
       "uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
       {"std_msgs/Header", "sensor_msgs/RegionOfInterest"}},
      {"sensor_msgs/PointField",
       "uint8 INT8 = 1\nuint8 UINT8 = 2\nuint8 INT16 = 3\nuint8 UINT16 = 4\nuint8 INT32 = 5\n"
       "uint8 UINT32 = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n"
       "string name\nuint32 offset\nuint8 datatype\nuint32 count\n",
       {}},
      {"sensor_msgs/PointCloud2",
       "std_msgs/Header header\nuint32 height\nuint32 width\n"
       "sensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\n"
       "uint32 row_step\nuint8[] data\nbool is_dense\n",
       {"std_msgs/Header", "sensor_msgs/PointField"}},
      {"stereo_msgs/DisparityImage",
       "std_msgs/Header header\nsensor_msgs/Image image\nfloat32 f\nfloat32 t\n"
       "sensor_msgs/RegionOfInterest valid_window\nfloat32 min_disparity\n"
       "float32 max_disparity\nfloat32 delta_d\n",
       {"std_msgs/Header", "sensor_msgs/Image", "sensor_msgs/RegionOfInterest"}},
      {"geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n", {}},
      {"geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n", {}},
      {"geometry_msgs/Transform",
       "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
       {"geometry_msgs/Vector3", "geometry_msgs/Quaternion"}},
      {"geometry_msgs/TransformStamped",
       "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
       {"std_msgs/Header", "geometry_msgs/Transform"}},
      {"tf2_msgs/TFMessage",
       "geometry_msgs/TransformStamped[] transforms\n",
       {"geometry_msgs/TransformStamped"}},
  };
  return definitions;
}

const Definition* Find(std::string_view name) {
  for (const Definition& d : Definitions()) {
    if (d.name == name) return &d;
  }
  return nullptr;
}

// Appends the definitions `d` uses, depth first, each once.
void AppendUses(const Definition& d, std::set<std::string_view>* done, std::string* out) {
  for (std::string_view name : d.uses) {
    if (!done->insert(name).second) continue;
    const Definition* used = Find(name);
    out->append(80, '=');
    out->append("\nMSG: ").append(name).append("\n").append(used->text);
    AppendUses(*used, done, out);
  }
}

}  // namespace

std::string RosMessageDefinition(std::string_view type) {
  // "pkg/msg/Name" → "pkg/Name".
  const std::size_t slash = type.find("/msg/");
  if (slash == std::string_view::npos) return "";
  std::string name(type.substr(0, slash));
  name.append("/").append(type.substr(slash + 5));
  const Definition* d = Find(name);
  if (d == nullptr) return "";
  std::string out(d->text);
  std::set<std::string_view> done;
  AppendUses(*d, &done, &out);
  return out;
}

}  // namespace craftscan::dds
