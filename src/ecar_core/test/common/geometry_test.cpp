#include "ecar_core/common/geometry.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace ecar {
namespace {

constexpr double kTol = 1e-9;

Vector6d randomTwist(std::mt19937* rng, double max_angle) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Vector3d w(u(*rng), u(*rng), u(*rng));
  w = w.normalized() * max_angle * std::abs(u(*rng));
  Vector6d xi;
  xi << w, 3.0 * u(*rng), 3.0 * u(*rng), 3.0 * u(*rng);
  return xi;
}

Sim3 randomSim3(std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Sim3 S;
  S.scale = std::exp(u(*rng));
  S.R = expSO3(Eigen::Vector3d(u(*rng), u(*rng), u(*rng)) * 2.0);
  S.t = Eigen::Vector3d(u(*rng), u(*rng), u(*rng)) * 5.0;
  return S;
}

TEST(GeometryTest, So3ExpLogRoundTrip) {
  std::mt19937 rng(1);
  for (int k = 0; k < 200; ++k) {
    const Eigen::Vector3d w = randomTwist(&rng, 3.0).head<3>();  // angle < pi: log is unique
    const Eigen::Matrix3d R = expSO3(w);
    EXPECT_TRUE((R.transpose() * R).isIdentity(kTol));
    EXPECT_NEAR(R.determinant(), 1.0, kTol);
    EXPECT_TRUE(logSO3(R).isApprox(w, kTol) || w.norm() < kTol) << w.transpose();
    EXPECT_TRUE(expSO3(logSO3(R)).isApprox(R, kTol));
    EXPECT_NEAR(rotationAngle(R), w.norm(), 1e-7);
  }
}

TEST(GeometryTest, So3SmallAngle) {
  const Eigen::Vector3d w(1e-12, -2e-12, 3e-12);
  EXPECT_TRUE(logSO3(expSO3(w)).isApprox(w, 1e-6));
  EXPECT_TRUE(expSO3(Eigen::Vector3d::Zero()).isIdentity());
}

TEST(GeometryTest, Se3ExpLogRoundTrip) {
  std::mt19937 rng(2);
  for (int k = 0; k < 200; ++k) {
    const Vector6d xi = randomTwist(&rng, 3.0);
    const SE3 T = expSE3(xi);
    EXPECT_TRUE(logSE3(T).isApprox(xi, 1e-8)) << xi.transpose();
    EXPECT_TRUE(expSE3(logSE3(T)).isApprox(T, kTol));
  }
}

TEST(GeometryTest, Se3ExpOfPureTranslation) {
  Vector6d xi;
  xi << 0, 0, 0, 1, -2, 3;
  const SE3 T = expSE3(xi);
  EXPECT_TRUE(T.linear().isIdentity());
  EXPECT_TRUE(T.translation().isApprox(Eigen::Vector3d(1, -2, 3)));
}

TEST(GeometryTest, Sim3ComposeAndInverse) {
  std::mt19937 rng(3);
  for (int k = 0; k < 50; ++k) {
    const Sim3 A = randomSim3(&rng), B = randomSim3(&rng);
    const Eigen::Vector3d p(0.3, -1.2, 2.5);
    EXPECT_TRUE(((A * B) * p).isApprox(A * (B * p), kTol));
    EXPECT_TRUE((A * B).matrix().isApprox(A.matrix() * B.matrix(), kTol));
    EXPECT_TRUE((A.inverse() * (A * p)).isApprox(p, kTol));
    const Sim3 I = A * A.inverse();
    EXPECT_NEAR(I.scale, 1.0, kTol);
    EXPECT_TRUE(I.R.isIdentity(kTol));
    EXPECT_LT(I.t.norm(), kTol);
    EXPECT_TRUE(A.inverse().matrix().isApprox(A.matrix().inverse(), kTol));
  }
}

TEST(GeometryTest, Sim3TransformPoseMapsPositionAndComposesRotation) {
  std::mt19937 rng(4);
  const Sim3 S = randomSim3(&rng);
  const SE3 T_v_c = expSE3(randomTwist(&rng, 2.0));
  const SE3 T_w_c = S.transformPose(T_v_c);
  EXPECT_TRUE(T_w_c.translation().isApprox(S * Eigen::Vector3d(T_v_c.translation()), kTol));
  EXPECT_TRUE(T_w_c.linear().isApprox(S.R * T_v_c.linear(), kTol));
}

