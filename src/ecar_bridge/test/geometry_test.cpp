// geometry_msgs conversions: poses, transforms, points and vectors, and the topic names.
#include "ecar_bridge/geometry.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
namespace {

ecar::SE3 makePose(const Eigen::Vector3d& axis_angle, const Eigen::Vector3d& t) {
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = Eigen::AngleAxisd(axis_angle.norm(), axis_angle.normalized()).toRotationMatrix();
  T.translation() = t;
  return T;
}

TEST(DeviceTopicsTest, NamesAreBuiltFromTheDevice) {
  const DeviceTopics topics{"device_0"};
  EXPECT_EQ(topics.image_raw(), "device_0/camera/image_raw");
  EXPECT_EQ(topics.camera_info(), "device_0/camera/camera_info");
  EXPECT_EQ(topics.imu(), "device_0/imu");
  EXPECT_EQ(topics.odometry(), "device_0/odometry");
  EXPECT_EQ(topics.frame_done(), "device_0/frame_done");
  EXPECT_EQ(topics.player_finished(), "device_0/player/finished");
  EXPECT_EQ(topics.touch(), "device_0/touch");
  EXPECT_EQ(topics.upload(), "/device_0/upload");
  EXPECT_EQ(topics.localGraph(), "/device_0/local_graph");
  EXPECT_EQ(topics.interaction(), "/device_0/interaction");
  EXPECT_EQ(topics.interactionResult(), "/device_0/interaction_result");
  EXPECT_EQ(topics.objects(), "/device_0/objects");
  EXPECT_EQ(topics.camera_frame(), "device_0/camera");
  EXPECT_EQ(topics.camera_server_frame(), "device_0/camera_server");
  EXPECT_EQ(topics.gt_frame(), "device_0/camera_gt");
  EXPECT_EQ(topics.odom_frame(), "device_0/odom");
}

TEST(PoseTest, RoundTrip) {
  const ecar::SE3 poses[] = {
      ecar::SE3::Identity(),
      makePose(Eigen::Vector3d(0.1, -0.2, 0.3), Eigen::Vector3d(1.5, -2.0, 30.25)),
      makePose(Eigen::Vector3d(3.1, 0.0, 0.0), Eigen::Vector3d(-4, 5, -6)),  // near 180 degrees
  };
  for (const ecar::SE3& T : poses) {
    const geometry_msgs::Pose msg = toMsg(T);
    const double qn =
        std::sqrt(msg.orientation.x * msg.orientation.x + msg.orientation.y * msg.orientation.y +
                  msg.orientation.z * msg.orientation.z + msg.orientation.w * msg.orientation.w);
    EXPECT_NEAR(qn, 1.0, 1e-12);
    EXPECT_EQ(msg.position.x, T.translation().x());
    EXPECT_EQ(msg.position.y, T.translation().y());
    EXPECT_EQ(msg.position.z, T.translation().z());
    const ecar::SE3 back = fromMsg(msg);
    EXPECT_TRUE(back.matrix().isApprox(T.matrix(), 1e-12)) << back.matrix() << "\n" << T.matrix();
  }
}

TEST(PoseTest, NormalisesAQuaternionOfAnotherNorm) {
  geometry_msgs::Pose pose;
  pose.orientation.z = 2.0;  // 180 degrees about z, norm 2
  const ecar::SE3 T = fromMsg(pose);
  EXPECT_TRUE(T.linear().isApprox(Eigen::Vector3d(-1, -1, 1).asDiagonal().toDenseMatrix(), 1e-12));
}

TEST(PoseTest, RejectsNanAndZeroQuaternionNamingTheField) {
  geometry_msgs::Pose pose;
  pose.orientation.w = 1.0;
  pose.position.y = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(fromMsg(pose), ecar::Error);
  try {
    fromMsg(pose, "keyframes[3].pose");
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_EQ(std::string(e.what()), "keyframes[3].pose: non-finite position");
  }

  pose.position.y = 0.0;
  pose.orientation.x = std::numeric_limits<double>::infinity();
  EXPECT_THROW(fromMsg(pose), ecar::Error);

  pose.orientation = geometry_msgs::Quaternion();  // all zero
  EXPECT_THROW(fromMsg(pose), ecar::Error);
}

TEST(TransformTest, CarriesTheFramesAndThePose) {
  const ecar::SE3 T_w_c = makePose(Eigen::Vector3d(0.0, 0.5, 0.0), Eigen::Vector3d(1, 2, 3));
  std_msgs::Header header = testing::someHeader();
  header.frame_id = "map";
  const geometry_msgs::TransformStamped tf = toTransformMsg(T_w_c, header, "device_3/camera_gt");
  EXPECT_EQ(tf.header.frame_id, "map");
  EXPECT_EQ(tf.header.stamp, header.stamp);
  EXPECT_EQ(tf.child_frame_id, "device_3/camera_gt");
  EXPECT_EQ(tf.transform.translation.x, 1.0);
  EXPECT_EQ(tf.transform.translation.y, 2.0);
  EXPECT_EQ(tf.transform.translation.z, 3.0);
  EXPECT_TRUE(fromMsg(tf).matrix().isApprox(T_w_c.matrix(), 1e-12));
}

TEST(Vector3Test, PointAndVectorRoundTrip) {
  const Eigen::Vector3d v(1.25, -2.5, 1e-9);
  const geometry_msgs::Vector3 m = toVector3Msg(v);
  EXPECT_EQ(m.x, 1.25);
  EXPECT_EQ(m.y, -2.5);
  EXPECT_EQ(m.z, 1e-9);
  EXPECT_EQ(fromMsg(m), v);
  const geometry_msgs::Point p = toPointMsg(v);
  EXPECT_EQ(p.y, -2.5);
  EXPECT_EQ(fromMsg(p), v);
}

}  // namespace
}  // namespace ecar_bridge
