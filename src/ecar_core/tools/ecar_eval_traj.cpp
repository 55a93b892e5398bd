// ecar_eval_traj: absolute and relative trajectory error of an estimate
// against ground truth, both TUM files (`timestamp tx ty tz qx qy qz qw`).
//
// Exit status: 0 on success, 1 on an evaluation error (missing or malformed
// file, too few matches), 2 on bad usage.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "ecar_core/common/error.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/io/trajectory.h"

namespace {

constexpr char kUsage[] =
    "usage: ecar_eval_traj GT EST [options]\n"
    "\n"
    "Absolute (ATE) and relative (RPE) pose error of the estimate EST against the\n"
    "ground truth GT, both TUM trajectories (timestamp tx ty tz qx qy qz qw).\n"
    "\n"
    "options:\n"
    "  --se3                 rigid alignment of EST onto GT (default)\n"
    "  --sim3                similarity alignment (also scale; monocular)\n"
    "  --no-align            no alignment: EST is already in GT's frame\n"
    "  --max-dt S            max timestamp difference to associate poses (default 0.02 s)\n"
    "  --rpe-delta D         RPE interval length in --rpe-unit (default 1)\n"
    "  --rpe-unit U          frames, seconds or meters (default seconds)\n"
    "  --summary FILE.json   write the results as JSON\n"
    "  --aligned OUT.txt     write EST aligned onto GT as a TUM trajectory\n"
    "  -h, --help            print this help\n";

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CliArgs {
  std::string gt_path;
  std::string est_path;
  std::string summary_path;  ///< empty: no JSON summary
  std::string aligned_path;  ///< empty: no aligned trajectory
  ecar::EvalOptions options;
  bool help = false;
};

double parseNumber(const std::string& flag, const std::string& text) {
  size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size()) {
    throw UsageError(flag + " expects a number, got '" + text + "'");
  }
  return value;
}

ecar::EvalOptions::RpeUnit parseRpeUnit(const std::string& text) {
  for (const auto unit :
       {ecar::EvalOptions::kFrames, ecar::EvalOptions::kSeconds, ecar::EvalOptions::kMeters}) {
    if (text == ecar::toString(unit)) return unit;
  }
  throw UsageError("--rpe-unit expects frames, seconds or meters, got '" + text + "'");
}

CliArgs parseArgs(int argc, char** argv) {
  CliArgs args;
  std::vector<std::string> positional;
  for (int k = 1; k < argc; ++k) {
    std::string flag = argv[k];
    std::string value;
    const size_t eq = flag.find('=');
    const std::string name = flag.substr(0, eq);  // "--opt=value" or "--opt value"
    if (name == "--max-dt" || name == "--rpe-delta" || name == "--rpe-unit" ||
        name == "--summary" || name == "--aligned") {
      if (eq != std::string::npos) {
        value = flag.substr(eq + 1);
        flag = name;
      } else if (k + 1 < argc) {
        value = argv[++k];
      } else {
        throw UsageError(flag + " expects a value");
      }
    }
    if (flag == "-h" || flag == "--help") {
      args.help = true;
    } else if (flag == "--se3") {
      args.options.alignment = ecar::Alignment::kSE3;
    } else if (flag == "--sim3") {
      args.options.alignment = ecar::Alignment::kSim3;
    } else if (flag == "--no-align") {
      args.options.alignment = ecar::Alignment::kNone;
    } else if (flag == "--max-dt") {
      args.options.max_dt = parseNumber(flag, value);
    } else if (flag == "--rpe-delta") {
      args.options.rpe_delta = parseNumber(flag, value);
    } else if (flag == "--rpe-unit") {
      args.options.rpe_unit = parseRpeUnit(value);
    } else if (flag == "--summary") {
      args.summary_path = value;
    } else if (flag == "--aligned") {
      args.aligned_path = value;
    } else if (flag.size() > 1 && flag[0] == '-') {
      throw UsageError("unknown option '" + flag + "'");
    } else {
      positional.push_back(flag);
    }
  }
  if (args.help) return args;
  if (positional.size() != 2) {
    throw UsageError("expected 2 trajectory files (GT EST), got " +
                     std::to_string(positional.size()));
  }
  args.gt_path = positional[0];
  args.est_path = positional[1];
  try {
    ecar::validate(args.options);
  } catch (const ecar::Error& e) {
    throw UsageError(e.what());
  }
  return args;
}

