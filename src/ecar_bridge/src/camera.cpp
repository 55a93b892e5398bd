#include "ecar_bridge/camera.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/distortion_models.h>
#include <sensor_msgs/image_encodings.h>

#include "ecar_bridge/geometry.h"
#include "ecar_core/common/error.h"

namespace ecar_bridge {
namespace {

bool allFinite(const double* begin, const double* end) {
  return std::all_of(begin, end, [](double x) { return std::isfinite(x); });
}

}  // namespace

sensor_msgs::CameraInfo toMsg(const ecar::PinholeCamera& camera, const std_msgs::Header& header) {
  const ecar::CameraParams& p = camera.params();
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<uint32_t>(p.width);
  info.height = static_cast<uint32_t>(p.height);
  info.distortion_model = sensor_msgs::distortion_models::PLUMB_BOB;
  info.D.assign(p.dist.begin(), p.dist.end());
  info.K = {p.fx, 0.0, p.cx, 0.0, p.fy, p.cy, 0.0, 0.0, 1.0};
  info.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  info.P = {p.fx, 0.0, p.cx, 0.0, 0.0, p.fy, p.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return info;
}

ecar::PinholeCamera fromMsg(const sensor_msgs::CameraInfo& info) {
  if (!allFinite(info.K.data(), info.K.data() + info.K.size()) ||
      !allFinite(info.D.data(), info.D.data() + info.D.size())) {
    throw ecar::Error("CameraInfo: non-finite value in K or D");
  }
  if (info.K[0] == 0.0 && info.K[4] == 0.0) {
    throw ecar::Error("CameraInfo: K is zero (uncalibrated camera)");
  }
  if (info.width == 0 || info.height == 0) {
    throw ecar::Error("CameraInfo: width and height must be positive, got " +
                      std::to_string(info.width) + "x" + std::to_string(info.height));
  }

  ecar::CameraParams p;
  p.width = static_cast<int>(info.width);
  p.height = static_cast<int>(info.height);
  p.fx = info.K[0];
  p.fy = info.K[4];
  p.cx = info.K[2];
  p.cy = info.K[5];

  const std::string& model = info.distortion_model;
  const size_t n = info.D.size();
  if (model == sensor_msgs::distortion_models::PLUMB_BOB) {
    if (n != 0 && n != 4 && n != 5) {
      throw ecar::Error("CameraInfo: plumb_bob needs 4 or 5 coefficients in D, got " +
                        std::to_string(n));
    }
  } else if (model == sensor_msgs::distortion_models::RATIONAL_POLYNOMIAL) {
    if (n != 0 && n != 8) {
      throw ecar::Error("CameraInfo: rational_polynomial needs 8 coefficients in D, got " +
                        std::to_string(n));
    }
    if (n == 8 && (info.D[5] != 0.0 || info.D[6] != 0.0 || info.D[7] != 0.0)) {
      throw ecar::Error("CameraInfo: rational_polynomial with non-zero k4..k6 is not supported");
    }
  } else if (!(model.empty() && n == 0)) {
    throw ecar::Error("CameraInfo: distortion_model \"" + model +
                      "\" is not supported (use plumb_bob)");
  }
  for (size_t i = 0; i < std::min<size_t>(n, p.dist.size()); ++i) p.dist[i] = info.D[i];

  return ecar::PinholeCamera(p);  // validates the values, throws ecar::Error
}

sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std_msgs::Header& header) {
  if (image.empty()) throw ecar::Error("toImageMsg: empty image");
  std::string encoding;
  switch (image.type()) {
    case CV_8UC1:
      encoding = sensor_msgs::image_encodings::MONO8;
      break;
    case CV_8UC3:
      encoding = sensor_msgs::image_encodings::BGR8;
      break;
    case CV_16UC1:
      encoding = sensor_msgs::image_encodings::MONO16;
      break;
    default:
      throw ecar::Error("toImageMsg: unsupported cv::Mat type " + std::to_string(image.type()) +
                        " (depth " + std::to_string(image.depth()) + ", " +
                        std::to_string(image.channels()) +
                        " channels); expected CV_8UC1, CV_8UC3 or CV_16UC1");
  }
  return cv_bridge::CvImage(header, encoding, image).toImageMsg();
}

cv::Mat grayOf(const sensor_msgs::ImageConstPtr& image) {
  try {
    return cv_bridge::toCvShare(image, sensor_msgs::image_encodings::MONO8)->image;
  } catch (const cv_bridge::Exception& e) {
    throw ecar::Error("image: encoding \"" + image->encoding + "\": " + e.what());
  }
}

sensor_msgs::Imu toMsg(const ecar::ImuSample& sample, const std_msgs::Header& header) {
  sensor_msgs::Imu imu;
  imu.header = header;
  imu.orientation.w = 1.0;
  imu.orientation_covariance[0] = -1.0;
  imu.angular_velocity = toVector3Msg(sample.gyro_c);
  imu.linear_acceleration = toVector3Msg(sample.acc_c);
  return imu;
}

ecar::ImuSample fromMsg(const sensor_msgs::Imu& imu) {
  ecar::ImuSample s;
  s.timestamp = imu.header.stamp.toSec();
  s.acc_c = fromMsg(imu.linear_acceleration);
  s.gyro_c = fromMsg(imu.angular_velocity);
  if (!s.acc_c.allFinite()) throw ecar::Error("imu: non-finite linear_acceleration");
  if (!s.gyro_c.allFinite()) throw ecar::Error("imu: non-finite angular_velocity");
  return s;
}

}  // namespace ecar_bridge
