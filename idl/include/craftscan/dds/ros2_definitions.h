// The ROS 2 message definitions (.msg text) of the ROS 2-compatible types in
// idl/ros2/, for recordings that carry their schema (MCAP's "ros2msg"
// encoding): the same fields as the IDL, fully qualified type names.
#pragma once

#include <string>
#include <string_view>

namespace craftscan::dds {

// The full message definition of `type` ("sensor_msgs/msg/Image", ...) as
// rosbag2 writes it into MCAP: the type's own .msg text, then for each type
// it uses (depth first, each once) a line of 80 '=', "MSG: pkg/Name" and
// that type's text. Empty for a type not among idl/ros2/. Thread-safe.
std::string RosMessageDefinition(std::string_view type);

}  // namespace craftscan::dds
