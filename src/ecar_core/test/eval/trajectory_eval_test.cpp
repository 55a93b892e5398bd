#include "ecar_core/eval/trajectory_eval.h"

#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

constexpr double kRadToDeg = 180.0 / M_PI;

// A smooth, non-planar trajectory sampled every dt seconds from t0.
Trajectory makeTrajectory(size_t n, double dt = 0.1, double t0 = 100.0) {
  Trajectory traj;
  for (size_t k = 0; k < n; ++k) {
    const double s = static_cast<double>(k) * dt;
    Vector6d xi;
    xi << 0.3 * std::sin(0.5 * s), 0.2 * std::cos(0.3 * s), 0.8 * s, 5.0 * std::cos(0.2 * s),
        4.0 * std::sin(0.3 * s), 1.5 * std::sin(0.7 * s);
    StampedPose pose;
    pose.timestamp = t0 + s;
    pose.T_w_c = expSE3(xi);
    traj.push_back(pose);
  }
  return traj;
}

Sim3 makeSim3(double scale, const Eigen::Vector3d& w, const Eigen::Vector3d& t) {
  Sim3 S;
  S.scale = scale;
  S.R = expSO3(w);
  S.t = t;
  return S;
}

void expectSim3Near(const Sim3& actual, const Sim3& expected, double tol) {
  EXPECT_NEAR(actual.scale, expected.scale, tol);
  EXPECT_TRUE(actual.R.isApprox(expected.R, tol)) << actual.R << "\nvs\n" << expected.R;
  EXPECT_TRUE((actual.t - expected.t).norm() < tol * std::max(1.0, expected.t.norm()))
      << actual.t.transpose() << " vs " << expected.t.transpose();
}

std::vector<Eigen::Vector3d> randomPoints(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::vector<Eigen::Vector3d> points(n);
  for (auto& p : points) p = Eigen::Vector3d(u(rng), u(rng), u(rng));
  return points;
}

std::vector<Eigen::Vector3d> transformed(const Sim3& S, const std::vector<Eigen::Vector3d>& pts) {
  std::vector<Eigen::Vector3d> out;
  for (const auto& p : pts) out.push_back(S * p);
  return out;
}

// ---------------------------------------------------------------- umeyama

TEST(UmeyamaTest, RecoversSim3OnNoiselessData) {
  const Sim3 S = makeSim3(2.5, {0.4, -1.1, 2.0}, {3.0, -7.0, 12.0});
  const auto src = randomPoints(50, 1);
  expectSim3Near(umeyama(src, transformed(S, src), true), S, 1e-10);
}

TEST(UmeyamaTest, RecoversSe3OnNoiselessData) {
  const Sim3 S = makeSim3(1.0, {-2.5, 0.3, 0.9}, {-1.0, 0.5, 100.0});
  const auto src = randomPoints(50, 2);
  expectSim3Near(umeyama(src, transformed(S, src), false), S, 1e-10);
  // Minimal case: three non-collinear points.
  const std::vector<Eigen::Vector3d> three = {{0, 0, 0}, {1, 0, 0}, {0, 2, 0}};
  expectSim3Near(umeyama(three, transformed(S, three), false), S, 1e-10);
}

TEST(UmeyamaTest, WithoutScaleStillFindsTheRotationOfScaledData) {
  const Sim3 S = makeSim3(3.0, {0.2, 0.5, -0.7}, {1.0, 2.0, 3.0});
  const auto src = randomPoints(40, 3);
  const Sim3 fit = umeyama(src, transformed(S, src), false);
  EXPECT_EQ(fit.scale, 1.0);
  EXPECT_TRUE(fit.R.isApprox(S.R, 1e-10));
}

TEST(UmeyamaTest, PlanarPointsGiveAProperRotation) {
  // Planar points are exactly fitted by a reflection too; Umeyama must return det(R) = +1.
  std::vector<Eigen::Vector3d> src = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 3, 0}};
  const Sim3 S = makeSim3(0.5, {1.0, 1.0, 0.0}, {0, 0, 1});
  const Sim3 fit = umeyama(src, transformed(S, src), true);
  EXPECT_NEAR(fit.R.determinant(), 1.0, 1e-12);
  expectSim3Near(fit, S, 1e-10);
}

