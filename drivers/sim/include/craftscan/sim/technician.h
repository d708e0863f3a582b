// A simulated technician holding the calibration board in front of the rig
// for a guided calibration: where the board is at each moment, as a person
// would move it. They go through the held poses (HeldPoses) one after
// another: move to the next (about a second, accelerating and slowing
// down, so frames in between are motion-blurred), hold it (1.5 s, with a
// hand's tremor of a few hundredths of a millimetre), move on. Like a
// person they also make mistakes, on a fixed schedule over the poses:
//   every 5th pose   they hold it only 0.4 s before moving on (too short)
//   every 6th        they first take the board out of the view for a second
//   every 7th        they first hold it far too close (cut off) for a second
// The schedule depends on time only, so a frame at time t is reproducible.
// PlatterTechnicianAt: the same for a board laid on the platter.
#pragma once

#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/sim/station.h"

namespace craftscan::sim {

struct TechnicianFrame {
  cv::Matx44d rig_from_board = cv::Matx44d::eye();
  // The board's apparent motion during the exposure (left image, px):
  // render the frame blurred along it.
  cv::Vec2d blur_px{0, 0};
  std::string activity;  // "moving", "holding", "out of view", "too close"
  int pose_index = 0;    // the held pose being moved to or held
};

// The technician at `seconds` after the board was first shown.
TechnicianFrame TechnicianAt(const SimStation& station, const BoardSpec& board, double seconds);

// The same person laying a board on the platter for the turntable-axis
// calibration (platter_board scene), on a fixed schedule:
//   0 – 1.5 s     the platter is empty (they fetch the board)
//   1.5 – 2.7 s   they slide it into place from farther out, turned
//   2.7 – 3.7 s   their hand still adjusts it (a millimetre or so)
//   from 3.7 s    it lies still, `centre_off_axis_mm` off the axis, turning
//                 with the platter
//   5.2 – 5.8 s   they lean in over the platter: the board is hidden (with
//                 8 frames a second, while the platter turns)
// blur_px: the board's apparent motion during the exposure while sliding
// or adjusting (left image, at turntable angle 0, where the placing is).
struct PlatterTechnicianFrame {
  bool board_visible = false;
  double centre_off_axis_mm = 20;
  double yaw_rad = 0;
  cv::Vec2d blur_px{0, 0};
  std::string activity;  // "out of view", "placing", "adjusting", "lying", "leaning in"
};
PlatterTechnicianFrame PlatterTechnicianAt(const SimStation& station, double seconds,
                                           double centre_off_axis_mm = 20);

// Blurs `image` (in place) along `blur_px` (a linear motion blur of that
// length); no-op below half a pixel.
void ApplyMotionBlur(const cv::Vec2d& blur_px, cv::Mat* image);

}  // namespace craftscan::sim
