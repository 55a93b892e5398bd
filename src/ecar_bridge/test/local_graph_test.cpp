// The local graph's wire encoding: TrackedPoint quantisation, positions by
// index, edgeslam keyframes and map points, planes and objects, bad fields.
#include "ecar_bridge/local_graph.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
namespace {

using testing::someObject;
using testing::somePose;

void expectPoseNear(const ecar::SE3& a, const ecar::SE3& b) {
  EXPECT_LT((a.translation() - b.translation()).norm(), 1e-9);
  EXPECT_LT((a.linear() - b.linear()).norm(), 1e-9);
}

TEST(TrackedPointTest, RoundTripsOnItsGrid) {
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
  p.v = 45.0625f;  // 360.5 -> 361
  EXPECT_EQ(toMsg(p).v, 361);
}

TEST(MapPointFullTest, RoundTripAndBadFields) {
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
  ecar_msgs::MapPointFull bad = m;
  bad.normal[1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.max_distance = 0.1f;  // below min_distance
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(KeyFrameInfoTest, RoundTrips) {
  ecar::GraphKeyFrame kf;
  kf.id = ecar::KeyFrameId(5);
  kf.device = "device_1";
  kf.T_w_c = somePose();
  kf.points = {ecar::MapPointId(1), ecar::MapPointId(8)};
  const ecar::GraphKeyFrame kf2 = fromMsg(toMsg(kf));
  EXPECT_EQ(kf2.device, "device_1");
  EXPECT_EQ(kf2.id, kf.id);
  EXPECT_EQ(kf2.points, kf.points);
  EXPECT_TRUE(kf2.T_w_c.isApprox(kf.T_w_c, 1e-12));
}

ecar::LocalGraph ecarGraph() {
  ecar::LocalGraph g;
  g.device = "device_0";
  g.frame_index = 12;
  g.status = ecar::GraphStatus::kRelocalised;
  g.T_w_c = somePose();
  g.map_epoch = 77;
  for (uint32_t i = 1; i <= 5; ++i) {
    g.points.push_back({ecar::MapPointId(i), 10.0f * i, 20.0f, 45.0f, 1});
  }
  g.positions.push_back({ecar::MapPointId(2), Eigen::Vector3f(1.0f, 2.0f, 3.5f)});
  ecar::Plane floor;
  floor.id = ecar::PlaneId(2);
  floor.label = ecar::PlaneLabel::kFloor;
  floor.boundary = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}};
  g.planes.push_back(floor);
  g.removed_planes = {ecar::PlaneId(5), ecar::PlaneId(9)};
  g.objects.push_back(someObject());
  return g;
}

TEST(LocalGraphTest, EcarRoundTrip) {
  const ecar::LocalGraph g = ecarGraph();
  ecar_msgs::LocalGraph msg;
  toMsg(g, &msg);
  EXPECT_EQ(msg.header.frame_id, "map");
  EXPECT_EQ(msg.device_id, "device_0");
  EXPECT_EQ(msg.status, ecar_msgs::LocalGraph::RELOCALISED);
  EXPECT_EQ(msg.map_epoch, 77u);
  EXPECT_EQ(msg.sync_mode, ecar_msgs::LocalGraph::SYNC_ECAR);
  EXPECT_EQ(msg.points.size(), 5u);
  ASSERT_EQ(msg.positions.size(), 1u);
  EXPECT_EQ(msg.positions[0].index, 1);  // points[1] has id 2
  const ecar::LocalGraph back = fromMsg(msg);
  EXPECT_EQ(back.device, "device_0");
  EXPECT_EQ(back.frame_index, 12u);
  EXPECT_EQ(back.status, ecar::GraphStatus::kRelocalised);
  EXPECT_EQ(back.map_epoch, 77u);
  expectPoseNear(back.T_w_c, g.T_w_c);
  ASSERT_EQ(back.points.size(), 5u);
  EXPECT_EQ(back.points[4].id, ecar::MapPointId(5));
  EXPECT_FLOAT_EQ(back.points[4].u, 50.0f);
  ASSERT_EQ(back.positions.size(), 1u);
  EXPECT_EQ(back.positions[0].id, ecar::MapPointId(2));
  EXPECT_FLOAT_EQ(back.positions[0].p_w.z(), 3.5f);
  ASSERT_EQ(back.planes.size(), 1u);
  EXPECT_EQ(back.planes[0].label, ecar::PlaneLabel::kFloor);
  EXPECT_EQ(back.removed_planes, g.removed_planes);
  ASSERT_EQ(back.objects.size(), 1u);
  EXPECT_EQ(back.objects[0].version, 9u);
  // Plane id 0 is no plane.
  ecar_msgs::LocalGraph zero = msg;
  zero.removed_planes.push_back(0);
  try {
    fromMsg(zero);
    ADD_FAILURE() << "removed plane 0 accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("removed_planes[2]"), std::string::npos) << e.what();
  }
  // A position whose point is not in the graph cannot be encoded.
  ecar::LocalGraph wrong = g;
  wrong.positions.push_back({ecar::MapPointId(99), Eigen::Vector3f(1, 2, 3)});
  EXPECT_THROW(toMsg(wrong, &msg), ecar::Error);
}

TEST(LocalGraphTest, EdgeslamRoundTrip) {
  ecar::LocalGraph g;
  g.frame_index = 8;
  g.status = ecar::GraphStatus::kOk;
  g.T_w_c = somePose();
  g.mode = ecar::SyncMode::kEdgeSlam;
  g.keyframes.push_back({ecar::KeyFrameId(3), "device_1", somePose(), {ecar::MapPointId(7)}});
  ecar::GraphMapPoint s;
  s.id = ecar::MapPointId(7);
  s.p_w = Eigen::Vector3f(0.5f, 1.0f, 2.0f);
  s.normal = Eigen::Vector3f(0.0f, 0.6f, 0.8f);
  s.min_distance = 0.5f;
  s.max_distance = 4.0f;
  for (int i = 0; i < 32; ++i) s.descriptor[i] = static_cast<uint8_t>(i * 7);
  g.map_points.push_back(s);
  ecar_msgs::LocalGraph msg;
  toMsg(g, &msg);
  EXPECT_EQ(msg.sync_mode, ecar_msgs::LocalGraph::SYNC_EDGESLAM);
  EXPECT_EQ(msg.keyframes[0].device_id, "device_1");
  const ecar::LocalGraph back = fromMsg(msg);
  EXPECT_EQ(back.mode, ecar::SyncMode::kEdgeSlam);
  EXPECT_EQ(back.frame_index, 8u);
  expectPoseNear(back.T_w_c, g.T_w_c);
  ASSERT_EQ(back.keyframes.size(), 1u);
  EXPECT_EQ(back.keyframes[0].id, ecar::KeyFrameId(3));
  expectPoseNear(back.keyframes[0].T_w_c, g.T_w_c);
  ASSERT_EQ(back.keyframes[0].points.size(), 1u);
  ASSERT_EQ(back.map_points.size(), 1u);
  EXPECT_EQ(back.map_points[0].id, s.id);
  EXPECT_EQ(back.map_points[0].p_w, s.p_w);
  EXPECT_EQ(back.map_points[0].normal, s.normal);
  EXPECT_FLOAT_EQ(back.map_points[0].max_distance, 4.0f);
  EXPECT_EQ(back.map_points[0].descriptor, s.descriptor);
  msg.map_points[0].normal[1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(fromMsg(msg), ecar::Error);
}

TEST(LocalGraphTest, BadFieldsAreReportedByName) {
  ecar_msgs::LocalGraph msg;
  msg.status = ecar_msgs::LocalGraph::OK;
  msg.pose.orientation.w = 1.0;
  msg.points.resize(3);
  msg.positions.resize(3);
  for (uint16_t i = 0; i < 3; ++i) msg.positions[i].index = i;
  msg.positions[2].y = std::numeric_limits<float>::quiet_NaN();
  try {
    fromMsg(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("positions[2]"), std::string::npos) << e.what();
  }
  // A position naming a point the graph does not have.
  msg.positions[2].y = 0.0f;
  msg.positions[1].index = 3;
  try {
    fromMsg(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("positions[1].index"), std::string::npos) << e.what();
  }
  msg.positions.clear();
  msg.pose.position.x = std::numeric_limits<double>::infinity();
  try {
    fromMsg(msg);
    FAIL() << "no exception";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("pose"), std::string::npos) << e.what();
  }
  // The pose of a graph that is not tracked is not read.
  msg.status = ecar_msgs::LocalGraph::LOST;
  EXPECT_NO_THROW(fromMsg(msg));
  msg.status = 9;
  EXPECT_THROW(fromMsg(msg), ecar::Error);
}

TEST(LocalGraphTest, EveryListIsBounded) {
  const auto error = [](const ecar_msgs::LocalGraph& msg) {
    try {
      fromMsg(msg);
    } catch (const ecar::Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  ecar_msgs::LocalGraph msg;
  msg.status = ecar_msgs::LocalGraph::LOST;
  msg.points.resize(kMaxGraphPoints + 1);
  EXPECT_NE(error(msg).find("points: 65536 entries, more than 65535"), std::string::npos);
  msg.points.resize(2);
  msg.positions.resize(3);
  EXPECT_NE(error(msg).find("positions: 3 entries, more than 2"), std::string::npos);
  msg.positions.clear();
  msg.keyframes.resize(kMaxGraphKeyFrames + 1);
  EXPECT_NE(error(msg).find("keyframes: 1001 entries"), std::string::npos) << error(msg);
  msg.keyframes.resize(1);
  msg.keyframes[0].point_ids.resize(kMaxGraphMapPoints + 1);
  EXPECT_NE(error(msg).find("keyframes[].point_ids"), std::string::npos) << error(msg);
  msg.keyframes.clear();
  msg.planes.resize(1);
  msg.planes[0].boundary.resize(kMaxPlaneBoundary + 1);
  EXPECT_NE(error(msg).find("planes[].boundary"), std::string::npos) << error(msg);
  msg.planes.clear();
  msg.objects.resize(kMaxGraphObjects + 1);
  EXPECT_NE(error(msg).find("objects: 100001 entries"), std::string::npos) << error(msg);
}

TEST(LocalGraphTest, BadPlanesAndObjectsAreSkippedWithTheirReason) {
  ecar_msgs::LocalGraph msg;
  toMsg(ecarGraph(), &msg);
  msg.objects.push_back(msg.objects[0]);
  msg.objects[1].start.x = std::numeric_limits<double>::quiet_NaN();
  msg.planes[0].normal.z = 3.0;
  EXPECT_THROW(fromMsg(msg), ecar::Error);
  std::vector<std::string> skipped;
  const ecar::LocalGraph g = fromMsg(msg, &skipped);
  EXPECT_TRUE(g.planes.empty());
  EXPECT_EQ(g.objects.size(), 1u);
  ASSERT_EQ(skipped.size(), 2u);
  EXPECT_NE(skipped[0].find("planes[0].normal"), std::string::npos) << skipped[0];
  EXPECT_NE(skipped[1].find("objects[1].start"), std::string::npos) << skipped[1];
}

}  // namespace
}  // namespace ecar_bridge
