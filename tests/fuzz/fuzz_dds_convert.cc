// Fuzz target: the readers of received DDS messages in craftscan/dds/convert.h
// (CloudFromPointCloud2, CloudFromMessage, ImageToMat, StereoCaptureToMats,
// DisparityToMat). The first byte picks the reader; the message's fields
// come from the following bytes and its arrays from the rest, with lengths
// that are true, as Cyclone's deserialiser guarantees. A flag makes the
// sizes agree with the data so that the conversions themselves get reached.
// Properties: a success gives a valid cloud / Mats of the stated size whose
// every byte is readable; a failure names the problem.
#include <algorithm>
#include <cstring>
#include <deque>
#include <string>
#include <type_traits>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/dds/convert.h"
#include "fuzz_target.h"

namespace {

using craftscan::fuzz::FuzzInput;

// Points `sequence` at `storage` (not released by the message).
template <typename Sequence, typename T>
void Borrow(Sequence* sequence, std::vector<T>* storage) {
  sequence->_buffer = storage->empty() ? nullptr : storage->data();
  sequence->_length = static_cast<uint32_t>(storage->size());
  sequence->_maximum = sequence->_length;
  sequence->_release = false;
}

// A string field: null, one of `known`, or raw bytes (kept alive by `strings`).
char* StringField(FuzzInput& in, const std::vector<const char*>& known,
                  std::deque<std::string>* strings) {
  const std::uint32_t pick = in.Small(static_cast<std::uint32_t>(known.size()) + 1);
  if (pick == 0) return nullptr;
  strings->push_back(pick <= known.size() ? std::string(known[pick - 1]) : in.String(24));
  return strings->back().data();
}

// `count` values of T from the input (zero once it runs out).
template <typename T>
std::vector<T> Array(FuzzInput& in, std::size_t count) {
  std::vector<T> values(count);
  for (T& v : values) {
    const auto bits = in.Integral<std::conditional_t<sizeof(T) == 4, uint32_t, uint8_t>>();
    std::memcpy(&v, &bits, sizeof(T));
  }
  return values;
}

// Reads every byte of `mat` from instrumented code so ASan checks the bounds.
void TouchAll(const cv::Mat& mat) {
  unsigned char sum = 0;
  for (int y = 0; y < mat.rows; ++y) {
    const unsigned char* row = mat.ptr<unsigned char>(y);
    for (std::size_t i = 0; i < static_cast<std::size_t>(mat.cols) * mat.elemSize(); ++i) {
      sum ^= row[i];
    }
  }
  volatile unsigned char sink = sum;
  (void)sink;
}

const std::vector<const char*> kEncodings = {"mono8", "bgr8", "32FC1", "rgb8", "16UC1"};

int EncodingBytes(const char* encoding) {
  const std::string name = encoding ? encoding : "";
  return name == "bgr8" || name == "rgb8" ? 3 : name == "32FC1" ? 4 : name == "16UC1" ? 2 : 1;
}

void FuzzPointCloud2(FuzzInput& in) {
  std::deque<std::string> strings;  // stable addresses
  craftscan::dds::ros::PointCloud2 m{};
  const std::uint8_t flags = in.Integral<std::uint8_t>();
  m.height = in.Integral<uint32_t>();
  m.width = in.Integral<uint32_t>();
  m.point_step = in.Integral<uint32_t>();
  m.row_step = in.Integral<uint32_t>();
  m.is_bigendian = (flags & 1) != 0;
  m.is_dense = (flags & 8) != 0;
  std::vector<craftscan::dds::ros::PointField> fields(in.Small(8));
  for (auto& field : fields) {
    field.name = StringField(
        in, {"x", "y", "z", "rgb", "rgba", "normal_x", "normal_y", "normal_z", "intensity"},
        &strings);
    field.offset = (flags & 2) ? in.Integral<uint32_t>() : in.Small(63);
    field.datatype = in.Integral<std::uint8_t>();
    field.count = (flags & 2) ? in.Integral<uint32_t>() : in.Small(2);
  }
  std::vector<std::uint8_t> data = in.Rest();
  if (flags & 4) {  // consistent sizes
    m.height = 1 + m.height % 64;
    m.row_step = static_cast<uint32_t>(data.size() / m.height);
    m.width = m.point_step == 0 ? 0 : std::min(m.width, m.row_step / m.point_step);
    data.resize(static_cast<std::size_t>(m.row_step) * m.height);
  }
  Borrow(&m.fields, &fields);
  Borrow(&m.data, &data);

  craftscan::PointCloud cloud;
  cloud.points_mm.resize(2);  // must be replaced
  std::string error, why;
  if (!craftscan::fuzz::Outcome(craftscan::dds::CloudFromPointCloud2(m, &cloud, &error), error))
    return;
  CRAFTSCAN_FUZZ_CHECK(cloud.IsValid(&why));
  CRAFTSCAN_FUZZ_CHECK(cloud.size() <= static_cast<std::uint64_t>(m.width) * m.height);
}

void FuzzCloudMessage(FuzzInput& in) {
  std::deque<std::string> strings;  // stable addresses
  craftscan::dds::msg::PointCloud m{};
  const std::uint8_t flags = in.Integral<std::uint8_t>();
  m.session = StringField(in, {"20240501-093000-egg"}, &strings);
  m.kind = StringField(in, {"view", "fused"}, &strings);
  m.frame_id = StringField(in, {"world"}, &strings);
  m.view_index = in.Integral<int32_t>();
  m.point_count = in.Integral<uint32_t>();
  std::vector<float> xyz = Array<float>(in, in.Integral<std::uint16_t>() % 4096);
  std::vector<std::uint8_t> rgb = Array<std::uint8_t>(in, in.Integral<std::uint16_t>() % 4096);
  std::vector<float> normals = Array<float>(in, in.Integral<std::uint16_t>() % 4096);
  if (flags & 4) {  // consistent sizes
    m.point_count = static_cast<uint32_t>(xyz.size() / 3);
    xyz.resize(3 * m.point_count);
    rgb.resize((flags & 1) ? 3 * m.point_count : 0);
    normals.resize((flags & 2) ? 3 * m.point_count : 0);
  }
  Borrow(&m.xyz, &xyz);
  Borrow(&m.rgb, &rgb);
  Borrow(&m.normals, &normals);

  craftscan::PointCloud cloud;
  craftscan::dds::CloudMeta meta;
  std::string error, why;
  if (!craftscan::fuzz::Outcome(craftscan::dds::CloudFromMessage(m, &cloud, &meta, &error), error))
    return;
  CRAFTSCAN_FUZZ_CHECK(cloud.IsValid(&why));
  CRAFTSCAN_FUZZ_CHECK(cloud.size() == m.point_count);
}

void FuzzImage(FuzzInput& in) {
  std::deque<std::string> strings;  // stable addresses
  craftscan::dds::ros::Image m{};
  const std::uint8_t flags = in.Integral<std::uint8_t>();
  m.encoding = StringField(in, kEncodings, &strings);
  m.is_bigendian = flags & 1;
  m.height = in.Integral<uint32_t>();
  m.width = in.Integral<uint32_t>();
  m.step = in.Integral<uint32_t>();
  std::vector<std::uint8_t> data = in.Rest();
  if (flags & 4) {  // consistent sizes
    m.height = 1 + m.height % 64;
    m.step = static_cast<uint32_t>(data.size() / m.height);
    m.width = std::min(m.width, m.step / static_cast<uint32_t>(EncodingBytes(m.encoding)));
    data.resize(static_cast<std::size_t>(m.step) * m.height);
  }
  Borrow(&m.data, &data);

  cv::Mat mat;
  std::string error;
  if (!craftscan::fuzz::Outcome(craftscan::dds::ImageToMat(m, &mat, &error), error)) return;
  CRAFTSCAN_FUZZ_CHECK(mat.rows == static_cast<int>(m.height) &&
                       mat.cols == static_cast<int>(m.width));
  CRAFTSCAN_FUZZ_CHECK(static_cast<int>(mat.elemSize()) == EncodingBytes(m.encoding));
  TouchAll(mat);
}

void FuzzStereoCapture(FuzzInput& in) {
  std::deque<std::string> strings;  // stable addresses
  craftscan::dds::msg::StereoCapture m{};
  const std::uint8_t flags = in.Integral<std::uint8_t>();
  m.encoding = StringField(in, kEncodings, &strings);
  m.height = in.Integral<uint32_t>();
  m.width = in.Integral<uint32_t>();
  const std::size_t left_bytes = in.Integral<std::uint16_t>();
  std::vector<std::uint8_t> left = Array<std::uint8_t>(in, left_bytes);
  std::vector<std::uint8_t> right = in.Rest();
  if (flags & 4) {  // consistent sizes
    m.height = 1 + m.height % 64;
    const uint32_t row = static_cast<uint32_t>(left.size() / m.height);
    m.width = row / static_cast<uint32_t>(EncodingBytes(m.encoding));
    left.resize(static_cast<std::size_t>(m.width) * EncodingBytes(m.encoding) * m.height);
    right.resize(left.size());
  }
  Borrow(&m.left_data, &left);
  Borrow(&m.right_data, &right);

  cv::Mat left_mat, right_mat;
  std::string error;
  if (!craftscan::fuzz::Outcome(
          craftscan::dds::StereoCaptureToMats(m, &left_mat, &right_mat, &error), error))
    return;
  CRAFTSCAN_FUZZ_CHECK(left_mat.size() == right_mat.size() && left_mat.type() == right_mat.type());
  CRAFTSCAN_FUZZ_CHECK(left_mat.rows == static_cast<int>(m.height) &&
                       left_mat.cols == static_cast<int>(m.width));
  TouchAll(left_mat);
  TouchAll(right_mat);
}

void FuzzDisparity(FuzzInput& in) {
  craftscan::dds::msg::Disparity m{};
  const std::uint8_t flags = in.Integral<std::uint8_t>();
  m.height = in.Integral<uint32_t>();
  m.width = in.Integral<uint32_t>();
  std::vector<float> data = Array<float>(in, in.remaining() / 4);
  if (flags & 4) {  // consistent sizes
    m.height = 1 + m.height % 64;
    m.width = static_cast<uint32_t>(data.size() / m.height);
    data.resize(static_cast<std::size_t>(m.width) * m.height);
  }
  Borrow(&m.data, &data);

  cv::Mat mat;
  std::string error;
  if (!craftscan::fuzz::Outcome(craftscan::dds::DisparityToMat(m, &mat, &error), error)) return;
  CRAFTSCAN_FUZZ_CHECK(mat.type() == CV_32FC1 && mat.rows == static_cast<int>(m.height) &&
                       mat.cols == static_cast<int>(m.width));
  TouchAll(mat);
}

}  // namespace

CRAFTSCAN_FUZZ_TARGET(dds_convert) {
  FuzzInput in(data, size);
  switch (in.Small(4)) {
    case 0:
      FuzzPointCloud2(in);
      break;
    case 1:
      FuzzCloudMessage(in);
      break;
    case 2:
      FuzzImage(in);
      break;
    case 3:
      FuzzStereoCapture(in);
      break;
    default:
      FuzzDisparity(in);
      break;
  }
  return 0;
}
