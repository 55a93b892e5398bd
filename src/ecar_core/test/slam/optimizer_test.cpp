#include "ecar_core/slam/optimizer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace ecar {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kDegToRad = M_PI / 180.0;
constexpr double kWidth = 640.0, kHeight = 480.0;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Intrinsics makeK() {
  Intrinsics K;
  K.fx = 500.0;
  K.fy = 510.0;
  K.cx = 320.0;
  K.cy = 240.0;
  return K;
}

Eigen::Vector3d randomUnit(std::mt19937* rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Eigen::Vector3d(n(*rng), n(*rng), n(*rng)).normalized();
}

// Moves the camera centre by `trans` metres and turns it by `rot_deg`, both
// in random directions.
SE3 perturb(const SE3& T_c_w, double trans, double rot_deg, std::mt19937* rng) {
  SE3 T_w_c = T_c_w.inverse();
  T_w_c.linear() = expSO3(randomUnit(rng) * rot_deg * kDegToRad) * T_w_c.linear();
  T_w_c.translation() += randomUnit(rng) * trans;
  return T_w_c.inverse();
}

double positionError(const SE3& a_c_w, const SE3& b_c_w) {
  return (a_c_w.inverse().translation() - b_c_w.inverse().translation()).norm();
}

double angleErrorDeg(const SE3& a, const SE3& b) {
  return rotationAngle(a.linear() * b.linear().transpose()) * kRadToDeg;
}

Eigen::Vector2d project(const Intrinsics& K, const SE3& T_c_w, const Eigen::Vector3d& p_w) {
  const Eigen::Vector3d p_c = T_c_w * p_w;
  return Eigen::Vector2d(K.fx * p_c.x() / p_c.z() + K.cx, K.fy * p_c.y() / p_c.z() + K.cy);
}

// Moves uv by 20-100 px in a random direction.
Eigen::Vector2d grossError(const Eigen::Vector2d& uv, std::mt19937* rng) {
  std::uniform_real_distribution<double> size(20.0, 100.0), angle(0.0, 2.0 * M_PI);
  const double r = size(*rng), a = angle(*rng);
  return uv + r * Eigen::Vector2d(std::cos(a), std::sin(a));
}

// ---------------------------------------------------------------- Jacobians

// Central differences of a cost function's residuals in every parameter.
std::vector<Eigen::MatrixXd> numericJacobians(const ceres::CostFunction& cost,
                                              std::vector<std::vector<double>> params) {
  const int m = cost.num_residuals();
  std::vector<Eigen::MatrixXd> jacobians;
  for (size_t b = 0; b < params.size(); ++b) {
    Eigen::MatrixXd J(m, params[b].size());
    for (size_t j = 0; j < params[b].size(); ++j) {
      const double x = params[b][j];
      const double h = 1e-5 * std::max(1.0, std::abs(x));
      Eigen::VectorXd plus(m), minus(m);
      std::vector<const double*> ptrs;
      params[b][j] = x + h;
      for (const auto& p : params) ptrs.push_back(p.data());
      EXPECT_TRUE(cost.Evaluate(ptrs.data(), plus.data(), nullptr));
      params[b][j] = x - h;
      EXPECT_TRUE(cost.Evaluate(ptrs.data(), minus.data(), nullptr));
      params[b][j] = x;
      J.col(j) = (plus - minus) / (2.0 * h);
    }
    jacobians.push_back(J);
  }
  return jacobians;
}

// Analytic (autodiff) Jacobians and residuals of a cost function.
std::vector<Eigen::MatrixXd> analyticJacobians(const ceres::CostFunction& cost,
                                               const std::vector<std::vector<double>>& params,
                                               Eigen::VectorXd* residuals) {
  const int m = cost.num_residuals();
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  std::vector<RowMajor> storage;
  std::vector<double*> jac_ptrs;
  std::vector<const double*> ptrs;
  for (const auto& p : params) {
    storage.emplace_back(m, p.size());
    ptrs.push_back(p.data());
  }
  for (auto& s : storage) jac_ptrs.push_back(s.data());
  residuals->resize(m);
  EXPECT_TRUE(cost.Evaluate(ptrs.data(), residuals->data(), jac_ptrs.data()));
  return std::vector<Eigen::MatrixXd>(storage.begin(), storage.end());
}

// A random pose [aa, t] (every few trials the identity rotation or a tiny
// one) and a point 1-10 m in front of it, seen inside the image.
void randomPoseAndPoint(int trial, std::mt19937* rng, std::vector<double>* pose,
                        Eigen::Vector3d* p_w, Eigen::Vector2d* uv) {
  std::uniform_real_distribution<double> u(-1.0, 1.0), angle(0.0, 3.0), depth(1.0, 10.0);
  Eigen::Vector3d aa = randomUnit(rng) * angle(*rng);
  if (trial % 10 == 0) aa.setZero();
  if (trial % 10 == 1) aa *= 1e-9;
  *pose = {aa.x(), aa.y(), aa.z(), 3.0 * u(*rng), 3.0 * u(*rng), 3.0 * u(*rng)};
  const SE3 T_c_w = paramsToPose(pose->data());
  const Eigen::Vector3d p_c = depth(*rng) * Eigen::Vector3d(0.6 * u(*rng), 0.45 * u(*rng), 1.0);
  *p_w = T_c_w.inverse() * p_c;
  *uv = Eigen::Vector2d(320.0 + 300.0 * u(*rng), 240.0 + 220.0 * u(*rng));
}

