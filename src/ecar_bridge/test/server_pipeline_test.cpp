// The server's internal messages: TrackedFrame, KeyFrameEvent, KeyFramePlanes, VisibleStructure.
#include "ecar_bridge/server_pipeline.h"

#include <limits>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
namespace {

using testing::someObject;
using testing::somePose;

TEST(TrackedFrameTest, RoundTrips) {
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
  r.map_epoch = 1234;
  FrameMeta meta;
  meta.device = "device_0";
  meta.frame_index = 40;
  meta.stamp = ros::Time(100, 5);
  meta.upload_sent = ros::Time(100, 6);
  meta.server_received = ros::Time(100, 7);
  meta.tracking_time = 0.025f;
  meta.cpu_time = 0.0125f;
  meta.reset = true;
  const ecar_msgs::TrackedFrame m = toMsg(r, meta);
  EXPECT_EQ(m.status, ecar_msgs::TrackedFrame::RELOCALISED);
  EXPECT_EQ(m.map_epoch, 1234u);
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
  EXPECT_EQ(r2.map_epoch, 1234u);
  EXPECT_EQ(meta2.device, meta.device);
  EXPECT_EQ(meta2.frame_index, meta.frame_index);
  EXPECT_EQ(meta2.stamp, meta.stamp);
  EXPECT_EQ(meta2.upload_sent, meta.upload_sent);
  EXPECT_EQ(meta2.server_received, meta.server_received);
  EXPECT_FLOAT_EQ(meta2.tracking_time, meta.tracking_time);
  EXPECT_FLOAT_EQ(meta2.cpu_time, meta.cpu_time);
  EXPECT_TRUE(meta2.reset);
  ecar_msgs::TrackedFrame bad = m;
  bad.point_ids.pop_back();
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(TrackedFrameTest, StatusOfEveryState) {
  ecar::TrackResult r;
  const FrameMeta meta;
  EXPECT_EQ(toMsg(r, meta).status, ecar_msgs::TrackedFrame::NOT_INITIALISED);
  r.state = ecar::TrackingState::kLost;
  EXPECT_EQ(toMsg(r, meta).status, ecar_msgs::TrackedFrame::LOST);
  r.state = ecar::TrackingState::kOk;
  EXPECT_EQ(toMsg(r, meta).status, ecar_msgs::TrackedFrame::OK);
}

TEST(KeyFrameEventTest, RoundTrips) {
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

TEST(KeyFramePlanesTest, RoundTrips) {
  ecar::KeyFramePlanes k;
  k.keyframe = ecar::KeyFrameId(9);
  k.frame_index = 36;
  k.timestamp = 4.25;
  k.T_w_c = somePose();
  k.map_epoch = 55;
  k.planes = {ecar::PlaneId(1), ecar::PlaneId(4)};
  k.update.created = {ecar::PlaneId(4)};
  const ecar_msgs::KeyFramePlanes m = toMsg(k, "device_2");
  EXPECT_EQ(m.device_id, "device_2");
  EXPECT_EQ(m.planes_created, 1u);
  EXPECT_EQ(m.planes_updated, 0u);
  const ecar::KeyFramePlanes back = fromMsg(m);
  EXPECT_EQ(back.keyframe, k.keyframe);
  EXPECT_EQ(back.frame_index, 36u);
  EXPECT_DOUBLE_EQ(back.timestamp, 4.25);
  EXPECT_TRUE(back.T_w_c.isApprox(k.T_w_c, 1e-12));
  EXPECT_EQ(back.map_epoch, 55u);
  EXPECT_EQ(back.planes, k.planes);
  EXPECT_TRUE(back.done());
}

TEST(VisibleStructureTest, RoundTrips) {
  ecar::VisibleStructure v;
  ecar::Plane wall;
  wall.id = ecar::PlaneId(3);
  wall.label = ecar::PlaneLabel::kWall;
  wall.normal = Eigen::Vector3d::UnitY();
  v.planes = {wall};
  ecar::VirtualObject live = someObject();
  live.deleted = false;
  v.objects = {live};
  v.objects_computed = true;
  v.cells = {{1, 2, 3}, {-4, 5, 0}};
  v.milliseconds = 2.5;
  v.cpu_ms = 1.25;
  ecar_msgs::VisibleStructure m;
  toMsg(v, &m);
  EXPECT_EQ(m.cells, (std::vector<int32_t>{1, 2, 3, -4, 5, 0}));
  EXPECT_TRUE(m.objects_in_graph);
  EXPECT_FALSE(m.stale);
  const ecar::VisibleStructure back = fromMsg(m);
  ASSERT_EQ(back.planes.size(), 1u);
  EXPECT_EQ(back.planes[0].id, wall.id);
  ASSERT_EQ(back.objects.size(), 1u);
  EXPECT_EQ(back.objects[0].id, live.id);
  EXPECT_EQ(back.cells, v.cells);
  EXPECT_TRUE(back.objects_computed);
  EXPECT_NEAR(back.milliseconds, 2.5, 1e-4);
  EXPECT_NEAR(back.cpu_ms, 1.25, 1e-4);
  m.cells.pop_back();
  EXPECT_THROW(fromMsg(m), ecar::Error);
}

}  // namespace
}  // namespace ecar_bridge
