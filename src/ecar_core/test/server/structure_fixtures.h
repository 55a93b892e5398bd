// Fixtures shared by the server's structure tests: the corridor camera, a pose
// looking down the corridor and a keyframe of noisy floor points.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>

#include <Eigen/Geometry>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/structure/plane.h"

namespace ecar::testing {

/// 640x480, fx = fy = 525, principal point at the centre.
inline ecar::PinholeCamera camera640() {
  ecar::CameraParams p;
  p.width = 640;
  p.height = 480;
  p.fx = 525.0;
  p.fy = 525.0;
  p.cx = 319.5;
  p.cy = 239.5;
  return ecar::PinholeCamera(p);
}

/// A camera at height 1.5 m at x = x0 looking along +x (optical z = world x,
/// x = -y, y = -z), pitched down by 5 degrees.
inline ecar::SE3 lookingAlongX(double x0) {
  ecar::SE3 T = ecar::SE3::Identity();
  Eigen::Matrix3d R;
  R.col(0) = -Eigen::Vector3d::UnitY();
  R.col(1) = -Eigen::Vector3d::UnitZ();
  R.col(2) = Eigen::Vector3d::UnitX();
  T.linear() = Eigen::AngleAxisd(5.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()) * R;
  T.translation() = Eigen::Vector3d(x0, 0.0, 1.5);
  return T;
}

/// Floor points z = 0 (1 cm noise) over x in [1, 7], y in [-1.2, 1.2], 5 cm apart.
inline ecar::PlaneKeyFrameInput floorKeyFrame(ecar::KeyFrameId id, const ecar::SE3& T_w_c) {
  ecar::PlaneKeyFrameInput in;
  in.keyframe = id;
  in.camera_center_w = T_w_c.translation();
  in.up_w = Eigen::Vector3d::UnitZ();
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.01);
  uint32_t next = 1;
  for (double x = 1.0; x <= 7.0; x += 0.05) {
    for (double y = -1.2; y <= 1.2; y += 0.05) {
      in.points.push_back({ecar::MapPointId(next++), Eigen::Vector3d(x, y, noise(rng))});
    }
  }
  return in;
}

}  // namespace ecar::testing
