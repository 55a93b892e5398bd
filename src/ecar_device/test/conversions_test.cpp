// Round trips and field mappings of every conversion in ecar_device/conversions.h.
#include "ecar_device/conversions.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar_device {
namespace {

ecar::SE3 somePose() {
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.5, -2.0, 0.25);
  return T;
}

void expectPoseNear(const ecar::SE3& a, const ecar::SE3& b) {
  EXPECT_LT((a.translation() - b.translation()).norm(), 1e-9);
  EXPECT_LT((a.linear() - b.linear()).norm(), 1e-9);
}

TEST(TrackedPointTest, RoundTripKeepsTheWireResolution) {
  ecar::ReceivedPoint p;
  p.id = ecar::MapPointId(42);
  p.keypoint = cv::KeyPoint(123.4567f, 45.0625f, 31.0f, 359.9f, 0.0f, 3);
  const ecar_msgs::TrackedPoint m = toTrackedPoint(p);
  EXPECT_EQ(m.id, 42u);
  EXPECT_EQ(m.u, 988);    // 123.4567 * 8 = 987.65
  EXPECT_EQ(m.v, 361);    // 45.0625 * 8 = 360.5 -> 361
  EXPECT_EQ(m.angle, 0);  // 359.9 deg wraps to step 0
  EXPECT_EQ(m.octave, 3);
  const ecar::ReceivedPoint back = fromTrackedPoint(m);
  EXPECT_EQ(back.id, p.id);
  EXPECT_NEAR(back.keypoint.pt.x, p.keypoint.pt.x, 1.0 / 16.0);
  EXPECT_NEAR(back.keypoint.pt.y, p.keypoint.pt.y, 1.0 / 16.0);
  EXPECT_EQ(back.keypoint.octave, 3);
  p.keypoint.angle = 90.0f;
  EXPECT_NEAR(fromTrackedPoint(toTrackedPoint(p)).keypoint.angle, 90.0f, 1.40625f / 2);
  p.keypoint.pt.x = -1.0f;
  EXPECT_THROW(toTrackedPoint(p), ecar::Error);
}

TEST(LocalGraphTest, EcarRoundTrip) {
  ecar::LocalGraphInput g;
  g.frame_index = 12;
  g.T_w_c = somePose();
  for (uint32_t i = 1; i <= 5; ++i) {
    g.points.push_back({ecar::MapPointId(i), cv::KeyPoint(10.0f * i, 20.0f, 31.0f, 45.0f, 0, 1)});
  }
  g.positions.push_back({ecar::MapPointId(2), Eigen::Vector3d(1.0, 2.0, 3.5)});
  ecar_msgs::LocalGraph msg;
  toLocalGraph(g, &msg);
  EXPECT_EQ(msg.sync_mode, ecar_msgs::LocalGraph::SYNC_ECAR);
  EXPECT_EQ(msg.points.size(), 5u);
  const ecar::LocalGraphInput back = fromLocalGraph(msg);
  EXPECT_EQ(back.frame_index, 12u);
  expectPoseNear(back.T_w_c, g.T_w_c);
  ASSERT_EQ(back.points.size(), 5u);
  EXPECT_EQ(back.points[4].id, ecar::MapPointId(5));
  EXPECT_FLOAT_EQ(back.points[4].keypoint.pt.x, 50.0f);
  ASSERT_EQ(msg.positions.size(), 1u);
  EXPECT_EQ(msg.positions[0].index, 1);  // points[1] has id 2
  ASSERT_EQ(back.positions.size(), 1u);
  EXPECT_EQ(back.positions[0].id, ecar::MapPointId(2));
  EXPECT_DOUBLE_EQ(back.positions[0].p_w.z(), 3.5);
}

