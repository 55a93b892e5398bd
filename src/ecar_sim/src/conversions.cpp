#include "ecar_sim/conversions.h"

#include <algorithm>
#include <cmath>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/distortion_models.h>
#include <sensor_msgs/image_encodings.h>
#include <Eigen/Geometry>

#include "ecar_core/common/error.h"

namespace ecar_sim {
namespace {

bool allFinite(const double* begin, const double* end) {
  return std::all_of(begin, end, [](double x) { return std::isfinite(x); });
}

}  // namespace

sensor_msgs::CameraInfo toCameraInfo(const ecar::PinholeCamera& camera,
                                     const std_msgs::Header& header) {
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

ecar::PinholeCamera fromCameraInfo(const sensor_msgs::CameraInfo& info) {
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

geometry_msgs::Pose toPose(const ecar::SE3& T) {
  const Eigen::Quaterniond q(T.rotation());
  geometry_msgs::Pose pose;
  pose.position.x = T.translation().x();
  pose.position.y = T.translation().y();
  pose.position.z = T.translation().z();
  pose.orientation.x = q.x();
  pose.orientation.y = q.y();
  pose.orientation.z = q.z();
  pose.orientation.w = q.w();
  return pose;
}

ecar::SE3 fromPose(const geometry_msgs::Pose& pose) {
  const Eigen::Vector3d t(pose.position.x, pose.position.y, pose.position.z);
  Eigen::Quaterniond q(pose.orientation.w, pose.orientation.x, pose.orientation.y,
                       pose.orientation.z);
  if (!t.allFinite()) throw ecar::Error("Pose: non-finite position");
  if (!q.coeffs().allFinite()) throw ecar::Error("Pose: non-finite orientation");
  if (q.norm() < 1e-9) throw ecar::Error("Pose: zero quaternion in orientation");
  q.normalize();
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = t;
  return T;
}

geometry_msgs::TransformStamped toTransform(const ecar::SE3& T_parent_child,
                                            const std_msgs::Header& header,
                                            const std::string& child_frame) {
  const geometry_msgs::Pose pose = toPose(T_parent_child);
  geometry_msgs::TransformStamped tf;
  tf.header = header;
  tf.child_frame_id = child_frame;
  tf.transform.translation.x = pose.position.x;
  tf.transform.translation.y = pose.position.y;
  tf.transform.translation.z = pose.position.z;
  tf.transform.rotation = pose.orientation;
  return tf;
}

sensor_msgs::Imu toImu(const ecar::ImuSample& sample, const std_msgs::Header& header) {
  sensor_msgs::Imu imu;
  imu.header = header;
  imu.orientation.w = 1.0;
  imu.orientation_covariance[0] = -1.0;
  imu.angular_velocity = toVector3(sample.gyro_c);
  imu.linear_acceleration = toVector3(sample.acc_c);
  return imu;
}

ecar_msgs::Touch toTouchMsg(const ecar::TouchEvent& touch, const std_msgs::Header& header) {
  ecar_msgs::Touch m;
  m.header = header;
  m.u = static_cast<float>(touch.uv.x());
  m.v = static_cast<float>(touch.uv.y());
  switch (touch.phase) {
    case ecar::TouchPhase::kBegin:
      m.phase = ecar_msgs::Touch::BEGIN;
      break;
    case ecar::TouchPhase::kMove:
      m.phase = ecar_msgs::Touch::MOVE;
      break;
    case ecar::TouchPhase::kEnd:
      m.phase = ecar_msgs::Touch::END;
      break;
  }
  m.r = touch.r;
  m.g = touch.g;
  m.b = touch.b;
  m.width = static_cast<float>(touch.width);
  return m;
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

geometry_msgs::Vector3 toVector3(const Eigen::Vector3d& v) {
  geometry_msgs::Vector3 m;
  m.x = v.x();
  m.y = v.y();
  m.z = v.z();
  return m;
}

Eigen::Vector3d fromVector3(const geometry_msgs::Vector3& v) { return {v.x, v.y, v.z}; }

geometry_msgs::Point toPoint(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

Eigen::Vector3d fromPoint(const geometry_msgs::Point& p) { return {p.x, p.y, p.z}; }

ecar_msgs::Plane toPlaneMsg(const ecar::Plane& plane) {
  ecar_msgs::Plane m;
  m.id = plane.id.value;
  m.label = static_cast<uint8_t>(plane.label);
  m.normal = toVector3(plane.normal);
  m.offset = plane.offset;
  m.boundary.reserve(plane.boundary.size());
  for (const auto& p : plane.boundary) m.boundary.push_back(toPoint(p));
  m.version = plane.version;
  m.num_points = plane.num_points;
  return m;
}

ecar_msgs::VirtualObject toVirtualObjectMsg(const ecar::VirtualObject& vo) {
  ecar_msgs::VirtualObject m;
  m.id = vo.id.value;
  m.kind = static_cast<uint8_t>(vo.kind);
  m.position = toPoint(vo.position);
  m.start = toPoint(vo.start);
  m.end = toPoint(vo.end);
  m.r = vo.r;
  m.g = vo.g;
  m.b = vo.b;
  m.width = vo.width;
  m.normal = toVector3(vo.normal);
  m.plane_id = vo.plane.value;
  m.owner = vo.owner;
  m.version = vo.version;
  m.deleted = vo.deleted;
  return m;
}

}  // namespace ecar_sim
