// The matcher on real Middlebury scenes with ground truth. Thresholds were
// set from measured figures (2026-11-22, default options; tightened on
// 2026-12-06, when the default aggregation went from the paper's 4
// iterations to 2) with a small margin for floating-point differences
// between machines; they are never loosened.
#include <gtest/gtest.h>

#include <filesystem>

#include "craftscan/pipeline/stereo/adcensus.h"
#include "stereo_scene.h"
#include "test_paths.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;

const fs::path kStereo = fs::path(::craftscan::testing::SharedDataDir()) / "stereo";

DisparityMetrics MatchScene(const std::string& scene_name, ArmRule rule,
                            int aggregation_iterations = ADCensusOptions{}.aggregation_iterations) {
  StereoScene scene;
  std::string error;
  const fs::path dir = kStereo / scene_name;
  EXPECT_TRUE(LoadStereoScene(dir.string(), &scene, &error)) << error;
  ADCensusOptions options;
  options.num_disparities = scene.ndisp;
  options.arm_rule = rule;
  options.aggregation_iterations = aggregation_iterations;
  options.num_threads = 2;
  const DisparityResult result = ComputeDisparity(scene.left, scene.right, options);
  EXPECT_TRUE(result.IsUsable()) << result.message;
  return EvaluateDisparity(result.disparity, scene.gt, scene.mask_nonocc);
}

#define SKIP_WITHOUT_SCENE(name)                                             \
  if (!fs::exists(kStereo / (name) / "scene.json"))                          \
  GTEST_SKIP() << "shared data not found at " << (kStereo / (name)).string() \
               << " (configure with -DCRAFTSCAN_SHARED_DATA=...)"

TEST(Middlebury, TeddyBad2NonOccluded) {
  SKIP_WITHOUT_SCENE("teddy_2003");
  const DisparityMetrics m = MatchScene("teddy_2003", ArmRule::kImproved);
  EXPECT_LT(m.bad2, 4.2);  // measured 3.91 (4.03 with 4 iterations)
  EXPECT_LT(m.bad1, 6.0);  // measured 5.63 (6.10)
  EXPECT_EQ(m.density, 100.0);
}

TEST(Middlebury, ConesBad2NonOccluded) {
  SKIP_WITHOUT_SCENE("cones_2003");
  const DisparityMetrics m = MatchScene("cones_2003", ArmRule::kImproved);
  EXPECT_LT(m.bad2, 2.8);   // measured 2.53 (2.62 with 4 iterations)
  EXPECT_LT(m.bad1, 3.45);  // measured 3.14 (3.18)
}

// The paper's claim: gradient-split arms help where texture is weak.
TEST(Middlebury, ImprovedArmsBeatClassicOnWeakTexture) {
  for (const char* name : {"books_2005_third", "lampshade1_2006_third"}) {
    SKIP_WITHOUT_SCENE(name);
    const DisparityMetrics improved = MatchScene(name, ArmRule::kImproved);
    const DisparityMetrics classic = MatchScene(name, ArmRule::kClassic);
    // measured 14.0 vs 15.8, 15.6 vs 17.2 (4 iterations: 14.7 vs 17.3, 18.7 vs 20.2)
    EXPECT_LT(improved.bad1, classic.bad1 - 1.0) << name;
  }
}

// The default's two aggregation iterations against the paper's four: on the
// 23 shared scenes two do better on bad-1, bad-2 and the mean error in 21–22
// of them. Here three scenes of three datasets, each must not lose on bad-2.
TEST(Middlebury, TwoAggregationIterationsDoNoWorseThanThePapersFour) {
  for (const char* name : {"teddy_2003", "books_2005_third", "lampshade1_2006_third"}) {
    SKIP_WITHOUT_SCENE(name);
    const DisparityMetrics two = MatchScene(name, ArmRule::kImproved, 2);
    const DisparityMetrics four = MatchScene(name, ArmRule::kImproved, 4);
    // measured 3.91 vs 4.00, 6.64 vs 6.97, 9.02 vs 10.08
    EXPECT_LT(two.bad2, four.bad2) << name;
    EXPECT_LT(two.bad1, four.bad1) << name;
  }
}

}  // namespace
}  // namespace craftscan
