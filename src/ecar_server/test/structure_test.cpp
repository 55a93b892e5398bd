// Structure: planes from a keyframe's points, the keyframe's cells, and which
// planes and virtual objects reach a pose (grid and keyframe attachment).
#include "ecar_server/structure.h"

#include <random>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_server/markers.h"
#include "structure_fixtures.h"

namespace ecar_server {
namespace {

using ecar_server::testing::camera640;
using ecar_server::testing::floorKeyFrame;
using ecar_server::testing::lookingAlongX;

ecar::VirtualObject lineAt(double x, double y) {
  ecar::VirtualObject vo;
  vo.start = Eigen::Vector3d(x, y, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, y, 0.0);
  vo.width = 0.05f;
  vo.owner = "device_0";
  return vo;
}

bool holds(const VisibleStructure& v, ecar::ObjectId id) {
  for (const auto& o : v.objects) {
    if (o.id == id) return true;
  }
  return false;
}

TEST(StructureTest, FloorPlaneCellsAndObjectsInGridMode) {
  ServerConfig config;  // VO store in memory
  Structure s(config);
  const auto grid = s.gridConnection(camera640());
  const ecar::SE3 T_w_c = lookingAlongX(0.0);
  const KeyFrameStructure k =
      s.integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(1), T_w_c), T_w_c, *grid);
  ASSERT_EQ(k.update.created.size(), 1u);
  EXPECT_GT(k.cells, 100u);
  EXPECT_EQ(s.grid().cellsOfKeyFrame(ecar::KeyFrameId(1)).size(), k.cells);
  const std::vector<ecar::Plane> planes = s.planes().planes();
  ASSERT_EQ(planes.size(), 1u);
  EXPECT_EQ(planes[0].label, ecar::PlaneLabel::kFloor);
  EXPECT_GT(s.gridPlanes()->size(), 0u);

  const ecar::VoOutcome near = s.vos().registerObject(lineAt(4.0, 0.0));
  const ecar::VoOutcome far = s.vos().registerObject(lineAt(25.0, 0.0));  // beyond the points
  const ecar::VoOutcome behind = s.vos().registerObject(lineAt(-3.0, 0.0));
  ASSERT_TRUE(near.accepted && far.accepted && behind.accepted);

  const VisibleStructure v = s.visible(T_w_c, {ecar::KeyFrameId(1)}, *grid);
  EXPECT_TRUE(v.error.empty());
  ASSERT_EQ(v.planes.size(), 1u);
  EXPECT_EQ(v.planes[0].id, planes[0].id);
  EXPECT_FALSE(v.cells.empty());
  EXPECT_TRUE(holds(v, near.id));
  EXPECT_TRUE(holds(v, far.id));  // 25 m away: the per-point test reaches it
  EXPECT_FALSE(holds(v, behind.id));
  EXPECT_LT(v.milliseconds, 50.0);

  // Turned around, the camera sees the object behind it and not the others.
  ecar::SE3 T_back = lookingAlongX(1.0);
  T_back.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ()) * T_back.linear();
  const VisibleStructure back = s.visible(T_back, {}, *grid);
  EXPECT_TRUE(holds(back, behind.id));
  EXPECT_FALSE(holds(back, near.id));

  // A deleted object leaves the local graphs.
  ASSERT_TRUE(s.vos().remove(near.id).accepted);
  EXPECT_FALSE(holds(s.visible(T_w_c, {}, *grid), near.id));
}

TEST(StructureTest, KeyFrameModeFollowsTheLocalKeyFrames) {
  ServerConfig config;
  config.vo.attach_mode = ecar::VoAttachMode::kKeyFrame;
  Structure s(config);
  const auto grid = s.gridConnection(camera640());
  const ecar::SE3 T_w_c = lookingAlongX(0.0);
  s.integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(1), T_w_c), T_w_c, *grid);
  const ecar::VoOutcome r = s.vos().registerObject(lineAt(4.0, 0.0), ecar::KeyFrameId(1));
  ASSERT_TRUE(r.accepted);
  EXPECT_TRUE(holds(s.visible(T_w_c, {ecar::KeyFrameId(1)}, *grid), r.id));
  EXPECT_FALSE(holds(s.visible(T_w_c, {ecar::KeyFrameId(2)}, *grid), r.id));
  // Without a keyframe a registration is refused with a reason.
  const ecar::VoOutcome no = s.vos().registerObject(lineAt(4.0, 0.5));
  EXPECT_FALSE(no.accepted);
  EXPECT_FALSE(no.reason.empty());
}

TEST(StructureTest, AnUnopenableStoreLeavesThePlanes) {
  ServerConfig config;
  config.vo.database_path = "/nonexistent_dir_ecar/vo.sqlite";
  Structure s(config);
  const auto grid = s.gridConnection(camera640());
  const ecar::SE3 T_w_c = lookingAlongX(0.0);
  s.integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(1), T_w_c), T_w_c, *grid);
  const VisibleStructure v = s.visible(T_w_c, {}, *grid);
  EXPECT_EQ(v.planes.size(), 1u);
  EXPECT_TRUE(v.objects.empty());
  EXPECT_NE(v.error.find("nonexistent_dir_ecar"), std::string::npos) << v.error;
  EXPECT_THROW(s.vos(), ecar::Error);
}

TEST(StructureTest, MarkersShowPlanesObjectsAndCells) {
  ecar::Plane floor;
  floor.id = ecar::PlaneId(1);
  floor.label = ecar::PlaneLabel::kFloor;
  floor.boundary = {{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}};
  ecar::VirtualObject line = lineAt(1.0, 1.0);
  line.id = ecar::ObjectId(7);
  line.r = 255;
  ecar::VirtualObject gone = line;
  gone.id = ecar::ObjectId(8);
  gone.deleted = true;
  const DeviceCells cells{ecar::DeviceId(2), {{0, 0, 0}, {1, 0, 0}}};
  const visualization_msgs::MarkerArray m =
      structureMarkers({floor}, {line, gone}, {cells}, 0.1, "map", ros::Time(1.0));
  ASSERT_EQ(m.markers.size(), 3u);  // planes, one live object, one device's cells
  EXPECT_EQ(m.markers[0].ns, "planes");
  EXPECT_EQ(m.markers[0].points.size(), 6u);  // a quad: two triangles
  EXPECT_EQ(m.markers[0].colors[0].g, labelColour(ecar::PlaneLabel::kFloor).g);
  EXPECT_LT(m.markers[0].colors[0].a, 1.0f);
  EXPECT_EQ(m.markers[1].ns, "objects");
  EXPECT_EQ(m.markers[1].id, 7);
  EXPECT_FLOAT_EQ(m.markers[1].scale.x, 0.05f);
  EXPECT_FLOAT_EQ(m.markers[1].color.r, 1.0f);
  EXPECT_EQ(m.markers[1].points.size(), 2u);
  EXPECT_EQ(m.markers[2].ns, "cells");
  EXPECT_EQ(m.markers[2].id, 2);
  EXPECT_EQ(m.markers[2].points.size(), 2u);
  EXPECT_NEAR(m.markers[2].points[1].x, 0.15, 1e-9);
}

}  // namespace
}  // namespace ecar_server
