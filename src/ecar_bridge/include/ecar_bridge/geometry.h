// geometry_msgs <-> Eigen / ecar_core: poses, points, vectors, transforms.
//
// Every to*() has its inverse, tested in test/geometry_test.cpp. Readers throw
// ecar::Error naming the field when a message cannot be used; callers (nodes,
// nodelets) log it with a throttled warning and drop the message.
#pragma once

#include <string>

#include <geometry_msgs/Point.h>
#include <geometry_msgs/Pose.h>
#include <geometry_msgs/TransformStamped.h>
#include <geometry_msgs/Vector3.h>
#include <std_msgs/Header.h>
#include <Eigen/Core>

#include "ecar_core/common/geometry.h"

namespace ecar_bridge {

geometry_msgs::Pose toMsg(const ecar::SE3& T);
/// Throws ecar::Error ("<field>: non-finite position", "... orientation",
/// "... zero quaternion") on a non-finite pose or a (near-)zero quaternion; a
/// quaternion of another norm is normalised.
ecar::SE3 fromMsg(const geometry_msgs::Pose& pose, const std::string& field = "Pose");

geometry_msgs::Point toPointMsg(const Eigen::Vector3d& p);
/// Field for field (not checked).
Eigen::Vector3d fromMsg(const geometry_msgs::Point& p);
geometry_msgs::Vector3 toVector3Msg(const Eigen::Vector3d& v);
/// Field for field (not checked).
Eigen::Vector3d fromMsg(const geometry_msgs::Vector3& v);

/// tf of `child_frame` in `header.frame_id`: T_parent_child maps child
/// coordinates into the parent frame.
geometry_msgs::TransformStamped toTransformMsg(const ecar::SE3& T_parent_child,
                                               const std_msgs::Header& header,
                                               const std::string& child_frame);
/// The transform of a TransformStamped (checked as fromMsg(Pose)).
ecar::SE3 fromMsg(const geometry_msgs::TransformStamped& tf);

}  // namespace ecar_bridge
