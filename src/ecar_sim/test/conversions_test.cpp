#include "ecar_sim/conversions.h"

#include <cmath>
#include <cstring>
#include <limits>

#include <gtest/gtest.h>
#include <sensor_msgs/image_encodings.h>
#include <Eigen/Geometry>

#include "ecar_core/common/error.h"

namespace ecar_sim {
namespace {

ecar::PinholeCamera makeCamera() {
  ecar::CameraParams p;
  p.width = 752;
  p.height = 480;
  p.fx = 458.654;
  p.fy = 457.296;
  p.cx = 367.215;
  p.cy = 248.375;
  p.dist = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.001};
  return ecar::PinholeCamera(p);
}

std_msgs::Header makeHeader() {
  std_msgs::Header h;
  h.seq = 42;
  h.stamp = ros::Time(1234, 5678);
  h.frame_id = "device_3/camera";
  return h;
}

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
  EXPECT_EQ(topics.camera_frame(), "device_0/camera");
  EXPECT_EQ(topics.gt_frame(), "device_0/camera_gt");
  EXPECT_EQ(topics.odom_frame(), "device_0/odom");
}

TEST(CameraInfoTest, FieldsFollowTheRosConvention) {
  const ecar::PinholeCamera camera = makeCamera();
  const sensor_msgs::CameraInfo info = toCameraInfo(camera, makeHeader());
  EXPECT_EQ(info.header.seq, 42u);
  EXPECT_EQ(info.header.frame_id, "device_3/camera");
  EXPECT_EQ(info.header.stamp, ros::Time(1234, 5678));
  EXPECT_EQ(info.width, 752u);
  EXPECT_EQ(info.height, 480u);
  EXPECT_EQ(info.distortion_model, "plumb_bob");
  ASSERT_EQ(info.D.size(), 5u);
  for (size_t i = 0; i < 5; ++i) EXPECT_EQ(info.D[i], camera.params().dist[i]) << "D[" << i << "]";
  const boost::array<double, 9> K = {458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1};
  const boost::array<double, 9> R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  const boost::array<double, 12> P = {458.654, 0, 367.215, 0, 0, 457.296, 248.375, 0, 0, 0, 1, 0};
  EXPECT_EQ(info.K, K);
  EXPECT_EQ(info.R, R);
  EXPECT_EQ(info.P, P);
}

TEST(CameraInfoTest, RoundTripKeepsIntrinsicsAndDistortion) {
  const ecar::PinholeCamera camera = makeCamera();
  const ecar::PinholeCamera back = fromCameraInfo(toCameraInfo(camera, makeHeader()));
  EXPECT_EQ(back.width(), camera.width());
  EXPECT_EQ(back.height(), camera.height());
  EXPECT_EQ(back.params().fx, camera.params().fx);
  EXPECT_EQ(back.params().fy, camera.params().fy);
  EXPECT_EQ(back.params().cx, camera.params().cx);
  EXPECT_EQ(back.params().cy, camera.params().cy);
  EXPECT_EQ(back.params().dist, camera.params().dist);
  EXPECT_TRUE(back.hasDistortion());
}

TEST(CameraInfoTest, AcceptsFourCoefficientsAndEmptyModel) {
  sensor_msgs::CameraInfo info = toCameraInfo(makeCamera(), makeHeader());
  info.D.resize(4);
  EXPECT_EQ(fromCameraInfo(info).params().dist[4], 0.0);

  info.distortion_model = "";
  info.D.clear();
  EXPECT_FALSE(fromCameraInfo(info).hasDistortion());

  info.distortion_model = "rational_polynomial";
  info.D = {0.1, 0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0};
  EXPECT_EQ(fromCameraInfo(info).params().dist[4], 0.001);
}

TEST(CameraInfoTest, RejectsWhatItCannotRepresent) {
  const sensor_msgs::CameraInfo good = toCameraInfo(makeCamera(), makeHeader());

  sensor_msgs::CameraInfo info = good;
  info.K.fill(0.0);  // uncalibrated, as camera drivers publish it
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.K[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.K[4] = -1.0;
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.width = 0;
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.D[2] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.D.resize(3);
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.distortion_model = "equidistant";
  info.D.resize(4);
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);

  info = good;
  info.distortion_model = "rational_polynomial";
  info.D = {0.1, 0.01, 0.0, 0.0, 0.001, 0.5, 0.0, 0.0};
  EXPECT_THROW(fromCameraInfo(info), ecar::Error);
}

