// Two turns' fused clouds on disk: `craftscan-bench scan --turns 2
// --save-turns DIR` writes them, `craftscan-bench turn-join --dir DIR` joins
// them again (so the join can be measured without rendering and matching).
//
//   DIR/turn_a.ply, DIR/turn_b.ply   each turn's fused cloud (binary PLY,
//                                     normals and colours) in its own
//                                     turntable frame, mm
//   DIR/truth_a_from_b.txt           the true join: 16 numbers, row-major
//   DIR/turn_a.json, DIR/turn_b.json each turn's own report (ScanReportJson:
//                                     conditioning, registration, fusion)
//   DIR/turn_a_viewK.ply, …          each view's conditioned cloud (what
//                                     fusion starts from), in its turn's frame
//   DIR/turn_a_object_from_turn.txt, … the turn's frame in the object's (16
//                                     numbers, row-major: the truth of each turn)
//   DIR/turn_a_truth_seen.ply, …      the true surface the turn's cameras saw,
//                                     object frame
#pragma once

#include <string>

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan::bench {

// Creates `dir` if needed. Returns false with *why naming the file.
bool SaveTurns(const std::string& dir, const PointCloud& turn_a, const PointCloud& turn_b,
               const cv::Matx44d& truth_a_from_b, std::string* why);

}  // namespace craftscan::bench
