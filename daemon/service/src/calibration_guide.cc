#include "craftscan/daemon/calibration_guide.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

namespace craftscan::daemon {
namespace {

double Angle(const cv::Point2f& a, const cv::Point2f& b, const cv::Point2f& c) {
  // The angle at b between b→a and b→c.
  const cv::Point2d u(a.x - b.x, a.y - b.y), v(c.x - b.x, c.y - b.y);
  const double n = std::hypot(u.x, u.y) * std::hypot(v.x, v.y);
  if (n <= 0) return CV_PI / 2;
  return std::acos(std::clamp((u.x * v.x + u.y * v.y) / n, -1.0, 1.0));
}

double MaxMotion(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b) {
  if (a.size() != b.size() || a.empty()) return 1e9;
  double m = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    m = std::max(m, static_cast<double>(std::hypot(a[i].x - b[i].x, a[i].y - b[i].y)));
  }
  return m;
}

// The corners of both images as the console draws them (preview px), or null.
nlohmann::json BoardJson(const GuideInput& f, double scale) {
  auto points = [scale](const std::vector<cv::Point2f>& c) {
    nlohmann::json list = nlohmann::json::array();
    for (const cv::Point2f& p : c) {
      list.push_back({std::round(p.x * scale * 10) / 10, std::round(p.y * scale * 10) / 10});
    }
    return list;
  };
  if (f.left.empty() && f.right.empty()) return nullptr;
  return {{"left", points(f.left)}, {"right", points(f.right)}};
}

// The least distance of `c` from the image's edges, as a share of its
// width (x) or height (y).
double EdgeMargin(const std::vector<cv::Point2f>& c, cv::Size size) {
  double m = 1;
  for (const cv::Point2f& p : c) {
    const double x = static_cast<double>(p.x) / size.width;
    const double y = static_cast<double>(p.y) / size.height;
    m = std::min({m, x, 1 - x, y, 1 - y});
  }
  return m;
}

}  // namespace

bool BoardStillness::Feed(std::int64_t stamp_ns, const std::vector<cv::Point2f>& corners,
                          double still_px) {
  const double motion = MaxMotion(corners, last_);
  last_ = corners;
  if (motion > still_px) {
    since_ns_ = stamp_ns;
    hold_s_ = 0;
    return false;
  }
  if (since_ns_ < 0) since_ns_ = stamp_ns;
  hold_s_ = static_cast<double>(stamp_ns - since_ns_) * 1e-9;
  return true;
}

void BoardStillness::Reset() {
  last_.clear();
  since_ns_ = -1;
  hold_s_ = 0;
}

CalibrationGuide::CalibrationGuide(CalibrationGuideOptions options) : o_(std::move(options)) {
  covered_.assign(static_cast<std::size_t>(o_.grid_cols * o_.grid_rows), false);
}

std::array<double, 4> CalibrationGuide::Params(const std::vector<cv::Point2f>& c) const {
  const double w = o_.image_size.width, h = o_.image_size.height;
  cv::Point2d mean(0, 0);
  for (const cv::Point2f& p : c) mean += cv::Point2d(p.x, p.y);
  mean *= 1.0 / static_cast<double>(std::max<std::size_t>(c.size(), 1));
  double size = 0, skew = 0;
  const std::size_t n = c.size(), cols = static_cast<std::size_t>(o_.board_cols);
  if (o_.chessboard && n == cols * static_cast<std::size_t>(o_.board_rows) && cols >= 2) {
    const cv::Point2f up_left = c[0], up_right = c[cols - 1], down_right = c[n - 1],
                      down_left = c[n - cols];
    // Shoelace area of the outer quadrilateral.
    const cv::Point2f q[4] = {up_left, up_right, down_right, down_left};
    double area = 0;
    for (int i = 0; i < 4; ++i) {
      const cv::Point2f& a = q[i];
      const cv::Point2f& b = q[(i + 1) % 4];
      area += static_cast<double>(a.x) * b.y - static_cast<double>(b.x) * a.y;
    }
    size = std::sqrt(std::abs(area) / 2 / (w * h));
    skew = std::min(1.0, 2 * std::abs(CV_PI / 2 - Angle(up_left, up_right, down_right)));
  } else if (n >= 3) {
    std::vector<cv::Point2f> hull;
    cv::convexHull(c, hull);
    size = std::sqrt(cv::contourArea(hull) / (w * h));
  }
  return {mean.x / w, mean.y / h, size, skew};
}

std::array<double, 4> CalibrationGuide::Bars() const {
  std::array<double, 4> bars{0, 0, 0, 0};
  if (params_.empty()) return bars;
  for (int i = 0; i < 4; ++i) {
    double lo = 1e9, hi = -1e9;
    for (const auto& p : params_) {
      lo = std::min(lo, p[static_cast<std::size_t>(i)]);
      hi = std::max(hi, p[static_cast<std::size_t>(i)]);
    }
    bars[static_cast<std::size_t>(i)] =
        std::min(1.0, (hi - lo) / o_.ranges[static_cast<std::size_t>(i)]);
  }
  return bars;
}

