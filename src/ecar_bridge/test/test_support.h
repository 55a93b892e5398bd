// Values shared by the bridge's tests.
#pragma once

#include <std_msgs/Header.h>
#include <Eigen/Geometry>

#include "ecar_core/common/geometry.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar_bridge::testing {

inline ecar::SE3 somePose() {
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.5, -2.0, 0.25);
  return T;
}

inline std_msgs::Header someHeader() {
  std_msgs::Header h;
  h.seq = 42;
  h.stamp = ros::Time(1234, 5678);
  h.frame_id = "device_3/camera";
  return h;
}

inline ecar::VirtualObject someObject() {
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
  vo.map = ecar::MapId(3);
  return vo;
}

}  // namespace ecar_bridge::testing
