// DeviceObjects: held planes and VOs by version, tombstones, touch rays on a
// floor plane, strokes to lines, grabbing and moving a VO, projection for drawing.
#include "ecar_core/device/device_objects.h"

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

PinholeCamera testCamera() { return PinholeCamera(CameraParams()); }

/// The floor z = 0 (normal up), 20 m x 20 m around the origin.
Plane floorPlane(uint32_t version = 1) {
  Plane p;
  p.id = PlaneId(7);
  p.label = PlaneLabel::kFloor;
  p.normal = Eigen::Vector3d::UnitZ();
  p.offset = 0.0;
  p.boundary = {{-10, -10, 0}, {10, -10, 0}, {10, 10, 0}, {-10, 10, 0}};
  p.version = version;
  p.num_points = 100;
  return p;
}

VirtualObject line(uint32_t id, uint32_t version, const Eigen::Vector3d& a,
                   const Eigen::Vector3d& b) {
  VirtualObject vo;
  vo.id = ObjectId(id);
  vo.kind = VoKind::kLine;
  vo.start = a;
  vo.end = b;
  vo.position = 0.5 * (a + b);
  vo.width = 0.02f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.plane = PlaneId(7);
  vo.owner = "device_1";
  vo.version = version;
  return vo;
}

/// A camera 1.5 m above the floor looking at (0, 5, 0).
SE3 floorPose() { return lookAt({0, 0, 1.5}, {0, 5, 0}); }

Eigen::Vector2d pixelOf(const SE3& T_w_c, const Eigen::Vector3d& p_w) {
  return *testCamera().project(T_w_c.inverse() * p_w);
}

Touch touchAt(const SE3& T_w_c, const Eigen::Vector3d& p_w, TouchPhase phase) {
  Touch t;
  t.uv = pixelOf(T_w_c, p_w);
  t.phase = phase;
  t.r = 255;
  t.g = 0;
  t.b = 10;
  t.width = 0.03f;
  return t;
}

TEST(DeviceObjects, ConfigValidationNamesTheKey) {
  DeviceObjectsConfig c;
  c.segment_length = 0.0;
  try {
    c.validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("segment_length"), std::string::npos) << e.what();
  }
  c = DeviceObjectsConfig();
  c.min_segment_length = 1.0;
  EXPECT_THROW(c.validate(), Error);
  c = DeviceObjectsConfig();
  c.pick_radius = std::nan("");
  EXPECT_THROW(DeviceObjects(c, "d"), Error);
}

TEST(DeviceObjects, HeldObjectsFollowVersionsAndTombstones) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  EXPECT_EQ(objects.applyGraph({floorPlane(2)}, {line(1, 2, {0, 1, 0}, {1, 1, 0})}), 2u);
  // Older and equal versions are ignored.
  Plane old_plane = floorPlane(1);
  old_plane.offset = 5.0;
  EXPECT_EQ(objects.applyGraph(
                {old_plane}, {line(1, 1, {0, 2, 0}, {1, 2, 0}), line(1, 2, {0, 3, 0}, {1, 3, 0})}),
            0u);
  EXPECT_DOUBLE_EQ(objects.planes().at(PlaneId(7)).offset, 0.0);
  EXPECT_DOUBLE_EQ(objects.object(ObjectId(1))->start.y(), 1.0);
  // A newer version replaces.
  EXPECT_EQ(objects.applyGraph({}, {line(1, 3, {0, 4, 0}, {1, 4, 0})}), 1u);
  EXPECT_DOUBLE_EQ(objects.object(ObjectId(1))->start.y(), 4.0);
  EXPECT_EQ(objects.object(ObjectId(1))->version, 3u);
  // A tombstone removes it; older states never bring it back.
  VirtualObject tomb = line(1, 4, {0, 4, 0}, {1, 4, 0});
  tomb.deleted = true;
  EXPECT_EQ(objects.applyGraph({}, {tomb}), 1u);
  EXPECT_FALSE(objects.object(ObjectId(1)));
  EXPECT_EQ(objects.applyGraph({}, {line(1, 3, {0, 4, 0}, {1, 4, 0})}), 0u);
  EXPECT_FALSE(objects.object(ObjectId(1)));
  EXPECT_TRUE(objects.objects().empty());
  // A plane the server fused into another goes; an unknown id changes nothing.
  ASSERT_EQ(objects.planes().count(PlaneId(7)), 1u);
  EXPECT_EQ(objects.applyGraph({}, {}, {PlaneId(7), PlaneId(40)}), 1u);
  EXPECT_TRUE(objects.planes().empty());
  objects.clear();
  EXPECT_TRUE(objects.planes().empty());
}

