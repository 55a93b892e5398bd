#include "ecar_bridge/geometry.h"

#include <Eigen/Geometry>

#include "ecar_core/common/error.h"

namespace ecar_bridge {

geometry_msgs::Pose toMsg(const ecar::SE3& T) {
  const Eigen::Quaterniond q(T.rotation());
  geometry_msgs::Pose pose;
  pose.position = toPointMsg(T.translation());
  pose.orientation.x = q.x();
  pose.orientation.y = q.y();
  pose.orientation.z = q.z();
  pose.orientation.w = q.w();
  return pose;
}

ecar::SE3 fromMsg(const geometry_msgs::Pose& pose, const std::string& field) {
  const Eigen::Vector3d t = fromMsg(pose.position);
  Eigen::Quaterniond q(pose.orientation.w, pose.orientation.x, pose.orientation.y,
                       pose.orientation.z);
  if (!t.allFinite()) throw ecar::Error(field + ": non-finite position");
  if (!q.coeffs().allFinite()) throw ecar::Error(field + ": non-finite orientation");
  if (q.norm() < 1e-9) throw ecar::Error(field + ": zero quaternion in orientation");
  q.normalize();
  ecar::SE3 T = ecar::SE3::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = t;
  return T;
}

geometry_msgs::Point toPointMsg(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

Eigen::Vector3d fromMsg(const geometry_msgs::Point& p) { return {p.x, p.y, p.z}; }

geometry_msgs::Vector3 toVector3Msg(const Eigen::Vector3d& v) {
  geometry_msgs::Vector3 m;
  m.x = v.x();
  m.y = v.y();
  m.z = v.z();
  return m;
}

Eigen::Vector3d fromMsg(const geometry_msgs::Vector3& v) { return {v.x, v.y, v.z}; }

geometry_msgs::TransformStamped toTransformMsg(const ecar::SE3& T_parent_child,
                                               const std_msgs::Header& header,
                                               const std::string& child_frame) {
  const geometry_msgs::Pose pose = toMsg(T_parent_child);
  geometry_msgs::TransformStamped tf;
  tf.header = header;
  tf.child_frame_id = child_frame;
  tf.transform.translation.x = pose.position.x;
  tf.transform.translation.y = pose.position.y;
  tf.transform.translation.z = pose.position.z;
  tf.transform.rotation = pose.orientation;
  return tf;
}

ecar::SE3 fromMsg(const geometry_msgs::TransformStamped& tf) {
  geometry_msgs::Pose pose;
  pose.position.x = tf.transform.translation.x;
  pose.position.y = tf.transform.translation.y;
  pose.position.z = tf.transform.translation.z;
  pose.orientation = tf.transform.rotation;
  return fromMsg(pose, "transform " + tf.child_frame_id);
}

}  // namespace ecar_bridge
