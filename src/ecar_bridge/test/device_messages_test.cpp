// What a device publishes: Upload (and the JPEG decode), DeviceFrame, RoundTripMetrics.
#include "ecar_bridge/device_messages.h"

#include <limits>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
namespace {

using testing::somePose;

void expectPoseNear(const ecar::SE3& a, const ecar::SE3& b) {
  EXPECT_LT((a.translation() - b.translation()).norm(), 1e-9);
  EXPECT_LT((a.linear() - b.linear()).norm(), 1e-9);
}

TEST(UploadTest, RoundTrip) {
  UploadContent c;
  c.device_id = "device_3";
  c.camera_frame = "device_3/camera";
  c.frame_index = 44;
  c.stamp = ros::Time(100, 5);
  c.sent = ros::Time(100, 900);
  c.jpeg = {0xff, 0xd8, 0x01, 0xff, 0xd9};
  c.gravity_c = Eigen::Vector3d(0.1, -9.7, 0.5);
  c.T_o_c = somePose();
  c.last_graph_frame = 40;
  c.reset = true;
  const ecar_msgs::Upload msg = toMsg(c);
  EXPECT_EQ(msg.image.format, "jpeg");
  EXPECT_EQ(msg.image.header.stamp, c.stamp);
  EXPECT_EQ(msg.header.frame_id, "device_3/camera");
  EXPECT_EQ(msg.image.data, c.jpeg);
  EXPECT_TRUE(msg.has_gravity);
  EXPECT_TRUE(msg.has_odometry);
  const UploadContent back = fromMsg(msg);
  EXPECT_EQ(back.device_id, c.device_id);
  EXPECT_EQ(back.camera_frame, c.camera_frame);
  EXPECT_EQ(back.frame_index, 44u);
  EXPECT_EQ(back.stamp, c.stamp);
  EXPECT_EQ(back.sent, c.sent);
  EXPECT_TRUE(back.jpeg.empty());  // the image stays in the message
  ASSERT_TRUE(back.gravity_c.has_value());
  EXPECT_LT((*back.gravity_c - *c.gravity_c).norm(), 1e-12);
  ASSERT_TRUE(back.T_o_c.has_value());
  expectPoseNear(*back.T_o_c, *c.T_o_c);
  EXPECT_EQ(back.last_graph_frame, 40u);
  EXPECT_TRUE(back.reset);
  // Bytes on the wire: the JPEG plus the fixed fields and strings.
  EXPECT_GT(wireBytes(msg), c.jpeg.size() + c.device_id.size());
  c.gravity_c.reset();
  c.T_o_c.reset();
  const ecar_msgs::Upload bare_msg = toMsg(c);
  EXPECT_EQ(bare_msg.odometry.orientation.w, 1.0);  // identity when absent
  const UploadContent bare = fromMsg(bare_msg);
  EXPECT_FALSE(bare.gravity_c.has_value());
  EXPECT_FALSE(bare.T_o_c.has_value());
}

TEST(UploadTest, NonFiniteMotionNamesTheField) {
  UploadContent c;
  c.gravity_c = Eigen::Vector3d(0.0, -9.81, 0.3);
  c.T_o_c = somePose();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ecar_msgs::Upload upload = toMsg(c);
  upload.gravity.y = nan;
  try {
    fromMsg(upload);
    FAIL() << "NaN gravity accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("gravity"), std::string::npos) << e.what();
  }
  upload = toMsg(c);
  upload.odometry.position.x = nan;
  try {
    fromMsg(upload);
    FAIL() << "NaN odometry accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("odometry"), std::string::npos) << e.what();
  }
  upload.has_odometry = false;  // ignored when flagged absent
  EXPECT_NO_THROW(fromMsg(upload));
}

TEST(UploadTest, ImageDecodesOrNamesTheField) {
  cv::Mat grey(48, 64, CV_8U);
  cv::randu(grey, 0, 256);
  ecar_msgs::Upload upload;
  upload.image.format = "jpeg";
  cv::imencode(".jpg", grey, upload.image.data, {cv::IMWRITE_JPEG_QUALITY, 90});
  cv::Mat decoded;
  decodeImage(upload, 64, 48, &decoded);
  EXPECT_EQ(decoded.cols, 64);
  EXPECT_EQ(decoded.rows, 48);
  EXPECT_EQ(decoded.type(), CV_8U);
  const auto error = [&](int width, int height) {
    try {
      decodeImage(upload, width, height, &decoded);
    } catch (const ecar::Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  // Another camera size: refused from the header, before decoding.
  EXPECT_NE(error(640, 480).find("image: JPEG of 64x48, not the camera's 640x480"),
            std::string::npos)
      << error(640, 480);
  // compressed_image_transport's format string is JPEG too; PNG is not decoded at all.
  upload.image.format = "mono8; jpeg compressed mono8";
  EXPECT_EQ(error(64, 48), "");
  upload.image.format = "png";
  EXPECT_NE(error(64, 48).find("image format 'png': uploads are JPEG only"), std::string::npos);
  upload.image.format = "jpeg";
  const std::vector<uint8_t> good = upload.image.data;
  upload.image.data.resize(good.size() / 2);  // truncated
  EXPECT_NE(error(64, 48).find("does not decode"), std::string::npos) << error(64, 48);
  upload.image.data.assign(500, 0xAB);
  EXPECT_NE(error(64, 48).find("not a JPEG"), std::string::npos);
  upload.image.data.clear();
  EXPECT_NE(error(64, 48).find("no bytes"), std::string::npos);
  EXPECT_TRUE(isJpegFormat("JPEG"));
  EXPECT_TRUE(isJpegFormat("jpg"));
  EXPECT_FALSE(isJpegFormat("png"));
  EXPECT_FALSE(isJpegFormat(""));
}

TEST(DeviceFrameTest, Fields) {
  ecar::DeviceTrackResult r;
  r.frame_index = 9;
  r.state = ecar::TrackingState::kOk;
  r.T_w_c = somePose();
  r.inliers = 150;
  r.total_ms = 12.5;
  std::map<ecar::ObjectId, ecar::VirtualObject> held;
  held[ecar::ObjectId(4)].version = 2;
  held[ecar::ObjectId(7)].version = 5;
  const auto msg = toMsg("device_0", ros::Time(5, 0), "map", r, 10, 800, true, held);
  EXPECT_EQ(msg.header.frame_id, "map");
  EXPECT_EQ(msg.header.stamp, ros::Time(5, 0));
  EXPECT_EQ(msg.device_id, "device_0");
  EXPECT_EQ(msg.frame_index, 9u);
  EXPECT_EQ(msg.status, ecar_msgs::DeviceFrame::OK);
  EXPECT_NEAR(msg.pose.position.x, 1.5, 1e-12);
  EXPECT_EQ(msg.tracked_points, 150u);
  EXPECT_EQ(msg.keyframes, 10u);
  EXPECT_EQ(msg.local_points, 800u);
  EXPECT_TRUE(msg.uploaded);
  EXPECT_FLOAT_EQ(msg.tracking_time, 0.0125f);
  EXPECT_EQ(msg.object_ids, (std::vector<uint32_t>{4, 7}));
  EXPECT_EQ(msg.object_versions, (std::vector<uint32_t>{2, 5}));
  r.state = ecar::TrackingState::kLost;
  const auto lost = toMsg("d", ros::Time(), "map", r, 0, 0, false, {});
  EXPECT_EQ(lost.status, ecar_msgs::DeviceFrame::LOST);
  EXPECT_TRUE(lost.object_ids.empty());
}

TEST(RoundTripMetricsTest, LatencyPartsAndBytes) {
  ecar_msgs::LocalGraph g;
  g.device_id = "device_0";
  g.frame_index = 16;
  g.points.resize(100);
  g.positions.resize(30);
  g.server_received = ros::Time(10, 10000000);  // 10 ms after sending
  g.server_sent = ros::Time(10, 30000000);
  g.server_time = 0.02f;
  g.tracking_time = 0.012f;
  g.server_cpu_time = 0.011f;
  RoundTrip t;
  t.device_id = "device_0";
  t.bytes_up = 20000;
  t.sent = ros::Time(10, 0);
  t.received = ros::Time(10, 35000000);
  t.tracking_time_device = 0.008f;
  t.tracking_cpu_time_device = 0.007f;
  t.jpeg_quality = 35;
  t.upload_budget = 87500;
  const auto m = toMsg(g, t);
  EXPECT_EQ(m.frame_index, 16u);
  EXPECT_EQ(m.bytes_up, 20000u);
  EXPECT_EQ(m.bytes_down, ros::serialization::serializationLength(g));
  EXPECT_EQ(m.points, 100u);
  EXPECT_EQ(m.positions, 30u);
  EXPECT_NEAR(m.latency, 0.035, 1e-6);
  EXPECT_NEAR(m.upload_time, 0.010, 1e-6);
  EXPECT_NEAR(m.server_time, 0.020, 1e-6);
  EXPECT_FLOAT_EQ(m.align_time, 0.012f);
  EXPECT_NEAR(m.download_time, 0.005, 1e-6);
  EXPECT_FLOAT_EQ(m.tracking_time_device, 0.008f);
  EXPECT_FLOAT_EQ(m.tracking_cpu_time_device, 0.007f);
  EXPECT_FLOAT_EQ(m.server_cpu_time, 0.011f);
  EXPECT_EQ(m.jpeg_quality, 35u);
  EXPECT_EQ(m.upload_budget, 87500u);
  EXPECT_EQ(m.header.stamp, t.received);
  g.sync_mode = ecar_msgs::LocalGraph::SYNC_EDGESLAM;
  g.map_points.resize(7);
  EXPECT_EQ(toMsg(g, t).points, 7u);
}

}  // namespace
}  // namespace ecar_bridge
