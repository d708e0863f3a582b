// `craftscan-bench registration`: pairwise registration and loop closure on
// Stanford-style range scans with ground-truth poses, against PCL's tuned
// FPFH + SampleConsensusPrerejective + ICP pipeline in the same run.
//
//   craftscan-bench registration [--bunny DIR] [--pairs a:b,...] [--threads N]
//                                [--repeat K] [--json FILE]
//
// DIR holds scans and a bun.conf (LoadStanfordScans: ASCII or binary PLY,
// extra elements skipped, metres converted to mm).
//
// Ring. The scans taken on the turntable are found from the ground-truth
// poses alone: for a reference scan r, every other scan's pose relative to it
// (RelativePose) is a rotation by some angle about an axis. The common axis is
// the candidate axis (one per scan rotated ≥ 10° from r) that the most scans
// agree with within 5°, refined as the principal direction of those scans'
// axes (sign fixed so that its largest component is positive). Scans whose
// axis deviates by more than 5° are off-ring; scans rotated by less than 10°
// from r count as on-ring. On the bunny the six bunNNN scans deviate by at
// most 1.6° (bun315), the off-ring views by 15° (ear_back, which 20° would
// let in), 46° (top3), 64° (chin) and 86° (top2). Every scan is tried as r;
// the first (in bun.conf order) with the most on-ring scans wins. On-ring
// scans are sorted by their angle θ about the axis (r_from_scan rotation,
// [0, 360°), r first), and the ring neighbour pairs are k → k−1 (source →
// target) plus the wrap-around 0 → n−1.
//
// overlap_pct: percentage of the source's raw points within 2 mm of a target
// point after the ground-truth pose (exact kd-tree). Default pairs: ring
// neighbours with overlap_pct ≥ 50; --pairs source:target,... (names with or
// without .ply) overrides.
//
// Per pair (times are medians over K repeats; poses come from the first run,
// deterministic for a thread count):
//   floor      RegisterFine from the ground truth (default FineOptions): the
//              pose fine registration settles at when started at the truth.
//              bun.conf itself is off by up to ~0.3° / 0.5 mm on some pairs,
//              so craftscan is judged against this pose ("vs_floor").
//   craftscan  ConditionCloud(source) + ConditionCloud(target) (condition_ms,
//              both) then RegisterPair (time_ms = coarse + fine, wall clock;
//              cpu_ms = process CPU time, all threads), default options with
//              num_threads = N.
//   pcl        pcl_baseline.h on the raw clouds: prepare_ms (VoxelGrids and
//              normals, both clouds) apart from time_ms (FPFH + RANSAC + ICP),
//              the same split as craftscan's.
// Errors are of target_from_source against the ground truth: rotation angle
// (deg) and translation distance (mm).
//
// Viewpoint. In each Cyberware scan's own frame the scanner looks down the
// −z axis from +z: with PCA normals oriented towards a far point on +z, 77–98 %
// of them point away from the object's centroid (the whole bunny in the common
// frame) on every one of the ten scans, and < 1 % are grazing (vs 18–32 % for
// ±x or ±y); towards −z only 2–23 % point outwards. So viewpoint_mm =
// (0, 0, 10⁴) for craftscan and PCL alike.
//
// ring4: the scans whose names contain 000, 090, 180 and 270 (a true
// single-axis ring on the bunny) are registered 090→000, 180→090, 270→180,
// 000→270 with RegisterPair, chained, and closed with CloseLoop (edge weight =
// fitness; sample points = the corners of view 000's bounding box). Reported:
// the largest error over the views of view0_from_view[k] against the ground
// truth, before (chained) and after closure, and the closure's own figures.
//
// A registration that fails is a result (status "failed" in the table and
// the JSON), not a failed run; the exit code is 1 only for unusable data or
// I/O errors, 2 for a bad command line.
//
// Times are wall-clock medians; cpu_ms and the 1-minute load average before
// and after the run (printed and in the JSON) tell a busy machine apart.
//
// Threads: RegistrationOptions, ConditioningOptions and PCL's OMP estimators
// get N; OpenCV's global pool is set to N for the run and restored.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>

#include "command.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/registration/loop_closure.h"
#include "craftscan/pipeline/registration/registration.h"
#include "craftscan/pipeline/registration/scan_dataset.h"
#include "pcl_baseline.h"

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;
using Clock = std::chrono::steady_clock;

constexpr double kOverlapGateMm = 2.0;
constexpr double kDefaultMinOverlapPct = 50.0;
constexpr double kOffRingAxisDeg = 5.0;          // axis deviation beyond which a scan is off-ring
constexpr double kMinAxisAngleDeg = 10.0;        // smaller rotations define no axis
const cv::Vec3d kScannerViewpointMm{0, 0, 1e4};  // see the file comment
constexpr double kRadToDeg = 180.0 / CV_PI;
const char* const kRing4Tokens[4] = {"000", "090", "180", "270"};

double NaN() { return std::numeric_limits<double>::quiet_NaN(); }

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

double CpuMsSince(std::clock_t start) {  // process CPU time, all threads
  return 1000.0 * static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
}

