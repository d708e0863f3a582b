#include "craftscan/sim/technician.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/sim/calibration_scenes.h"

namespace craftscan::sim {
namespace {

constexpr double kMoveS = 1.0;
constexpr double kHoldS = 1.5;
constexpr double kShortHoldS = 0.4;
constexpr double kMistakeS = 1.0;
constexpr double kExposureS = 0.03;  // motion during one exposure

struct Segment {
  double start = 0, end = 0;
  enum Kind { kMove, kHold, kOutOfView, kTooClose } kind = kHold;
  int pose = 0;  // the pose moved to / held
};

// Each pose k: [mistake], move, hold.
std::vector<Segment> Schedule(int poses, int cycles) {
  std::vector<Segment> s;
  double t = 0;
  for (int n = 0; n < poses * cycles; ++n) {
    const int k = n % poses;
    const int ordinal = n + 1;
    if (ordinal % 6 == 0) {
      s.push_back({t, t + kMistakeS, Segment::kOutOfView, k});
      t += kMistakeS;
    }
    s.push_back({t, t + kMoveS, Segment::kMove, k});
    t += kMoveS;
    if (ordinal % 7 == 0) {
      s.push_back({t, t + kMistakeS, Segment::kTooClose, k});
      t += kMistakeS;
    }
    const double hold = ordinal % 5 == 0 ? kShortHoldS : kHoldS;
    s.push_back({t, t + hold, Segment::kHold, k});
    t += hold;
  }
  return s;
}

cv::Matx44d Interpolate(const cv::Matx44d& a, const cv::Matx44d& b, double s) {
  const cv::Matx33d ra = a.get_minor<3, 3>(0, 0), rb = b.get_minor<3, 3>(0, 0);
  cv::Vec3d w;
  cv::Rodrigues(ra.t() * rb, w);
  cv::Matx33d r;
  cv::Rodrigues(w * s, r);
  const cv::Matx33d rs = ra * r;
  cv::Matx44d out = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out(i, j) = rs(i, j);
    out(i, 3) = a(i, 3) + s * (b(i, 3) - a(i, 3));
  }
  return out;
}

// The board's centre in the left image (px), roughly: pinhole with the
// rectified focal length, the rig frame's origin at the left camera.
cv::Vec2d CentrePx(const SimStation& station, const cv::Matx44d& rig_from_board,
                   const BoardSpec& board) {
  const std::vector<cv::Point3f> corners = BoardCornersInBoard(board);
  cv::Vec3d c(0, 0, 0);
  for (const cv::Point3f& p : corners) c += cv::Vec3d(p.x, p.y, p.z);
  c *= 1.0 / static_cast<double>(corners.size());
  const cv::Vec4d q = rig_from_board * cv::Vec4d(c[0], c[1], c[2], 1);
  const double f = station.calibration().rectified_focal_px();
  return {f * q[0] / q[2], f * q[1] / q[2]};
}

cv::Matx44d Pose(const SimStation& station, const BoardSpec& board,
                 const std::vector<Segment>& schedule, const std::vector<cv::Matx44d>& held,
                 double t, TechnicianFrame* frame) {
  const auto it =
      std::find_if(schedule.begin(), schedule.end(), [t](const Segment& s) { return t < s.end; });
  const Segment& s = it == schedule.end() ? schedule.back() : *it;
  const int n = static_cast<int>(held.size());
  const cv::Matx44d& target = held[static_cast<std::size_t>(s.pose)];
  const cv::Matx44d& previous = held[static_cast<std::size_t>((s.pose + n - 1) % n)];
  frame->pose_index = s.pose;
  const double u = std::clamp((t - s.start) / (s.end - s.start), 0.0, 1.0);
  switch (s.kind) {
    case Segment::kMove: {
      frame->activity = "moving";
      const double eased = 0.5 - 0.5 * std::cos(CV_PI * u);
      return Interpolate(previous, target, eased);
    }
    case Segment::kOutOfView: {
      frame->activity = "out of view";
      cv::Matx44d away = previous;
      away(0, 3) += 400 * std::sin(CV_PI * u);  // swung out to the side and back
      return away;
    }
    case Segment::kTooClose: {
      frame->activity = "too close";
      cv::Matx44d close = target;
      for (int i = 0; i < 3; ++i) close(i, 3) *= 0.45;
      return close;
    }
    case Segment::kHold:
    default: {
      frame->activity = "holding";
      // A hand's tremor: a few hundredths of a millimetre and degree.
      cv::Matx44d trembling = target;
      trembling(0, 3) += 0.03 * std::sin(2 * CV_PI * 1.3 * t);
      trembling(1, 3) += 0.03 * std::cos(2 * CV_PI * 1.7 * t);
      (void)station;
      (void)board;
      return trembling;
    }
  }
}

}  // namespace