TEST(PoseTest, RoundTrip) {
  const ecar::SE3 poses[] = {
      ecar::SE3::Identity(),
      makePose(Eigen::Vector3d(0.1, -0.2, 0.3), Eigen::Vector3d(1.5, -2.0, 30.25)),
      makePose(Eigen::Vector3d(3.1, 0.0, 0.0), Eigen::Vector3d(-4, 5, -6)),  // near 180 degrees
  };
  for (const ecar::SE3& T : poses) {
    const geometry_msgs::Pose msg = toPose(T);
    const double qn =
        std::sqrt(msg.orientation.x * msg.orientation.x + msg.orientation.y * msg.orientation.y +
                  msg.orientation.z * msg.orientation.z + msg.orientation.w * msg.orientation.w);
    EXPECT_NEAR(qn, 1.0, 1e-12);
    EXPECT_EQ(msg.position.x, T.translation().x());
    EXPECT_EQ(msg.position.y, T.translation().y());
    EXPECT_EQ(msg.position.z, T.translation().z());
    const ecar::SE3 back = fromPose(msg);
    EXPECT_TRUE(back.matrix().isApprox(T.matrix(), 1e-12)) << back.matrix() << "\n" << T.matrix();
  }
}

TEST(PoseTest, NormalisesAQuaternionOfAnotherNorm) {
  geometry_msgs::Pose pose;
  pose.orientation.z = 2.0;  // 180 degrees about z, norm 2
  const ecar::SE3 T = fromPose(pose);
  EXPECT_TRUE(T.linear().isApprox(Eigen::Vector3d(-1, -1, 1).asDiagonal().toDenseMatrix(), 1e-12));
}

TEST(PoseTest, RejectsNanAndZeroQuaternion) {
  geometry_msgs::Pose pose;
  pose.orientation.w = 1.0;
  pose.position.y = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(fromPose(pose), ecar::Error);

  pose.position.y = 0.0;
  pose.orientation.x = std::numeric_limits<double>::infinity();
  EXPECT_THROW(fromPose(pose), ecar::Error);

  pose.orientation = geometry_msgs::Quaternion();  // all zero
  EXPECT_THROW(fromPose(pose), ecar::Error);
}

TEST(TransformTest, CarriesTheFramesAndThePose) {
  const ecar::SE3 T_w_c = makePose(Eigen::Vector3d(0.0, 0.5, 0.0), Eigen::Vector3d(1, 2, 3));
  std_msgs::Header header = makeHeader();
  header.frame_id = "map";
  const geometry_msgs::TransformStamped tf = toTransform(T_w_c, header, "device_3/camera_gt");
  EXPECT_EQ(tf.header.frame_id, "map");
  EXPECT_EQ(tf.header.stamp, header.stamp);
  EXPECT_EQ(tf.child_frame_id, "device_3/camera_gt");
  EXPECT_EQ(tf.transform.translation.x, 1.0);
  EXPECT_EQ(tf.transform.translation.y, 2.0);
  EXPECT_EQ(tf.transform.translation.z, 3.0);
  geometry_msgs::Pose pose;
  pose.position.x = tf.transform.translation.x;
  pose.position.y = tf.transform.translation.y;
  pose.position.z = tf.transform.translation.z;
  pose.orientation = tf.transform.rotation;
  EXPECT_TRUE(fromPose(pose).matrix().isApprox(T_w_c.matrix(), 1e-12));
}

TEST(ImuTest, CarriesAccelerationAndRateWithoutOrientation) {
  ecar::ImuSample sample;
  sample.timestamp = 3.5;
  sample.acc_c = Eigen::Vector3d(0.1, -9.8, 0.3);
  sample.gyro_c = Eigen::Vector3d(0.01, 0.02, -0.03);
  const sensor_msgs::Imu imu = toImu(sample, makeHeader());
  EXPECT_EQ(imu.header.frame_id, "device_3/camera");
  EXPECT_EQ(imu.orientation_covariance[0], -1.0);
  EXPECT_EQ(fromVector3(imu.linear_acceleration), sample.acc_c);
  EXPECT_EQ(fromVector3(imu.angular_velocity), sample.gyro_c);
  EXPECT_EQ(imu.linear_acceleration_covariance[0], 0.0);  // unknown, but present
}

TEST(TouchTest, CarriesPixelPhaseColourAndWidth) {
  ecar::TouchEvent e;
  e.timestamp = 12.5;
  e.frame = 7;
  e.uv = Eigen::Vector2d(320.25, 100.5);
  e.r = 1;
  e.g = 2;
  e.b = 250;
  e.width = 0.05;
  const struct {
    ecar::TouchPhase phase;
    uint8_t expected;
  } phases[] = {{ecar::TouchPhase::kBegin, ecar_msgs::Touch::BEGIN},
                {ecar::TouchPhase::kMove, ecar_msgs::Touch::MOVE},
                {ecar::TouchPhase::kEnd, ecar_msgs::Touch::END}};
  for (const auto& c : phases) {
    e.phase = c.phase;
    const ecar_msgs::Touch m = toTouchMsg(e, makeHeader());
    EXPECT_EQ(m.phase, c.expected);
    EXPECT_EQ(m.header.stamp, ros::Time(1234, 5678));
    EXPECT_EQ(m.header.frame_id, "device_3/camera");
    EXPECT_EQ(m.u, 320.25f);
    EXPECT_EQ(m.v, 100.5f);
    EXPECT_EQ(m.r, 1);
    EXPECT_EQ(m.g, 2);
    EXPECT_EQ(m.b, 250);
    EXPECT_FLOAT_EQ(m.width, 0.05f);
  }
}