// The analytic Jacobians of cost (what Create() returns) and those of
// reference (autodiff on the templated functor) against central differences,
// and against each other.
void expectJacobiansMatch(const ceres::CostFunction& cost, const ceres::CostFunction& reference,
                          const std::vector<std::vector<double>>& params) {
  Eigen::VectorXd residuals, reference_residuals;
  const auto analytic = analyticJacobians(cost, params, &residuals);
  const auto autodiff = analyticJacobians(reference, params, &reference_residuals);
  const auto numeric = numericJacobians(cost, params);
  ASSERT_EQ(analytic.size(), numeric.size());
  EXPECT_LT((residuals - reference_residuals).cwiseAbs().maxCoeff(), 1e-9);
  for (size_t b = 0; b < analytic.size(); ++b) {
    const double scale = std::max(1.0, analytic[b].cwiseAbs().maxCoeff());
    EXPECT_LT((analytic[b] - numeric[b]).cwiseAbs().maxCoeff(), 1e-6 * scale)
        << "block " << b << "\nanalytic\n"
        << analytic[b] << "\nnumeric\n"
        << numeric[b];
    EXPECT_LT((autodiff[b] - numeric[b]).cwiseAbs().maxCoeff(), 1e-6 * scale) << "block " << b;
    // Not tighter: near the identity Ceres' AngleAxisRotatePoint is first order.
    EXPECT_LT((analytic[b] - autodiff[b]).cwiseAbs().maxCoeff(), 1e-7 * scale)
        << "block " << b << "\nanalytic\n"
        << analytic[b] << "\nautodiff\n"
        << autodiff[b];
  }
}

TEST(OptimizerTest, ReprojectionErrorJacobians) {
  std::mt19937 rng(7);
  const Intrinsics K = makeK();
  for (int trial = 0; trial < 100; ++trial) {
    std::vector<double> pose;
    Eigen::Vector3d p_w;
    Eigen::Vector2d uv;
    randomPoseAndPoint(trial, &rng, &pose, &p_w, &uv);
    std::unique_ptr<ceres::CostFunction> cost(ReprojectionError::Create(uv, 0.8, K));
    ASSERT_EQ(cost->num_residuals(), 2);
    ASSERT_EQ(cost->parameter_block_sizes(), std::vector<int32_t>({6, 3}));
    const ceres::AutoDiffCostFunction<ReprojectionError, 2, 6, 3> reference(
        new ReprojectionError(uv, 0.8, K));
    expectJacobiansMatch(*cost, reference, {pose, {p_w.x(), p_w.y(), p_w.z()}});
  }
}

TEST(OptimizerTest, PoseOnlyReprojectionErrorJacobians) {
  std::mt19937 rng(8);
  const Intrinsics K = makeK();
  for (int trial = 0; trial < 100; ++trial) {
    std::vector<double> pose;
    Eigen::Vector3d p_w;
    Eigen::Vector2d uv;
    randomPoseAndPoint(trial, &rng, &pose, &p_w, &uv);
    std::unique_ptr<ceres::CostFunction> cost(PoseOnlyReprojectionError::Create(p_w, uv, 0.5, K));
    ASSERT_EQ(cost->num_residuals(), 2);
    ASSERT_EQ(cost->parameter_block_sizes(), std::vector<int32_t>({6}));
    const ceres::AutoDiffCostFunction<PoseOnlyReprojectionError, 2, 6> reference(
        new PoseOnlyReprojectionError(p_w, uv, 0.5, K));
    expectJacobiansMatch(*cost, reference, {pose});
  }
}

TEST(OptimizerTest, ResidualIsScaledReprojectionError) {
  const Intrinsics K = makeK();
  std::mt19937 rng(3);
  const SE3 T_c_w = perturb(SE3::Identity(), 0.5, 30.0, &rng);
  double pose[6];
  poseToParams(T_c_w, pose);
  const Eigen::Vector3d p_w = T_c_w.inverse() * Eigen::Vector3d(0.4, -0.3, 4.0);
  const Eigen::Vector2d uv(300.0, 200.0);
  const Eigen::Vector2d expected = 0.5 * (project(K, T_c_w, p_w) - uv);
  double r[2];
  ASSERT_TRUE(PoseOnlyReprojectionError(p_w, uv, 0.5, K)(pose, r));
  EXPECT_NEAR(r[0], expected.x(), 1e-9);
  EXPECT_NEAR(r[1], expected.y(), 1e-9);
  ASSERT_TRUE(ReprojectionError(uv, 0.5, K)(pose, p_w.data(), r));
  EXPECT_NEAR(r[0], expected.x(), 1e-9);
  EXPECT_NEAR(r[1], expected.y(), 1e-9);
  // On the camera plane: no residual. Behind it: the mirrored projection
  // (the optimisers flag such observations as outliers).
  const Eigen::Vector3d on_plane = T_c_w.inverse() * Eigen::Vector3d(0.4, -0.3, 0.0);
  EXPECT_FALSE(ReprojectionError(uv, 0.5, K)(pose, on_plane.data(), r));
  EXPECT_FALSE(PoseOnlyReprojectionError(on_plane, uv, 0.5, K)(pose, r));
  const Eigen::Vector3d behind = T_c_w.inverse() * Eigen::Vector3d(0.4, -0.3, -4.0);
  ASSERT_TRUE(ReprojectionError(uv, 0.5, K)(pose, behind.data(), r));
  EXPECT_NEAR(r[0], 0.5 * (-0.1 * K.fx + K.cx - uv.x()), 1e-9);
}

