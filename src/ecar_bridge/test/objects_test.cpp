// Structure and interaction conversions: Plane, VirtualObject, Interaction,
// InteractionResult, Touch.
#include "ecar_bridge/objects.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "ecar_bridge/geometry.h"
#include "ecar_core/common/error.h"
#include "test_support.h"

namespace ecar_bridge {
namespace {

using testing::someObject;

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
  EXPECT_EQ(a.map, b.map);
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
  const ecar_msgs::Plane m = toMsg(p);
  EXPECT_EQ(m.id, 3u);
  EXPECT_EQ(m.label, ecar_msgs::Plane::WALL);
  EXPECT_DOUBLE_EQ(m.normal.y, 0.8);
  EXPECT_DOUBLE_EQ(m.offset, -2.5);
  ASSERT_EQ(m.boundary.size(), 3u);
  EXPECT_EQ(fromMsg(m.boundary[2]), p.boundary[2]);
  EXPECT_EQ(m.version, 4u);
  EXPECT_EQ(m.num_points, 120u);
  const ecar::Plane back = fromMsg(m);
  EXPECT_EQ(back.id, p.id);
  EXPECT_EQ(back.label, p.label);
  EXPECT_LT((back.normal - p.normal).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(back.offset, p.offset);
  EXPECT_EQ(back.boundary, p.boundary);
  EXPECT_EQ(back.version, 4u);
  EXPECT_EQ(back.num_points, 120u);
  ecar_msgs::Plane bad = m;
  bad.normal.x = 2.0;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.label = 7;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.boundary[1].z = std::numeric_limits<double>::infinity();
  try {
    fromMsg(bad, "planes[0]");
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("planes[0].boundary[1]"), std::string::npos) << e.what();
  }
}

TEST(VirtualObjectTest, RoundTripAndBadFields) {
  const ecar::VirtualObject vo = someObject();
  const ecar_msgs::VirtualObject m = toMsg(vo);
  EXPECT_EQ(m.id, 17u);
  EXPECT_EQ(m.kind, ecar_msgs::VirtualObject::LINE);
  EXPECT_EQ(fromMsg(m.start), vo.start);
  EXPECT_EQ(m.r, 200);
  EXPECT_FLOAT_EQ(m.width, 0.025f);
  EXPECT_EQ(fromMsg(m.normal), vo.normal);
  EXPECT_EQ(m.plane_id, 4u);
  EXPECT_EQ(m.owner, "device_1");
  EXPECT_EQ(m.version, 9u);
  EXPECT_TRUE(m.deleted);
  EXPECT_EQ(m.map_id, 3u);
  expectObjectEq(fromMsg(m), vo);
  ecar_msgs::VirtualObject bad = m;
  bad.start.y = std::numeric_limits<double>::quiet_NaN();
  try {
    fromMsg(bad, "objects[2]");
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("objects[2].start"), std::string::npos) << e.what();
  }
  bad = m;
  bad.kind = 5;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.normal.z = 0.0;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.width = -1.0f;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(InteractionTest, RoundTripOfEveryType) {
  ecar::VoRequest r;
  r.device = "device_0";
  r.request_id = 33;
  r.type = ecar::VoRequestType::kManipulate;
  r.object_id = ecar::ObjectId(17);
  r.object = someObject();
  r.base_version = 9;
  std_msgs::Header h;
  h.frame_id = "map";
  const ecar_msgs::Interaction m = toMsg(r, h);
  EXPECT_EQ(m.device_id, "device_0");
  EXPECT_EQ(m.header.frame_id, "map");
  EXPECT_EQ(m.type, ecar_msgs::Interaction::MANIPULATE);
  EXPECT_EQ(m.object_id, 17u);
  const ecar::VoRequest back = fromMsg(m);
  EXPECT_EQ(back.device, "device_0");
  EXPECT_EQ(back.request_id, 33u);
  EXPECT_EQ(back.type, r.type);
  EXPECT_EQ(back.object_id, r.object_id);
  EXPECT_EQ(back.base_version, 9u);
  expectObjectEq(back.object, r.object);
  for (auto type : {ecar::VoRequestType::kRegister, ecar::VoRequestType::kDelete}) {
    r.type = type;
    EXPECT_EQ(fromMsg(toMsg(r, h)).type, type);
  }
  // A DELETE's object is not read: a default (or garbage) one is fine.
  ecar_msgs::Interaction del = toMsg(r, h);
  del.object.start.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NO_THROW(fromMsg(del));
  ecar_msgs::Interaction bad = m;
  bad.type = 7;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.object.end.z = std::numeric_limits<double>::quiet_NaN();
  try {
    fromMsg(bad);
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("object.end"), std::string::npos) << e.what();
  }
}

TEST(InteractionResultTest, RoundTrip) {
  const ecar::VoResult r{"device_0",        12, false,
                         ecar::ObjectId(5), 3,  "stale base_version 2 (store has 3)"};
  const ecar_msgs::InteractionResult m = toMsg(r, std_msgs::Header());
  EXPECT_EQ(m.device_id, "device_0");
  const ecar::VoResult back = fromMsg(m);
  EXPECT_EQ(back.device, "device_0");
  EXPECT_EQ(back.request_id, 12u);
  EXPECT_FALSE(back.accepted);
  EXPECT_EQ(back.object_id, ecar::ObjectId(5));
  EXPECT_EQ(back.version, 3u);
  EXPECT_EQ(back.reason, r.reason);
  // resultOf: the answer to a request with the store's outcome.
  ecar::VoRequest request;
  request.device = "device_1";
  request.request_id = 77;
  ecar::VoOutcome o;
  o.accepted = true;
  o.id = ecar::ObjectId(12);
  o.version = 6;
  const ecar::VoResult res = ecar::resultOf(request, o);
  EXPECT_EQ(res.device, "device_1");
  EXPECT_EQ(res.request_id, 77u);
  EXPECT_TRUE(res.accepted);
  EXPECT_EQ(res.object_id, o.id);
  EXPECT_EQ(res.version, 6u);
}

TEST(TouchTest, RoundTripAndValidation) {
  ecar::Touch t;
  t.uv = Eigen::Vector2d(120.5, 300.25);
  t.phase = ecar::TouchPhase::kMove;
  t.r = 1;
  t.g = 2;
  t.b = 3;
  t.width = 0.04;
  std_msgs::Header h;
  h.frame_id = "device_0/camera";
  const ecar_msgs::Touch m = toMsg(t, h);
  EXPECT_EQ(m.phase, ecar_msgs::Touch::MOVE);
  const ecar::Touch back = fromMsg(m);
  EXPECT_EQ(back.uv, t.uv);
  EXPECT_EQ(back.phase, t.phase);
  EXPECT_EQ(back.r, 1);
  EXPECT_EQ(back.g, 2);
  EXPECT_EQ(back.b, 3);
  EXPECT_FLOAT_EQ(back.width, 0.04f);
  ecar_msgs::Touch bad = m;
  bad.u = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.width = 0.0f;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
  bad = m;
  bad.phase = 3;
  EXPECT_THROW(fromMsg(bad), ecar::Error);
}

TEST(TouchTest, ScriptedTouchesCarryPixelPhaseColourAndWidth) {
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
    const ecar_msgs::Touch m = toMsg(e, testing::someHeader());
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

}  // namespace
}  // namespace ecar_bridge