TEST(UmeyamaTest, ThrowsOnBadInput) {
  const auto pts = randomPoints(5, 4);
  EXPECT_THROW(umeyama(pts, randomPoints(4, 5), true), Error);  // size mismatch
  const std::vector<Eigen::Vector3d> two(pts.begin(), pts.begin() + 2);
  EXPECT_THROW(umeyama(two, two, true), Error);  // fewer than 3
  const std::vector<Eigen::Vector3d> same(5, Eigen::Vector3d(1, 2, 3));
  EXPECT_THROW(umeyama(same, pts, true), Error);   // coincident src
  EXPECT_THROW(umeyama(pts, same, false), Error);  // coincident dst
  std::vector<Eigen::Vector3d> line;
  for (int k = 0; k < 6; ++k) line.push_back(Eigen::Vector3d(1, 2, 3) * k);
  EXPECT_THROW(umeyama(line, line, true), Error);  // collinear: rotation about the line is free
  auto bad = pts;
  bad[2].y() = std::nan("");
  EXPECT_THROW(umeyama(bad, pts, true), Error);
  try {
    umeyama(two, two, true);
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("at least 3"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------- stats, options

TEST(ErrorStatsTest, KnownValues) {
  const ErrorStats s = computeStats({4.0, 1.0, 3.0, 2.0});
  EXPECT_EQ(s.n, 4u);
  EXPECT_DOUBLE_EQ(s.mean, 2.5);
  EXPECT_DOUBLE_EQ(s.median, 2.5);
  EXPECT_DOUBLE_EQ(s.rmse, std::sqrt(7.5));
  EXPECT_DOUBLE_EQ(s.std, std::sqrt(1.25));
  EXPECT_EQ(s.min, 1.0);
  EXPECT_EQ(s.max, 4.0);
  EXPECT_EQ(computeStats({5.0, 1.0, 3.0}).median, 3.0);
  const ErrorStats empty = computeStats({});
  EXPECT_EQ(empty.n, 0u);
  EXPECT_TRUE(std::isnan(empty.rmse));
  EXPECT_TRUE(toJson(empty)["rmse"].is_null());
}

TEST(EvalOptionsTest, ValidateNamesTheBadField) {
  const auto expectBad = [](const EvalOptions& o, const std::string& field) {
    try {
      validate(o);
      ADD_FAILURE() << "expected an error naming " << field;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  EXPECT_NO_THROW(validate(EvalOptions()));
  EvalOptions o;
  o.max_dt = -0.1;
  expectBad(o, "max_dt");
  o = EvalOptions();
  o.rpe_delta = 0.0;
  expectBad(o, "rpe_delta");
  o.rpe_delta = std::nan("");
  expectBad(o, "rpe_delta");
  o = EvalOptions();
  o.rpe_unit = EvalOptions::kFrames;
  o.rpe_delta = 1.5;
  expectBad(o, "rpe_delta");
}

// ---------------------------------------------------------------- ATE

TEST(AteTest, TrajectoryAgainstItselfIsZero) {
  const Trajectory gt = makeTrajectory(200);
  for (const Alignment a : {Alignment::kNone, Alignment::kSE3, Alignment::kSim3}) {
    EvalOptions options;
    options.alignment = a;
    const AteResult ate = computeAte(gt, gt, options);
    EXPECT_EQ(ate.matches.size(), gt.size());
    EXPECT_EQ(ate.errors.size(), gt.size());
    EXPECT_LT(ate.translation.max, 1e-9) << toString(a);
    EXPECT_NEAR(ate.alignment.scale, 1.0, 1e-12);
  }
}

TEST(AteTest, AlignmentUndoesAKnownTransform) {
  const Trajectory gt = makeTrajectory(300);
  const Sim3 S_v_w = makeSim3(0.3, {0.1, 0.2, -2.0}, {10, -3, 1});
  const Trajectory est = applyAlignment(gt, S_v_w);  // est lives in its own world v
  EvalOptions options;
  options.alignment = Alignment::kSim3;
  const AteResult sim3 = computeAte(gt, est, options);
  EXPECT_LT(sim3.translation.rmse, 1e-9);
  expectSim3Near(sim3.alignment, S_v_w.inverse(), 1e-9);
  // The aligned estimate coincides with the ground truth, orientation included.
  const Trajectory aligned = applyAlignment(est, sim3.alignment);
  for (size_t k = 0; k < gt.size(); ++k) EXPECT_TRUE(aligned[k].T_w_c.isApprox(gt[k].T_w_c, 1e-9));
  // Without scale the error cannot vanish; without alignment it is larger still.
  options.alignment = Alignment::kSE3;
  const double se3_rmse = computeAte(gt, est, options).translation.rmse;
  options.alignment = Alignment::kNone;
  const double none_rmse = computeAte(gt, est, options).translation.rmse;
  EXPECT_GT(se3_rmse, 0.1);
  EXPECT_GT(none_rmse, se3_rmse);
}

TEST(AteTest, NoAlignmentMeasuresAConstantOffset) {
  const Trajectory gt = makeTrajectory(100);
  Trajectory est = gt;
  for (auto& pose : est) pose.T_w_c.translation() += Eigen::Vector3d(0.3, 0.0, -0.4);
  EvalOptions options;
  options.alignment = Alignment::kNone;
  const AteResult ate = computeAte(gt, est, options);
  EXPECT_NEAR(ate.translation.rmse, 0.5, 1e-12);
  EXPECT_NEAR(ate.translation.std, 0.0, 1e-12);
  options.alignment = Alignment::kSE3;
  EXPECT_LT(computeAte(gt, est, options).translation.rmse, 1e-9);
}

TEST(AteTest, IsotropicNoiseGivesSigmaSqrt3) {
  const size_t n = 20000;
  const double sigma = 0.05;
  const Trajectory gt = makeTrajectory(n, 0.01);
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, sigma);
  Trajectory est = gt;
  for (auto& pose : est) {
    pose.T_w_c.translation() += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
  }
  const Sim3 S_v_w = makeSim3(1.7, {0.5, -0.5, 1.0}, {2, 3, 4});
  for (const Alignment a : {Alignment::kSE3, Alignment::kSim3}) {
    EvalOptions options;
    options.alignment = a;
    // SE(3) test: est in a rigidly moved world; Sim(3) test: also rescaled (noise scales too).
    const Sim3 S = a == Alignment::kSim3 ? S_v_w : makeSim3(1.0, {0.5, -0.5, 1.0}, {2, 3, 4});
    const AteResult ate = computeAte(gt, applyAlignment(est, S), options);
    EXPECT_EQ(ate.translation.n, n);
    EXPECT_NEAR(ate.translation.rmse, sigma * std::sqrt(3.0), 0.02 * sigma * std::sqrt(3.0))
        << toString(a);
    // |e| of a 3-D isotropic Gaussian follows a Maxwell law: mean 2 sigma sqrt(2 / pi).
    EXPECT_NEAR(ate.translation.mean, 2.0 * sigma * std::sqrt(2.0 / M_PI), 0.02 * sigma);
    expectSim3Near(ate.alignment, S.inverse(), 1e-2);
  }
}

TEST(AteTest, AssociatesByTimestamp) {
  const Trajectory gt = makeTrajectory(200, 0.01);  // 100 Hz ground truth
  Trajectory est;
  for (size_t k = 0; k < gt.size(); k += 3) {  // ~33 Hz estimate, stamps 4 ms late
    StampedPose pose = gt[k];
    pose.timestamp += 0.004;
    est.push_back(pose);
  }
  const AteResult ate = computeAte(gt, est, EvalOptions());
  EXPECT_EQ(ate.matches.size(), est.size());
  for (size_t m = 0; m < ate.matches.size(); ++m) {
    EXPECT_EQ(ate.matches[m].first, 3 * m);
    EXPECT_EQ(ate.matches[m].second, m);
  }
  EXPECT_LT(ate.translation.rmse, 1e-9);
}

TEST(AteTest, TooFewMatchesThrowsWithAClearMessage) {
  const Trajectory gt = makeTrajectory(50);
  const Trajectory other_clock = makeTrajectory(50, 0.1, 5000.0);
  try {
    computeAte(gt, other_clock, EvalOptions());
    FAIL() << "expected ecar::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("max_dt"), std::string::npos) << e.what();
  }
  const Trajectory two_poses(gt.begin(), gt.begin() + 2);
  EXPECT_THROW(computeAte(gt, two_poses, EvalOptions()), Error);  // 3 needed to align
  EvalOptions no_align;
  no_align.alignment = Alignment::kNone;
  EXPECT_EQ(computeAte(gt, two_poses, no_align).translation.n, 2u);
}

// ---------------------------------------------------------------- RPE

// est accumulates gt's relative motions, each followed by an extra drift D.
Trajectory withConstantDrift(const Trajectory& gt, const SE3& D, const SE3& T_v_w) {
  Trajectory est = gt;
  est[0].T_w_c = T_v_w * gt[0].T_w_c;
  for (size_t k = 1; k < gt.size(); ++k) {
    est[k].T_w_c = est[k - 1].T_w_c * (gt[k - 1].T_w_c.inverse() * gt[k].T_w_c) * D;
  }
  return est;
}

TEST(RpeTest, ConstantDriftEqualsTheInjectedDrift) {
  const Trajectory gt = makeTrajectory(150);  // 10 Hz
  Vector6d xi;
  xi << 0.002, -0.001, 0.003, 0.01, 0.02, -0.005;
  const SE3 D = expSE3(xi);
  Vector6d world;
  world << 0.5, 1.0, -0.3, 4.0, 5.0, 6.0;
  const Trajectory est = withConstantDrift(gt, D, expSE3(world));

  EvalOptions options;
  options.rpe_unit = EvalOptions::kFrames;
  options.rpe_delta = 1;
  const RpeResult frames = computeRpe(gt, est, options);
  EXPECT_EQ(frames.translation.n, gt.size() - 1);
  EXPECT_NEAR(frames.translation.mean, D.translation().norm(), 1e-9);
  EXPECT_NEAR(frames.translation.max - frames.translation.min, 0.0, 1e-9);
  EXPECT_NEAR(frames.rotation_deg.mean, rotationAngle(D.linear()) * kRadToDeg, 1e-7);
  EXPECT_NEAR(frames.rotation_deg.std, 0.0, 1e-7);

  // The same interval expressed in seconds gives the same pairs.
  options.rpe_unit = EvalOptions::kSeconds;
  options.rpe_delta = 0.1;
  const RpeResult seconds = computeRpe(gt, est, options);
  EXPECT_EQ(seconds.translation.n, frames.translation.n);
  EXPECT_NEAR(seconds.translation.rmse, frames.translation.rmse, 1e-12);
  EXPECT_NEAR(seconds.rotation_deg.rmse, frames.rotation_deg.rmse, 1e-9);
}

TEST(RpeTest, TrajectoryAgainstItselfIsZeroForEveryUnit) {
  const Trajectory gt = makeTrajectory(120);
  for (const auto unit : {EvalOptions::kFrames, EvalOptions::kSeconds, EvalOptions::kMeters}) {
    EvalOptions options;
    options.rpe_unit = unit;
    options.rpe_delta = 2;
    const RpeResult rpe = computeRpe(gt, gt, options);
    EXPECT_GT(rpe.translation.n, 0u) << toString(unit);
    EXPECT_LT(rpe.translation.max, 1e-9);
    EXPECT_LT(rpe.rotation_deg.max, 1e-9);
  }
}

TEST(RpeTest, MetersUseDistanceTravelledAlongGroundTruth) {
  // Straight line at 1 m per frame: 3 m apart means 3 frames apart.
  Trajectory gt;
  for (int k = 0; k < 20; ++k) {
    StampedPose pose;
    pose.timestamp = k;
    pose.T_w_c.translation() = Eigen::Vector3d(k, 0, 0);
    gt.push_back(pose);
  }
  Trajectory est = gt;
  for (auto& pose : est) pose.T_w_c.translation() *= 1.1;  // 10% too long
  EvalOptions options;
  options.alignment = Alignment::kNone;
  options.rpe_unit = EvalOptions::kMeters;
  options.rpe_delta = 3.0;
  const RpeResult rpe = computeRpe(gt, est, options);
  EXPECT_EQ(rpe.translation.n, 17u);
  EXPECT_NEAR(rpe.translation.mean, 0.3, 1e-12);
}

TEST(RpeTest, Sim3AppliesTheFittedScale) {
  const Trajectory gt = makeTrajectory(100);
  const Trajectory est = applyAlignment(gt, makeSim3(3.0, {0.3, 0.2, 0.1}, {1, 1, 1}));
  EvalOptions options;
  options.alignment = Alignment::kSim3;
  EXPECT_LT(computeRpe(gt, est, options).translation.max, 1e-9);
  options.alignment = Alignment::kSE3;
  const RpeResult se3 = computeRpe(gt, est, options);
  EXPECT_GT(se3.translation.mean, 0.1);
  EXPECT_LT(se3.rotation_deg.max, 1e-9);  // rotations do not depend on scale
}

TEST(RpeTest, NoPairWhenDeltaExceedsTheTrajectory) {
  const Trajectory gt = makeTrajectory(20);  // 1.9 s long
  EvalOptions options;
  options.rpe_delta = 10.0;
  const RpeResult rpe = computeRpe(gt, gt, options);
  EXPECT_EQ(rpe.translation.n, 0u);
  EXPECT_TRUE(std::isnan(rpe.translation.rmse));
  EXPECT_TRUE(toJson(rpe)["translation"]["rmse"].is_null());
}

TEST(JsonTest, AteSummaryHasTheDocumentedFields) {
  const Trajectory gt = makeTrajectory(30);
  EvalOptions options;
  options.alignment = Alignment::kSim3;
  const nlohmann::json j = toJson(computeAte(gt, gt, options));
  EXPECT_EQ(j["matched"], 30);
  EXPECT_EQ(j["translation"]["n"], 30);
  EXPECT_NEAR(j["alignment"]["scale"].get<double>(), 1.0, 1e-12);
  EXPECT_EQ(j["alignment"]["rotation"].size(), 3u);
  EXPECT_EQ(j["alignment"]["translation"].size(), 3u);
  EXPECT_FALSE(j.contains("errors"));
  EXPECT_EQ(toJson(options)["alignment"], "sim3");
  EXPECT_EQ(toJson(options)["rpe_unit"], "seconds");
}

// ---------------------------------------------------------------- CLI

// The ecar_eval_traj executable is built before this test, into ECAR_TOOL_DIR
// (ECAR_EVAL_TRAJ overrides); without either it is looked for next to this
// test binary, and the CLI tests are skipped when it is not there.
std::string findTool() {
  if (const char* env = std::getenv("ECAR_EVAL_TRAJ")) return env;
#ifdef ECAR_TOOL_DIR
  return std::string(ECAR_TOOL_DIR) + "/ecar_eval_traj";
#endif
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return "";
  const fs::path tool = self.parent_path() / "ecar_eval_traj";
  return fs::exists(tool) ? tool.string() : "";
}

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    tool_ = findTool();
    if (tool_.empty()) GTEST_SKIP() << "ecar_eval_traj not found next to the test binary";
    std::string pattern = (fs::temp_directory_path() / "ecar_eval_cli_test_XXXXXX").string();
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override {
    std::error_code ec;
    if (!dir_.empty()) fs::remove_all(dir_, ec);
  }
  std::string file(const std::string& name) const { return (dir_ / name).string(); }
  // Runs the tool with `args`; returns its exit status, stdout+stderr in *output.
  int run(const std::string& args, std::string* output) const {
    const std::string log = file("log.txt");
    const std::string command = "'" + tool_ + "' " + args + " >'" + log + "' 2>&1";
    const int status = std::system(command.c_str());
    std::ifstream in(log);
    output->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }

  std::string tool_;
  fs::path dir_;
};

TEST_F(CliTest, WritesJsonSummaryAndAlignedTrajectory) {
  const Trajectory gt = makeTrajectory(200);
  Trajectory est = gt;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (auto& pose : est) {
    pose.T_w_c.translation() += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
  }
  const Sim3 S_v_w = makeSim3(0.5, {0.0, 0.0, 1.0}, {1, 2, 3});
  est = applyAlignment(est, S_v_w);
  writeTum(file("gt.txt"), gt);
  writeTum(file("est.txt"), est);

  std::string output;
  const std::string args = "'" + file("gt.txt") + "' '" + file("est.txt") +
                           "' --sim3 --rpe-delta 5 --rpe-unit frames --summary '" +
                           file("summary.json") + "' --aligned '" + file("aligned.txt") + "'";
  ASSERT_EQ(run(args, &output), 0) << output;
  EXPECT_NE(output.find("ATE trans [m]"), std::string::npos) << output;
  EXPECT_NE(output.find("scale"), std::string::npos) << output;

  std::ifstream in(file("summary.json"));
  const nlohmann::json summary = nlohmann::json::parse(in);
  EXPECT_EQ(summary["gt"]["poses"], 200);
  EXPECT_EQ(summary["options"]["alignment"], "sim3");
  EXPECT_EQ(summary["options"]["rpe_unit"], "frames");
  EXPECT_EQ(summary["ate"]["matched"], 200);
  const AteResult ate = computeAte(gt, est, [] {
    EvalOptions o;
    o.alignment = Alignment::kSim3;
    return o;
  }());
  EXPECT_NEAR(summary["ate"]["translation"]["rmse"].get<double>(), ate.translation.rmse, 1e-12);
  EXPECT_NEAR(summary["ate"]["alignment"]["scale"].get<double>(), 2.0, 0.01);
  EXPECT_EQ(summary["rpe"]["translation"]["n"], 195);

  const Trajectory aligned = readTum(file("aligned.txt"));
  ASSERT_EQ(aligned.size(), gt.size());
  EXPECT_LT((aligned[10].T_w_c.translation() - gt[10].T_w_c.translation()).norm(), 0.1);
}

TEST_F(CliTest, ErrorsExitWithOneAndUsageWithTwo) {
  writeTum(file("gt.txt"), makeTrajectory(20));
  std::string output;
  EXPECT_EQ(run("'" + file("gt.txt") + "' '" + file("missing.txt") + "'", &output), 1);
  EXPECT_EQ(output.rfind("ecar_eval_traj: ", 0), 0u) << output;
  EXPECT_NE(output.find("missing.txt"), std::string::npos) << output;

  writeTum(file("far.txt"), makeTrajectory(20, 0.1, 9999.0));
  EXPECT_EQ(run("'" + file("gt.txt") + "' '" + file("far.txt") + "'", &output), 1);
  EXPECT_NE(output.find("max_dt"), std::string::npos) << output;

  EXPECT_EQ(run("'" + file("gt.txt") + "'", &output), 2) << output;
  EXPECT_EQ(run("a b --bogus", &output), 2) << output;
  EXPECT_EQ(run("a b --max-dt abc", &output), 2) << output;
  EXPECT_EQ(run("a b --rpe-unit parsecs", &output), 2) << output;
  EXPECT_EQ(run("a b --max-dt=-1", &output), 2) << output;
  EXPECT_EQ(run("--help", &output), 0);
  EXPECT_NE(output.find("usage: ecar_eval_traj GT EST"), std::string::npos) << output;
}

}  // namespace
}  // namespace ecar