TEST(OptimizerTest, PoseParamsRoundTrip) {
  std::mt19937 rng(11);
  double params[6];
  poseToParams(SE3::Identity(), params);
  for (double v : params) EXPECT_EQ(v, 0.0);
  EXPECT_TRUE(paramsToPose(params).isApprox(SE3::Identity(), 1e-15));
  for (double angle : {1e-12, 1e-6, 0.3, 2.0, M_PI - 1e-6}) {
    const Eigen::Vector3d aa = randomUnit(&rng) * angle;
    SE3 T = SE3::Identity();
    T.linear() = expSO3(aa);
    T.translation() = Eigen::Vector3d(1.0, -2.0, 3.0);
    poseToParams(T, params);
    EXPECT_LT((Eigen::Map<Eigen::Vector3d>(params) - aa).norm(), 1e-9) << angle;
    const SE3 back = paramsToPose(params);
    EXPECT_LT((back.matrix() - T.matrix()).cwiseAbs().maxCoeff(), 1e-12) << angle;
  }
}

// ------------------------------------------------------------ optimizePose

struct PoseScene {
  SE3 T_c_w;
  std::vector<PoseObservation> obs;
  std::vector<bool> is_outlier;
};

// n points 0.5-10 m in front of the camera, 1 px Gaussian pixel noise; a
// fraction of them moved by 20-100 px. (The depth range keeps rotation and
// translation apart: the ML estimate's spread is ~1 mm / 0.02 deg, so the
// tolerances below test convergence, not luck.)
PoseScene makePoseScene(int n, double outlier_ratio, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pu(0.0, kWidth), pv(0.0, kHeight), depth(0.5, 10.0);
  std::normal_distribution<double> noise(0.0, 1.0);
  const Intrinsics K = makeK();
  PoseScene scene;
  const SE3 T_w_c = lookAt(Eigen::Vector3d(1.0, 2.0, 0.5), Eigen::Vector3d(4.0, 8.0, 1.0));
  scene.T_c_w = T_w_c.inverse();
  const int num_outliers = static_cast<int>(std::lround(outlier_ratio * n));
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d px(pu(rng), pv(rng));
    const Eigen::Vector3d p_c =
        depth(rng) * Eigen::Vector3d((px.x() - K.cx) / K.fx, (px.y() - K.cy) / K.fy, 1.0);
    PoseObservation o;
    o.p_w = T_w_c * p_c;
    o.uv = px + Eigen::Vector2d(noise(rng), noise(rng));
    const bool outlier = i < num_outliers;
    if (outlier) o.uv = grossError(o.uv, &rng);
    scene.obs.push_back(o);
    scene.is_outlier.push_back(outlier);
  }
  return scene;
}

// Classification at the true pose: what a perfect optimiser would decide
// (with 1 px noise the 95% chi2 gate rejects ~5% of genuine inliers).
std::vector<bool> oracleInliers(const PoseScene& scene, double chi2_threshold) {
  const Intrinsics K = makeK();
  std::vector<bool> in;
  for (const auto& o : scene.obs) {
    in.push_back((project(K, scene.T_c_w, o.p_w) - o.uv).squaredNorm() * o.inv_sigma2 <=
                 chi2_threshold);
  }
  return in;
}

// The maximum-likelihood estimate: a long optimisation started at the truth.
SE3 optimumFromTruth(const PoseScene& scene) {
  PoseOptimizerConfig config;
  config.iterations_per_round = 100;
  SE3 T = scene.T_c_w;
  std::vector<bool> inliers;
  EXPECT_TRUE(optimizePose(makeK(), scene.obs, &T, &inliers, config).success);
  return T;
}

TEST(OptimizerTest, OptimizePoseConvergesFromPerturbedPose) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const PoseScene scene = makePoseScene(200, 0.0, seed);
    std::mt19937 rng(100 + seed);
    SE3 T = perturb(scene.T_c_w, 0.10, 5.0, &rng);
    std::vector<bool> inliers;
    const PoseOptimizerResult result = optimizePose(makeK(), scene.obs, &T, &inliers);
    ASSERT_TRUE(result.success) << seed;
    EXPECT_LT(positionError(T, scene.T_c_w), 0.002) << seed;
    EXPECT_LT(angleErrorDeg(T, scene.T_c_w), 0.05) << seed;
    const SE3 optimum = optimumFromTruth(scene);
    EXPECT_LT(positionError(T, optimum), 1e-5) << seed;
    EXPECT_LT(angleErrorDeg(T, optimum), 1e-4) << seed;
    ASSERT_EQ(inliers.size(), scene.obs.size());
    EXPECT_EQ(result.num_inliers, std::count(inliers.begin(), inliers.end(), true));
    EXPECT_GT(result.num_inliers, 180) << seed;  // ~95% pass the gate
    EXPECT_GT(result.final_cost, 0.0);
    EXPECT_LT(result.final_cost, result.num_inliers);  // 0.5 chi2, mean < 1 for inliers
  }
}