TEST(LocalGraphTest, NanIsReportedByField) {
  ecar_msgs::LocalGraph msg;
  msg.pose.orientation.w = 1.0;
  msg.points.resize(3);
  msg.positions.resize(3);
  for (uint16_t i = 0; i < 3; ++i) msg.positions[i].index = i;
  msg.positions[2].y = std::numeric_limits<float>::quiet_NaN();
  try {
    fromLocalGraph(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("positions[2]"), std::string::npos) << e.what();
  }
  // A position naming a point the graph does not have.
  msg.positions[2].y = 0.0f;
  msg.positions[1].index = 3;
  try {
    fromLocalGraph(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("positions[1].index"), std::string::npos) << e.what();
  }
  msg.positions.clear();
  msg.pose.position.x = std::numeric_limits<double>::infinity();
  try {
    fromLocalGraph(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("pose"), std::string::npos) << e.what();
  }
}

TEST(LocalGraphTest, EdgeslamRoundTrip) {
  ecar::FullLocalMap map;
  map.frame_index = 8;
  map.T_w_c = somePose();
  map.keyframes.push_back({ecar::KeyFrameId(3), somePose(), {ecar::MapPointId(7)}});
  ecar::PointSample s;
  s.id = ecar::MapPointId(7);
  s.p_w = Eigen::Vector3d(0.5, 1.0, 2.0);
  s.normal = Eigen::Vector3d(0.0, 0.6, 0.8);
  s.min_distance = 0.5f;
  s.max_distance = 4.0f;
  for (int i = 0; i < 32; ++i) s.descriptor[i] = static_cast<uint8_t>(i * 7);
  map.points.push_back(s);
  ecar_msgs::LocalGraph msg;
  toFullLocalGraph(map, &msg);
  EXPECT_EQ(msg.sync_mode, ecar_msgs::LocalGraph::SYNC_EDGESLAM);
  const ecar::FullLocalMap back = fromFullLocalGraph(msg);
  EXPECT_EQ(back.frame_index, 8u);
  expectPoseNear(back.T_w_c, map.T_w_c);
  ASSERT_EQ(back.keyframes.size(), 1u);
  EXPECT_EQ(back.keyframes[0].id, ecar::KeyFrameId(3));
  expectPoseNear(back.keyframes[0].T_w_c, map.T_w_c);
  ASSERT_EQ(back.keyframes[0].point_ids.size(), 1u);
  ASSERT_EQ(back.points.size(), 1u);
  EXPECT_EQ(back.points[0].id, s.id);
  EXPECT_LT((back.points[0].p_w - s.p_w).norm(), 1e-6);
  EXPECT_LT((back.points[0].normal - s.normal).norm(), 1e-6);
  EXPECT_FLOAT_EQ(back.points[0].max_distance, 4.0f);
  EXPECT_EQ(back.points[0].descriptor, s.descriptor);
  msg.map_points[0].normal[1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(fromFullLocalGraph(msg), ecar::Error);
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
  const ecar_msgs::Upload msg = toUpload(c);
  EXPECT_EQ(msg.image.format, "jpeg");
  EXPECT_EQ(msg.image.header.stamp, c.stamp);
  EXPECT_EQ(msg.header.frame_id, "device_3/camera");
  EXPECT_TRUE(msg.has_gravity);
  EXPECT_TRUE(msg.has_odometry);
  const UploadContent back = fromUpload(msg);
  EXPECT_EQ(back.device_id, c.device_id);
  EXPECT_EQ(back.frame_index, 44u);
  EXPECT_EQ(back.stamp, c.stamp);
  EXPECT_EQ(back.sent, c.sent);
  EXPECT_EQ(back.jpeg, c.jpeg);
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
  const UploadContent bare = fromUpload(toUpload(c));
  EXPECT_FALSE(bare.gravity_c.has_value());
  EXPECT_FALSE(bare.T_o_c.has_value());
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
  const auto msg = toDeviceFrame("device_0", ros::Time(5, 0), "map", r, 10, 800, true, held);
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
  const auto lost = toDeviceFrame("d", ros::Time(), "map", r, 0, 0, false, {});
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
  RoundTrip t;
  t.device_id = "device_0";
  t.bytes_up = 20000;
  t.sent = ros::Time(10, 0);
  t.received = ros::Time(10, 35000000);
  t.tracking_time_device = 0.008f;
  const auto m = toRoundTripMetrics(g, t);
  EXPECT_EQ(m.frame_index, 16u);
  EXPECT_EQ(m.bytes_up, 20000u);
  EXPECT_EQ(m.bytes_down, ros::serialization::serializationLength(g));
  EXPECT_EQ(m.points, 100u);
  EXPECT_EQ(m.positions, 30u);
  EXPECT_NEAR(m.latency, 0.035, 1e-6);
  EXPECT_NEAR(m.upload_time, 0.010, 1e-6);
  EXPECT_NEAR(m.server_time, 0.020, 1e-6);
  EXPECT_NEAR(m.download_time, 0.005, 1e-6);
  EXPECT_FLOAT_EQ(m.tracking_time_device, 0.008f);
  EXPECT_EQ(m.header.stamp, t.received);
  g.sync_mode = ecar_msgs::LocalGraph::SYNC_EDGESLAM;
  g.map_points.resize(7);
  EXPECT_EQ(toRoundTripMetrics(g, t).points, 7u);
}

ecar::VirtualObject someObject() {
  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(17);
  vo.kind = ecar::VoKind::kLine;
  vo.start = Eigen::Vector3d(1.0, 2.0, 0.0);
  vo.end = Eigen::Vector3d(1.5, 2.25, 0.0);
  vo.position = 0.5 * (vo.start + vo.end);
  vo.r = 200;
  vo.g = 10;
  vo.b = 3;
  vo.width = 0.025f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.plane = ecar::PlaneId(4);
  vo.owner = "device_1";
  vo.version = 9;
  vo.deleted = true;
  return vo;
}

void expectObjectEq(const ecar::VirtualObject& a, const ecar::VirtualObject& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.kind, b.kind);
  EXPECT_EQ(a.position, b.position);
  EXPECT_EQ(a.start, b.start);
  EXPECT_EQ(a.end, b.end);
  EXPECT_EQ(a.r, b.r);
  EXPECT_EQ(a.g, b.g);
  EXPECT_EQ(a.b, b.b);
  EXPECT_FLOAT_EQ(a.width, b.width);
  EXPECT_EQ(a.normal, b.normal);
  EXPECT_EQ(a.plane, b.plane);
  EXPECT_EQ(a.owner, b.owner);
  EXPECT_EQ(a.version, b.version);
  EXPECT_EQ(a.deleted, b.deleted);
}

