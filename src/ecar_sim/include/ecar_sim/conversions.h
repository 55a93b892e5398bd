// Conversions between ROS messages and ecar_core types, in one place.
//
// Every to*() has its inverse (or a test of the field mapping) in
// test/conversions_test.cpp. Functions that read a message throw ecar::Error
// with a text naming the field when the message cannot be represented; callers
// (nodes, nodelets) log it with a throttled warning and drop the message.
#pragma once

#include <string>

#include <ecar_msgs/Plane.h>
#include <ecar_msgs/Touch.h>
#include <ecar_msgs/VirtualObject.h>
#include <geometry_msgs/Point.h>
#include <geometry_msgs/Pose.h>
#include <geometry_msgs/TransformStamped.h>
#include <geometry_msgs/Vector3.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <std_msgs/Header.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/dataset.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar_sim {

/// Names of one device's topics and frames, built in one place. `ns` is the
/// device name without slashes, e.g. "device_0". Topic names are relative (they
/// resolve under the node's namespace, so `/device_0/...` for a node in `/`);
/// frame ids have no leading slash, as tf2 expects.
struct DeviceTopics {
  std::string ns;

  std::string image_raw() const { return ns + "/camera/image_raw"; }
  std::string camera_info() const { return ns + "/camera/camera_info"; }
  std::string imu() const { return ns + "/imu"; }
  /// geometry_msgs/PoseStamped: T_o_c, the camera in the device's odometry frame.
  std::string odometry() const { return ns + "/odometry"; }
  /// std_msgs/UInt32 from a consumer: the header.seq of the last image it has processed.
  std::string frame_done() const { return ns + "/frame_done"; }
  /// std_msgs/Bool, latched: true once the player has published every frame.
  std::string player_finished() const { return ns + "/player/finished"; }
  /// ecar_msgs/Touch: the user's touches on the camera image (scripted ones from the player).
  std::string touch() const { return ns + "/touch"; }

  /// The device's optical frame (x right, y down, z forward).
  std::string camera_frame() const { return ns + "/camera"; }
  /// The ground-truth camera pose of the dataset, a child of the world frame.
  std::string gt_frame() const { return ns + "/camera_gt"; }
  /// The device's odometry frame (the parent of odometry poses).
  std::string odom_frame() const { return ns + "/odom"; }
};

/// CameraInfo for an unrectified stream: distortion_model "plumb_bob",
/// D = (k1, k2, p1, p2, k3), K from fx fy cx cy, R = identity,
/// P = [K | 0], no binning and a full-image ROI.
sensor_msgs::CameraInfo toCameraInfo(const ecar::PinholeCamera& camera,
                                     const std_msgs::Header& header);

/// Intrinsics from K and D. Accepts "plumb_bob" (4 or 5 coefficients),
/// "rational_polynomial" whose k4..k6 are zero, and an empty model with an empty
/// D. Throws ecar::Error on an uncalibrated (K all zero), non-finite or
/// otherwise invalid CameraInfo and on a distortion it cannot represent.
/// fps is left 0 (CameraInfo does not carry it).
ecar::PinholeCamera fromCameraInfo(const sensor_msgs::CameraInfo& info);

geometry_msgs::Pose toPose(const ecar::SE3& T);

/// Throws ecar::Error on a non-finite position or orientation or on a
/// (near-)zero quaternion; a quaternion of another norm is normalised.
ecar::SE3 fromPose(const geometry_msgs::Pose& pose);

/// tf of `child_frame` in `header.frame_id`: T_parent_child maps child
/// coordinates into the parent frame.
geometry_msgs::TransformStamped toTransform(const ecar::SE3& T_parent_child,
                                            const std_msgs::Header& header,
                                            const std::string& child_frame);

/// Acceleration and angular rate of the sample; orientation_covariance[0] = -1
/// (no orientation); the other covariances are zero (unknown).
sensor_msgs::Imu toImu(const ecar::ImuSample& sample, const std_msgs::Header& header);

/// A scripted touch (pixel, phase, colour, width) with `header` (the player
/// gives it the stamp of the touch's frame and "<device>/camera"). The frame
/// index and timestamp of the event are not carried.
ecar_msgs::Touch toTouchMsg(const ecar::TouchEvent& touch, const std_msgs::Header& header);

/// Copies `image` into a message: CV_8UC1 -> "mono8", CV_8UC3 -> "bgr8",
/// CV_16UC1 -> "mono16". Throws ecar::Error on an empty image or another type.
sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std_msgs::Header& header);

geometry_msgs::Vector3 toVector3(const Eigen::Vector3d& v);
Eigen::Vector3d fromVector3(const geometry_msgs::Vector3& v);
geometry_msgs::Point toPoint(const Eigen::Vector3d& p);
Eigen::Vector3d fromPoint(const geometry_msgs::Point& p);

/// A structure plane, field for field (the server sends it, the device and
/// tests read it back; each reads with its own checks).
ecar_msgs::Plane toPlaneMsg(const ecar::Plane& plane);
/// A virtual object, field for field.
ecar_msgs::VirtualObject toVirtualObjectMsg(const ecar::VirtualObject& vo);

}  // namespace ecar_sim