TEST(OptimizerTest, OptimizePoseRejectsGrossOutliers) {
  const PoseOptimizerConfig config;
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const PoseScene scene = makePoseScene(200, 0.2, seed);
    std::mt19937 rng(200 + seed);
    SE3 T = perturb(scene.T_c_w, 0.10, 5.0, &rng);
    std::vector<bool> inliers;
    const PoseOptimizerResult result = optimizePose(makeK(), scene.obs, &T, &inliers, config);
    ASSERT_TRUE(result.success) << seed;
    EXPECT_LT(positionError(T, scene.T_c_w), 0.002) << seed;
    EXPECT_LT(angleErrorDeg(T, scene.T_c_w), 0.05) << seed;
    const SE3 optimum = optimumFromTruth(scene);
    EXPECT_LT(positionError(T, optimum), 1e-5) << seed;
    EXPECT_LT(angleErrorDeg(T, optimum), 1e-4) << seed;

    // With 1 px noise the 95% gate rejects ~5% of genuine observations even
    // at the true pose, so "wrongly flagged" means flagged although the
    // observation passes the gate at the true pose.
    const std::vector<bool> oracle = oracleInliers(scene, config.chi2_threshold);
    int outliers = 0, outliers_flagged = 0, genuine = 0, wrongly_flagged = 0, rejected = 0;
    for (size_t i = 0; i < scene.obs.size(); ++i) {
      if (scene.is_outlier[i]) {
        ++outliers;
        outliers_flagged += inliers[i] ? 0 : 1;
      } else {
        ++genuine;
        wrongly_flagged += oracle[i] && !inliers[i] ? 1 : 0;
        rejected += inliers[i] ? 0 : 1;
      }
    }
    EXPECT_GE(outliers_flagged, 0.95 * outliers) << seed;
    EXPECT_LT(wrongly_flagged, 0.02 * genuine) << seed;
    EXPECT_LT(rejected, 0.10 * genuine) << seed;  // ~5% by the gate's definition
  }
}

TEST(OptimizerTest, OptimizePoseRespectsInitialOutlierFlagsAndRetestsThem) {
  const PoseScene scene = makePoseScene(100, 0.0, 9);
  SE3 T = scene.T_c_w;
  std::vector<bool> inliers(scene.obs.size(), true);
  inliers[0] = inliers[1] = false;  // good observations wrongly flagged by the caller
  const PoseOptimizerResult result = optimizePose(makeK(), scene.obs, &T, &inliers);
  ASSERT_TRUE(result.success);
  const std::vector<bool> oracle = oracleInliers(scene, PoseOptimizerConfig().chi2_threshold);
  EXPECT_EQ(inliers[0], oracle[0]);
  EXPECT_EQ(inliers[1], oracle[1]);
}

// optimizePose has its own solver; Ceres on the same objective (Huber on
// PoseOnlyReprojectionError, one round) is the reference it must agree with.
TEST(OptimizerTest, OptimizePoseReachesTheCeresOptimumOfItsObjective) {
  const Intrinsics K = makeK();
  PoseOptimizerConfig config;
  config.rounds = 1;  // one robust round: no reclassification between solves
  config.iterations_per_round = 50;
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const PoseScene scene = makePoseScene(200, 0.2, seed);
    std::mt19937 rng(300 + seed);
    const SE3 start = perturb(scene.T_c_w, 0.10, 5.0, &rng);

    SE3 T = start;
    std::vector<bool> inliers;
    ASSERT_TRUE(optimizePose(K, scene.obs, &T, &inliers, config).success) << seed;

    double pose[6];
    poseToParams(start, pose);
    ceres::Problem problem;
    for (const PoseObservation& o : scene.obs) {
      problem.AddResidualBlock(
          PoseOnlyReprojectionError::Create(o.p_w, o.uv, std::sqrt(o.inv_sigma2), K),
          new ceres::HuberLoss(config.huber_delta), pose);
    }
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = 200;
    options.function_tolerance = 1e-14;
    options.parameter_tolerance = 1e-14;
    options.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    ASSERT_TRUE(summary.IsSolutionUsable()) << seed;
    const SE3 reference = paramsToPose(pose);
    EXPECT_LT(positionError(T, reference), 1e-5) << seed;
    EXPECT_LT(angleErrorDeg(T, reference), 1e-4) << seed;
    EXPECT_LT(positionError(T, scene.T_c_w), 0.005) << seed;
  }
}

// The tracker composes poses with Isometry3d::inverse() (a transpose): a
// rotation slightly off SO(3) on the way in must come out as a rotation, or the
// motion model amplifies the error frame after frame.
TEST(OptimizerTest, OptimizePoseReturnsARotation) {
  const PoseScene scene = makePoseScene(100, 0.0, 6);
  SE3 T = scene.T_c_w;
  T.linear() *= 1.0 + 1e-5;
  T.linear()(0, 1) += 1e-5;
  std::vector<bool> inliers;
  ASSERT_TRUE(optimizePose(makeK(), scene.obs, &T, &inliers).success);
  EXPECT_LT((T.linear() * T.linear().transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_NEAR(T.linear().determinant(), 1.0, 1e-12);
  EXPECT_LT(positionError(T, scene.T_c_w), 0.002);
}

TEST(OptimizerTest, OptimizePoseIsThreadSafe) {
  const PoseScene scene = makePoseScene(150, 0.1, 4);
  std::mt19937 rng(44);
  const SE3 start = perturb(scene.T_c_w, 0.05, 2.0, &rng);
  SE3 reference = start;
  std::vector<bool> reference_inliers;
  optimizePose(makeK(), scene.obs, &reference, &reference_inliers);

  std::vector<SE3> poses(4, start);
  std::vector<std::vector<bool>> inliers(4);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t]() {
      for (int k = 0; k < 5; ++k) {
        poses[t] = start;
        inliers[t].clear();
        optimizePose(makeK(), scene.obs, &poses[t], &inliers[t]);
      }
    });
  }
  for (auto& thread : threads) thread.join();
  for (int t = 0; t < 4; ++t) {
    EXPECT_TRUE(poses[t].isApprox(reference, 1e-12));
    EXPECT_EQ(inliers[t], reference_inliers);
  }
}

// ------------------------------------------------------- localBundleAdjust

struct BaScene {
  BaProblem truth;
  BaProblem noisy;
  std::vector<bool> is_outlier;  // per observation
};