TEST(DeviceObjects, RayHitsTheFloorAtTheAnalyticPoint) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  EXPECT_FALSE(objects.cast(pixelOf(T, {1, 4, 0}), T, cam));  // no planes yet
  objects.applyGraph({floorPlane()}, {});
  for (const Eigen::Vector3d& p :
       {Eigen::Vector3d(1, 4, 0), Eigen::Vector3d(-2, 8, 0), Eigen::Vector3d(0, 5, 0)}) {
    const auto hit = objects.cast(pixelOf(T, p), T, cam);
    ASSERT_TRUE(hit);
    EXPECT_EQ(hit->plane, PlaneId(7));
    EXPECT_FALSE(hit->object.valid());
    EXPECT_LT((hit->p_w - p).norm(), 1e-6) << hit->p_w.transpose();
    EXPECT_NEAR(hit->distance, (p - T.translation()).norm(), 1e-6);
  }
  // Beyond the boundary (plus margin) and above the horizon: no hit.
  EXPECT_FALSE(objects.cast(pixelOf(T, {0, 10.5, 0}), T, cam));
  EXPECT_FALSE(objects.cast(Eigen::Vector2d(320, 5), T, cam));
}

TEST(DeviceObjects, StrokeBecomesChainedLinesOnTheFloor) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  objects.applyGraph({floorPlane()}, {});
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  std::vector<VoRequest> out;
  EXPECT_EQ(objects.touch(touchAt(T, {0, 3, 0}, TouchPhase::kBegin), T, cam, &out),
            TouchOutcome::kStroke);
  EXPECT_TRUE(out.empty());
  EXPECT_TRUE(objects.stroking());
  for (int k = 1; k <= 10; ++k) {
    objects.touch(touchAt(T, {0.02 * k, 3, 0}, TouchPhase::kMove), T, cam, &out);
  }
  EXPECT_EQ(objects.touch(touchAt(T, {0.2, 3, 0}, TouchPhase::kEnd), T, cam, &out),
            TouchOutcome::kStroke);
  EXPECT_FALSE(objects.stroking());
  // Segments every 0.06 m (first step past 0.05), the rest at END: 4 lines.
  ASSERT_EQ(out.size(), 4u);
  for (size_t i = 0; i < out.size(); ++i) {
    const VoRequest& r = out[i];
    EXPECT_EQ(r.request_id, i + 1);
    EXPECT_EQ(r.type, VoRequestType::kRegister);
    EXPECT_FALSE(r.object_id.valid());
    EXPECT_EQ(r.base_version, 0u);
    const VirtualObject& vo = r.object;
    EXPECT_EQ(vo.kind, VoKind::kLine);
    EXPECT_NEAR(vo.start.z(), 0.0, 1e-9);
    EXPECT_NEAR(vo.end.z(), 0.0, 1e-9);
    EXPECT_NEAR(vo.start.y(), 3.0, 1e-6);
    EXPECT_LT((vo.normal - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
    EXPECT_EQ(vo.plane, PlaneId(7));
    EXPECT_EQ(vo.owner, "device_0");
    EXPECT_EQ(vo.r, 255);
    EXPECT_EQ(vo.b, 10);
    EXPECT_FLOAT_EQ(vo.width, 0.03f);
    EXPECT_LT((vo.position - 0.5 * (vo.start + vo.end)).norm(), 1e-12);
    if (i > 0) {
      EXPECT_LT((vo.start - out[i - 1].object.end).norm(), 1e-12);
    }
  }
  EXPECT_LT((out.front().object.start - Eigen::Vector3d(0, 3, 0)).norm(), 1e-6);
  EXPECT_LT((out.front().object.end - Eigen::Vector3d(0.06, 3, 0)).norm(), 1e-6);
  EXPECT_LT((out.back().object.end - Eigen::Vector3d(0.2, 3, 0)).norm(), 1e-6);
  EXPECT_EQ(objects.numInFlight(), 4u);

  // Answers: accepted ones become held VOs with their ids; a rejection says why.
  std::string what;
  for (uint32_t i = 1; i <= 3; ++i) {
    EXPECT_TRUE(objects.applyResult({"", i, true, ObjectId(100 + i), 1, ""}, &what)) << what;
  }
  EXPECT_FALSE(objects.applyResult({"", 4, false, ObjectId(), 0, "out of the map"}, &what));
  EXPECT_NE(what.find("out of the map"), std::string::npos) << what;
  EXPECT_FALSE(
      objects.applyResult({"", 4, true, ObjectId(104), 1, ""}, &what));  // answered already
  EXPECT_EQ(objects.numInFlight(), 0u);
  ASSERT_EQ(objects.objects().size(), 3u);
  EXPECT_EQ(objects.object(ObjectId(102))->version, 1u);
  EXPECT_LT((objects.object(ObjectId(101))->start - Eigen::Vector3d(0, 3, 0)).norm(), 1e-6);
}

TEST(DeviceObjects, GrabbedObjectMovesAlongItsPlane) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  objects.applyGraph({floorPlane()}, {line(5, 3, {0, 3, 0}, {0.2, 3, 0})});
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  // The VO is hit before the floor under it.
  const auto hit = objects.cast(pixelOf(T, {0.1, 3, 0}), T, cam);
  ASSERT_TRUE(hit);
  EXPECT_EQ(hit->object, ObjectId(5));
  std::vector<VoRequest> out;
  objects.touch(touchAt(T, {0.1, 3, 0}, TouchPhase::kBegin), T, cam, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(objects.grabbing());
  EXPECT_EQ(out[0].type, VoRequestType::kManipulate);
  EXPECT_EQ(out[0].object_id, ObjectId(5));
  EXPECT_EQ(out[0].base_version, 3u);
  EXPECT_LT((out[0].object.start - Eigen::Vector3d(0, 3, 0)).norm(), 1e-9);
  objects.touch(touchAt(T, {0.35, 3.25, 0}, TouchPhase::kMove), T, cam, &out);
  objects.touch(touchAt(T, {0.6, 3.5, 0}, TouchPhase::kEnd), T, cam, &out);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_FALSE(objects.grabbing());
  const Eigen::Vector3d delta(0.5, 0.5, 0.0);
  const VirtualObject& moved = out[2].object;
  EXPECT_EQ(out[2].request_id, out[0].request_id + 2);
  EXPECT_LT((moved.start - Eigen::Vector3d(0, 3, 0) - delta).norm(), 1e-6);
  EXPECT_LT((moved.end - Eigen::Vector3d(0.2, 3, 0) - delta).norm(), 1e-6);
  EXPECT_LT((moved.position - Eigen::Vector3d(0.1, 3, 0) - delta).norm(), 1e-6);
  EXPECT_NEAR(moved.start.z(), 0.0, 1e-9);
  EXPECT_EQ(moved.owner, "device_1");
  // The held copy moved at once; the accepted answer raises its version.
  EXPECT_LT((objects.object(ObjectId(5))->start - moved.start).norm(), 1e-12);
  std::string what;
  EXPECT_TRUE(objects.applyResult({"", out[2].request_id, true, ObjectId(5), 6, ""}, &what))
      << what;
  EXPECT_EQ(objects.object(ObjectId(5))->version, 6u);
  // An older server state (an earlier step of the drag) does not move it back.
  objects.applyGraph({}, {line(5, 5, {0.25, 3.25, 0}, {0.45, 3.25, 0})});
  EXPECT_LT((objects.object(ObjectId(5))->start - moved.start).norm(), 1e-12);
}

TEST(DeviceObjects, TouchOnNothingIsMissedAndItsMovesIgnored) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  std::vector<VoRequest> out;
  // No plane held yet: the stroke's BEGIN misses, its MOVE and END do nothing.
  EXPECT_EQ(objects.touch(touchAt(T, {0, 3, 0}, TouchPhase::kBegin), T, cam, &out),
            TouchOutcome::kMissed);
  EXPECT_EQ(objects.touch(touchAt(T, {0.1, 3, 0}, TouchPhase::kMove), T, cam, &out),
            TouchOutcome::kIgnored);
  EXPECT_EQ(objects.touch(touchAt(T, {0.2, 3, 0}, TouchPhase::kEnd), T, cam, &out),
            TouchOutcome::kIgnored);
  EXPECT_TRUE(out.empty());
  EXPECT_FALSE(objects.stroking());
  // With the floor held, the same BEGIN starts a stroke; one above the horizon misses.
  objects.applyGraph({floorPlane()}, {});
  EXPECT_EQ(objects.planeCount(), 1u);
  EXPECT_EQ(objects.touch(touchAt(T, {0, 3, 0}, TouchPhase::kBegin), T, cam, &out),
            TouchOutcome::kStroke);
  Touch sky = touchAt(T, {0, 3, 0}, TouchPhase::kBegin);
  sky.uv = Eigen::Vector2d(320, 5);
  EXPECT_EQ(objects.touch(sky, T, cam, &out), TouchOutcome::kMissed);
}

