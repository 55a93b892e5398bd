// Round trips of every message the server converts.
#include "ecar_server/conversions.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <ros/serialization.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"

namespace ecar_server {
namespace {

ecar::SE3 somePose() {
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.5, -2.25, 0.125);
  return T;
}

TEST(ConversionsTest, TrackedPointRoundTripsOnItsGrid) {
  ecar::GraphPoint p;
  p.id = ecar::MapPointId(42);
  p.u = 123.375f;
  p.v = 479.875f;
  p.angle = 90.0f;  // 64 steps exactly
  p.octave = 3;
  const ecar_msgs::TrackedPoint m = toMsg(p);
  EXPECT_EQ(m.u, 987);
  EXPECT_EQ(m.angle, 64);
  const ecar::GraphPoint q = fromMsg(m);
  EXPECT_EQ(q.id, p.id);
  EXPECT_FLOAT_EQ(q.u, p.u);
  EXPECT_FLOAT_EQ(q.v, p.v);
  EXPECT_FLOAT_EQ(q.angle, p.angle);
  EXPECT_EQ(q.octave, 3);
  EXPECT_EQ(ros::serialization::serializationLength(m), 10u);
  // Off the grid: within half a step; out of range: clamped, wrapped.
  p.u = 10.06f;
  p.angle = 359.9f;
  p.v = -3.0f;
  const ecar::GraphPoint r = fromMsg(toMsg(p));
  EXPECT_NEAR(r.u, 10.06f, 1.0f / 16);
  EXPECT_FLOAT_EQ(r.angle, 0.0f);
  EXPECT_FLOAT_EQ(r.v, 0.0f);
}

TEST(ConversionsTest, PositionAndMapPointRoundTrip) {
  // A position names its point by index into the graph's points.
  std::vector<ecar_msgs::TrackedPoint> points(3);
  points[2].id = 7;
  const ecar::GraphPosition pos{ecar::MapPointId(7), Eigen::Vector3f(1.0f, -2.5f, 3.25f)};
  const ecar_msgs::PointPosition wire = toMsg(pos, 2);
  EXPECT_EQ(wire.index, 2);
  const ecar::GraphPosition pos2 = fromMsg(wire, points);
  EXPECT_EQ(pos2.id, pos.id);
  EXPECT_EQ(pos2.p_w, pos.p_w);
  EXPECT_THROW(fromMsg(toMsg(pos, 3), points), ecar::Error);
  ecar::GraphMapPoint mp;
  mp.id = ecar::MapPointId(9);
  mp.p_w = Eigen::Vector3f(0.5f, 1.5f, -4.0f);
  mp.normal = Eigen::Vector3f(0.0f, 0.6f, 0.8f);
  mp.min_distance = 0.4f;
  mp.max_distance = 3.5f;
  for (size_t i = 0; i < 32; ++i) mp.descriptor[i] = static_cast<uint8_t>(7 * i);
  const ecar_msgs::MapPointFull m = toMsg(mp);
  EXPECT_EQ(ros::serialization::serializationLength(m), 68u);
  const ecar::GraphMapPoint mp2 = fromMsg(m);
  EXPECT_EQ(mp2.id, mp.id);
  EXPECT_EQ(mp2.p_w, mp.p_w);
  EXPECT_EQ(mp2.normal, mp.normal);
  EXPECT_EQ(mp2.min_distance, mp.min_distance);
  EXPECT_EQ(mp2.max_distance, mp.max_distance);
  EXPECT_EQ(mp2.descriptor, mp.descriptor);
}

TEST(ConversionsTest, KeyFrameInfoRoundTrips) {
  ecar::GraphKeyFrame kf;
  kf.id = ecar::KeyFrameId(5);
  kf.device = ecar::DeviceId(2);
  kf.T_w_c = somePose();
  kf.points = {ecar::MapPointId(1), ecar::MapPointId(8)};
  std::string name;
  const ecar::GraphKeyFrame kf2 = fromMsg(toMsg(kf, "device_1"), &name);
  EXPECT_EQ(name, "device_1");
  EXPECT_EQ(kf2.id, kf.id);
  EXPECT_EQ(kf2.points, kf.points);
  EXPECT_TRUE(kf2.T_w_c.isApprox(kf.T_w_c, 1e-12));
}

TEST(ConversionsTest, LocalGraphPayloadRoundTrips) {
  ecar::LocalGraphData d;
  d.mode = ecar::SyncMode::kEdgeSlam;
  d.points.push_back({ecar::MapPointId(2), 1.5f, 2.25f, 0.0f, 0});
  d.points.push_back({ecar::MapPointId(3), 8.5f, 9.25f, 45.0f, 1});
  d.positions.push_back({ecar::MapPointId(3), Eigen::Vector3f(1, 2, 3)});
  ecar::GraphKeyFrame kf;
  kf.id = ecar::KeyFrameId(4);
  kf.device = ecar::DeviceId(1);
  kf.points = {ecar::MapPointId(3)};
  d.keyframes.push_back(kf);
  d.map_points.push_back(ecar::GraphMapPoint());
  ecar_msgs::LocalGraph msg;
  fillPayload(
      d, [](ecar::DeviceId id) { return "device_" + std::to_string(id.value); }, &msg);
  EXPECT_EQ(msg.sync_mode, ecar_msgs::LocalGraph::SYNC_EDGESLAM);
  EXPECT_EQ(msg.keyframes[0].device_id, "device_1");
  const ecar::LocalGraphData d2 = payloadFromMsg(msg);
  EXPECT_EQ(d2.mode, d.mode);
  ASSERT_EQ(d2.points.size(), 2u);
  EXPECT_EQ(d2.points[1].id, d.points[1].id);
  EXPECT_FLOAT_EQ(d2.points[1].v, 9.25f);
  ASSERT_EQ(msg.positions.size(), 1u);
  EXPECT_EQ(msg.positions[0].index, 1);
  ASSERT_EQ(d2.positions.size(), 1u);
  EXPECT_EQ(d2.positions[0].id, d.positions[0].id);
  EXPECT_EQ(d2.positions[0].p_w, d.positions[0].p_w);
  // A position whose point is not in the graph cannot be encoded.
  d.positions.push_back({ecar::MapPointId(99), Eigen::Vector3f(1, 2, 3)});
  EXPECT_THROW(fillPayload(
                   d, [](ecar::DeviceId) { return std::string(); }, &msg),
               ecar::Error);
  ASSERT_EQ(d2.keyframes.size(), 1u);
  EXPECT_EQ(d2.keyframes[0].points, kf.points);
  EXPECT_EQ(d2.map_points.size(), 1u);
}

TEST(ConversionsTest, TrackedFrameRoundTrips) {
  ecar::TrackResult r;
  r.state = ecar::TrackingState::kOk;
  r.relocalised = true;
  r.T_w_c = somePose();
  r.tracked.push_back({ecar::MapPointId(11), cv::KeyPoint(20.125f, 30.5f, 31.0f, 180.0f, 0.0f, 2),
                       Eigen::Vector3d::Zero()});
  r.tracked.push_back({ecar::MapPointId(12), cv::KeyPoint(1.0f, 2.0f, 31.0f, 0.0f, 0.0f, 0),
                       Eigen::Vector3d::Zero()});
  r.local_keyframes = {ecar::KeyFrameId(3), ecar::KeyFrameId(1)};
  r.new_keyframe = ecar::KeyFrameId(3);
  FrameMeta meta;
  meta.device = "device_0";
  meta.frame_index = 40;
  meta.stamp = ros::Time(100, 5);
  meta.upload_sent = ros::Time(100, 6);
  meta.server_received = ros::Time(100, 7);
  meta.tracking_time = 0.025f;
  const ecar_msgs::TrackedFrame m = toMsg(r, meta);
  EXPECT_EQ(m.status, ecar_msgs::TrackedFrame::RELOCALISED);
  FrameMeta meta2;
  const ecar::TrackResult r2 = fromMsg(m, &meta2);
  EXPECT_EQ(r2.state, r.state);
  EXPECT_TRUE(r2.relocalised);
  EXPECT_TRUE(r2.T_w_c.isApprox(r.T_w_c, 1e-12));
  ASSERT_EQ(r2.tracked.size(), 2u);
  EXPECT_EQ(r2.tracked[0].id, r.tracked[0].id);
  EXPECT_FLOAT_EQ(r2.tracked[0].keypoint.pt.x, 20.125f);
  EXPECT_FLOAT_EQ(r2.tracked[0].keypoint.angle, 180.0f);
  EXPECT_EQ(r2.tracked[0].keypoint.octave, 2);
  EXPECT_EQ(r2.local_keyframes, r.local_keyframes);
  EXPECT_EQ(r2.new_keyframe, r.new_keyframe);
  EXPECT_EQ(meta2.device, meta.device);
  EXPECT_EQ(meta2.frame_index, meta.frame_index);
  EXPECT_EQ(meta2.stamp, meta.stamp);
  EXPECT_EQ(meta2.upload_sent, meta.upload_sent);
  EXPECT_EQ(meta2.server_received, meta.server_received);
  EXPECT_FLOAT_EQ(meta2.tracking_time, meta.tracking_time);
  ecar_msgs::TrackedFrame bad = m;
  bad.point_ids.pop_back();
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(ConversionsTest, StatusOfEveryState) {
  ecar::TrackResult r;
  EXPECT_EQ(toStatus(r), ecar_msgs::LocalGraph::NOT_INITIALISED);
  r.state = ecar::TrackingState::kLost;
  EXPECT_EQ(toStatus(r), ecar_msgs::LocalGraph::LOST);
  r.state = ecar::TrackingState::kOk;
  EXPECT_EQ(toStatus(r), ecar_msgs::LocalGraph::OK);
}

TEST(ConversionsTest, KeyFrameEventRoundTrips) {
  MappedKeyFrame kf;
  kf.id = ecar::KeyFrameId(17);
  kf.device = "device_3";
  kf.frame_index = 88;
  kf.timestamp = 12.5;
  kf.gravity_c = Eigen::Vector3d(0.1, -9.8, 0.2);
  const MappedKeyFrame kf2 = fromMsg(toMsg(kf));
  EXPECT_EQ(kf2.id, kf.id);
  EXPECT_EQ(kf2.device, kf.device);
  EXPECT_EQ(kf2.frame_index, kf.frame_index);
  EXPECT_DOUBLE_EQ(kf2.timestamp, kf.timestamp);
  ASSERT_TRUE(kf2.gravity_c.has_value());
  EXPECT_EQ(*kf2.gravity_c, *kf.gravity_c);
  kf.gravity_c.reset();
  EXPECT_FALSE(fromMsg(toMsg(kf)).gravity_c.has_value());
}

TEST(ConversionsTest, UploadMotionRoundTripsAndRejectsNaN) {
  UploadMotion motion;
  motion.gravity_c = Eigen::Vector3d(0.0, -9.81, 0.3);
  motion.T_o_c = somePose();
  ecar_msgs::Upload upload;
  setMotion(motion, &upload);
  const UploadMotion back = motionOf(upload);
  ASSERT_TRUE(back.gravity_c && back.T_o_c);
  EXPECT_EQ(*back.gravity_c, *motion.gravity_c);
  EXPECT_TRUE(back.T_o_c->isApprox(*motion.T_o_c, 1e-12));
  setMotion(UploadMotion(), &upload);
  EXPECT_FALSE(motionOf(upload).gravity_c || motionOf(upload).T_o_c);

  const double nan = std::numeric_limits<double>::quiet_NaN();
  setMotion(motion, &upload);
  upload.gravity.y = nan;
  try {
    motionOf(upload);
    FAIL() << "NaN gravity accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("gravity"), std::string::npos) << e.what();
  }
  setMotion(motion, &upload);
  upload.odometry.position.x = nan;
  try {
    motionOf(upload);
    FAIL() << "NaN odometry accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("odometry"), std::string::npos) << e.what();
  }
  upload.has_odometry = false;  // ignored when flagged absent
  EXPECT_NO_THROW(motionOf(upload));
}

TEST(ConversionsTest, ImageDecodesOrNamesTheField) {
  cv::Mat grey(48, 64, CV_8U);
  cv::randu(grey, 0, 256);
  ecar_msgs::Upload upload;
  upload.image.format = "jpeg";
  cv::imencode(".jpg", grey, upload.image.data, {cv::IMWRITE_JPEG_QUALITY, 90});
  const cv::Mat decoded = decodeImage(upload);
  EXPECT_EQ(decoded.cols, 64);
  EXPECT_EQ(decoded.rows, 48);
  EXPECT_EQ(decoded.type(), CV_8U);
  upload.image.data.resize(40);  // truncated
  EXPECT_THROW(decodeImage(upload), ecar::Error);
  upload.image.data.assign(500, 0xAB);
  EXPECT_THROW(decodeImage(upload), ecar::Error);
  upload.image.data.clear();
  EXPECT_THROW(decodeImage(upload), ecar::Error);
}

TEST(ConversionsTest, PlaneRoundTrips) {
  ecar::Plane p;
  p.id = ecar::PlaneId(9);
  p.label = ecar::PlaneLabel::kWall;
  p.normal = Eigen::Vector3d(0.6, 0.8, 0.0);
  p.offset = -1.25;
  p.boundary = {{0, 0, 0}, {1, 0, 0.5}, {1, 0, 2}};
  p.version = 4;
  p.num_points = 321;
  const ecar::Plane q = fromMsg(toMsg(p));
  EXPECT_EQ(q.id, p.id);
  EXPECT_EQ(q.label, p.label);
  EXPECT_EQ(q.normal, p.normal);
  EXPECT_EQ(q.offset, p.offset);
  EXPECT_EQ(q.boundary, p.boundary);
  EXPECT_EQ(q.version, 4u);
  EXPECT_EQ(q.num_points, 321u);
  EXPECT_EQ(toMsg(p).label, ecar_msgs::Plane::WALL);
  ecar_msgs::Plane bad = toMsg(p);
  bad.label = 7;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

ecar::VirtualObject someObject() {
  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(12);
  vo.kind = ecar::VoKind::kLine;
  vo.start = Eigen::Vector3d(1.0, 2.0, 0.0);
  vo.end = Eigen::Vector3d(1.5, 2.0, 0.0);
  vo.position = (vo.start + vo.end) / 2;
  vo.r = 10;
  vo.g = 200;
  vo.b = 30;
  vo.width = 0.05f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.plane = ecar::PlaneId(3);
  vo.owner = "device_0";
  vo.version = 5;
  vo.deleted = true;
  return vo;
}

TEST(ConversionsTest, VirtualObjectRoundTrips) {
  const ecar::VirtualObject vo = someObject();
  const ecar::VirtualObject q = fromMsg(toMsg(vo));
  EXPECT_EQ(q.id, vo.id);
  EXPECT_EQ(q.kind, vo.kind);
  EXPECT_EQ(q.position, vo.position);
  EXPECT_EQ(q.start, vo.start);
  EXPECT_EQ(q.end, vo.end);
  EXPECT_EQ(q.r, 10);
  EXPECT_EQ(q.g, 200);
  EXPECT_EQ(q.b, 30);
  EXPECT_EQ(q.width, 0.05f);
  EXPECT_EQ(q.normal, vo.normal);
  EXPECT_EQ(q.plane, vo.plane);
  EXPECT_EQ(q.owner, "device_0");
  EXPECT_EQ(q.version, 5u);
  EXPECT_TRUE(q.deleted);
  ecar_msgs::VirtualObject bad = toMsg(vo);
  bad.kind = 2;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(ConversionsTest, InteractionAndResultRoundTrip) {
  VoRequest r;
  r.device = "device_1";
  r.request_id = 77;
  r.type = VoRequest::Type::kManipulate;
  r.object = ecar::ObjectId(12);
  r.state = someObject();
  r.base_version = 4;
  const ecar_msgs::Interaction m = toMsg(r);
  EXPECT_EQ(m.type, ecar_msgs::Interaction::MANIPULATE);
  const VoRequest q = fromMsg(m);
  EXPECT_EQ(q.device, r.device);
  EXPECT_EQ(q.request_id, 77u);
  EXPECT_EQ(q.type, r.type);
  EXPECT_EQ(q.object, r.object);
  EXPECT_EQ(q.state.end, r.state.end);
  EXPECT_EQ(q.state.owner, r.state.owner);
  EXPECT_EQ(q.base_version, 4u);
  for (auto type : {VoRequest::Type::kRegister, VoRequest::Type::kDelete}) {
    r.type = type;
    EXPECT_EQ(fromMsg(toMsg(r)).type, type);
  }
  ecar_msgs::Interaction bad = m;
  bad.type = 9;
  EXPECT_THROW(fromMsg(bad), ecar::Error);

  ecar::VoOutcome o;
  o.accepted = false;
  o.id = ecar::ObjectId(12);
  o.version = 6;
  o.reason = "stale base_version 4";
  const ecar_msgs::InteractionResult res = toMsg(r, o);
  EXPECT_EQ(res.device_id, "device_1");
  EXPECT_EQ(res.request_id, 77u);
  const ecar::VoOutcome p = outcomeFromMsg(res);
  EXPECT_FALSE(p.accepted);
  EXPECT_EQ(p.id, o.id);
  EXPECT_EQ(p.version, 6u);
  EXPECT_EQ(p.reason, o.reason);
}

}  // namespace
}  // namespace ecar_server