// Keyframes 0.3 m apart along a gently curving path, looking sideways at
// points 2-6 m away (each placed in the view of a random keyframe). The
// keyframes at both ends of the path are fixed and exact: with the gauge fixed
// at one end only, scale uncertainty grows along the path and the ML estimate
// itself ends centimetres off at 1 px noise. Free keyframes are perturbed by
// 5 cm / 0.5 deg, points by 5 cm per axis. With `second_camera`, odd
// keyframes see through it instead (devices with different cameras).
BaScene makeBaScene(int num_keyframes, int num_points, double outlier_ratio, unsigned seed,
                    const std::optional<Intrinsics>& second_camera = std::nullopt) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::uniform_real_distribution<double> pu(0.0, kWidth), pv(0.0, kHeight), depth(2.0, 6.0),
      u(0.0, 1.0);
  std::uniform_int_distribution<int> keyframe(0, num_keyframes - 1);
  BaScene scene;
  BaProblem& truth = scene.truth;
  for (int k = 0; k < num_keyframes; ++k) {
    const Eigen::Vector3d eye(0.3 * k, 0.2 * std::sin(0.6 * k), 1.5 + 0.1 * std::cos(0.4 * k));
    const Eigen::Vector3d target = eye + Eigen::Vector3d(0.5 * std::sin(0.7 * k), 10.0, 0.0);
    BaProblem::KeyFrame kf;
    kf.T_c_w = lookAt(eye, target).inverse();
    kf.K = second_camera && k % 2 == 1 ? *second_camera : makeK();
    kf.fixed = k == 0 || k == num_keyframes - 1;
    truth.keyframes.push_back(kf);
  }
  for (int p = 0; p < num_points; ++p) {
    const BaProblem::KeyFrame& seen_by = truth.keyframes[keyframe(rng)];
    const Intrinsics& K = seen_by.K;
    const SE3 T_w_c = seen_by.T_c_w.inverse();
    const Eigen::Vector3d ray((pu(rng) - K.cx) / K.fx, (pv(rng) - K.cy) / K.fy, 1.0);
    truth.points.push_back({T_w_c * (depth(rng) * ray)});
  }
  for (int p = 0; p < num_points; ++p) {
    for (int k = 0; k < num_keyframes; ++k) {
      const Eigen::Vector3d p_c = truth.keyframes[k].T_c_w * truth.points[p].p_w;
      if (p_c.z() < 0.5) continue;
      const Eigen::Vector2d uv =
          project(truth.keyframes[k].K, truth.keyframes[k].T_c_w, truth.points[p].p_w);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() >= kWidth || uv.y() >= kHeight) continue;
      BaProblem::Observation o;
      o.keyframe = k;
      o.point = p;
      o.uv = uv + Eigen::Vector2d(noise(rng), noise(rng));
      const bool outlier = u(rng) < outlier_ratio;
      if (outlier) o.uv = grossError(o.uv, &rng);
      truth.observations.push_back(o);
      scene.is_outlier.push_back(outlier);
    }
  }
  scene.noisy = truth;
  for (auto& kf : scene.noisy.keyframes) {
    if (!kf.fixed) kf.T_c_w = perturb(kf.T_c_w, 0.05, 0.5, &rng);
  }
  for (auto& point : scene.noisy.points) {
    point.p_w += 0.05 * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
  }
  return scene;
}

TEST(OptimizerTest, LocalBundleAdjustRecoversPosesAndFlagsOutliers) {
  BaScene scene = makeBaScene(10, 500, 0.05, 21);
  // A point nobody sees and one seen only through a NaN pixel: untouched.
  scene.noisy.points.push_back({Eigen::Vector3d(1.0, 8.0, 1.0)});
  scene.noisy.points.push_back({Eigen::Vector3d(2.0, 8.0, 1.0)});
  BaProblem::Observation nan_obs;
  nan_obs.keyframe = 3;
  nan_obs.point = static_cast<int>(scene.noisy.points.size()) - 1;
  nan_obs.uv = Eigen::Vector2d(kNaN, 100.0);
  scene.noisy.observations.push_back(nan_obs);
  scene.is_outlier.push_back(true);

  BaProblem ba = scene.noisy;
  const BaResult result = localBundleAdjust(&ba);
  ASSERT_TRUE(result.converged);
  EXPECT_LT(result.final_cost, result.initial_cost);
  int inliers = 0;
  for (const auto& o : ba.observations) inliers += o.outlier ? 0 : 1;
  EXPECT_LT(result.final_cost, 1.0 * inliers);  // at the noise level: 0.5 chi2 < 1 on average

  double max_position_error = 0.0, max_angle_error = 0.0, start_error = 0.0;
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    const SE3& truth = scene.truth.keyframes[k].T_c_w;
    if (ba.keyframes[k].fixed) {
      EXPECT_TRUE(ba.keyframes[k].T_c_w.isApprox(scene.noisy.keyframes[k].T_c_w, 0.0));
      continue;
    }
    max_position_error = std::max(max_position_error, positionError(ba.keyframes[k].T_c_w, truth));
    max_angle_error = std::max(max_angle_error, angleErrorDeg(ba.keyframes[k].T_c_w, truth));
    start_error = std::max(start_error, positionError(scene.noisy.keyframes[k].T_c_w, truth));
  }
  EXPECT_GT(start_error, 0.04);
  EXPECT_LT(max_position_error, 0.01);
  EXPECT_LT(max_angle_error, 0.1);

  // The ML estimate (long optimisation from the truth) is ~3 mm from the
  // truth here; 5 + 10 iterations from 5 cm off get within 2 mm of it.
  BaProblem optimum = scene.truth;
  BaConfig long_config;
  long_config.iterations_second = 200;
  ASSERT_TRUE(localBundleAdjust(&optimum, long_config).converged);
  for (size_t k = 0; k < optimum.keyframes.size(); ++k) {
    EXPECT_LT(positionError(ba.keyframes[k].T_c_w, optimum.keyframes[k].T_c_w), 0.002) << k;
  }

  int outliers = 0, outliers_flagged = 0, genuine = 0, genuine_flagged = 0, flagged = 0;
  for (size_t i = 0; i < ba.observations.size(); ++i) {
    flagged += ba.observations[i].outlier ? 1 : 0;
    if (scene.is_outlier[i]) {
      ++outliers;
      outliers_flagged += ba.observations[i].outlier ? 1 : 0;
    } else {
      ++genuine;
      genuine_flagged += ba.observations[i].outlier ? 1 : 0;
    }
  }
  EXPECT_EQ(result.num_outliers, flagged);
  EXPECT_GT(outliers, 0.03 * genuine);
  EXPECT_GE(outliers_flagged, 0.95 * outliers);
  EXPECT_LT(genuine_flagged, 0.05 * genuine);  // the 95% gate, after fitting

  const size_t n = ba.points.size();
  EXPECT_EQ(ba.points[n - 2].p_w, scene.noisy.points[n - 2].p_w);
  EXPECT_EQ(ba.points[n - 1].p_w, scene.noisy.points[n - 1].p_w);
  EXPECT_TRUE(ba.observations.back().outlier);
}