TEST(DeviceObjects, GrabbingAVoIsAGrab) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  objects.applyGraph({floorPlane()}, {line(5, 3, {0, 3, 0}, {0.2, 3, 0})});
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  std::vector<VoRequest> out;
  EXPECT_EQ(objects.touch(touchAt(T, {0.1, 3, 0}, TouchPhase::kBegin), T, cam, &out),
            TouchOutcome::kGrab);
  EXPECT_EQ(objects.touch(touchAt(T, {0.1, 4, 0}, TouchPhase::kEnd), T, cam, &out),
            TouchOutcome::kGrab);
  EXPECT_EQ(out.size(), 2u);
}

TEST(DeviceObjects, RejectedMoveYieldsToTheServersState) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  objects.applyGraph({floorPlane()}, {line(5, 3, {0, 3, 0}, {0.2, 3, 0})});
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  std::vector<VoRequest> out;
  objects.touch(touchAt(T, {0.1, 3, 0}, TouchPhase::kBegin), T, cam, &out);
  objects.touch(touchAt(T, {0.1, 4, 0}, TouchPhase::kEnd), T, cam, &out);
  std::string what;
  EXPECT_FALSE(objects.applyResult({"", out[1].request_id, false, ObjectId(5), 3, "stale"}, &what));
  // The server's state of the same version replaces the local move.
  objects.applyGraph({}, {line(5, 3, {0, 3, 0}, {0.2, 3, 0})});
  EXPECT_NEAR(objects.object(ObjectId(5))->start.y(), 3.0, 1e-12);
}

