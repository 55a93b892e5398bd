// Device motion for the synthetic world: camera poses at the camera rate with
// what a phone's sensors would report alongside (gravity from the accelerometer,
// angular rate from the gyro, drifting VIO odometry).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/sim/scene.h"

namespace ecar {

struct MotionSample {
  double timestamp = 0.0;  ///< seconds from the start of the sequence
  SE3 T_w_c = SE3::Identity();
  /// Accelerometer at rest: the specific force of gravity (+9.81 m/s^2 up) in
  /// the camera optical frame.
  Eigen::Vector3d gravity_c = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_c = Eigen::Vector3d::Zero();  ///< angular rate, camera frame, rad/s
  /// Device odometry T_o_c: gravity-aligned, starts at the first pose, drifts
  /// in position and yaw as OdometryNoise describes.
  SE3 T_o_c = SE3::Identity();
  /// The camera sees a blank surface (TrajectorySpec::blank_start): render it
  /// with RenderOptions::blank.
  bool blank = false;
};

constexpr double kGravity = 9.81;

/// The whole path of a device, sampled at `fps`. `max_frames` > 0 truncates.
/// Throws ecar::Error naming the device when the path leaves the free space
/// (closer than 5 cm to a surface).
std::vector<MotionSample> generateMotion(const Scene& scene, const DeviceSpec& device, double fps,
                                         int max_frames = 0);

/// Gravity reading in the camera frame for a pose (accelerometer at rest).
Eigen::Vector3d gravityInCamera(const SE3& T_w_c);

}  // namespace ecar