// Devices with different cameras in one window: each keyframe's observations
// are projected with its own intrinsics. Projected with one camera for all
// (what a single-camera map did), the same problem ends far from the truth.
TEST(OptimizerTest, LocalBundleAdjustKeyframesWithTheirOwnCameras) {
  const Intrinsics wide{600.0, 600.0, 400.0, 300.0};  // an 800x600 phone
  const BaScene scene = makeBaScene(10, 500, 0.0, 33, wide);
  BaProblem ba = scene.noisy;
  ASSERT_TRUE(localBundleAdjust(&ba).converged);
  double max_error = 0.0;
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    max_error =
        std::max(max_error, positionError(ba.keyframes[k].T_c_w, scene.truth.keyframes[k].T_c_w));
  }
  EXPECT_LT(max_error, 0.01);
  int flagged = 0;
  for (const auto& o : ba.observations) flagged += o.outlier ? 1 : 0;
  // About 5% of 1 px observations lie past chi2 95% (5.991).
  EXPECT_LT(flagged, static_cast<int>(ba.observations.size()) * 8 / 100);

  BaProblem one_camera = scene.noisy;
  for (auto& kf : one_camera.keyframes) kf.K = makeK();
  localBundleAdjust(&one_camera);
  int one_camera_flagged = 0;
  for (const auto& o : one_camera.observations) one_camera_flagged += o.outlier ? 1 : 0;
  EXPECT_GT(one_camera_flagged, static_cast<int>(ba.observations.size()) / 5);
}

// Monocular scale is free: a window whose only fixed keyframe is the first
// one keeps whatever scale it starts with. Odometry edges between consecutive
// keyframes (1% noise) bring a map 5% too large back to metres.
TEST(OptimizerTest, OdometryEdgesHoldTheMapsScale) {
  const BaScene scene = makeBaScene(10, 400, 0.0, 41);
  const Eigen::Vector3d c0 = scene.truth.keyframes[0].T_c_w.inverse().translation();
  const double wrong = 1.05;
  BaProblem start =
      scene.truth;  // exact observations of the true map, scaled: zero reprojection error
  for (size_t k = 0; k < start.keyframes.size(); ++k) {
    BaProblem::KeyFrame& kf = start.keyframes[k];
    kf.fixed = k == 0;
    const Eigen::Vector3d c = c0 + wrong * (kf.T_c_w.inverse().translation() - c0);
    kf.T_c_w.translation() = -(kf.T_c_w.linear() * c);
  }
  for (auto& p : start.points) p.p_w = c0 + wrong * (p.p_w - c0);
  const auto centre = [](const BaProblem& ba, size_t k) -> Eigen::Vector3d {
    return ba.keyframes[k].T_c_w.inverse().translation();
  };
  // Scale of a solution: its path length over the true one.
  const auto scale_of = [&](const BaProblem& ba) {
    double est = 0.0, truth = 0.0;
    for (size_t k = 1; k < ba.keyframes.size(); ++k) {
      est += (centre(ba, k) - centre(ba, k - 1)).norm();
      truth += (centre(scene.truth, k) - centre(scene.truth, k - 1)).norm();
    }
    return est / truth;
  };
  BaProblem without = start;
  ASSERT_TRUE(localBundleAdjust(&without).converged);
  EXPECT_NEAR(scale_of(without), wrong, 0.005);  // nothing in the images says otherwise

  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.01);
  BaProblem with = start;
  for (size_t k = 1; k < with.keyframes.size(); ++k) {
    BaProblem::OdometryEdge e;
    e.from = static_cast<int>(k - 1);
    e.to = static_cast<int>(k);
    const Eigen::Vector3d t = scene.truth.keyframes[k - 1].T_c_w * centre(scene.truth, k);
    e.t_from_to = t * (1.0 + noise(rng));
    e.sigma = 0.002 + 0.02 * t.norm();
    with.odometry.push_back(e);
  }
  BaConfig config;
  config.iterations_second = 30;
  ASSERT_TRUE(localBundleAdjust(&with, config).converged);
  EXPECT_NEAR(scale_of(with), 1.0, 0.01);
  // The residual is zero at the truth and 1/sigma per metre off.
  double residual[3];
  std::array<double, 6> a, b;
  poseToParams(scene.truth.keyframes[0].T_c_w, a.data());
  poseToParams(scene.truth.keyframes[1].T_c_w, b.data());
  const Eigen::Vector3d t01 = scene.truth.keyframes[0].T_c_w * centre(scene.truth, 1);
  OdometryTranslationError(t01, 0.5)(a.data(), b.data(), residual);
  EXPECT_LT(Eigen::Map<Eigen::Vector3d>(residual).norm(), 1e-9);
  OdometryTranslationError(t01 + Eigen::Vector3d(0.1, 0, 0), 0.5)(a.data(), b.data(), residual);
  EXPECT_NEAR(residual[0], -0.2, 1e-9);
}