TEST(ImageTest, EncodingFollowsTheMatType) {
  struct Case {
    int type;
    const char* encoding;
  };
  const Case cases[] = {{CV_8UC1, sensor_msgs::image_encodings::MONO8.c_str()},
                        {CV_8UC3, sensor_msgs::image_encodings::BGR8.c_str()},
                        {CV_16UC1, sensor_msgs::image_encodings::MONO16.c_str()}};
  for (const Case& c : cases) {
    cv::Mat image(3, 5, c.type);
    cv::randu(image, 0, 255);
    const sensor_msgs::ImagePtr msg = toImageMsg(image, makeHeader());
    ASSERT_TRUE(msg);
    EXPECT_EQ(msg->encoding, c.encoding);
    EXPECT_EQ(msg->width, 5u);
    EXPECT_EQ(msg->height, 3u);
    EXPECT_EQ(msg->step, image.step[0]);
    EXPECT_EQ(msg->header.seq, 42u);
    EXPECT_EQ(msg->header.frame_id, "device_3/camera");
    ASSERT_EQ(msg->data.size(), image.total() * image.elemSize());
    EXPECT_EQ(std::memcmp(msg->data.data(), image.data, msg->data.size()), 0);
  }
}

TEST(ImageTest, RejectsEmptyAndUnsupportedImages) {
  EXPECT_THROW(toImageMsg(cv::Mat(), makeHeader()), ecar::Error);
  EXPECT_THROW(toImageMsg(cv::Mat(2, 2, CV_32FC1, cv::Scalar(1.0f)), makeHeader()), ecar::Error);
  EXPECT_THROW(toImageMsg(cv::Mat(2, 2, CV_8UC4, cv::Scalar(1, 2, 3, 4)), makeHeader()),
               ecar::Error);
}

TEST(Vector3Test, RoundTrip) {
  const Eigen::Vector3d v(1.25, -2.5, 1e-9);
  const geometry_msgs::Vector3 m = toVector3(v);
  EXPECT_EQ(m.x, 1.25);
  EXPECT_EQ(m.y, -2.5);
  EXPECT_EQ(m.z, 1e-9);
  EXPECT_EQ(fromVector3(m), v);
}

TEST(StructureTest, PlaneAndVirtualObjectFieldMapping) {
  ecar::Plane plane;
  plane.id = ecar::PlaneId(4);
  plane.label = ecar::PlaneLabel::kWall;
  plane.normal = Eigen::Vector3d(0.0, 1.0, 0.0);
  plane.offset = -2.4;
  plane.boundary = {Eigen::Vector3d(0, 2.4, 0), Eigen::Vector3d(3, 2.4, 0),
                    Eigen::Vector3d(3, 2.4, 2.7)};
  plane.version = 7;
  plane.num_points = 321;
  const ecar_msgs::Plane pm = toPlaneMsg(plane);
  EXPECT_EQ(pm.id, 4u);
  EXPECT_EQ(pm.label, ecar_msgs::Plane::WALL);
  EXPECT_DOUBLE_EQ(pm.normal.y, 1.0);
  EXPECT_DOUBLE_EQ(pm.offset, -2.4);
  ASSERT_EQ(pm.boundary.size(), 3u);
  EXPECT_EQ(fromPoint(pm.boundary[2]), plane.boundary[2]);
  EXPECT_EQ(pm.version, 7u);
  EXPECT_EQ(pm.num_points, 321u);

  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(9);
  vo.kind = ecar::VoKind::kLine;
  vo.start = Eigen::Vector3d(1, 2, 0);
  vo.end = Eigen::Vector3d(2, 2, 0);
  vo.position = Eigen::Vector3d(1.5, 2, 0);
  vo.r = 10;
  vo.g = 20;
  vo.b = 30;
  vo.width = 0.02f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.plane = ecar::PlaneId(4);
  vo.owner = "device_0";
  vo.version = 3;
  vo.deleted = true;
  const ecar_msgs::VirtualObject vm = toVirtualObjectMsg(vo);
  EXPECT_EQ(vm.id, 9u);
  EXPECT_EQ(vm.kind, ecar_msgs::VirtualObject::LINE);
  EXPECT_EQ(fromPoint(vm.start), vo.start);
  EXPECT_EQ(fromPoint(vm.end), vo.end);
  EXPECT_EQ(fromPoint(vm.position), vo.position);
  EXPECT_EQ(vm.r, 10);
  EXPECT_EQ(vm.g, 20);
  EXPECT_EQ(vm.b, 30);
  EXPECT_FLOAT_EQ(vm.width, 0.02f);
  EXPECT_EQ(fromVector3(vm.normal), vo.normal);
  EXPECT_EQ(vm.plane_id, 4u);
  EXPECT_EQ(vm.owner, "device_0");
  EXPECT_EQ(vm.version, 3u);
  EXPECT_TRUE(vm.deleted);
}

}  // namespace
}  // namespace ecar_sim

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
