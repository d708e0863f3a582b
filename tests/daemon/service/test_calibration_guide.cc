// The guided calibration's decisions (calibration_guide.h) on synthetic
// board corners: nothing is taken until the board has been still for the
// hold time, a blurred or repeated pose is refused with its reason, the
// advice follows the weakest diversity bar, and the guide is done only when
// the views, bars and coverage are there. The turntable's guide
// (PlatterGuide) turns only once the board lies still, whole and away from
// the picture's edges, and at each angle uses a still board or gives up on
// the angle after its wait.
#include <gtest/gtest.h>

#include "craftscan/daemon/calibration_guide.h"

namespace craftscan::daemon {
namespace {

constexpr std::int64_t kFrameNs = 125'000'000;  // 8 frames a second

// A 9×6 chessboard's corners: centre (cx, cy), corner spacing `step`,
// sheared by `shear` px per row (the top right angle moves away from 90°).
std::vector<cv::Point2f> Board(double cx, double cy, double step, double shear = 0) {
  std::vector<cv::Point2f> c;
  for (int r = 0; r < 6; ++r) {
    for (int k = 0; k < 9; ++k) {
      c.emplace_back(static_cast<float>(cx + (k - 4) * step + r * shear),
                     static_cast<float>(cy + (r - 2.5) * step));
    }
  }
  return c;
}

GuideInput Frame(std::int64_t n, const std::vector<cv::Point2f>& corners, double blur = 1.5) {
  GuideInput in;
  in.stamp_ns = n * kFrameNs;
  in.left_found = in.right_found = !corners.empty();
  in.left = in.right = corners;
  in.blur_px = blur;
  return in;
}

CalibrationGuideOptions Options() {
  CalibrationGuideOptions o;
  o.image_size = cv::Size(1280, 1024);
  o.views_needed = 4;
  return o;
}

TEST(CalibrationGuide, TakesAViewOnlyAfterTheBoardIsHeldStill) {
  CalibrationGuide guide(Options());
  std::int64_t n = 0;
  EXPECT_EQ(guide.Feed(Frame(n++, {})).state, "searching");
  // Moving: the corners shift 5 px a frame.
  for (int i = 0; i < 5; ++i) {
    const GuideDecision d = guide.Feed(Frame(n++, Board(400 + 5 * i, 500, 40)));
    EXPECT_EQ(d.state, "moving");
    EXPECT_FALSE(d.take);
  }
  // Held: 1 s of frames (8) before the take.
  int frames_to_take = 0;
  GuideDecision d;
  do {
    d = guide.Feed(Frame(n++, Board(420, 500, 40)));
    ++frames_to_take;
    if (!d.take) {
      EXPECT_EQ(d.state, "holding");
    }
  } while (!d.take && frames_to_take < 30);
  EXPECT_TRUE(d.take);
  // Still since the last frame it moved in: taken once 1 s of frames passed.
  EXPECT_EQ(frames_to_take, 8);
  guide.Taken(Frame(n, Board(420, 500, 40)));
  EXPECT_EQ(guide.views(), 1);
  // Still held: not taken twice.
  for (int i = 0; i < 20; ++i) EXPECT_FALSE(guide.Feed(Frame(n++, Board(420, 500, 40))).take);
}

TEST(CalibrationGuide, RefusesBlurredRepeatedAndCutOffBoardsWithTheReason) {
  CalibrationGuide guide(Options());
  std::int64_t n = 0;
  auto hold = [&](const std::vector<cv::Point2f>& c, double blur = 1.5, bool right = true) {
    guide.Feed(Frame(n++, {}));  // it goes away, then comes back
    GuideDecision d;
    for (int i = 0; i < 12; ++i) {
      GuideInput in = Frame(n++, c, blur);
      in.right_found = right;
      d = guide.Feed(in);
      if (d.take) {
        guide.Taken(in);
        break;
      }
    }
    return d;
  };
  EXPECT_TRUE(hold(Board(400, 400, 40)).take);
  EXPECT_EQ(hold(Board(404, 402, 40)).rejected, "duplicate pose");
  EXPECT_EQ(hold(Board(900, 700, 40), 6.0).rejected, "blurred");
  EXPECT_EQ(hold(Board(900, 700, 40), 1.5, false).rejected, "board cut off");
  EXPECT_TRUE(hold(Board(900, 700, 40)).take);
  EXPECT_EQ(guide.views(), 2);
}

TEST(CalibrationGuide, AdviceFollowsTheWeakestBarAndDoneNeedsEverything) {
  CalibrationGuideOptions o = Options();
  CalibrationGuide guide(o);
  std::int64_t n = 0;
  auto take = [&](const std::vector<cv::Point2f>& c) {
    guide.Feed(Frame(n++, {}));
    for (int i = 0; i < 12; ++i) {
      const GuideInput in = Frame(n++, c);
      if (guide.Feed(in).take) {
        guide.Taken(in);
        return true;
      }
    }
    return false;
  };
  // Four views in the top left, all square: x, y and size spread a little,
  // skew not at all.
  ASSERT_TRUE(take(Board(300, 250, 30)));
  ASSERT_TRUE(take(Board(600, 250, 45)));
  ASSERT_TRUE(take(Board(300, 500, 45)));
  ASSERT_TRUE(take(Board(600, 500, 30)));
  EXPECT_FALSE(guide.Done()) << "enough views, but not diverse";
  const GuideDecision d = guide.Feed(Frame(n++, Board(600, 500, 30)));
  EXPECT_NE(d.advice.find("Tilt"), std::string::npos) << d.advice;  // skew weakest (0)
  // Spread everything: far corners, big and small, sheared both ways.
  ASSERT_TRUE(take(Board(150, 130, 25, 12)));
  ASSERT_TRUE(take(Board(1130, 890, 25, -12)));
  ASSERT_TRUE(take(Board(640, 512, 100)));
  ASSERT_TRUE(take(Board(1100, 150, 30, 25)));
  ASSERT_TRUE(take(Board(180, 880, 30, -25)));
  ASSERT_TRUE(take(Board(640, 200, 110, 10)));
  ASSERT_TRUE(take(Board(640, 830, 110, -10)));
  const std::array<double, 4> bars = guide.Bars();
  std::printf("bars x %.2f y %.2f size %.2f skew %.2f, coverage %.2f\n", bars[0], bars[1], bars[2],
              bars[3], guide.Coverage());
  EXPECT_EQ(bars[0], 1.0);
  EXPECT_EQ(bars[1], 1.0);
  EXPECT_TRUE(guide.Done() == (bars[2] >= 1 && bars[3] >= 1 && guide.Coverage() >= 0.75));
  const nlohmann::json overlay = guide.Overlay(d, Frame(n, Board(640, 512, 40)), 0.5);
  EXPECT_EQ(overlay["board"]["left"].size(), 54u);
  EXPECT_DOUBLE_EQ(overlay["board"]["left"][0][0].get<double>(), (640 - 160) * 0.5);
  EXPECT_EQ(overlay["coverage"]["cells"].size(), 12u);
  EXPECT_EQ(overlay["views_accepted"], guide.views());
}

// --- the turntable axis -------------------------------------------------------

PlatterGuideOptions PlatterOptions() {
  PlatterGuideOptions o;
  o.image_size = cv::Size(1280, 1024);
  o.angles = 3;
  return o;
}

TEST(PlatterGuide, TurnsOnlyOnceTheBoardLiesStillWholeAndAwayFromTheEdges) {
  PlatterGuide guide(PlatterOptions());
  std::int64_t n = 0;
  GuideDecision d = guide.Place(Frame(n++, {}));
  EXPECT_EQ(d.state, "searching");
  EXPECT_NE(d.advice.find("Lay the board"), std::string::npos) << d.advice;
  // Seen by the left camera only.
  GuideInput left_only = Frame(n++, Board(640, 600, 40));
  left_only.right_found = false;
  left_only.right.clear();
  d = guide.Place(left_only);
  EXPECT_EQ(d.rejected, "board cut off");
  EXPECT_NE(d.advice.find("right camera"), std::string::npos) << d.advice;
  // A hand still moving it.
  for (int i = 0; i < 4; ++i) {
    d = guide.Place(Frame(n++, Board(640 + 2 * i, 600, 40)));
    EXPECT_EQ(d.state, "moving");
    EXPECT_NE(d.advice.find("Let go"), std::string::npos) << d.advice;
  }
  // Still, but its corners 10 px from the right edge.
  for (int i = 0; i < 12; ++i) {
    d = guide.Place(Frame(n++, Board(1270 - 4 * 40, 600, 40)));
    EXPECT_FALSE(d.take);
  }
  EXPECT_EQ(d.rejected, "near the edge");
  // Moved to the middle: one second of stillness, then it turns.
  int frames = 0;
  do {
    d = guide.Place(Frame(n++, Board(640, 600, 40)));
    ++frames;
  } while (!d.take && frames < 30);
  EXPECT_TRUE(d.take);
  EXPECT_EQ(frames, 9);  // the frame it arrived in moved; 8 more make 1 s
  // Blurred: not turned.
  PlatterGuide blurred(PlatterOptions());
  for (int i = 0; i < 20; ++i) d = blurred.Place(Frame(i, Board(640, 600, 40), 5.0));
  EXPECT_FALSE(d.take);
  EXPECT_EQ(d.rejected, "blurred");
}

TEST(PlatterGuide, UsesAStillBoardAtEachAngleAndGivesUpOnAnAngleAfterItsWait) {
  PlatterGuide guide(PlatterOptions());
  std::int64_t n = 0;
  // Angle 0: found still in its second frame.
  guide.StartAngle(0, 0, -1);
  EXPECT_FALSE(guide.Turn(Frame(n++, Board(640, 600, 40))).take);
  GuideDecision d = guide.Turn(Frame(n++, Board(640, 600, 40)));
  EXPECT_TRUE(d.take);
  EXPECT_EQ(guide.found(), 1);
  // Angle 120: hidden for 1 s, then seen sliding, then still.
  guide.StartAngle(1, 120, -1);
  for (int i = 0; i < 8; ++i) {
    d = guide.Turn(Frame(n++, {}));
    EXPECT_EQ(d.state, "searching");
  }
  EXPECT_EQ(guide.Turn(Frame(n++, Board(600, 600, 40))).state, "moving");
  EXPECT_EQ(guide.Turn(Frame(n++, Board(603, 600, 40))).state, "moving");
  EXPECT_TRUE(guide.Turn(Frame(n++, Board(603.2, 600, 40))).take);
  // Angle 240: never seen; given up after angle_wait_s (4 s = 32 frames).
  guide.StartAngle(2, 240, -1);
  int frames = 0;
  do {
    d = guide.Turn(Frame(n++, {}));
    ++frames;
  } while (d.state != "missed" && frames < 100);
  EXPECT_EQ(frames, 33);
  EXPECT_EQ(d.rejected, "board not found");
  EXPECT_NE(d.advice.find("240°"), std::string::npos) << d.advice;
  EXPECT_EQ(guide.found(), 2);
  EXPECT_EQ(guide.missed(), 1);
  const nlohmann::json o = guide.Overlay(d, Frame(n, {}), 0.5);
  EXPECT_EQ(o["mode"], "turntable");
  ASSERT_EQ(o["steps"].size(), 3u);
  EXPECT_EQ(o["steps"][1]["angle_deg"], 120);
  EXPECT_EQ(o["steps"][2]["found"], false);
  EXPECT_EQ(o["views_accepted"], 2);
}

}  // namespace
}  // namespace craftscan::daemon
