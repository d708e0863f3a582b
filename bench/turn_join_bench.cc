// `craftscan-bench turn-join`: joins two saved turns (turn_files.h) as
// JoinTurns does in a two-turn scan and scores the join against the truth.
//
//   craftscan-bench turn-join --dir DIR [--threads N] [--json FILE]
//
// Prints the verdict, the fit (overlap), RMSE, ambiguity and constraint, the
// time, and turn_rot_err_deg / turn_trans_err_mm (the rotation's angle
// between the join and the truth; the displacement of turn B's centroid).
// Exit 0 when joined, 1 when refused or on bad data, 2 on a bad command line.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "command.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/registration/registration.h"
#include "craftscan/pipeline/registration/turn_join.h"
#include "craftscan/pipeline/surface/fusion.h"
#include "turn_files.h"

namespace craftscan::bench {

namespace fs = std::filesystem;

bool SaveTurns(const std::string& dir, const PointCloud& turn_a, const PointCloud& turn_b,
               const cv::Matx44d& truth_a_from_b, std::string* why) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return (*why = "cannot create '" + dir + "': " + ec.message(), false);
  if (!WritePly((fs::path(dir) / "turn_a.ply").string(), turn_a, true, why)) return false;
  if (!WritePly((fs::path(dir) / "turn_b.ply").string(), turn_b, true, why)) return false;
  const std::string path = (fs::path(dir) / "truth_a_from_b.txt").string();
  std::ofstream out(path);
  out.precision(17);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out << truth_a_from_b(r, c) << (c == 3 ? '\n' : ' ');
  if (!out.flush()) return (*why = "cannot write '" + path + "'", false);
  return true;
}

namespace {

class TurnJoinCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "turn-join",
        "Join two saved turns (craftscan-bench scan --turns 2 --save-turns DIR) and score the "
        "join against the truth");
    sub->add_option("--dir", dir_, "The folder --save-turns wrote")->required();
    sub->add_option("--threads", threads_, "Threads")
        ->check(CLI::Range(1, 256))
        ->capture_default_str();
    sub->add_option("--json", json_path_, "Write the figures as JSON to this file");
    sub->add_flag("--from-truth", from_truth_,
                  "Also refine from the true join (fine ICP as the join's last step): where the "
                  "two clouds' own best fit lies against the truth");
    return sub;
  }

  int Run() override {
    PointCloud a, b;
    std::string why;
    for (auto [name, cloud] : {std::pair{"turn_a.ply", &a}, std::pair{"turn_b.ply", &b}}) {
      if (!ReadPly((fs::path(dir_) / name).string(), cloud, &why)) {
        std::cerr << "craftscan-bench turn-join: " << why << "\n";
        return kExitDataError;
      }
    }
    cv::Matx44d truth;
    {
      const std::string path = (fs::path(dir_) / "truth_a_from_b.txt").string();
      std::ifstream in(path);
      for (int i = 0; i < 16; ++i) in >> truth.val[i];
      if (!in) {
        std::cerr << "craftscan-bench turn-join: '" << path << "' needs 16 numbers\n";
        return kExitDataError;
      }
    }
    TurnJoinOptions options;
    options.num_threads = threads_;
    const TurnJoinResult j = JoinTurns(a, b, options);
    if (j.status == TurnJoinResult::Status::kFailed) {
      std::cerr << "craftscan-bench turn-join: " << j.message << "\n";
      return kExitDataError;
    }
    cv::Vec3d centre(0, 0, 0);
    for (const cv::Vec3f& p : b.points_mm) centre += cv::Vec3d(p);
    centre /= static_cast<double>(b.size());
    const cv::Vec4d c(centre[0], centre[1], centre[2], 1);
    const cv::Vec4d d = j.a_from_b * c - truth * c;
    const double rot = RotationErrorDeg(j.a_from_b, truth);
    const double trans = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    std::cout << "turn-join: " << a.size() << " + " << b.size() << " points: " << ToString(j.status)
              << ", overlap " << 100 * j.overlap << " %, RMSE " << j.rmse_mm << " mm, ambiguity "
              << j.ambiguity << " (" << j.alternative_deg << "° / " << j.alternative_mm
              << " mm, contradicted " << 100 * j.alternative_contradicted << " %), constraint "
              << j.constraint << ", " << j.hypotheses << " hypotheses, " << j.time_ms << " ms\n"
              << "  turn_rot_err_deg " << rot << " turn_trans_err_mm " << trans << "\n";
    if (!j.IsUsable()) std::cout << "  " << j.message << "\n";
    if (from_truth_) {
      ViewCloud va, vb;
      FusionOptions f;
      f.voxel_mm = options.fine_voxel_mm;
      f.refine_along_normal = false;
      va.fine = FuseClouds({a}, f, &why);
      vb.fine = FuseClouds({b}, f, &why);
      auto report = [&](const char* what, const cv::Matx44d& from, const FineOptions& fo) {
        const RegistrationResult r = RegisterFine(vb, va, from, fo, threads_);
        const cv::Vec4d e = r.target_from_source * c - truth * c;
        std::cout << "  from " << what << ": " << (r.IsUsable() ? "converged" : r.message) << " at "
                  << RotationErrorDeg(r.target_from_source, truth) << "° / "
                  << std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) << " mm, " << r.iterations
                  << " iterations\n";
        return r.target_from_source;
      };
      report("the truth", truth, options.fine);
      FineOptions longer = options.fine;
      longer.max_iterations = 2000;
      longer.min_update_mm = 1e-6;
      report("the join, 2000 iterations", j.a_from_b, longer);
      FineOptions wide = longer;
      wide.min_correspondence_mm = 2;
      report("the join, gate >= 2 mm", j.a_from_b, wide);
      FineOptions all = longer;
      all.max_source_points = 0;
      report("the join, every point", j.a_from_b, all);
      FineOptions lit = longer;
      lit.tangent_projection = false;
      report("the join, point to point", j.a_from_b, lit);
      FineOptions plane = options.fine;
      plane.method = FineMethod::kPointToPlane;
      report("the join, point-to-plane", j.a_from_b, plane);
      report("the truth, point-to-plane", truth, plane);
      plane.max_iterations = 2000;
      plane.min_update_mm = 1e-6;
      report("the join, point-to-plane 2000", j.a_from_b, plane);
    }
    if (!json_path_.empty()) {
      nlohmann::json root = {
          {"status", ToString(j.status)}, {"overlap", j.overlap},       {"rmse_mm", j.rmse_mm},
          {"ambiguity", j.ambiguity},     {"constraint", j.constraint}, {"time_ms", j.time_ms},
          {"turn_rot_err_deg", rot},      {"turn_trans_err_mm", trans}, {"message", j.message}};
      std::ofstream out(json_path_);
      out << root.dump(2) << "\n";
      if (!out.flush()) {
        std::cerr << "craftscan-bench turn-join: cannot write '" << json_path_ << "'\n";
        return kExitDataError;
      }
    }
    return j.IsUsable() ? kExitOk : kExitDataError;
  }

 private:
  std::string dir_, json_path_;
  int threads_ = 2;
  bool from_truth_ = false;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeTurnJoinCommand() { return std::make_unique<TurnJoinCommand>(); }

}  // namespace craftscan::bench