TEST(VirtualObjectTest, RoundTripAndBadFields) {
  const ecar::VirtualObject vo = someObject();
  const ecar_msgs::VirtualObject m = toVirtualObject(vo);
  EXPECT_EQ(m.id, 17u);
  EXPECT_EQ(m.kind, ecar_msgs::VirtualObject::LINE);
  EXPECT_EQ(m.plane_id, 4u);
  expectObjectEq(fromVirtualObject(m), vo);
  ecar_msgs::VirtualObject bad = m;
  bad.start.y = std::numeric_limits<double>::quiet_NaN();
  try {
    fromVirtualObject(bad, "objects[2]");
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("objects[2].start"), std::string::npos) << e.what();
  }
  bad = m;
  bad.kind = 5;
  EXPECT_THROW(fromVirtualObject(bad), ecar::Error);
  bad = m;
  bad.normal.z = 0.0;
  EXPECT_THROW(fromVirtualObject(bad), ecar::Error);
}

TEST(PlaneMsgTest, RoundTripAndBadFields) {
  ecar::Plane p;
  p.id = ecar::PlaneId(3);
  p.label = ecar::PlaneLabel::kWall;
  p.normal = Eigen::Vector3d(0.6, 0.8, 0.0);
  p.offset = -2.5;
  p.boundary = {{0, 0, 0}, {1, 0, 0}, {1, 1, 2}};
  p.version = 4;
  p.num_points = 120;
  const ecar_msgs::Plane m = toPlane(p);
  EXPECT_EQ(m.label, ecar_msgs::Plane::WALL);
  const ecar::Plane back = fromPlane(m);
  EXPECT_EQ(back.id, p.id);
  EXPECT_EQ(back.label, p.label);
  EXPECT_LT((back.normal - p.normal).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(back.offset, p.offset);
  EXPECT_EQ(back.boundary, p.boundary);
  EXPECT_EQ(back.version, 4u);
  EXPECT_EQ(back.num_points, 120u);
  ecar_msgs::Plane bad = m;
  bad.normal.x = 2.0;
  EXPECT_THROW(fromPlane(bad), ecar::Error);
  bad = m;
  bad.boundary[1].z = std::numeric_limits<double>::infinity();
  try {
    fromPlane(bad, "planes[0]");
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("planes[0].boundary[1]"), std::string::npos) << e.what();
  }
}