TEST(OptimizerTest, LocalBundleAdjustWithoutSecondPass) {
  BaScene scene = makeBaScene(6, 200, 0.0, 5);
  BaConfig config;
  config.iterations_second = 0;
  BaProblem ba = scene.noisy;
  const BaResult result = localBundleAdjust(&ba, config);
  EXPECT_TRUE(result.converged);
  EXPECT_LT(result.final_cost, result.initial_cost);
}

// ---------------------------------------------------------- gravity prior

double tiltDeg(const SE3& T_c_w, const Eigen::Vector3d& up_c) {
  const Eigen::Vector3d map_up = T_c_w.linear() * Eigen::Vector3d::UnitZ();
  return std::atan2(map_up.cross(up_c).norm(), map_up.dot(up_c)) * kRadToDeg;
}

TEST(OptimizerTest, GravityPriorResidualIsTheTiltInSigmas) {
  const SE3 T_c_w =
      lookAt(Eigen::Vector3d(1.0, 2.0, 1.5), Eigen::Vector3d(1.5, 9.0, 1.2)).inverse();
  double params[6];
  poseToParams(T_c_w, params);
  const Eigen::Vector3d up_c = T_c_w.linear() * Eigen::Vector3d::UnitZ();
  const double sigma = 0.5 * kDegToRad;
  double r[3];
  ASSERT_TRUE(GravityPriorError(up_c, sigma)(params, r));
  EXPECT_LT(Eigen::Map<Eigen::Vector3d>(r).norm(), 1e-12);

  // A reading tilted by 2 degrees: the residual is the chord, 2 sin(1 deg), in sigmas.
  const Eigen::Vector3d tilted = expSO3(Eigen::Vector3d(2.0 * kDegToRad, 0.0, 0.0)) * up_c;
  ASSERT_TRUE(GravityPriorError(tilted, sigma)(params, r));
  EXPECT_NEAR(Eigen::Map<Eigen::Vector3d>(r).norm() * sigma, 2.0 * std::sin(1.0 * kDegToRad),
              1e-12);

  std::unique_ptr<ceres::CostFunction> cost(GravityPriorError::Create(tilted, sigma));
  const double* blocks[] = {params};
  double r2[3];
  ASSERT_TRUE(cost->Evaluate(blocks, r2, nullptr));
  for (int i = 0; i < 3; ++i) EXPECT_DOUBLE_EQ(r2[i], r[i]);
}

// A map whose every keyframe and point is turned 0.5 degrees about the world
// x axis fits its observations as well as the level one: reprojections alone
// cannot see the tilt (here nothing is fixed; in a long map it is the slow
// drift). The keyframes' gravity readings level it; yaw needs no reading.
TEST(OptimizerTest, GravityPriorLevelsATiltedMap) {
  BaScene scene = makeBaScene(8, 300, 0.0, 3);
  const Eigen::Matrix3d Q = expSO3(Eigen::Vector3d(0.5 * kDegToRad, 0.0, 0.0));
  BaProblem tilted = scene.truth;
  for (auto& kf : tilted.keyframes) {
    kf.up_c = kf.T_c_w.linear() * Eigen::Vector3d::UnitZ();  // the true up, as measured
    kf.T_c_w.linear() = kf.T_c_w.linear() * Q.transpose();
    kf.fixed = false;
  }
  for (auto& p : tilted.points) p.p_w = Q * p.p_w;

  BaConfig off;
  off.gravity_sigma_deg = 0.0;
  BaProblem without = tilted;
  ASSERT_TRUE(localBundleAdjust(&without, off).converged);
  BaProblem with = tilted;
  ASSERT_TRUE(localBundleAdjust(&with).converged);  // the default prior
  for (size_t k = 0; k < tilted.keyframes.size(); ++k) {
    const Eigen::Vector3d& up = *tilted.keyframes[k].up_c;
    EXPECT_NEAR(tiltDeg(tilted.keyframes[k].T_c_w, up), 0.5, 1e-9) << k;
    EXPECT_GT(tiltDeg(without.keyframes[k].T_c_w, up), 0.4) << k;
    EXPECT_LT(tiltDeg(with.keyframes[k].T_c_w, up), 0.05) << k;
  }
  // Keyframes without a reading, or fixed ones, get no prior.
  BaProblem no_reading = tilted;
  for (auto& kf : no_reading.keyframes) kf.up_c.reset();
  BaProblem fixed = tilted;
  fixed.keyframes[0].fixed = true;
  ASSERT_TRUE(localBundleAdjust(&no_reading).converged);
  ASSERT_TRUE(localBundleAdjust(&fixed).converged);
  for (size_t k = 0; k < tilted.keyframes.size(); ++k) {
    const Eigen::Vector3d& up = *tilted.keyframes[k].up_c;
    EXPECT_GT(tiltDeg(no_reading.keyframes[k].T_c_w, up), 0.4) << k;
  }
  EXPECT_NEAR(tiltDeg(fixed.keyframes[0].T_c_w, *tilted.keyframes[0].up_c), 0.5, 1e-9);
}

