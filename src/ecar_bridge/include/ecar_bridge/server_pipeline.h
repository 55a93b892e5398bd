// The edge server's internal messages, between its nodelets (zero-copy inside
// the manager): Tracking -> /ecar/tracked_frame -> GridConnection ->
// /ecar/visible_structure -> GraphPublisher; LocalMapping ->
// /ecar/keyframe_mapped -> PlaneSegmentation -> /ecar/keyframe_planes ->
// GridConnection.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include <ecar_msgs/KeyFrameEvent.h>
#include <ecar_msgs/KeyFramePlanes.h>
#include <ecar_msgs/TrackedFrame.h>
#include <ecar_msgs/VisibleStructure.h>
#include <ros/time.h>
#include <Eigen/Core>

#include "ecar_core/server/grid_connection.h"
#include "ecar_core/server/plane_segmentation.h"
#include "ecar_core/slam/tracker.h"

namespace ecar_bridge {

/// What a tracked frame carries besides the tracking result.
struct FrameMeta {
  std::string device;
  uint32_t frame_index = 0;
  ros::Time stamp;             ///< capture time (Upload.header.stamp)
  ros::Time upload_sent;       ///< Upload.sent
  ros::Time server_received;   ///< server clock at reception
  float receive_time = 0.0f;   ///< seconds from reception to the start of alignment
  float tracking_time = 0.0f;  ///< seconds
  float cpu_time = 0.0f;       ///< seconds of the aligning thread's CPU (TrackedFrame.cpu_time)
  bool reset = false;          ///< Upload.reset
};

/// TrackedFrame of a tracking result: status, pose, tracked points (ids and
/// quantised keypoints), local keyframes, new keyframe, map epoch.
ecar_msgs::TrackedFrame toMsg(const ecar::TrackResult& result, const FrameMeta& meta);
/// The tracking result of a TrackedFrame: state, relocalised, T_w_c, tracked
/// (ids and keypoints; p_w zero), local_keyframes, new_keyframe, map_epoch.
/// Throws ecar::Error when point_ids and points disagree or the pose is not finite.
ecar::TrackResult fromMsg(const ecar_msgs::TrackedFrame& msg, FrameMeta* meta = nullptr);

/// A keyframe the mapper finished, as /ecar/keyframe_mapped reports it.
struct MappedKeyFrame {
  ecar::KeyFrameId id;
  std::string device;
  uint32_t frame_index = 0;
  double timestamp = 0.0;  ///< capture time, seconds
  std::optional<Eigen::Vector3d> gravity_c;
};
ecar_msgs::KeyFrameEvent toMsg(const MappedKeyFrame& kf);
MappedKeyFrame fromMsg(const ecar_msgs::KeyFrameEvent& msg);

/// A segmented keyframe; `device_name` names planes.device.
ecar_msgs::KeyFramePlanes toMsg(const ecar::KeyFramePlanes& planes, const std::string& device_name);
/// The keyframe, its pose, epoch and planes (device id left invalid: the
/// message names the device). Throws ecar::Error on a bad pose.
ecar::KeyFramePlanes fromMsg(const ecar_msgs::KeyFramePlanes& msg);

/// The structure fields of a VisibleStructure (the caller sets `frame`).
void toMsg(const ecar::VisibleStructure& visible, ecar_msgs::VisibleStructure* msg);
/// Planes, objects and cells of a VisibleStructure (not its frame). Throws
/// ecar::Error naming the field on a bad plane or object, or cells that are
/// not triples.
ecar::VisibleStructure fromMsg(const ecar_msgs::VisibleStructure& msg);

}  // namespace ecar_bridge