TEST(TouchTest, RoundTripAndValidation) {
  ecar::TouchInput t;
  t.uv = Eigen::Vector2d(120.5, 300.25);
  t.phase = ecar::TouchInput::kMove;
  t.r = 1;
  t.g = 2;
  t.b = 3;
  t.width = 0.04f;
  std_msgs::Header h;
  h.frame_id = "device_0/camera";
  const ecar_msgs::Touch m = toTouch(t, h);
  EXPECT_EQ(m.phase, ecar_msgs::Touch::MOVE);
  EXPECT_NO_THROW(validateTouch(m));
  const ecar::TouchInput back = fromTouch(m);
  EXPECT_EQ(back.uv, t.uv);
  EXPECT_EQ(back.phase, t.phase);
  EXPECT_EQ(back.r, 1);
  EXPECT_EQ(back.g, 2);
  EXPECT_EQ(back.b, 3);
  EXPECT_FLOAT_EQ(back.width, 0.04f);
  ecar_msgs::Touch bad = m;
  bad.u = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(validateTouch(bad), ecar::Error);
  bad = m;
  bad.width = 0.0f;
  EXPECT_THROW(validateTouch(bad), ecar::Error);
  bad = m;
  bad.phase = 3;
  EXPECT_THROW(validateTouch(bad), ecar::Error);
}

TEST(InteractionTest, RoundTrip) {
  ecar::VoRequest r;
  r.request_id = 33;
  r.type = ecar::VoRequestType::kManipulate;
  r.object_id = ecar::ObjectId(17);
  r.object = someObject();
  r.base_version = 9;
  std_msgs::Header h;
  h.frame_id = "map";
  const ecar_msgs::Interaction m = toInteraction(r, "device_0", h);
  EXPECT_EQ(m.device_id, "device_0");
  EXPECT_EQ(m.header.frame_id, "map");
  EXPECT_EQ(m.type, ecar_msgs::Interaction::MANIPULATE);
  EXPECT_EQ(m.object_id, 17u);
  const ecar::VoRequest back = fromInteraction(m);
  EXPECT_EQ(back.request_id, 33u);
  EXPECT_EQ(back.type, r.type);
  EXPECT_EQ(back.object_id, r.object_id);
  EXPECT_EQ(back.base_version, 9u);
  expectObjectEq(back.object, r.object);
  ecar_msgs::Interaction bad = m;
  bad.type = 7;
  EXPECT_THROW(fromInteraction(bad), ecar::Error);
}

TEST(InteractionResultTest, RoundTrip) {
  const ecar::VoResult r{12, false, ecar::ObjectId(5), 3, "stale base_version 2 (store has 3)"};
  const ecar_msgs::InteractionResult m = toInteractionResult(r, "device_0", std_msgs::Header());
  EXPECT_EQ(m.device_id, "device_0");
  const ecar::VoResult back = fromInteractionResult(m);
  EXPECT_EQ(back.request_id, 12u);
  EXPECT_FALSE(back.accepted);
  EXPECT_EQ(back.object_id, ecar::ObjectId(5));
  EXPECT_EQ(back.version, 3u);
  EXPECT_EQ(back.reason, r.reason);
}

}  // namespace
}  // namespace ecar_device