double CalibrationGuide::Coverage() const {
  const auto n = std::count(covered_.begin(), covered_.end(), true);
  return covered_.empty() ? 0 : static_cast<double>(n) / static_cast<double>(covered_.size());
}

bool CalibrationGuide::Done() const {
  if (views() >= o_.max_views) return true;
  if (views() < o_.views_needed || Coverage() < o_.coverage_done) return false;
  for (double b : Bars()) {
    if (b < o_.bar_done) return false;
  }
  return true;
}

std::string CalibrationGuide::Advice() const {
  if (params_.empty()) return "Hold the board still in front of the cameras";
  const std::array<double, 4> bars = Bars();
  if (*std::min_element(bars.begin(), bars.end()) >= o_.bar_done &&
      Coverage() >= o_.coverage_done) {
    const int more = std::max(0, o_.views_needed - views());
    if (more == 0) return "Enough views: put the board down; the calibration is computed now";
    return "Hold the board still in another pose: " + std::to_string(more) + " more view" +
           (more == 1 ? "" : "s") + " to go";
  }
  // The weakest bar says where to go; within it, the side not yet visited.
  int weakest = 0;
  for (int i = 1; i < 4; ++i) {
    if (bars[static_cast<std::size_t>(i)] < bars[static_cast<std::size_t>(weakest)]) weakest = i;
  }
  if (Coverage() < o_.coverage_done && bars[static_cast<std::size_t>(weakest)] >= 0.8) {
    // Bars nearly full but corners of the picture empty: name a free cell.
    for (int r = 0; r < o_.grid_rows; ++r) {
      for (int c = 0; c < o_.grid_cols; ++c) {
        if (covered_[static_cast<std::size_t>(r * o_.grid_cols + c)]) continue;
        const std::string v = r == 0 ? "top" : r == o_.grid_rows - 1 ? "bottom" : "middle";
        const std::string h = c == 0 ? "left" : c == o_.grid_cols - 1 ? "right" : "centre";
        return "Move the board towards the " + v + " " + h + " of the picture";
      }
    }
  }
  double lo = 1e9, hi = -1e9;
  for (const auto& p : params_) {
    lo = std::min(lo, p[static_cast<std::size_t>(weakest)]);
    hi = std::max(hi, p[static_cast<std::size_t>(weakest)]);
  }
  switch (weakest) {
    case 0:
      return lo > 1 - hi ? "Move the board to the left edge of the picture"
                         : "Move the board to the right edge of the picture";
    case 1:
      return lo > 1 - hi ? "Move the board up to the top of the picture"
                         : "Move the board down to the bottom of the picture";
    case 2:
      return hi < 0.5 ? "Bring the board closer to the cameras"
                      : "Move the board farther from the cameras";
    default:
      return "Tilt the board: turn its top away from the cameras, or one side";
  }
}

GuideDecision CalibrationGuide::Feed(const GuideInput& f) {
  GuideDecision d;
  const bool whole = f.left_found && f.right_found;
  if (!f.left_found && !f.right_found) {
    still_.Reset();
    need_move_ = false;
    d.state = "searching";
    d.advice = "Hold the board up in front of both cameras";
    return d;
  }
  if (!still_.Feed(f.stamp_ns, f.left, o_.still_px)) {
    need_move_ = false;
    d.state = "moving";
    d.advice = params_.empty() ? "Hold the board still" : Advice();
    return d;
  }
  if (need_move_) {
    d.state = "captured";
    d.advice = "Taken. " + Advice();
    return d;
  }
  if (!whole) {
    d.state = "rejected";
    d.rejected = "board cut off";
    d.advice = "Both cameras must see the whole board: move it towards the middle or farther away";
    return d;
  }
  if (still_.hold_s() < o_.hold_s) {
    d.state = "holding";
    d.advice = "Hold still";
    return d;
  }
  if (o_.chessboard && f.blur_px > o_.max_blur_px) {
    d.state = "rejected";
    d.rejected = "blurred";
    d.advice = "The picture is blurred: hold the board still, or add light";
    return d;
  }
  const std::array<double, 4> p = Params(f.left);
  double nearest = 1e9;
  for (const auto& q : params_) {
    double distance = 0;
    for (int i = 0; i < 4; ++i) {
      distance += std::abs(p[static_cast<std::size_t>(i)] - q[static_cast<std::size_t>(i)]);
    }
    nearest = std::min(nearest, distance);
  }
  if (nearest < o_.min_param_distance) {
    d.state = "rejected";
    d.rejected = "duplicate pose";
    d.advice = "This pose is taken already. " + Advice();
    return d;
  }
  d.take = true;
  d.state = "captured";
  return d;
}

void CalibrationGuide::Taken(const GuideInput& f) {
  params_.push_back(Params(f.left));
  for (const cv::Point2f& c : f.left) {
    const int col =
        std::clamp(static_cast<int>(c.x * o_.grid_cols / o_.image_size.width), 0, o_.grid_cols - 1);
    const int row = std::clamp(static_cast<int>(c.y * o_.grid_rows / o_.image_size.height), 0,
                               o_.grid_rows - 1);
    covered_[static_cast<std::size_t>(row * o_.grid_cols + col)] = true;
  }
  need_move_ = true;
}

