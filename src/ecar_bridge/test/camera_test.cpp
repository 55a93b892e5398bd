// sensor_msgs conversions: CameraInfo, Image, Imu.
#include "ecar_bridge/camera.h"

#include <cmath>
#include <cstring>
#include <limits>

#include <gtest/gtest.h>
#include <sensor_msgs/image_encodings.h>

#include "ecar_bridge/geometry.h"
#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
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

TEST(CameraInfoTest, FieldsFollowTheRosConvention) {
  const ecar::PinholeCamera camera = makeCamera();
  const sensor_msgs::CameraInfo info = toMsg(camera, testing::someHeader());
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
  const ecar::PinholeCamera back = fromMsg(toMsg(camera, testing::someHeader()));
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
  sensor_msgs::CameraInfo info = toMsg(makeCamera(), testing::someHeader());
  info.D.resize(4);
  EXPECT_EQ(fromMsg(info).params().dist[4], 0.0);

  info.distortion_model = "";
  info.D.clear();
  EXPECT_FALSE(fromMsg(info).hasDistortion());

  info.distortion_model = "rational_polynomial";
  info.D = {0.1, 0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0};
  EXPECT_EQ(fromMsg(info).params().dist[4], 0.001);
}

TEST(CameraInfoTest, RejectsWhatItCannotRepresent) {
  const sensor_msgs::CameraInfo good = toMsg(makeCamera(), testing::someHeader());

  sensor_msgs::CameraInfo info = good;
  info.K.fill(0.0);  // uncalibrated, as camera drivers publish it
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.K[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.K[4] = -1.0;
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.width = 0;
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.D[2] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.D.resize(3);
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.distortion_model = "equidistant";
  info.D.resize(4);
  EXPECT_THROW(fromMsg(info), ecar::Error);

  info = good;
  info.distortion_model = "rational_polynomial";
  info.D = {0.1, 0.01, 0.0, 0.0, 0.001, 0.5, 0.0, 0.0};
  EXPECT_THROW(fromMsg(info), ecar::Error);
}

TEST(ImuTest, CarriesAccelerationAndRateWithoutOrientation) {
  ecar::ImuSample sample;
  sample.timestamp = 3.5;
  sample.acc_c = Eigen::Vector3d(0.1, -9.8, 0.3);
  sample.gyro_c = Eigen::Vector3d(0.01, 0.02, -0.03);
  const sensor_msgs::Imu imu = toMsg(sample, testing::someHeader());
  EXPECT_EQ(imu.header.frame_id, "device_3/camera");
  EXPECT_EQ(imu.orientation_covariance[0], -1.0);
  EXPECT_EQ(fromMsg(imu.linear_acceleration), sample.acc_c);
  EXPECT_EQ(fromMsg(imu.angular_velocity), sample.gyro_c);
  EXPECT_EQ(imu.linear_acceleration_covariance[0], 0.0);  // unknown, but present
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
    const sensor_msgs::ImagePtr msg = toImageMsg(image, testing::someHeader());
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
  EXPECT_THROW(toImageMsg(cv::Mat(), testing::someHeader()), ecar::Error);
  EXPECT_THROW(toImageMsg(cv::Mat(2, 2, CV_32FC1, cv::Scalar(1.0f)), testing::someHeader()),
               ecar::Error);
  EXPECT_THROW(toImageMsg(cv::Mat(2, 2, CV_8UC4, cv::Scalar(1, 2, 3, 4)), testing::someHeader()),
               ecar::Error);
}

TEST(ImuTest, ReadsTheSampleAndRejectsNonFiniteValues) {
  ecar::ImuSample sample;
  sample.acc_c = Eigen::Vector3d(0.1, -9.8, 0.3);
  sample.gyro_c = Eigen::Vector3d(0.01, 0.02, -0.03);
  sensor_msgs::Imu imu = toMsg(sample, testing::someHeader());
  const ecar::ImuSample back = fromMsg(imu);
  EXPECT_EQ(back.acc_c, sample.acc_c);
  EXPECT_EQ(back.gyro_c, sample.gyro_c);
  EXPECT_DOUBLE_EQ(back.timestamp, ros::Time(1234, 5678).toSec());
  imu.linear_acceleration.y = std::numeric_limits<double>::quiet_NaN();
  try {
    fromMsg(imu);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("linear_acceleration"), std::string::npos) << e.what();
  }
}

TEST(ImageTest, GrayOfSharesMono8AndConvertsColour) {
  cv::Mat grey(4, 6, CV_8UC1, cv::Scalar(77));
  const sensor_msgs::ImageConstPtr mono = toImageMsg(grey, testing::someHeader());
  const cv::Mat g = grayOf(mono);
  EXPECT_EQ(g.type(), CV_8UC1);
  EXPECT_EQ(g.at<uint8_t>(2, 3), 77);
  EXPECT_EQ(g.data, mono->data.data());  // a view, not a copy
  const sensor_msgs::ImageConstPtr colour =
      toImageMsg(cv::Mat(4, 6, CV_8UC3, cv::Scalar(10, 20, 30)), testing::someHeader());
  EXPECT_EQ(grayOf(colour).type(), CV_8UC1);
  sensor_msgs::ImagePtr weird = toImageMsg(grey, testing::someHeader());
  weird->encoding = "no_such_encoding";
  try {
    grayOf(weird);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_encoding"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace ecar_bridge