TEST(DeviceObjects, ProjectionClipsAndScalesWithDepth) {
  const PinholeCamera cam = testCamera();
  const SE3 I = SE3::Identity();
  auto l = projectSegment(I, cam, {0, 0, 2}, {1, 0, 2}, 0.02, 0.05, 40.0);
  ASSERT_TRUE(l);
  EXPECT_NEAR(l->a.x(), 319.5, 1e-9);
  EXPECT_NEAR(l->b.x(), 319.5 + 262.5, 1e-9);
  EXPECT_NEAR(l->b.y(), 239.5, 1e-9);
  EXPECT_NEAR(l->thickness, 525.0 * 0.02 / 2.0, 1e-9);
  // Far away: at least 1 px; near: at most max_thickness.
  EXPECT_DOUBLE_EQ(projectSegment(I, cam, {0, 0, 50}, {1, 0, 50}, 0.02, 0.05, 40.0)->thickness,
                   1.0);
  EXPECT_DOUBLE_EQ(projectSegment(I, cam, {0, 0, 0.1}, {0, 0.01, 0.1}, 0.02, 0.05, 40.0)->thickness,
                   40.0);
  // Behind the camera: nothing; crossing the near plane: clipped at z = near.
  EXPECT_FALSE(projectSegment(I, cam, {0, 0, -1}, {1, 0, -2}, 0.02, 0.05, 40.0));
  l = projectSegment(I, cam, {1, 0, -1}, {1, 0, 1}, 0.02, 0.5, 40.0);
  ASSERT_TRUE(l);
  EXPECT_NEAR(l->a.x(), 319.5 + 525.0 * 1.0 / 0.5, 1e-6);
  EXPECT_NEAR(l->b.x(), 319.5 + 525.0, 1e-6);
  // A rotated, translated pose gives the same pixels as project().
  const SE3 T = floorPose();
  l = projectSegment(T, cam, {1, 4, 0}, {-1, 6, 0}, 0.05, 0.05, 40.0);
  ASSERT_TRUE(l);
  EXPECT_LT((l->a - pixelOf(T, {1, 4, 0})).norm(), 1e-9);
  EXPECT_LT((l->b - pixelOf(T, {-1, 6, 0})).norm(), 1e-9);
}

TEST(DeviceObjects, DrawListHasHeldAndPendingLines) {
  DeviceObjects objects(DeviceObjectsConfig(), "device_0");
  const SE3 T = floorPose();
  const PinholeCamera cam = testCamera();
  VirtualObject behind = line(2, 1, {0, -3, 0}, {0.2, -3, 0});
  objects.applyGraph({floorPlane()}, {line(1, 1, {0, 3, 0}, {0.2, 3, 0}), behind});
  std::vector<ScreenLine> lines;
  objects.drawList(T, cam, &lines);
  ASSERT_EQ(lines.size(), 1u);  // the one behind the camera is clipped away
  EXPECT_FALSE(lines[0].pending);
  EXPECT_LT((lines[0].a - pixelOf(T, {0, 3, 0})).norm(), 1e-9);
  std::vector<VoRequest> out;
  objects.touch(touchAt(T, {1, 5, 0}, TouchPhase::kBegin), T, cam, &out);
  objects.touch(touchAt(T, {1.1, 5, 0}, TouchPhase::kMove), T, cam, &out);
  objects.touch(touchAt(T, {1.13, 5, 0}, TouchPhase::kMove), T, cam, &out);
  ASSERT_EQ(out.size(), 1u);
  objects.drawList(T, cam, &lines);
  ASSERT_EQ(lines.size(), 3u);  // held, in flight, stroke tail
  EXPECT_TRUE(lines[1].pending);
  EXPECT_TRUE(lines[2].pending);
  EXPECT_EQ(lines[2].red, 255);
  EXPECT_EQ(lines[2].blue, 10);
  EXPECT_LT((lines[2].b - pixelOf(T, {1.13, 5, 0})).norm(), 1e-6);
}

}  // namespace
}  // namespace ecar