TechnicianFrame TechnicianAt(const SimStation& station, const BoardSpec& board, double seconds) {
  // The placements depend on the station and board only: kept for the next
  // frame of the same (one render thread calls this per camera).
  thread_local const SimStation* cached_station = nullptr;
  thread_local BoardSpec cached_board;
  thread_local std::vector<cv::Matx44d> held;
  if (cached_station != &station || cached_board.type != board.type ||
      cached_board.cols != board.cols || cached_board.rows != board.rows ||
      cached_board.square_mm != board.square_mm || held.empty()) {
    held.clear();
    for (const HeldPose& p : HeldPoses(board.type)) {
      held.push_back(PlaceHeldBoard(station, board, p).rig_from_board);
    }
    cached_station = &station;
    cached_board = board;
  }
  const std::vector<HeldPose>& poses = HeldPoses(board.type);
  const std::vector<Segment> schedule = Schedule(static_cast<int>(poses.size()), 8);
  TechnicianFrame frame;
  const double t = std::max(0.0, seconds);
  frame.rig_from_board = Pose(station, board, schedule, held, t, &frame);
  TechnicianFrame later;
  const cv::Matx44d next = Pose(station, board, schedule, held, t + kExposureS, &later);
  frame.blur_px = CentrePx(station, next, board) - CentrePx(station, frame.rig_from_board, board);
  if (frame.activity == "holding") frame.blur_px = {0, 0};
  return frame;
}

namespace {

struct PlatterPlacement {
  bool visible = false;
  double off_axis_mm = 0, yaw_rad = 0;
  const char* activity = "";
};

PlatterPlacement PlatterPlacementAt(double t, double off_axis_mm) {
  constexpr double kFetched = 1.5, kSlid = 2.7, kAdjusted = 3.7, kLean = 5.2, kLeanEnd = 5.8;
  if (t < kFetched) return {false, off_axis_mm, 0, "out of view"};
  if (t < kSlid) {
    const double u = (t - kFetched) / (kSlid - kFetched);
    const double eased = 0.5 - 0.5 * std::cos(CV_PI * u);
    return {true, off_axis_mm + 40 * (1 - eased), 0.6 * (1 - eased), "placing"};
  }
  if (t < kAdjusted) {
    const double u = (t - kSlid) / (kAdjusted - kSlid);
    return {true, off_axis_mm + 1.2 * std::sin(3 * CV_PI * u), 0.01 * std::sin(2 * CV_PI * u),
            "adjusting"};
  }
  if (t >= kLean && t < kLeanEnd) return {false, off_axis_mm, 0, "leaning in"};
  return {true, off_axis_mm, 0, "lying"};
}

// The left image position (px) of a world point at turntable angle 0.
cv::Vec2d WorldPx(const SimStation& station, const cv::Vec3d& p) {
  const cv::Vec4d q = station.rig_from_world() * cv::Vec4d(p[0], p[1], p[2], 1);
  const double f = station.calibration().rectified_focal_px();
  return {f * q[0] / q[2], f * q[1] / q[2]};
}

}  // namespace

PlatterTechnicianFrame PlatterTechnicianAt(const SimStation& station, double seconds,
                                           double centre_off_axis_mm) {
  const double t = std::max(0.0, seconds);
  const PlatterPlacement now = PlatterPlacementAt(t, centre_off_axis_mm);
  const PlatterPlacement later = PlatterPlacementAt(t + kExposureS, centre_off_axis_mm);
  PlatterTechnicianFrame frame;
  frame.board_visible = now.visible;
  frame.centre_off_axis_mm = now.off_axis_mm;
  frame.yaw_rad = now.yaw_rad;
  frame.activity = now.activity;
  if (now.visible && later.visible) {
    // The board's centre lies at (off axis, 0) on the platter (PlatterBoardScene).
    frame.blur_px =
        WorldPx(station, {later.off_axis_mm, 0, 0}) - WorldPx(station, {now.off_axis_mm, 0, 0});
  }
  return frame;
}

void ApplyMotionBlur(const cv::Vec2d& blur_px, cv::Mat* image) {
  const double length = std::hypot(blur_px[0], blur_px[1]);
  if (length < 0.5 || image->empty()) return;
  const int size = 2 * static_cast<int>(std::ceil(length / 2)) + 1;
  cv::Mat kernel = cv::Mat::zeros(size, size, CV_32F);
  const cv::Point2d c(size / 2.0, size / 2.0);
  const cv::Point2d d(blur_px[0] / 2, blur_px[1] / 2);
  cv::line(kernel, c - d, c + d, cv::Scalar(1.0), 1, cv::LINE_AA);
  kernel /= cv::sum(kernel)[0];
  cv::filter2D(*image, *image, -1, kernel);
}

}  // namespace craftscan::sim