void printStatsRow(const char* label, const ecar::ErrorStats& s) {
  if (s.n == 0) {
    std::printf("%-15s %6zu  %s\n", label, s.n, "n/a (no pose pair is rpe-delta apart)");
    return;
  }
  std::printf("%-15s %6zu %10.6f %10.6f %10.6f %10.6f %10.6f %10.6f\n", label, s.n, s.rmse, s.mean,
              s.median, s.std, s.min, s.max);
}

void printReport(const CliArgs& args, size_t gt_size, size_t est_size, const ecar::AteResult& ate,
                 const ecar::RpeResult& rpe) {
  const ecar::EvalOptions& o = args.options;
  std::printf("ground truth   %s (%zu poses)\n", args.gt_path.c_str(), gt_size);
  std::printf("estimate       %s (%zu poses)\n", args.est_path.c_str(), est_size);
  std::printf("matched poses  %zu (max_dt %g s)\n", ate.matches.size(), o.max_dt);
  if (o.alignment == ecar::Alignment::kSim3) {
    std::printf("alignment      sim3, scale %.6f\n", ate.alignment.scale);
  } else {
    std::printf("alignment      %s\n", ecar::toString(o.alignment).c_str());
  }
  std::printf("RPE delta      %g %s\n\n", o.rpe_delta, ecar::toString(o.rpe_unit).c_str());
  std::printf("%-15s %6s %10s %10s %10s %10s %10s %10s\n", "", "n", "rmse", "mean", "median", "std",
              "min", "max");
  printStatsRow("ATE trans [m]", ate.translation);
  printStatsRow("RPE trans [m]", rpe.translation);
  printStatsRow("RPE rot [deg]", rpe.rotation_deg);
}

void writeSummary(const CliArgs& args, size_t gt_size, size_t est_size, const ecar::AteResult& ate,
                  const ecar::RpeResult& rpe) {
  const nlohmann::json summary = {{"gt", {{"path", args.gt_path}, {"poses", gt_size}}},
                                  {"est", {{"path", args.est_path}, {"poses", est_size}}},
                                  {"options", ecar::toJson(args.options)},
                                  {"ate", ecar::toJson(ate)},
                                  {"rpe", ecar::toJson(rpe)}};
  std::ofstream out(args.summary_path);
  out << summary.dump(2) << "\n";
  if (!out) throw ecar::Error("cannot write summary '" + args.summary_path + "'");
}

void run(const CliArgs& args) {
  const ecar::Trajectory gt = ecar::readTum(args.gt_path);
  const ecar::Trajectory est = ecar::readTum(args.est_path);
  const ecar::AteResult ate = ecar::computeAte(gt, est, args.options);
  const ecar::RpeResult rpe = ecar::computeRpe(gt, est, args.options);
  printReport(args, gt.size(), est.size(), ate, rpe);
  if (!args.summary_path.empty()) writeSummary(args, gt.size(), est.size(), ate, rpe);
  if (!args.aligned_path.empty()) {
    ecar::writeTum(args.aligned_path, ecar::applyAlignment(est, ate.alignment),
                   args.est_path + " aligned onto " + args.gt_path + " (" +
                       ecar::toString(args.options.alignment) + ")");
  }
}

}  // namespace

int main(int argc, char** argv) {
  CliArgs args;
  try {
    args = parseArgs(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "ecar_eval_traj: " << e.what() << "\n(run with --help for usage)\n";
    return 2;
  }
  if (args.help) {
    std::cout << kUsage;
    return 0;
  }
  try {
    run(args);
  } catch (const std::exception& e) {
    std::cerr << "ecar_eval_traj: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
