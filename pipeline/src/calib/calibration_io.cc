// Versioned OpenCV YAML calibration files, written atomically.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "calibration_internal.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/atomic_file.h"

namespace craftscan {

using calib_internal::Fail;

namespace {

constexpr const char* kFormatName = "craftscan-stereo-calibration";

// --- Writing ------------------------------------------------------------------

void WriteIntrinsics(cv::FileStorage& fs, const char* name, const CameraIntrinsics& camera) {
  fs << name << "{";
  fs << "camera_matrix" << cv::Mat(camera.camera_matrix);
  fs << "distortion" << camera.DistortionCoeffs();
  fs << "}";
}

void WriteReport(cv::FileStorage& fs, const CalibrationReport& r) {
  fs << "report"
     << "{";
  fs << "rms_left_px" << r.rms_left_px << "rms_right_px" << r.rms_right_px;
  fs << "rms_stereo_px" << r.rms_stereo_px;
  fs << "epipolar_mean_px" << r.epipolar_mean_px << "epipolar_max_px" << r.epipolar_max_px;
  fs << "coverage_grid" << r.coverage_grid;
  fs << "coverage_left" << r.coverage_left << "coverage_right" << r.coverage_right;
  fs << "views_used" << r.views_used;
  fs << "verdict" << std::string(ToString(r.verdict));
  fs << "verdict_reason" << r.verdict_reason;
  fs << "turntable_steps" << r.turntable_steps;
  fs << "turntable_residual_mm" << r.turntable_residual_mm;
  fs << "turntable_max_angle_error_deg" << r.turntable_max_angle_error_deg;
  fs << "views"
     << "[";
  for (const ViewReport& v : r.views) {
    fs << "{";
    fs << "name" << v.name << "used" << static_cast<int>(v.used) << "message" << v.message;
    fs << "num_points" << v.num_points;
    fs << "rms_left_px" << v.rms_left_px << "rms_right_px" << v.rms_right_px;
    fs << "rms_stereo_px" << v.rms_stereo_px;
    fs << "}";
  }
  fs << "]";
  fs << "}";
}

// OpenCV's YAML reader (4.6) loops forever when text follows the first
// top-level collection and the next character after the three it skips (as
// a "---") is a '-' that does not start "---": its search for the next
// document neither advances nor fails there. Found twice by tests/fuzz:
// "%YAML:1.0\n---YAML:1.0\n---\n- 1\n" and "%YAML:1.0\n  -A\n0 --\nx\n". A
// calibration file is one document as SaveCalibration writes it: a "%"
// directive only on the first line, at most one "---" line with nothing
// after the marker, and one map at column 0, so every other line that
// starts at column 0 is one of its keys ("name:"); nested values are
// indented. Then that map runs to the end of the file and OpenCV never
// looks for a second document. Files of other shapes are refused before
// OpenCV sees them.
bool IsRootKeyLine(std::string_view line) {
  std::size_t i = 0;
  while (i < line.size() &&
         (std::isalnum(static_cast<unsigned char>(line[i])) != 0 || line[i] == '_'))
    ++i;
  if (i == 0 || i >= line.size() || line[i] != ':') return false;
  return i + 1 == line.size() || line[i + 1] == ' ' || line[i + 1] == '\r';
}

bool HasOneDocumentShape(const std::string& text, std::string* why) {
  int markers = 0;
  std::size_t line_number = 0;
  for (std::size_t begin = 0; begin < text.size();) {
    std::size_t end = text.find('\n', begin);
    if (end == std::string::npos) end = text.size();
    const std::string_view line(text.data() + begin, end - begin);
    ++line_number;
    if (line.rfind("%", 0) == 0 && line_number != 1) {
      *why = "line " + std::to_string(line_number) + ": a '%' directive after the first line";
      return false;
    }
    if (line.rfind("---", 0) == 0) {
      if (++markers > 1) {
        *why = "line " + std::to_string(line_number) + ": a second document ('---')";
        return false;
      }
      if (line.find_first_not_of(" \t\r", 3) != std::string_view::npos) {
        *why = "line " + std::to_string(line_number) + ": text after the document marker '---'";
        return false;
      }
    } else if (line_number != 1 && !line.empty() && line[0] != ' ' && line[0] != '\r' &&
               line[0] != '#' && !IsRootKeyLine(line)) {
      *why = "line " + std::to_string(line_number) +
             ": not a key of the file's map ('name:') and not indented";
      return false;
    }
    begin = end + 1;
  }
  return true;
}

std::string ToYaml(const StereoCalibration& c) {
  cv::FileStorage fs(
      ".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  fs << "format" << kFormatName;
  fs << "format_version" << StereoCalibration::kFormatVersion;
  fs << "image_width" << c.image_size.width << "image_height" << c.image_size.height;
  fs << "board"
     << "{";
  fs << "type" << std::string(ToString(c.board.type));
  fs << "cols" << c.board.cols << "rows" << c.board.rows;
  fs << "square_mm" << c.board.square_mm << "marker_mm" << c.board.marker_mm;
  fs << "aruco_dictionary" << c.board.aruco_dictionary;
  fs << "}";
  WriteIntrinsics(fs, "left", c.left);
  WriteIntrinsics(fs, "right", c.right);
  fs << "R" << cv::Mat(c.R) << "T" << cv::Mat(c.T);
  fs << "R1" << cv::Mat(c.R1) << "R2" << cv::Mat(c.R2);
  fs << "P1" << cv::Mat(c.P1) << "P2" << cv::Mat(c.P2) << "Q" << cv::Mat(c.Q);
  fs << "turntable"
     << "{";
  fs << "valid" << static_cast<int>(c.turntable.valid);
  fs << "direction_in_rig" << cv::Mat(c.turntable.direction_in_rig);
  fs << "point_in_rig_mm" << cv::Mat(c.turntable.point_in_rig_mm);
  fs << "}";
  WriteReport(fs, c.report);
  return fs.releaseAndGetString();
}

// --- Reading ------------------------------------------------------------------

// Reads keys from one file, turning every problem into a message that names
// the file and the key.
class Reader {
 public:
  Reader(std::string path, std::string* error) : path_(std::move(path)), error_(error) {}

  bool Fail(const std::string& what) { return craftscan::Fail(error_, "'" + path_ + "': " + what); }

  bool Node(const cv::FileNode& parent, const std::string& key, const std::string& name,
            cv::FileNode* out) {
    *out = parent[key];
    if (out->empty() || out->isNone()) return Fail("missing key '" + name + "'");
    return true;
  }

  bool Int(const cv::FileNode& parent, const std::string& key, const std::string& name, int* out) {
    cv::FileNode n;
    if (!Node(parent, key, name, &n)) return false;
    if (!n.isInt()) return Fail("key '" + name + "': expected an integer");
    *out = static_cast<int>(n);
    return true;
  }

  bool Real(const cv::FileNode& parent, const std::string& key, const std::string& name,
            double* out) {
    cv::FileNode n;
    if (!Node(parent, key, name, &n)) return false;
    if (!n.isReal() && !n.isInt()) return Fail("key '" + name + "': expected a number");
    *out = static_cast<double>(n);
    if (!std::isfinite(*out)) return Fail("key '" + name + "': not finite");
    return true;
  }

  bool String(const cv::FileNode& parent, const std::string& key, const std::string& name,
              std::string* out) {
    cv::FileNode n;
    if (!Node(parent, key, name, &n)) return false;
    if (!n.isString()) return Fail("key '" + name + "': expected a string");
    *out = static_cast<std::string>(n);
    return true;
  }

  // Whether `n` is an opencv-matrix map with integer rows and cols in 1..16
  // and a list of rows × cols values. Checked before reading: cv::read
  // allocates rows × cols elements before it looks at the data, so a few
  // bytes could ask for gigabytes (found by tests/fuzz).
  static bool IsSmallMatrix(const cv::FileNode& n) {
    if (!n.isMap()) return false;
    const cv::FileNode rows = n["rows"], cols = n["cols"], data = n["data"];
    if (!rows.isInt() || !cols.isInt() || !data.isSeq()) return false;
    const int r = static_cast<int>(rows), c = static_cast<int>(cols);
    return r >= 1 && r <= 16 && c >= 1 && c <= 16 && data.size() == static_cast<std::size_t>(r * c);
  }

  // A matrix of exactly rows × cols (a 3-vector may also be stored 1×3).
  bool Matrix(const cv::FileNode& parent, const std::string& key, const std::string& name, int rows,
              int cols, cv::Mat* out) {
    cv::FileNode n;
    if (!Node(parent, key, name, &n)) return false;
    cv::Mat m;
    if (IsSmallMatrix(n)) n >> m;
    if (m.empty() || m.channels() != 1) {
      return Fail("key '" + name + "': expected an opencv-matrix");
    }
    const bool vector_transposed = cols == 1 && m.rows == 1 && m.cols == rows;
    if ((m.rows != rows || m.cols != cols) && !vector_transposed) {
      return Fail("key '" + name + "': expected a " + std::to_string(rows) + "x" +
                  std::to_string(cols) + " matrix, got " + std::to_string(m.rows) + "x" +
                  std::to_string(m.cols));
    }
    m.reshape(1, rows).convertTo(*out, CV_64F);
    if (!cv::checkRange(*out)) return Fail("key '" + name + "': contains non-finite values");
    return true;
  }

  template <int M, int N>
  bool Matx(const cv::FileNode& parent, const std::string& key, const std::string& name,
            cv::Matx<double, M, N>* out) {
    cv::Mat m;
    if (!Matrix(parent, key, name, M, N, &m)) return false;
    m.copyTo(cv::Mat(*out, false));
    return true;
  }

  bool Intrinsics(const cv::FileNode& root, const std::string& key, CameraIntrinsics* out) {
    cv::FileNode n;
    if (!Node(root, key, key, &n)) return false;
    if (!n.isMap()) return Fail("key '" + key + "': expected a map");
    if (!Matx(n, "camera_matrix", key + ".camera_matrix", &out->camera_matrix)) return false;
    cv::FileNode d;
    if (!Node(n, "distortion", key + ".distortion", &d)) return false;
    cv::Mat coeffs;
    if (IsSmallMatrix(d)) d >> coeffs;
    const int count = static_cast<int>(coeffs.total());
    if (coeffs.empty() || (coeffs.rows != 1 && coeffs.cols != 1) || (count != 5 && count != 8)) {
      return Fail("key '" + key + ".distortion': expected a 1x5 or 1x8 matrix, got " +
                  std::to_string(coeffs.rows) + "x" + std::to_string(coeffs.cols));
    }
    if (!cv::checkRange(coeffs)) return Fail("key '" + key + ".distortion': not finite");
    if (!out->SetDistortionCoeffs(coeffs)) return Fail("key '" + key + ".distortion': invalid");
    return true;
  }

  // Optional report: missing or odd values keep their defaults.
  static void Report(const cv::FileNode& n, CalibrationReport* r) {
    if (!n.isMap()) return;
    auto real = [](const cv::FileNode& node, double* out) {
      if (node.isReal() || node.isInt()) *out = static_cast<double>(node);
    };
    auto integer = [](const cv::FileNode& node, int* out) {
      if (node.isInt()) *out = static_cast<int>(node);
    };
    auto text = [](const cv::FileNode& node, std::string* out) {
      if (node.isString()) *out = static_cast<std::string>(node);
    };
    real(n["rms_left_px"], &r->rms_left_px);
    real(n["rms_right_px"], &r->rms_right_px);
    real(n["rms_stereo_px"], &r->rms_stereo_px);
    real(n["epipolar_mean_px"], &r->epipolar_mean_px);
    real(n["epipolar_max_px"], &r->epipolar_max_px);
    integer(n["coverage_grid"], &r->coverage_grid);
    real(n["coverage_left"], &r->coverage_left);
    real(n["coverage_right"], &r->coverage_right);
    integer(n["views_used"], &r->views_used);
    std::string verdict;
    text(n["verdict"], &verdict);
    CalibrationVerdictFromString(verdict, &r->verdict);
    text(n["verdict_reason"], &r->verdict_reason);
    integer(n["turntable_steps"], &r->turntable_steps);
    real(n["turntable_residual_mm"], &r->turntable_residual_mm);
    real(n["turntable_max_angle_error_deg"], &r->turntable_max_angle_error_deg);
    const cv::FileNode views = n["views"];
    if (!views.isSeq()) return;
    for (cv::FileNodeIterator it = views.begin(); it != views.end(); ++it) {
      const cv::FileNode v = *it;
      if (!v.isMap()) continue;
      ViewReport view;
      text(v["name"], &view.name);
      int used = 0;
      integer(v["used"], &used);
      view.used = used != 0;
      text(v["message"], &view.message);
      integer(v["num_points"], &view.num_points);
      real(v["rms_left_px"], &view.rms_left_px);
      real(v["rms_right_px"], &view.rms_right_px);
      real(v["rms_stereo_px"], &view.rms_stereo_px);
      r->views.push_back(std::move(view));
    }
  }

 private:
  std::string path_;
  std::string* error_;
};

bool ReadCalibration(const cv::FileStorage& fs, Reader& in, StereoCalibration* c) {
  const cv::FileNode root = fs.root();
  if (!root.isMap()) return in.Fail("not a YAML map of keys (empty or not a calibration file)");
  std::string format;
  if (!in.String(root, "format", "format", &format)) return false;
  if (format != kFormatName) {
    return in.Fail("key 'format' is '" + format + "', expected '" + kFormatName + "'");
  }
  int version = 0;
  if (!in.Int(root, "format_version", "format_version", &version)) return false;
  if (version != StereoCalibration::kFormatVersion) {
    return in.Fail("format_version " + std::to_string(version) +
                   " is not supported (this build reads version " +
                   std::to_string(StereoCalibration::kFormatVersion) + ")");
  }
  if (!in.Int(root, "image_width", "image_width", &c->image_size.width) ||
      !in.Int(root, "image_height", "image_height", &c->image_size.height)) {
    return false;
  }

  cv::FileNode board;
  if (!in.Node(root, "board", "board", &board)) return false;
  if (!board.isMap()) return in.Fail("key 'board': expected a map");
  std::string type;
  if (!in.String(board, "type", "board.type", &type)) return false;
  if (!BoardTypeFromString(type, &c->board.type)) {
    return in.Fail("key 'board.type': unknown board type '" + type + "'");
  }
  if (!in.Int(board, "cols", "board.cols", &c->board.cols) ||
      !in.Int(board, "rows", "board.rows", &c->board.rows) ||
      !in.Real(board, "square_mm", "board.square_mm", &c->board.square_mm) ||
      !in.Real(board, "marker_mm", "board.marker_mm", &c->board.marker_mm) ||
      !in.Int(board, "aruco_dictionary", "board.aruco_dictionary", &c->board.aruco_dictionary)) {
    return false;
  }

  if (!in.Intrinsics(root, "left", &c->left) || !in.Intrinsics(root, "right", &c->right)) {
    return false;
  }
  cv::Matx31d t;
  if (!in.Matx(root, "R", "R", &c->R) || !in.Matx(root, "T", "T", &t) ||
      !in.Matx(root, "R1", "R1", &c->R1) || !in.Matx(root, "R2", "R2", &c->R2) ||
      !in.Matx(root, "P1", "P1", &c->P1) || !in.Matx(root, "P2", "P2", &c->P2) ||
      !in.Matx(root, "Q", "Q", &c->Q)) {
    return false;
  }
  c->T = cv::Vec3d(t(0), t(1), t(2));

  cv::FileNode turntable;
  if (!in.Node(root, "turntable", "turntable", &turntable)) return false;
  if (!turntable.isMap()) return in.Fail("key 'turntable': expected a map");
  int valid = 0;
  cv::Matx31d direction, point;
  if (!in.Int(turntable, "valid", "turntable.valid", &valid) ||
      !in.Matx(turntable, "direction_in_rig", "turntable.direction_in_rig", &direction) ||
      !in.Matx(turntable, "point_in_rig_mm", "turntable.point_in_rig_mm", &point)) {
    return false;
  }
  c->turntable.valid = valid != 0;
  c->turntable.direction_in_rig = cv::Vec3d(direction(0), direction(1), direction(2));
  c->turntable.point_in_rig_mm = cv::Vec3d(point(0), point(1), point(2));

  Reader::Report(root["report"], &c->report);

  std::string why;
  if (!c->IsValid(&why)) return in.Fail("invalid calibration: " + why);
  return true;
}

}  // namespace

bool SaveCalibration(const std::string& path, const StereoCalibration& calibration,
                     std::string* error) {
  namespace fs = std::filesystem;
  std::string why;
  if (path.empty()) return Fail(error, "SaveCalibration: empty path");
  if (!calibration.IsValid(&why)) {
    return Fail(error, "'" + path + "': refusing to save an invalid calibration: " + why);
  }
  std::string text;
  try {
    text = ToYaml(calibration);
  } catch (const cv::Exception& e) {
    return Fail(error,
                "'" + path + "': cannot format the calibration: " + calib_internal::CvErrorText(e));
  }

  if (!WriteFileAtomically(path, text, &why)) return Fail(error, why);
  return true;
}

bool LoadCalibration(const std::string& path, StereoCalibration* calibration, std::string* error) {
  namespace fs = std::filesystem;
  if (calibration == nullptr) return Fail(error, "LoadCalibration: no output");
  std::error_code ec;
  if (!fs::exists(path, ec)) return Fail(error, "'" + path + "': no such file");
  if (!fs::is_regular_file(path, ec)) return Fail(error, "'" + path + "': not a regular file");
  // A calibration is a few kB; 16 MiB is far beyond any real one.
  constexpr std::uintmax_t kMaxBytes = 16u << 20;
  const std::uintmax_t size = fs::file_size(path, ec);
  Reader in(path, error);
  if (ec) return in.Fail("cannot read: " + ec.message());
  if (size == 0) return Fail(error, "'" + path + "': empty file");
  if (size > kMaxBytes) return in.Fail("larger than 16 MiB: not a calibration file");
  // Read once: the bytes checked here are the bytes OpenCV parses.
  std::string text(static_cast<std::size_t>(size), '\0');
  {
    std::ifstream file(path, std::ios::binary);
    if (!file.read(text.data(), static_cast<std::streamsize>(size))) return in.Fail("cannot read");
  }
  std::string why;
  if (!HasOneDocumentShape(text, &why)) return in.Fail("not a calibration file: " + why);
  StereoCalibration loaded;
  try {
    // Always parse as YAML, whatever the extension.
    cv::FileStorage storage(
        text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
    if (!storage.isOpened()) return in.Fail("cannot open or parse as OpenCV YAML");
    if (!ReadCalibration(storage, in, &loaded)) return false;
  } catch (const cv::Exception& e) {
    return in.Fail(std::string("malformed YAML: ") + calib_internal::CvErrorText(e));
  } catch (const std::exception& e) {
    // OpenCV's parser lets std::length_error through on some malformed keys
    // (found by tests/fuzz).
    return in.Fail(std::string("malformed YAML: ") + e.what());
  }
  *calibration = std::move(loaded);
  return true;
}

}  // namespace craftscan
