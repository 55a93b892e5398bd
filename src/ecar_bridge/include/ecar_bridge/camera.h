// sensor_msgs <-> ecar_core: camera calibration, images and IMU samples.
#pragma once

#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <std_msgs/Header.h>
#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/dataset.h"

namespace ecar_bridge {

/// CameraInfo for an unrectified stream: distortion_model "plumb_bob",
/// D = (k1, k2, p1, p2, k3), K from fx fy cx cy, R = identity, P = [K | 0], no
/// binning and a full-image ROI.
sensor_msgs::CameraInfo toMsg(const ecar::PinholeCamera& camera, const std_msgs::Header& header);
/// Intrinsics from K and D. Accepts "plumb_bob" (4 or 5 coefficients),
/// "rational_polynomial" whose k4..k6 are zero, and an empty model with an empty
/// D. Throws ecar::Error on an uncalibrated (K all zero), non-finite or
/// otherwise invalid CameraInfo and on a distortion it cannot represent. fps
/// is left 0 (CameraInfo does not carry it).
ecar::PinholeCamera fromMsg(const sensor_msgs::CameraInfo& info);

/// Copies `image` into a message: CV_8UC1 -> "mono8", CV_8UC3 -> "bgr8",
/// CV_16UC1 -> "mono16". Throws ecar::Error on an empty image or another type.
sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std_msgs::Header& header);
/// The image as 8-bit grey (a shared view when it is mono8 already). Throws
/// ecar::Error naming the encoding when it cannot be converted.
cv::Mat grayOf(const sensor_msgs::ImageConstPtr& image);

/// Acceleration and angular rate of the sample; orientation_covariance[0] = -1
/// (no orientation); the other covariances are zero (unknown).
sensor_msgs::Imu toMsg(const ecar::ImuSample& sample, const std_msgs::Header& header);
/// The sample of an Imu message (timestamp from its header). Throws
/// ecar::Error ("imu: non-finite ...") on a non-finite rate or acceleration.
ecar::ImuSample fromMsg(const sensor_msgs::Imu& imu);

}  // namespace ecar_bridge