TEST(GeometryTest, MakeSe3UsesTumQuaternion) {
  // 90 degrees about z, TUM order (qx qy qz qw) = (0 0 sin45 cos45); Eigen ctor is (w, x, y, z).
  const double h = std::sqrt(0.5);
  const SE3 T = makeSE3(Eigen::Quaterniond(h, 0, 0, h), Eigen::Vector3d(1, 2, 3));
  EXPECT_TRUE((T.linear() * Eigen::Vector3d::UnitX()).isApprox(Eigen::Vector3d::UnitY(), kTol));
  // A non-unit quaternion is normalised.
  const SE3 T2 = makeSE3(Eigen::Quaterniond(2 * h, 0, 0, 2 * h), Eigen::Vector3d::Zero());
  EXPECT_TRUE(T2.linear().isApprox(T.linear(), kTol));
}

TEST(GeometryTest, InterpolateEndpointsAndMidpoint) {
  Vector6d xi;
  xi << 0, 0, 1.0, 2, 0, 0;
  const SE3 a = SE3::Identity(), b = expSE3(xi);
  EXPECT_TRUE(interpolate(a, b, 0.0).isApprox(a, kTol));
  EXPECT_TRUE(interpolate(a, b, 1.0).isApprox(b, kTol));
  const SE3 mid = interpolate(a, b, 0.5);
  EXPECT_NEAR(rotationAngle(mid.linear()), 0.5, kTol);
  EXPECT_TRUE(mid.translation().isApprox(0.5 * b.translation(), kTol));
}

void expectLooksAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
                   const Eigen::Vector3d& up_w) {
  const SE3 T_w_c = lookAt(eye, target, up_w);
  const Eigen::Matrix3d R = T_w_c.linear();
  EXPECT_TRUE((R.transpose() * R).isIdentity(kTol));
  EXPECT_NEAR(R.determinant(), 1.0, kTol);  // right-handed: x right, y down, z forward
  EXPECT_TRUE(T_w_c.translation().isApprox(eye, kTol));
  // The target sits on the optical axis, in front of the camera.
  const Eigen::Vector3d p_c = T_w_c.inverse() * target;
  EXPECT_NEAR(p_c.x(), 0.0, kTol);
  EXPECT_NEAR(p_c.y(), 0.0, kTol);
  EXPECT_NEAR(p_c.z(), (target - eye).norm(), kTol);
  // Image "down" (+y) points away from up_w unless looking along up_w.
  const Eigen::Vector3d forward = (target - eye).normalized();
  if (forward.cross(up_w).norm() > 1e-6) {
    EXPECT_LT(R.col(1).dot(up_w), 0.0);
    EXPECT_NEAR(R.col(0).dot(up_w), 0.0, kTol);  // x (right) is horizontal
  }
}

TEST(GeometryTest, LookAtGivesOrthonormalOpticalFrameOnTarget) {
  expectLooksAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(5, 0, 0), Eigen::Vector3d::UnitZ());
  expectLooksAt(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(-2, 4, 0.5), Eigen::Vector3d::UnitZ());
  expectLooksAt(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(4, -1, 7), Eigen::Vector3d(0, -1, 0));
  // Looking straight along up_w: any orthonormal frame on the target will do.
  expectLooksAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, 3), Eigen::Vector3d::UnitZ());
}

TEST(GeometryTest, LookAtAlongXWithZUpHasRightEqualMinusY) {
  const SE3 T_w_c = lookAt(Eigen::Vector3d::Zero(), Eigen::Vector3d(1, 0, 0));
  EXPECT_TRUE(T_w_c.linear().col(0).isApprox(-Eigen::Vector3d::UnitY(), kTol));
  EXPECT_TRUE(T_w_c.linear().col(1).isApprox(-Eigen::Vector3d::UnitZ(), kTol));
  EXPECT_TRUE(T_w_c.linear().col(2).isApprox(Eigen::Vector3d::UnitX(), kTol));
}

TEST(GeometryTest, NearestRotationIsOrthonormalAndNear) {
  const Eigen::Matrix3d R = expSO3(Eigen::Vector3d(0.3, -1.1, 0.7));
  Eigen::Matrix3d M = R;
  M(0, 1) += 2e-6;  // rounding of many products: off SO(3)
  M(2, 0) -= 1e-6;
  M.col(1) *= 1.0 + 3e-6;
  const Eigen::Matrix3d P = nearestRotation(M);
  EXPECT_LT((P.transpose() * P - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_NEAR(P.determinant(), 1.0, 1e-12);
  EXPECT_LT((P - R).norm(), 1e-5);
  EXPECT_LT((nearestRotation(R) - R).norm(), 1e-12);  // a rotation stays itself
}

TEST(GeometryTest, IsFinite) {
  SE3 T = SE3::Identity();
  EXPECT_TRUE(isFinite(T));
  T.translation().x() = std::nan("");
  EXPECT_FALSE(isFinite(T));
}

}  // namespace
}  // namespace ecar