// ------------------------------------------------------------- degenerate

TEST(OptimizerTest, OptimizePoseDegenerateInputs) {
  const Intrinsics K = makeK();
  std::mt19937 rng(1);
  const SE3 start = perturb(SE3::Identity(), 0.3, 10.0, &rng);

  // No observations.
  SE3 T = start;
  std::vector<bool> inliers(3, true);
  PoseOptimizerResult result = optimizePose(K, {}, &T, &inliers);
  EXPECT_FALSE(result.success);
  EXPECT_TRUE(inliers.empty());
  EXPECT_TRUE(T.isApprox(start, 0.0));
  EXPECT_FALSE(optimizePose(K, {}, nullptr, nullptr).success);

  // Too few observations.
  PoseScene scene = makePoseScene(5, 0.0, 3);
  T = scene.T_c_w;
  result = optimizePose(K, scene.obs, &T, &inliers);
  EXPECT_FALSE(result.success);
  EXPECT_TRUE(T.isApprox(scene.T_c_w, 0.0));

  // NaN pixel, NaN point, bad information, point behind the camera: these
  // are outliers and the rest is solved.
  scene = makePoseScene(60, 0.0, 4);
  scene.obs[0].uv.x() = kNaN;
  scene.obs[1].p_w.z() = kNaN;
  scene.obs[2].inv_sigma2 = 0.0;
  const Eigen::Vector3d p_c = scene.T_c_w * scene.obs[3].p_w;
  scene.obs[3].p_w = scene.T_c_w.inverse() * Eigen::Vector3d(p_c.x(), p_c.y(), -p_c.z());
  T = scene.T_c_w;
  result = optimizePose(K, scene.obs, &T, &inliers);
  EXPECT_TRUE(result.success);
  ASSERT_EQ(inliers.size(), scene.obs.size());
  for (int i = 0; i < 4; ++i) EXPECT_FALSE(inliers[i]) << i;
  EXPECT_LT(positionError(T, scene.T_c_w), 0.01);

  // Everything behind the camera.
  for (auto& o : scene.obs) {
    const Eigen::Vector3d q = scene.T_c_w * o.p_w;
    o.p_w = scene.T_c_w.inverse() * Eigen::Vector3d(q.x(), q.y(), -std::abs(q.z()));
  }
  T = scene.T_c_w;
  result = optimizePose(K, scene.obs, &T, &inliers);
  EXPECT_FALSE(result.success);
  EXPECT_EQ(result.num_inliers, 0);

  // A non-finite starting pose.
  scene = makePoseScene(60, 0.0, 4);
  T = scene.T_c_w;
  T.translation().x() = kNaN;
  EXPECT_FALSE(optimizePose(K, scene.obs, &T, &inliers).success);
}

TEST(OptimizerTest, LocalBundleAdjustDegenerateInputs) {
  // Empty problem.
  BaProblem empty;
  BaResult result = localBundleAdjust(&empty);
  EXPECT_FALSE(result.converged);
  EXPECT_EQ(result.num_outliers, 0);
  EXPECT_FALSE(localBundleAdjust(nullptr).converged);

  // Keyframes and points but no observations: nothing moves.
  BaScene scene = makeBaScene(4, 50, 0.0, 6);
  BaProblem ba = scene.noisy;
  ba.observations.clear();
  result = localBundleAdjust(&ba);
  EXPECT_FALSE(result.converged);
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    EXPECT_TRUE(ba.keyframes[k].T_c_w.isApprox(scene.noisy.keyframes[k].T_c_w, 0.0));
  }

  // Bad observations among good ones: flagged, the rest solved.
  ba = scene.noisy;
  const size_t n = ba.observations.size();
  ba.observations[0].uv.y() = kNaN;
  ba.observations[1].keyframe = 99;
  ba.observations[2].point = -1;
  ba.observations[3].inv_sigma2 = kNaN;
  BaProblem::Observation behind = ba.observations[4];
  const Eigen::Vector3d behind_p_w =
      ba.keyframes[behind.keyframe].T_c_w.inverse() * Eigen::Vector3d(0.0, 0.0, -3.0);
  ba.points.push_back({behind_p_w});
  behind.point = static_cast<int>(ba.points.size()) - 1;
  ba.observations.push_back(behind);
  result = localBundleAdjust(&ba);
  EXPECT_TRUE(result.converged);
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(ba.observations[i].outlier) << i;
  EXPECT_TRUE(ba.observations[n].outlier);
  EXPECT_EQ(ba.points.back().p_w, behind_p_w);
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    EXPECT_TRUE(ba.keyframes[k].T_c_w.matrix().allFinite());
  }

  // Every keyframe fixed: structure-only adjustment, the poses stay.
  ba = scene.noisy;
  for (auto& kf : ba.keyframes) kf.fixed = true;
  result = localBundleAdjust(&ba);
  EXPECT_TRUE(result.converged);
  EXPECT_LT(result.final_cost, result.initial_cost);
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    EXPECT_TRUE(ba.keyframes[k].T_c_w.isApprox(scene.noisy.keyframes[k].T_c_w, 0.0));
  }

  // A non-finite keyframe: its observations are outliers, it stays as given.
  ba = scene.noisy;
  ba.keyframes[2].T_c_w.translation().x() = kNaN;
  result = localBundleAdjust(&ba);
  EXPECT_TRUE(result.converged);
  for (const auto& o : ba.observations) {
    if (o.keyframe == 2) {
      EXPECT_TRUE(o.outlier);
    }
  }
  EXPECT_TRUE(std::isnan(ba.keyframes[2].T_c_w.translation().x()));
}

}  // namespace
}  // namespace ecar
