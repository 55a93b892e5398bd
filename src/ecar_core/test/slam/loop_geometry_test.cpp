// The geometry of loop closing and map merging: the robust similarity between
// matched map points, and the pose graph that spreads a loop's correction.
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "ecar_core/slam/pose_graph.h"
#include "ecar_core/slam/sim3_solver.h"

namespace ecar {
namespace {

Sim3 someSimilarity(double scale) {
  Sim3 S;
  S.scale = scale;
  S.R = expSO3(Eigen::Vector3d(0.1, -0.3, 0.7));
  S.t = Eigen::Vector3d(2.0, -1.0, 0.5);
  return S;
}

double rotationErrorDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return logSO3(a.transpose() * b).norm() * 180.0 / M_PI;
}

// A pose made from a product of similarities leaves as a rotation: the
// tracker composes it with Isometry3d::inverse(), a transpose.
TEST(PoseGraphTest, MetricPoseIsARotation) {
  Sim3 S = someSimilarity(1.3);
  for (int i = 0; i < 2000; ++i) S = S * someSimilarity(1.0) * someSimilarity(1.0).inverse();
  S.R(0, 1) += 1e-6;  // and rounding beyond that
  const SE3 T = metricPose(S);
  EXPECT_LT((T.linear().transpose() * T.linear() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_LT((T.linear() - someSimilarity(1.3).R).norm(), 1e-5);
  EXPECT_LT((T.translation() - S.t / S.scale).norm(), 1e-12);
}

// 200 pairs, 30% of them wrong, 1 cm noise: the similarity is found, and the
// wrong pairs are the outliers.
TEST(Sim3SolverTest, FindsTheSimilarityAmongOutliers) {
  for (const bool fix_scale : {false, true}) {
    const Sim3 truth = someSimilarity(fix_scale ? 1.0 : 1.3);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> coord(-5.0, 5.0);
    std::normal_distribution<double> noise(0.0, 0.01);
    std::vector<PointPair> pairs;
    std::vector<bool> wrong;
    for (int i = 0; i < 200; ++i) {
      PointPair p;
      p.source = Eigen::Vector3d(coord(rng), coord(rng), coord(rng));
      p.target = truth * p.source + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      wrong.push_back(i % 10 < 3);
      if (wrong.back()) p.target = Eigen::Vector3d(coord(rng), coord(rng), coord(rng));
      p.tolerance = 0.05;
      pairs.push_back(p);
    }
    Sim3EstimateConfig config;
    config.fix_scale = fix_scale;
    const Sim3Estimate e = estimateSim3(pairs, config);
    ASSERT_TRUE(e.success) << e.reason;
    EXPECT_NEAR(e.S.scale, truth.scale, 0.002);
    EXPECT_LT(rotationErrorDeg(e.S.R, truth.R), 0.1);
    EXPECT_LT((e.S.t - truth.t).norm(), 0.01);
    int agree = 0;
    for (size_t i = 0; i < pairs.size(); ++i) agree += e.inliers[i] == !wrong[i] ? 1 : 0;
    EXPECT_GE(agree, 198) << "inliers are the right pairs";
  }
}

TEST(Sim3SolverTest, RefusesTooFewOrUnusablePairs) {
  std::vector<PointPair> pairs(10);
  for (size_t i = 0; i < pairs.size(); ++i) {
    pairs[i].source = Eigen::Vector3d(static_cast<double>(i), i * i, 1.0);
    pairs[i].target = pairs[i].source;
  }
  Sim3Estimate e = estimateSim3(pairs);  // 20 inliers needed
  EXPECT_FALSE(e.success);
  EXPECT_NE(e.reason.find("10 usable pairs"), std::string::npos) << e.reason;
  pairs[0].source.x() = std::nan("");
  pairs[1].tolerance = 0.0;
  Sim3EstimateConfig config;
  config.min_inliers = 3;
  e = estimateSim3(pairs, config);
  ASSERT_TRUE(e.success) << e.reason;
  EXPECT_EQ(e.num_inliers, 8);
  EXPECT_FALSE(e.inliers[0]);
  EXPECT_FALSE(e.inliers[1]);
}

// A loop of 40 keyframes on a 10 m circle, walked with monocular drift: each
// relative measurement 1% too short (scale drift) and turned 0.2 degrees too
// far (yaw drift), with noise on top, so the last keyframe ends metres from
// the first. One loop edge (the true relative pose of the last to the first)
// and the pose graph close the loop and bring every keyframe back near the
// truth. (A pose graph spreads a systematic drift; random noise on the
// relative poses stays, as it must: the measurements say no more.)
TEST(PoseGraphTest, ALoopEdgeRemovesTheDrift) {
  const int n = 40;
  std::vector<Sim3> truth(n);
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * M_PI * i / n;
    SE3 T_w_c = SE3::Identity();
    T_w_c.linear() = expSO3(Eigen::Vector3d(0.0, 0.0, a + M_PI / 2)) *
                     expSO3(Eigen::Vector3d(-M_PI / 2, 0.0, 0.0));  // looking along the tangent
    T_w_c.translation() = Eigen::Vector3d(10.0 * std::cos(a), 10.0 * std::sin(a), 1.5);
    truth[i] = similarityOf(T_w_c.inverse());
  }
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 1.0);
  // Odometry-like chain: S_i_w = M_i_{i-1} S_{i-1}_w with noisy measurements M.
  std::vector<Sim3> drifted(n);
  drifted[0] = truth[0];
  std::vector<PoseGraphEdge> edges;
  for (int i = 1; i < n; ++i) {
    Sim3 m = relative(truth[i], truth[i - 1]);
    Sim3 err;
    err.R = expSO3(0.2 * M_PI / 180.0 *
                   Eigen::Vector3d(0.2 * noise(rng), 0.2 * noise(rng), 1.0 + 0.2 * noise(rng)));
    err.t = 0.002 * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    err.scale = 1.0 - 0.01 * (1.0 + 0.2 * noise(rng));
    m = err * m;
    drifted[i] = m * drifted[i - 1];
    edges.push_back({i, i - 1, m, 1.0});
  }
  double drift = 0.0;
  for (int i = 0; i < n; ++i) {
    drift = std::max(drift, (metricPose(drifted[i]).inverse().translation() -
                             metricPose(truth[i]).inverse().translation())
                                .norm());
  }
  ASSERT_GT(drift, 2.0) << "the chain must drift for the test to mean anything";
  edges.push_back({n - 1, 0, relative(truth[n - 1], truth[0]), 1.0});
  std::vector<bool> fixed(n, false);
  fixed[0] = true;
  const PoseGraphResult r = optimizePoseGraph(drifted, fixed, edges);
  ASSERT_TRUE(r.converged);
  EXPECT_LT(r.final_cost, r.initial_cost / 1000);
  // The loop is closed: the last keyframe is where it should be.
  EXPECT_LT((metricPose(r.S_c_w[n - 1]).inverse().translation() -
             metricPose(truth[n - 1]).inverse().translation())
                .norm(),
            0.05);
  double error = 0.0;
  for (int i = 0; i < n; ++i) {
    // Positions in the (possibly rescaled) map: compare through the metric pose.
    error = std::max(error, (metricPose(r.S_c_w[i]).inverse().translation() -
                             metricPose(truth[i]).inverse().translation())
                                .norm());
  }
  EXPECT_LT(error, drift / 4) << "drift " << drift << " m";
  // The fixed node did not move.
  EXPECT_LT((r.S_c_w[0].t - drifted[0].t).norm(), 1e-12);
  // SE(3) only: every scale stays 1.
  PoseGraphConfig se3;
  se3.fix_scale = true;
  const PoseGraphResult s = optimizePoseGraph(drifted, fixed, edges, se3);
  ASSERT_TRUE(s.converged);
  for (int i = 0; i < n; ++i) EXPECT_EQ(s.S_c_w[i].scale, drifted[i].scale);
}

}  // namespace
}  // namespace ecar
