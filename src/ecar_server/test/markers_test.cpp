// The interactive markers of virtual objects: marker names, the MOVE_PLANE
// control's plane, and moves projected into the object's plane; and the
// vo.share mode parsing.
#include "ecar_server/markers.h"

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "ecar_core/common/error.h"
#include "ecar_server/config.h"

namespace ecar_server {
namespace {

Eigen::Quaterniond quat(const geometry_msgs::Quaternion& q) {
  return Eigen::Quaterniond(q.w, q.x, q.y, q.z);
}

ecar::VirtualObject wallLine() {
  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(42);
  vo.kind = ecar::VoKind::kLine;
  vo.start = Eigen::Vector3d(1.0, 2.0, 1.0);
  vo.end = Eigen::Vector3d(1.0, 2.6, 1.0);  // 0.6 m along y on the wall x = 1
  vo.position = 0.5 * (vo.start + vo.end);
  vo.normal = -Eigen::Vector3d::UnitX();
  vo.r = 255;
  vo.g = 0;
  vo.b = 51;
  vo.version = 3;
  return vo;
}

TEST(VoMarkers, NameRoundTrip) {
  EXPECT_EQ(voMarkerName(ecar::ObjectId(7)), "vo_7");
  EXPECT_EQ(voMarkerId("vo_7"), ecar::ObjectId(7));
  EXPECT_EQ(voMarkerId(voMarkerName(ecar::ObjectId(4294967295u))), ecar::ObjectId(4294967295u));
  for (const char* bad : {"", "vo_", "vo_0", "vo_x1", "vo_1a", "obj_3", "vo_4294967296",
                          "vo_99999999999", "VO_3", "vo_-1"}) {
    EXPECT_FALSE(voMarkerId(bad).valid()) << bad;
  }
}

TEST(VoMarkers, MovePlaneControlIsTheObjectsPlane) {
  const ecar::VirtualObject vo = wallLine();
  const visualization_msgs::InteractiveMarker im = voInteractiveMarker(vo, "map");
  EXPECT_EQ(im.name, "vo_42");
  EXPECT_EQ(im.header.frame_id, "map");
  EXPECT_DOUBLE_EQ(im.pose.position.x, 1.0);
  EXPECT_DOUBLE_EQ(im.pose.position.y, 2.3);
  EXPECT_DOUBLE_EQ(im.pose.position.z, 1.0);
  EXPECT_DOUBLE_EQ(im.pose.orientation.w, 1.0);
  ASSERT_EQ(im.controls.size(), 1u);
  const auto& c = im.controls[0];
  EXPECT_EQ(c.interaction_mode, visualization_msgs::InteractiveMarkerControl::MOVE_PLANE);
  EXPECT_TRUE(c.always_visible);
  // MOVE_PLANE moves orthogonally to the control's x axis: that is the normal.
  const Eigen::Vector3d x = quat(c.orientation) * Eigen::Vector3d::UnitX();
  EXPECT_NEAR((x - vo.normal).norm(), 0.0, 1e-9);
  EXPECT_NEAR(quat(c.orientation).norm(), 1.0, 1e-9);
  ASSERT_EQ(c.markers.size(), 1u);
  const auto& disc = c.markers[0];
  EXPECT_EQ(disc.type, visualization_msgs::Marker::CYLINDER);
  const Eigen::Vector3d axis = quat(disc.pose.orientation) * Eigen::Vector3d::UnitZ();
  EXPECT_NEAR((axis - vo.normal).norm(), 0.0, 1e-9);
  EXPECT_NEAR(disc.scale.x, 0.5, 1e-9);  // the line's length (0.6 m) capped at 0.5 m
  EXPECT_FLOAT_EQ(disc.color.r, 1.0f);
  EXPECT_FLOAT_EQ(disc.color.b, 0.2f);
}

TEST(VoMarkers, FloorNormalAndDegenerateNormal) {
  ecar::VirtualObject vo = wallLine();
  vo.normal = Eigen::Vector3d::UnitZ();
  const auto im = voInteractiveMarker(vo, "map");
  const Eigen::Vector3d x = quat(im.controls[0].orientation) * Eigen::Vector3d::UnitX();
  EXPECT_NEAR((x - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-9);
  vo.normal = -Eigen::Vector3d::UnitX();  // opposite of the control's own x axis
  const auto flipped = voInteractiveMarker(vo, "map");
  const Eigen::Vector3d fx = quat(flipped.controls[0].orientation) * Eigen::Vector3d::UnitX();
  EXPECT_NEAR((fx + Eigen::Vector3d::UnitX()).norm(), 0.0, 1e-9);
}

TEST(VoMarkers, MoveKeepsTheObjectInItsPlane) {
  const ecar::VirtualObject vo = wallLine();
  // Dragged 0.3 m along y, 0.2 m up, and 0.1 m off the wall: the off-wall part is dropped.
  const ecar::VirtualObject moved = movedInPlane(vo, vo.position + Eigen::Vector3d(-0.1, 0.3, 0.2));
  const Eigen::Vector3d d(0.0, 0.3, 0.2);
  EXPECT_NEAR((moved.position - (vo.position + d)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((moved.start - (vo.start + d)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((moved.end - (vo.end + d)).norm(), 0.0, 1e-12);
  EXPECT_EQ(moved.id, vo.id);
  EXPECT_EQ(moved.version, vo.version);
  EXPECT_EQ(moved.r, vo.r);
  EXPECT_TRUE(moved.normal.isApprox(vo.normal));
}

ecar::VirtualObject lineAt(double x, double y) {
  ecar::VirtualObject vo;
  vo.start = Eigen::Vector3d(x, y, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, y, 0.0);
  vo.width = 0.05f;
  vo.owner = "device_0";
  return vo;
}

TEST(StructureMarkers, ShowPlanesObjectsAndCells) {
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

TEST(MapMarkers, PointsKeyFramesByDeviceAndCameras) {
  ecar::MapOverview map;
  map.points = {{1, 2, 3}, {4, 5, 6}};
  map.keyframes = {{ecar::KeyFrameId(1), ecar::DeviceId(1), {0, 0, 1}},
                   {ecar::KeyFrameId(2), ecar::DeviceId(2), {1, 0, 1}}};
  ecar::SE3 T = ecar::SE3::Identity();
  T.translation() = Eigen::Vector3d(3, 0, 1);
  const visualization_msgs::MarkerArray m =
      mapMarkers(map, {CameraMarker{ecar::DeviceId(2), T}}, "map", ros::Time(2.0));
  ASSERT_EQ(m.markers.size(), 3u);
  EXPECT_EQ(m.markers[0].ns, "map_points");
  EXPECT_EQ(m.markers[0].points.size(), 2u);
  EXPECT_DOUBLE_EQ(m.markers[0].points[1].z, 6.0);
  EXPECT_EQ(m.markers[1].ns, "keyframes");
  ASSERT_EQ(m.markers[1].colors.size(), 2u);
  EXPECT_NE(m.markers[1].colors[0].r + m.markers[1].colors[0].g + m.markers[1].colors[0].b,
            m.markers[1].colors[1].r + m.markers[1].colors[1].g + m.markers[1].colors[1].b);
  EXPECT_EQ(m.markers[2].ns, "cameras");
  EXPECT_EQ(m.markers[2].id, 2);
  ASSERT_EQ(m.markers[2].points.size(), 2u);
  EXPECT_DOUBLE_EQ(m.markers[2].points[1].z, 1.4);  // 0.4 m along the optical axis (z)
}

TEST(VoShare, ParsesAndValidates) {
  EXPECT_EQ(parseVoShareMode("graph"), VoShareMode::kGraph);
  EXPECT_EQ(parseVoShareMode("direct"), VoShareMode::kDirect);
  EXPECT_STREQ(toString(VoShareMode::kDirect), "direct");
  EXPECT_THROW(parseVoShareMode("broadcast"), ecar::Error);
  ServerConfig c;
  EXPECT_EQ(c.voShare(), VoShareMode::kGraph);
  c.vo_share = "broadcast";
  try {
    c.validate();
    FAIL() << "vo.share 'broadcast' accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("vo.share"), std::string::npos) << e.what();
  }
  c.vo_share = "direct";
  c.vo_marker_drag_rate = -1.0;
  EXPECT_THROW(c.validate(), ecar::Error);
}

}  // namespace
}  // namespace ecar_server