// 1-minute load average (NaN where unavailable): timings on a shared machine
// mean little without it.
double LoadAverage() {
  double load[1];
  return getloadavg(load, 1) == 1 ? load[0] : NaN();
}

double Median(std::vector<double> values) {
  if (values.empty()) return NaN();
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

std::string Format(double value, int precision) {
  if (!std::isfinite(value)) return "-";
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", precision, value);
  return buffer;
}

Json ToJson(double value) { return std::isfinite(value) ? Json(value) : Json(nullptr); }

Json ToJson(const cv::Vec3d& v) { return Json::array({ToJson(v[0]), ToJson(v[1]), ToJson(v[2])}); }

Json ToJson(const cv::Matx44d& m) {
  Json rows = Json::array();
  for (int r = 0; r < 4; ++r) {
    rows.push_back(
        Json::array({ToJson(m(r, 0)), ToJson(m(r, 1)), ToJson(m(r, 2)), ToJson(m(r, 3))}));
  }
  return rows;
}

// Rotation vector (axis × angle, rad) of a pose's rotation.
cv::Vec3d RotationVector(const cv::Matx44d& pose) {
  const cv::Matx33d r = pose.get_minor<3, 3>(0, 0);
  cv::Vec3d w;
  cv::Rodrigues(r, w);
  return w;
}

// --- Ring detection -----------------------------------------------------------

struct Ring {
  std::vector<int> order;            // on-ring scans, sorted by angle (reference first)
  std::vector<double> angle_deg;     // per scan in file order; NaN off-ring
  std::vector<double> axis_dev_deg;  // per scan: deviation of its axis (NaN: < 10° rotation)
  cv::Vec3d axis{0, 0, 0};           // in the reference scan's frame
  int reference = -1;
};

double AxisDeviationDeg(const cv::Vec3d& a, const cv::Vec3d& b) {  // sign-free
  return std::acos(std::min(1.0, std::abs(a.dot(b)))) * kRadToDeg;
}

// See the file comment. False with *error when no axis can be found.
bool FindRing(const std::vector<RangeScan>& scans, Ring* ring, std::string* error) {
  const int n = static_cast<int>(scans.size());
  const double min_angle = kMinAxisAngleDeg / kRadToDeg;
  int best_count = 0;
  for (int r = 0; r < n; ++r) {
    std::vector<cv::Vec3d> w(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
      w[i] = RotationVector(RelativePose(scans[r].world_from_scan, scans[i].world_from_scan));
    }
    auto count_inliers = [&](const cv::Vec3d& axis) {
      int count = 0;
      for (int i = 0; i < n; ++i) {
        const double angle = cv::norm(w[i]);
        if (angle < min_angle || AxisDeviationDeg(w[i] / angle, axis) <= kOffRingAxisDeg) ++count;
      }
      return count;
    };
    for (int c = 0; c < n; ++c) {
      const double angle = cv::norm(w[c]);
      if (angle < min_angle) continue;
      cv::Vec3d axis = w[c] / angle;
      if (count_inliers(axis) <= best_count) continue;
      // Refine: principal direction of the agreeing axes.
      cv::Matx33d scatter = cv::Matx33d::zeros();
      for (int i = 0; i < n; ++i) {
        const double a = cv::norm(w[i]);
        if (a < min_angle || AxisDeviationDeg(w[i] / a, axis) > kOffRingAxisDeg) continue;
        const cv::Vec3d u = w[i] / a;
        scatter += u * u.t();
      }
      cv::Mat values, vectors;
      cv::eigen(cv::Mat(scatter), values, vectors);
      const cv::Vec3d refined(vectors.at<double>(0, 0), vectors.at<double>(0, 1),
                              vectors.at<double>(0, 2));
      const int refined_count = count_inliers(refined);
      const int count = std::max(refined_count, count_inliers(axis));
      if (count <= best_count) continue;
      best_count = count;
      ring->reference = r;
      ring->axis = refined_count >= count ? refined : axis;
    }
  }
  if (ring->reference < 0) {
    if (error)
      *error = "cannot find a turntable axis: no two scans differ by a rotation of " +
               Format(kMinAxisAngleDeg, 0) + " degrees or more";
    return false;
  }
  cv::Vec3d& axis = ring->axis;
  int largest = 0;
  for (int k = 1; k < 3; ++k) {
    if (std::abs(axis[k]) > std::abs(axis[largest])) largest = k;
  }
  if (axis[largest] < 0) axis = -axis;
  axis /= cv::norm(axis);

  ring->angle_deg.assign(static_cast<std::size_t>(n), NaN());
  ring->axis_dev_deg.assign(static_cast<std::size_t>(n), NaN());
  std::vector<std::pair<double, int>> on_ring;
  for (int i = 0; i < n; ++i) {
    const cv::Vec3d w = RotationVector(
        RelativePose(scans[ring->reference].world_from_scan, scans[i].world_from_scan));
    const double angle = cv::norm(w);
    if (angle >= min_angle) {
      ring->axis_dev_deg[i] = AxisDeviationDeg(w / angle, axis);
      if (ring->axis_dev_deg[i] > kOffRingAxisDeg) continue;
    }
    double theta = std::fmod((w.dot(axis) >= 0 ? angle : -angle) * kRadToDeg + 360.0, 360.0);
    if (i == ring->reference) theta = 0;
    ring->angle_deg[i] = theta;
    on_ring.emplace_back(theta, i);
  }
  std::stable_sort(on_ring.begin(), on_ring.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& [theta, i] : on_ring) ring->order.push_back(i);
  return true;
}

// --- Results ------------------------------------------------------------------

struct PoseError {
  double rot_deg = NaN();
  double trans_mm = NaN();
};

PoseError ErrorOf(const cv::Matx44d& estimate, const cv::Matx44d& reference) {
  return {RotationErrorDeg(estimate, reference), TranslationErrorMm(estimate, reference)};
}

struct PairResult {
  int source = 0, target = 0;
  double overlap_pct = NaN();
  cv::Matx44d ground_truth = cv::Matx44d::eye();

  RegistrationResult floor;
  PoseError floor_error;

  RegistrationResult craftscan;
  PoseError craftscan_error, craftscan_vs_floor;
  double condition_ms = NaN(), time_ms = NaN(), cpu_ms = NaN();
  std::size_t source_fine_points = 0, target_fine_points = 0;
  std::size_t source_coarse_points = 0, target_coarse_points = 0;
  std::string condition_error;

  PclBaselineResult pcl;
  PoseError pcl_error;
  double pcl_time_ms = NaN(), pcl_cpu_ms = NaN(), pcl_prepare_ms = NaN(), pcl_coarse_ms = NaN(),
         pcl_fine_ms = NaN();
};

struct Ring4Result {
  bool found = false;  // all four scans exist
  bool ok = false;
  std::string message;  // why not ok
  std::array<int, 4> views{};
  std::array<RegistrationResult, 4> edges;  // 090→000, 180→090, 270→180, 000→270
  std::array<PoseError, 4> edge_errors;
  LoopClosureResult closure;
  PoseError open_loop, closed;  // max over views 1..3
  double register_ms = 0, closure_ms = 0;
};

Json RegistrationJson(const RegistrationResult& r) {
  Json j;
  j["status"] = r.IsUsable() ? "ok" : "failed";
  if (!r.message.empty()) j["message"] = r.message;
  j["fitness"] = ToJson(r.fitness);
  j["rmse_mm"] = ToJson(r.rmse_mm);
  j["iterations"] = r.iterations;
  j["converged"] = r.converged;
  return j;
}

class RegistrationCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "registration",
        "Pairwise registration and loop closure on range scans with ground truth, vs PCL");
    sub->add_option("--bunny", dir_, "Folder with bun.conf and the scans it lists")
        ->capture_default_str();
    sub->add_option("--pairs", pair_specs_,
                    "Comma-separated source:target scan names (default: ring neighbours with "
                    ">= 50 % overlap)")
        ->delimiter(',');
    sub->add_option("--threads", threads_, "Threads for craftscan and PCL's OMP estimators")
        ->check(CLI::Range(1, 256))
        ->capture_default_str();
    sub->add_option("--repeat", repeat_, "Runs per pair and method; times = median")
        ->check(CLI::Range(1, 1000))
        ->capture_default_str();
    sub->add_option("--json", json_path_, "Write the results as JSON to this file");
    return sub;
  }

  int Run() override {
    if (!json_path_.empty()) {  // fail before the run, not after it
      const fs::path parent = fs::path(json_path_).parent_path();
      std::error_code ec;
      if (!parent.empty() && !fs::is_directory(parent, ec)) {
        return DataError("--json: folder '" + parent.string() + "' does not exist");
      }
    }
    std::error_code ec;
    if (!fs::is_directory(dir_, ec)) {
      return DataError("scan folder '" + dir_ + "' does not exist or is not a folder");
    }
    std::string error;
    if (!LoadStanfordScans(dir_, &scans_, &error)) return DataError(error);
    if (scans_.size() < 2) return DataError("'" + dir_ + "/bun.conf' lists fewer than 2 scans");
    for (const RangeScan& scan : scans_) {
      if (scan.cloud.empty()) return DataError("scan '" + scan.name + "' has no points");
    }

    std::vector<std::pair<int, int>> pairs;
    ring_found_ = FindRing(scans_, &ring_, &ring_error_);
    if (ring_found_) {
      PrintRing();
    } else if (pair_specs_.empty()) {
      return DataError(ring_error_ + " (give --pairs)");
    }
    if (pair_specs_.empty()) {
      if (int code = DefaultPairs(&pairs); code != kExitOk) return code;
    } else {
      if (int code = ParsePairs(&pairs); code != kExitOk) return code;
    }

    load_before_ = LoadAverage();
    const int previous_threads = cv::getNumThreads();
    cv::setNumThreads(threads_);
    std::vector<PairResult> results;
    for (const auto& [source, target] : pairs) results.push_back(RunPair(source, target));
    Ring4Result ring4 = RunRing4();
    cv::setNumThreads(previous_threads);
    load_after_ = LoadAverage();

    const SpeedUp speed_up = SpeedUpOverPcl(results);
    if (speed_up.pairs > 0)
      std::printf(
          "\nspeed-up over PCL, median of %d pair(s): registration %s× (PCL ms / reg ms), "
          "whole %s× ((PCL pre + PCL ms) / (cond ms + reg ms))\n",
          speed_up.pairs, Format(speed_up.registration, 1).c_str(),
          Format(speed_up.whole, 1).c_str());
    PrintRing4(ring4);
    std::printf("\nload average (1 min) before / after the run: %s / %s\n",
                Format(load_before_, 2).c_str(), Format(load_after_, 2).c_str());
    std::fflush(stdout);
    if (!json_path_.empty()) return WriteJson(results, ring4);
    return kExitOk;
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench registration: " << message << "\n";
    return kExitDataError;
  }
  static int UsageError(const std::string& message) {
    std::cerr << "craftscan-bench registration: " << message << "\nRun with --help for usage.\n";
    return kExitUsage;
  }

  // How many times faster than the PCL baseline, the median over the pairs
  // both registered: registration alone, and with each side's preparation
  // (craftscan's conditioning of both clouds, PCL's voxel grids and normals).
  struct SpeedUp {
    int pairs = 0;
    double registration = NaN(), whole = NaN();
  };
  static SpeedUp SpeedUpOverPcl(const std::vector<PairResult>& results) {
    std::vector<double> registration, whole;
    for (const PairResult& r : results) {
      if (!r.craftscan.IsUsable() || !r.pcl.ok || !(r.time_ms > 0)) continue;
      registration.push_back(r.pcl_time_ms / r.time_ms);
      whole.push_back((r.pcl_prepare_ms + r.pcl_time_ms) / (r.condition_ms + r.time_ms));
    }
    SpeedUp out;
    out.pairs = static_cast<int>(registration.size());
    if (out.pairs > 0) {
      out.registration = Median(registration);
      out.whole = Median(whole);
    }
    return out;
  }

  cv::Matx44d GroundTruth(int source, int target) const {
    return RelativePose(scans_[target].world_from_scan, scans_[source].world_from_scan);
  }

  double OverlapPct(int source, int target) {
    const std::pair<int, int> key(source, target);
    for (const auto& [k, v] : overlap_cache_) {
      if (k == key) return v;
    }
    const PointCloud moved = TransformCloud(GroundTruth(source, target), scans_[source].cloud);
    const std::vector<float> d = NearestDistancesMm(moved, scans_[target].cloud);
    const auto within =
        std::count_if(d.begin(), d.end(), [](float x) { return x <= kOverlapGateMm; });
    const double pct = d.empty() ? 0.0 : 100.0 * static_cast<double>(within) / d.size();
    overlap_cache_.emplace_back(key, pct);
    return pct;
  }

  void PrintRing() const {
    std::printf("registration: %zu scans in '%s'; ring axis (%.3f, %.3f, %.3f) in %s's frame\n",
                scans_.size(), dir_.c_str(), ring_.axis[0], ring_.axis[1], ring_.axis[2],
                scans_[ring_.reference].name.c_str());
    std::printf("  ring:");
    for (int i : ring_.order)
      std::printf(" %s (%.1f°)", scans_[i].name.c_str(), ring_.angle_deg[i]);
    std::printf("\n  off-ring (axis > %.0f° off):", kOffRingAxisDeg);
    for (std::size_t i = 0; i < scans_.size(); ++i) {
      if (std::isnan(ring_.angle_deg[i])) {
        std::printf(" %s (%.0f°)", scans_[i].name.c_str(), ring_.axis_dev_deg[i]);
      }
    }
    std::printf("\n");
    std::fflush(stdout);
  }

  int DefaultPairs(std::vector<std::pair<int, int>>* pairs) {
    const std::vector<int>& order = ring_.order;
    const int n = static_cast<int>(order.size());
    if (n < 2) return DataError("fewer than 2 scans on the turntable ring");
    std::vector<std::pair<int, int>> neighbours;
    for (int k = 1; k < n; ++k) neighbours.emplace_back(order[k], order[k - 1]);
    if (n > 2) neighbours.emplace_back(order[0], order[n - 1]);
    std::printf("  ring neighbours (source -> target, overlap within %.0f mm at ground truth):\n",
                kOverlapGateMm);
    for (const auto& [s, t] : neighbours) {
      const double pct = OverlapPct(s, t);
      const bool used = pct >= kDefaultMinOverlapPct;
      std::printf("    %s -> %s  %.1f %%%s\n", scans_[s].name.c_str(), scans_[t].name.c_str(), pct,
                  used ? "" : "  (below 50 %: skipped)");
      if (used) pairs->emplace_back(s, t);
    }
    std::printf("\n");
    std::fflush(stdout);
    if (pairs->empty()) {
      return DataError("no ring neighbour pair has at least 50 % overlap (give --pairs)");
    }
    return kExitOk;
  }

  int FindScan(const std::string& name) const {
    for (std::size_t i = 0; i < scans_.size(); ++i) {
      if (scans_[i].name == name || scans_[i].name == name + ".ply") return static_cast<int>(i);
    }
    return -1;
  }

  int ParsePairs(std::vector<std::pair<int, int>>* pairs) const {
    std::string known;
    for (const RangeScan& scan : scans_) known += (known.empty() ? "" : ", ") + scan.name;
    for (const std::string& spec : pair_specs_) {
      const std::size_t colon = spec.find(':');
      if (colon == std::string::npos || colon == 0 || colon + 1 == spec.size() ||
          spec.find(':', colon + 1) != std::string::npos) {
        return UsageError("--pairs: expected source:target, got '" + spec + "'");
      }
      const std::string names[2] = {spec.substr(0, colon), spec.substr(colon + 1)};
      int index[2];
      for (int k = 0; k < 2; ++k) {
        index[k] = FindScan(names[k]);
        if (index[k] < 0) {
          return UsageError("--pairs: unknown scan '" + names[k] +
                            "' (scans in bun.conf: " + known + ")");
        }
      }
      if (index[0] == index[1]) {
        return UsageError("--pairs: '" + spec + "' registers a scan onto itself");
      }
      pairs->emplace_back(index[0], index[1]);
    }
    return kExitOk;
  }

  ConditioningOptions Conditioning() const {
    ConditioningOptions options;
    options.viewpoint_mm = kScannerViewpointMm;
    options.num_threads = threads_;
    return options;
  }

  RegistrationOptions Registration() const {
    RegistrationOptions options;
    options.num_threads = threads_;
    return options;
  }

  PairResult RunPair(int source, int target) {
    if (!header_printed_) {
      std::printf("registration: %d thread(s), %d repeat(s); errors vs ground truth (deg / mm)\n",
                  threads_, repeat_);
      std::printf("%-26s %7s %13s %13s %13s %7s %7s %13s %7s %7s\n", "pair (source -> target)",
                  "overlap", "floor err", "craftscan err", "vs floor", "cond ms", "reg ms",
                  "PCL err", "PCL ms", "PCL pre");
      header_printed_ = true;
    }
    PairResult r;
    r.source = source;
    r.target = target;
    r.overlap_pct = OverlapPct(source, target);
    r.ground_truth = GroundTruth(source, target);
    const PointCloud& raw_source = scans_[source].cloud;
    const PointCloud& raw_target = scans_[target].cloud;

    // craftscan: conditioning and registration, K times.
    const ConditioningOptions conditioning = Conditioning();
    const RegistrationOptions options = Registration();
    std::vector<double> condition_ms, register_ms, register_cpu_ms;
    ViewCloud view_source, view_target;
    for (int k = 0; k < repeat_; ++k) {
      auto start = Clock::now();
      view_source = ConditionCloud(raw_source, conditioning);
      view_target = ConditionCloud(raw_target, conditioning);
      condition_ms.push_back(MsSince(start));
      if (!view_source.ok() || !view_target.ok()) {
        r.condition_error = !view_source.ok() ? scans_[source].name + ": " + view_source.error
                                              : scans_[target].name + ": " + view_target.error;
        break;
      }
      start = Clock::now();
      const std::clock_t cpu_start = std::clock();
      RegistrationResult result = RegisterPair(view_source, view_target, options);
      register_ms.push_back(MsSince(start));
      register_cpu_ms.push_back(CpuMsSince(cpu_start));
      if (k == 0) r.craftscan = std::move(result);
    }
    r.condition_ms = Median(condition_ms);
    r.time_ms = Median(register_ms);
    r.cpu_ms = Median(register_cpu_ms);
    if (r.condition_error.empty()) {
      r.source_fine_points = view_source.fine.size();
      r.target_fine_points = view_target.fine.size();
      r.source_coarse_points = view_source.coarse.size();
      r.target_coarse_points = view_target.coarse.size();
      r.floor = RegisterFine(view_source, view_target, r.ground_truth, options.fine, threads_);
      r.floor_error = ErrorOf(r.floor.target_from_source, r.ground_truth);
      if (r.craftscan.IsUsable()) {
        r.craftscan_error = ErrorOf(r.craftscan.target_from_source, r.ground_truth);
        if (r.floor.IsUsable()) {
          r.craftscan_vs_floor =
              ErrorOf(r.craftscan.target_from_source, r.floor.target_from_source);
        }
      }
    } else {
      r.craftscan.status = RegistrationResult::Status::kFailed;
      r.craftscan.message = "conditioning failed: " + r.condition_error;
    }

    // PCL, K times.
    PclBaselineOptions pcl_options;
    pcl_options.viewpoint_mm = kScannerViewpointMm;
    pcl_options.num_threads = threads_;
    std::vector<double> pcl_ms, pcl_cpu, pcl_prepare, pcl_coarse, pcl_fine;
    for (int k = 0; k < repeat_; ++k) {
      PclBaselineResult result = RunPclBaseline(raw_source, raw_target, pcl_options);
      pcl_ms.push_back(result.time_ms);
      pcl_cpu.push_back(result.cpu_ms);
      pcl_prepare.push_back(result.prepare_ms);
      pcl_coarse.push_back(result.coarse_ms);
      pcl_fine.push_back(result.fine_ms);
      if (k == 0) r.pcl = std::move(result);
    }
    r.pcl_time_ms = Median(pcl_ms);
    r.pcl_cpu_ms = Median(pcl_cpu);
    r.pcl_prepare_ms = Median(pcl_prepare);
    r.pcl_coarse_ms = Median(pcl_coarse);
    r.pcl_fine_ms = Median(pcl_fine);
    r.pcl_error = ErrorOf(r.pcl.target_from_source, r.ground_truth);

    auto pair_of = [](const PoseError& e) {
      return Format(e.rot_deg, 3) + "/" + Format(e.trans_mm, 2);
    };
    const std::string name = scans_[source].name + " -> " + scans_[target].name;
    std::printf("%-26s %6.1f%% %13s %13s %13s %7s %7s %13s %7s %7s\n", name.c_str(), r.overlap_pct,
                pair_of(r.floor_error).c_str(),
                r.craftscan.IsUsable() ? pair_of(r.craftscan_error).c_str() : "FAILED",
                pair_of(r.craftscan_vs_floor).c_str(), Format(r.condition_ms, 0).c_str(),
                Format(r.time_ms, 0).c_str(), pair_of(r.pcl_error).c_str(),
                Format(r.pcl_time_ms, 0).c_str(), Format(r.pcl_prepare_ms, 0).c_str());
    if (!r.craftscan.IsUsable())
      std::printf("  craftscan failed: %s\n", r.craftscan.message.c_str());
    if (!r.floor.IsUsable())
      std::printf("  floor (fine from ground truth) failed: %s\n", r.floor.message.c_str());
    if (!r.pcl.ok) std::printf("  pcl: %s\n", r.pcl.message.c_str());
    std::fflush(stdout);
    return r;
  }

  int FindByToken(const char* token) const {
    for (std::size_t i = 0; i < scans_.size(); ++i) {
      if (scans_[i].name.find(token) != std::string::npos) return static_cast<int>(i);
    }
    return -1;
  }

  Ring4Result RunRing4() const {
    Ring4Result out;
    for (int k = 0; k < 4; ++k) {
      out.views[k] = FindByToken(kRing4Tokens[k]);
      if (out.views[k] < 0) {
        out.message = std::string("no scan whose name contains '") + kRing4Tokens[k] + "'";
        return out;
      }
    }
    out.found = true;
    const ConditioningOptions conditioning = Conditioning();
    std::array<ViewCloud, 4> views;
    for (int k = 0; k < 4; ++k) {
      views[k] = ConditionCloud(scans_[out.views[k]].cloud, conditioning);
      if (!views[k].ok()) {
        out.message = scans_[out.views[k]].name + ": conditioning failed: " + views[k].error;
        return out;
      }
    }
    const RegistrationOptions options = Registration();
    std::vector<PoseEdge> edges;
    std::vector<cv::Matx44d> chained(4, cv::Matx44d::eye());
    auto start = Clock::now();
    for (int k = 0; k < 4; ++k) {
      const int source = (k + 1) % 4, target = k;  // 090→000, 180→090, 270→180, 000→270
      out.edges[k] = RegisterPair(views[source], views[target], options);
      const cv::Matx44d truth = RelativePose(scans_[out.views[target]].world_from_scan,
                                             scans_[out.views[source]].world_from_scan);
      out.edge_errors[k] = ErrorOf(out.edges[k].target_from_source, truth);
      if (!out.edges[k].IsUsable()) {
        out.message = scans_[out.views[source]].name + " -> " + scans_[out.views[target]].name +
                      ": registration failed: " + out.edges[k].message;
        return out;
      }
      PoseEdge edge;
      edge.source = source;
      edge.target = target;
      edge.target_from_source = out.edges[k].target_from_source;
      edge.weight = std::max(out.edges[k].fitness, 1e-3);
      edges.push_back(edge);
      if (source != 0) chained[source] = chained[target] * out.edges[k].target_from_source;
    }
    out.register_ms = MsSince(start);

    cv::Vec3f lo = scans_[out.views[0]].cloud.points_mm.front(), hi = lo;
    for (const cv::Vec3f& p : scans_[out.views[0]].cloud.points_mm) {
      for (int c = 0; c < 3; ++c) {
        lo[c] = std::min(lo[c], p[c]);
        hi[c] = std::max(hi[c], p[c]);
      }
    }
    std::vector<cv::Vec3d> samples;
    for (int corner = 0; corner < 8; ++corner) {
      samples.emplace_back(corner & 1 ? hi[0] : lo[0], corner & 2 ? hi[1] : lo[1],
                           corner & 4 ? hi[2] : lo[2]);
    }
    start = Clock::now();
    out.closure = CloseLoop(4, edges, chained, samples, LoopClosureOptions{});
    out.closure_ms = MsSince(start);

    out.open_loop = out.closed = PoseError{0, 0};
    for (int k = 1; k < 4; ++k) {
      const cv::Matx44d truth =
          RelativePose(scans_[out.views[0]].world_from_scan, scans_[out.views[k]].world_from_scan);
      const PoseError open = ErrorOf(chained[k], truth);
      out.open_loop.rot_deg = std::max(out.open_loop.rot_deg, open.rot_deg);
      out.open_loop.trans_mm = std::max(out.open_loop.trans_mm, open.trans_mm);
    }
    if (!out.closure.IsUsable() || out.closure.view0_from_view.size() != 4) {
      out.message =
          "CloseLoop failed: " +
          (out.closure.message.empty() ? std::string("no poses returned") : out.closure.message);
      return out;
    }
    for (int k = 1; k < 4; ++k) {
      const cv::Matx44d truth =
          RelativePose(scans_[out.views[0]].world_from_scan, scans_[out.views[k]].world_from_scan);
      const PoseError closed = ErrorOf(out.closure.view0_from_view[k], truth);
      out.closed.rot_deg = std::max(out.closed.rot_deg, closed.rot_deg);
      out.closed.trans_mm = std::max(out.closed.trans_mm, closed.trans_mm);
    }
    out.ok = true;
    return out;
  }

  void PrintRing4(const Ring4Result& r) const {
    std::printf("\nring4 (000/090/180/270): ");
    if (!r.found) {
      std::printf("skipped: %s\n", r.message.c_str());
      std::fflush(stdout);
      return;
    }
    std::printf("\n");
    for (int k = 0; k < 4; ++k) {
      const int source = (k + 1) % 4;
      const RegistrationResult& e = r.edges[k];
      std::printf("  %s -> %s  %s  err %s deg / %s mm  fitness %s\n",
                  scans_[r.views[source]].name.c_str(), scans_[r.views[k]].name.c_str(),
                  e.IsUsable() ? "ok    " : "FAILED", Format(r.edge_errors[k].rot_deg, 3).c_str(),
                  Format(r.edge_errors[k].trans_mm, 2).c_str(), Format(e.fitness, 3).c_str());
    }
    if (!r.ok) {
      std::printf("  %s\n", r.message.c_str());
    } else {
      const LoopClosureResult& c = r.closure;
      std::printf("  open loop: %.3f deg / %.2f mm RMS at the sample points\n", c.open_loop_rot_deg,
                  c.open_loop_rms_mm);
      std::printf("  closure: model %s, axis fit RMS %.2f mm, residual RMS %.2f / max %.2f mm\n",
                  ToString(c.model), c.axis_rms_mm, c.rms_mm, c.max_mm);
      std::printf(
          "  max view error vs ground truth: chained %.3f deg / %.2f mm, "
          "closed %.3f deg / %.2f mm\n",
          r.open_loop.rot_deg, r.open_loop.trans_mm, r.closed.rot_deg, r.closed.trans_mm);
      std::printf("  time: 4 registrations %.0f ms, closure %.1f ms\n", r.register_ms,
                  r.closure_ms);
    }
    std::fflush(stdout);
  }

  Json PairJson(const PairResult& r) const {
    Json j;
    j["source"] = scans_[r.source].name;
    j["target"] = scans_[r.target].name;
    j["overlap_pct"] = ToJson(r.overlap_pct);
    Json floor = RegistrationJson(r.floor);
    floor["rot_err_deg"] = ToJson(r.floor_error.rot_deg);
    floor["trans_err_mm"] = ToJson(r.floor_error.trans_mm);
    j["floor"] = std::move(floor);

    Json c = RegistrationJson(r.craftscan);
    c["rot_err_deg"] = ToJson(r.craftscan_error.rot_deg);
    c["trans_err_mm"] = ToJson(r.craftscan_error.trans_mm);
    c["vs_floor"] = {{"rot_deg", ToJson(r.craftscan_vs_floor.rot_deg)},
                     {"trans_mm", ToJson(r.craftscan_vs_floor.trans_mm)}};
    c["time_ms"] = ToJson(r.time_ms);
    c["cpu_ms"] = ToJson(r.cpu_ms);
    c["condition_ms"] = ToJson(r.condition_ms);
    c["points"] = {{"source_fine", r.source_fine_points},
                   {"target_fine", r.target_fine_points},
                   {"source_coarse", r.source_coarse_points},
                   {"target_coarse", r.target_coarse_points}};
    c["correspondences"] = r.craftscan.correspondences;
    c["target_from_source"] = ToJson(r.craftscan.target_from_source);
    j["craftscan"] = std::move(c);

    Json p;
    p["status"] = r.pcl.ok ? "ok" : "failed";
    if (!r.pcl.message.empty()) p["message"] = r.pcl.message;
    p["rot_err_deg"] = ToJson(r.pcl_error.rot_deg);
    p["trans_err_mm"] = ToJson(r.pcl_error.trans_mm);
    p["time_ms"] = ToJson(r.pcl_time_ms);
    p["cpu_ms"] = ToJson(r.pcl_cpu_ms);
    p["prepare_ms"] = ToJson(r.pcl_prepare_ms);
    p["coarse_ms"] = ToJson(r.pcl_coarse_ms);
    p["fine_ms"] = ToJson(r.pcl_fine_ms);
    p["fitness"] = ToJson(r.pcl.fitness);
    p["rmse_mm"] = ToJson(r.pcl.rmse_mm);
    p["ransac_inliers"] = r.pcl.ransac_inliers;
    p["icp_converged"] = r.pcl.icp_converged;
    p["icp_iterations"] = r.pcl.icp_iterations;
    p["points"] = {{"source", r.pcl.source_points},
                   {"target", r.pcl.target_points},
                   {"icp_source", r.pcl.icp_source_points},
                   {"icp_target", r.pcl.icp_target_points}};
    p["coarse_rot_err_deg"] =
        ToJson(RotationErrorDeg(r.pcl.coarse_target_from_source, r.ground_truth));
    p["coarse_trans_err_mm"] =
        ToJson(TranslationErrorMm(r.pcl.coarse_target_from_source, r.ground_truth));
    j["pcl"] = std::move(p);
    j["ground_truth"] = ToJson(r.ground_truth);
    return j;
  }

  Json Ring4Json(const Ring4Result& r) const {
    if (!r.ok) return nullptr;
    Json j;
    j["views"] = Json::array();
    for (int v : r.views) j["views"].push_back(scans_[v].name);
    j["rot_err_deg"] = ToJson(r.closed.rot_deg);
    j["trans_err_mm"] = ToJson(r.closed.trans_mm);
    j["open_loop"] = {{"rot_err_deg", ToJson(r.open_loop.rot_deg)},
                      {"trans_err_mm", ToJson(r.open_loop.trans_mm)}};
    const LoopClosureResult& c = r.closure;
    j["closure"] = {{"model", ToString(c.model)},
                    {"message", c.message},
                    {"open_loop_rot_deg", ToJson(c.open_loop_rot_deg)},
                    {"open_loop_rms_mm", ToJson(c.open_loop_rms_mm)},
                    {"axis_rms_mm", ToJson(c.axis_rms_mm)},
                    {"rms_mm", ToJson(c.rms_mm)},
                    {"max_mm", ToJson(c.max_mm)},
                    {"axis_direction", ToJson(c.axis_direction)},
                    {"axis_point_mm", ToJson(c.axis_point_mm)}};
    Json edges = Json::array();
    for (int k = 0; k < 4; ++k) {
      Json e = RegistrationJson(r.edges[k]);
      e["source"] = scans_[r.views[(k + 1) % 4]].name;
      e["target"] = scans_[r.views[k]].name;
      e["rot_err_deg"] = ToJson(r.edge_errors[k].rot_deg);
      e["trans_err_mm"] = ToJson(r.edge_errors[k].trans_mm);
      edges.push_back(std::move(e));
    }
    j["edges"] = std::move(edges);
    j["register_ms"] = ToJson(r.register_ms);
    j["closure_ms"] = ToJson(r.closure_ms);
    return j;
  }

  int WriteJson(const std::vector<PairResult>& results, const Ring4Result& ring4) const {
    Json root;
    root["bunny"] = dir_;
    root["threads"] = threads_;
    root["repeat"] = repeat_;
    root["viewpoint_mm"] = ToJson(kScannerViewpointMm);
    root["load_avg_1min"] = {{"before", ToJson(load_before_)}, {"after", ToJson(load_after_)}};
    Json ring;
    if (!ring_found_) {
      ring["error"] = ring_error_;
    } else {
      ring["axis"] = ToJson(ring_.axis);
      ring["reference"] = scans_[ring_.reference].name;
      ring["scans"] = Json::array();
      for (int i : ring_.order) {
        ring["scans"].push_back(
            {{"name", scans_[i].name}, {"angle_deg", ToJson(ring_.angle_deg[i])}});
      }
      ring["off_ring"] = Json::array();
      for (std::size_t i = 0; i < scans_.size(); ++i) {
        if (std::isnan(ring_.angle_deg[i])) ring["off_ring"].push_back(scans_[i].name);
      }
    }
    root["ring"] = std::move(ring);
    root["pairs"] = Json::array();
    for (const PairResult& r : results) root["pairs"].push_back(PairJson(r));
    const SpeedUp speed_up = SpeedUpOverPcl(results);
    root["speed_up_over_pcl"] = {{"pairs", speed_up.pairs},
                                 {"registration", ToJson(speed_up.registration)},
                                 {"whole", ToJson(speed_up.whole)}};
    root["ring4"] = Ring4Json(ring4);
    if (!ring4.ok) root["ring4_message"] = ring4.message;
    std::ofstream out(json_path_, std::ios::trunc);
    if (out) out << root.dump(2) << "\n";
    out.close();
    if (!out) return DataError("cannot write --json file '" + json_path_ + "'");
    return kExitOk;
  }

  std::string dir_ = "../shared/data/clouds/bunny";
  std::vector<std::string> pair_specs_;
  int threads_ = 2;
  int repeat_ = 3;
  std::string json_path_;

  std::vector<RangeScan> scans_;
  Ring ring_;
  bool ring_found_ = false;
  std::string ring_error_;
  std::vector<std::pair<std::pair<int, int>, double>> overlap_cache_;
  bool header_printed_ = false;
  double load_before_ = NaN(), load_after_ = NaN();
};

}  // namespace

std::unique_ptr<BenchCommand> MakeRegistrationCommand() {
  return std::make_unique<RegistrationCommand>();
}

}  // namespace craftscan::bench