nlohmann::json CalibrationGuide::Overlay(const GuideDecision& d, const GuideInput& f,
                                         double scale) const {
  nlohmann::json cells = nlohmann::json::array();
  for (bool c : covered_) cells.push_back(c ? 1 : 0);
  const std::array<double, 4> bars = Bars();
  return {{"kind", "calibration"},
          {"state", d.state},
          {"board", BoardJson(f, scale)},
          {"hold_s", std::round(still_.hold_s() * 10) / 10},
          {"hold_needed_s", o_.hold_s},
          {"coverage", {{"cols", o_.grid_cols}, {"rows", o_.grid_rows}, {"cells", cells}}},
          {"diversity", {{"x", bars[0]}, {"y", bars[1]}, {"size", bars[2]}, {"skew", bars[3]}}},
          {"views_accepted", views()},
          {"views_needed", o_.views_needed},
          {"rejected", d.rejected},
          {"advice", d.advice}};
}

// --- the turntable axis ----------------------------------------------------------

GuideDecision PlatterGuide::Place(const GuideInput& f) {
  GuideDecision d;
  if (!f.left_found && !f.right_found) {
    still_.Reset();
    d.state = "searching";
    d.advice = "Lay the board flat on the platter, printed side up, near its middle";
    return d;
  }
  if (!f.left_found || !f.right_found) {
    still_.Reset();
    d.state = "rejected";
    d.rejected = "board cut off";
    d.advice = std::string("The ") + (f.left_found ? "right" : "left") +
               " camera does not see the whole board: move it towards the middle of the platter";
    return d;
  }
  if (!still_.Feed(f.stamp_ns, f.left, o_.still_px)) {
    d.state = "moving";
    d.advice = "Let go of the board: it must lie still on the platter";
    return d;
  }
  if (EdgeMargin(f.left, o_.image_size) < o_.min_margin) {
    d.state = "rejected";
    d.rejected = "near the edge";
    d.advice =
        "The board is at the edge of the picture: move it towards the middle of the "
        "platter, so that it stays in view as it turns";
    return d;
  }
  if (still_.hold_s() < o_.hold_s) {
    d.state = "holding";
    d.advice = "Hands off the platter";
    return d;
  }
  if (f.blur_px > o_.max_blur_px) {
    d.state = "rejected";
    d.rejected = "blurred";
    d.advice = "The picture is blurred: add light, or check the focus";
    return d;
  }
  d.take = true;
  d.state = "captured";
  d.advice = "Keep clear: the platter turns now";
  return d;
}

void PlatterGuide::StartAngle(int index, double angle_deg, std::int64_t stamp_ns) {
  angle_index_ = index;
  angle_deg_ = angle_deg;
  angle_start_ns_ = stamp_ns;
  last_left_.clear();
}

GuideDecision PlatterGuide::Turn(const GuideInput& f) {
  GuideDecision d;
  if (angle_start_ns_ < 0) angle_start_ns_ = f.stamp_ns;
  const double waited_s = static_cast<double>(f.stamp_ns - angle_start_ns_) * 1e-9;
  const bool still = f.left_found && MaxMotion(f.left, last_left_) <= o_.still_px;
  last_left_ = f.left_found ? f.left : std::vector<cv::Point2f>{};
  char at[64];
  std::snprintf(at, sizeof at, "at %.0f°", angle_deg_);
  if (still) {
    ++found_;
    steps_.push_back({{"angle_deg", angle_deg_}, {"found", true}});
    d.take = true;
    d.state = "captured";
    d.advice = std::string("Board measured ") + at + "; keep clear of the platter";
    return d;
  }
  if (waited_s >= o_.angle_wait_s) {
    ++missed_;
    steps_.push_back({{"angle_deg", angle_deg_}, {"found", false}});
    d.state = "missed";
    d.rejected = f.left_found ? "board moving" : "board not found";
    d.advice = std::string("The board was not seen lying still ") + at +
               ": keep hands and tools out of the view; if the board slid, stop and lay it "
               "again";
    return d;
  }
  d.state = f.left_found ? "moving" : "searching";
  d.advice = f.left_found
                 ? std::string("Waiting for the board to lie still ") + at
                 : std::string("Looking for the board ") + at + ": keep out of the cameras' view";
  return d;
}

nlohmann::json PlatterGuide::Overlay(const GuideDecision& d, const GuideInput& f,
                                     double scale) const {
  return {{"kind", "calibration"},
          {"mode", "turntable"},
          {"state", d.state},
          {"board", BoardJson(f, scale)},
          {"hold_s", std::round(still_.hold_s() * 10) / 10},
          {"hold_needed_s", o_.hold_s},
          {"angle_deg", placing() ? nlohmann::json(nullptr) : nlohmann::json(angle_deg_)},
          {"steps", steps_},
          {"views_accepted", found_},
          {"views_needed", o_.angles},
          {"rejected", d.rejected},
          {"advice", d.advice}};
}

}  // namespace craftscan::daemon
