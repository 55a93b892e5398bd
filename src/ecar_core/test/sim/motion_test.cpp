// Device trajectories: shape, speed, gravity, gyro and odometry drift.
#include "ecar_core/sim/motion.h"

#include <cmath>

#include <gtest/gtest.h>

#include "ecar_core/common/camera.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

const DeviceSpec& firstOfType(const Scene& scene, TrajectoryType type) {
  for (const auto& d : scene.devices) {
    if (d.trajectory.type == type) return d;
  }
  throw std::runtime_error("no device of that type");
}

TEST(MotionTest, CorridorWalkCoversTheCorridorAtWalkingSpeed) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const auto m = generateMotion(scene, scene.devices[0], 30.0);
  ASSERT_GT(m.size(), 300u);
  EXPECT_NEAR(m[1].timestamp - m[0].timestamp, 1.0 / 30.0, 1e-12);
  EXPECT_LT(m.front().T_w_c.translation().x(), 1.0);
  EXPECT_GT(m.back().T_w_c.translation().x(), 29.0);
  const double duration = m.back().timestamp;
  const double speed = 28.8 / duration;
  EXPECT_GT(speed, 0.8);
  EXPECT_LT(speed, 1.6);
  // Hand-held: the height bobs by centimetres, the camera looks down the corridor.
  double zmin = 1e9, zmax = -1e9, max_step = 0;
  for (size_t i = 0; i < m.size(); ++i) {
    zmin = std::min(zmin, m[i].T_w_c.translation().z());
    zmax = std::max(zmax, m[i].T_w_c.translation().z());
    if (i > 0) {
      max_step =
          std::max(max_step, (m[i].T_w_c.translation() - m[i - 1].T_w_c.translation()).norm());
    }
    EXPECT_GT(m[i].T_w_c.linear().col(2).x(), 0.8) << "camera should look along +x at " << i;
  }
  EXPECT_GT(zmax - zmin, 0.02);
  EXPECT_LT(zmax - zmin, 0.15);
  EXPECT_LT(max_step, 2.0 / 30.0);  // no jumps
}

TEST(MotionTest, GravityAndGyroAreConsistentWithThePoses) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const auto m = generateMotion(scene, scene.devices[0], 30.0, 200);
  ASSERT_EQ(m.size(), 200u);
  for (size_t i = 0; i < m.size(); ++i) {
    EXPECT_NEAR(m[i].gravity_c.norm(), kGravity, 1e-9);
    // Rotated back to the world, the reading points straight up.
    const Eigen::Vector3d up = m[i].T_w_c.linear() * m[i].gravity_c;
    EXPECT_NEAR(up.z(), kGravity, 1e-9);
  }
  // Integrating the gyro reproduces the orientation change over 1 s within 0.2 deg.
  Eigen::Matrix3d R = m[10].T_w_c.linear();
  for (size_t i = 10; i < 40; ++i) R = R * expSO3(m[i].gyro_c * (1.0 / 30.0));
  const double err = rotationAngle(R.transpose() * m[40].T_w_c.linear()) * 180.0 / M_PI;
  EXPECT_LT(err, 0.2);
}

TEST(MotionTest, HalfCircleSweeps180DegreesLookingAtTheTarget) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const DeviceSpec& dev = firstOfType(scene, TrajectoryType::kHalfCircle);
  const auto m = generateMotion(scene, dev, 30.0);
  const PinholeCamera cam(scene.camera);
  const Eigen::Vector3d c = dev.trajectory.target;
  auto angle = [&](const SE3& T) {
    const Eigen::Vector3d p = T.translation() - c;
    return std::atan2(p.y(), p.x());
  };
  double swept = 0;
  for (size_t i = 1; i < m.size(); ++i) {
    double da = angle(m[i].T_w_c) - angle(m[i - 1].T_w_c);
    if (da > M_PI) da -= 2 * M_PI;
    if (da < -M_PI) da += 2 * M_PI;
    swept += da;
    const auto px = cam.project(m[i].T_w_c.inverse() * c);
    ASSERT_TRUE(px.has_value());
    EXPECT_LT((*px - Eigen::Vector2d(cam.params().cx, cam.params().cy)).norm(), 40.0);
  }
  EXPECT_NEAR(std::fabs(swept) * 180.0 / M_PI, 180.0, 3.0);
}

TEST(MotionTest, ShakeStaysAroundItsSpot) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const DeviceSpec& dev = firstOfType(scene, TrajectoryType::kShake);
  const auto m = generateMotion(scene, dev, 30.0);
  double max_dev = 0, path = 0;
  for (size_t i = 0; i < m.size(); ++i) {
    max_dev = std::max(max_dev, (m[i].T_w_c.translation() - dev.trajectory.position).norm());
    if (i > 0) path += (m[i].T_w_c.translation() - m[i - 1].T_w_c.translation()).norm();
  }
  EXPECT_LT(max_dev, 3.5 * dev.trajectory.shake_amplitude);
  EXPECT_GT(path, 0.3);  // it does move
}

TEST(MotionTest, OdometryStartsAtIdentityAndDriftsRealistically) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const auto m = generateMotion(scene, scene.devices[0], 30.0);
  // Gravity-aligned at the first pose: no translation, same tilt as the truth.
  EXPECT_LT(m.front().T_o_c.translation().norm(), 1e-12);
  EXPECT_NEAR(m.front().T_o_c.linear().col(2).z(), m.front().T_w_c.linear().col(2).z(), 1e-9);
  // Relative motion first -> last in odometry vs truth: drift of 0.2% - 5% of the 29 m.
  const SE3 rel_gt = m.front().T_w_c.inverse() * m.back().T_w_c;
  const SE3 rel_odom = m.front().T_o_c.inverse() * m.back().T_o_c;
  const double drift = (rel_gt.translation() - rel_odom.translation()).norm();
  EXPECT_GT(drift, 0.002 * 28.8);
  EXPECT_LT(drift, 0.05 * 28.8);
  // Roll and pitch never drift: the odometry's "up" matches the truth's.
  for (const auto& s : m) {
    EXPECT_NEAR(s.T_o_c.linear().row(2).dot(s.T_w_c.linear().row(2)), 1.0, 1e-9);
  }
}

// ring_small's `blind` is walker's walk with the camera blank for 3 s from
// 4 s on: exactly those samples are marked, and the motion is walker's.
TEST(MotionTest, BlankSpanMarksItsSamplesOnly) {
  const Scene scene = loadScene(kScenes + "/ring_small.yaml");
  const auto blind = generateMotion(scene, scene.device("blind"), 30.0);
  const auto walker = generateMotion(scene, scene.device("walker"), 30.0);
  ASSERT_EQ(blind.size(), walker.size());
  int blank = 0;
  for (const MotionSample& m : blind) {
    const bool inside = m.timestamp >= 4.0 - 1e-9 && m.timestamp < 7.0 - 1e-9;
    EXPECT_EQ(m.blank, inside) << "t = " << m.timestamp;
    blank += m.blank ? 1 : 0;
  }
  EXPECT_EQ(blank, 90);
  for (const MotionSample& m : walker) EXPECT_FALSE(m.blank);
}

}  // namespace
}  // namespace ecar
