// Conversions between ecar_msgs and ecar_core types for the edge server, in
// one place. Each has its round trip (or field-mapping) test in
// test/conversions_test.cpp. Readers of device input throw ecar::Error naming
// the field when a message cannot be used; the nodelets warn and drop it.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/KeyFrameEvent.h>
#include <ecar_msgs/KeyFrameInfo.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/MapPointFull.h>
#include <ecar_msgs/Plane.h>
#include <ecar_msgs/PointPosition.h>
#include <ecar_msgs/TrackedFrame.h>
#include <ecar_msgs/TrackedPoint.h>
#include <ecar_msgs/Upload.h>
#include <ecar_msgs/VirtualObject.h>
#include <ros/time.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/sync/local_graph.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/slam/slam_system.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar_server {

/// TrackedPoint: u, v rounded to 1/8 px (clamped to the uint16 range), angle
/// to 256 steps of 1.40625 degrees, octave clamped to [0, 255].
ecar_msgs::TrackedPoint toMsg(const ecar::GraphPoint& p);
ecar::GraphPoint fromMsg(const ecar_msgs::TrackedPoint& msg);

/// A position on the wire names its point by `index` into LocalGraph.points.
ecar_msgs::PointPosition toMsg(const ecar::GraphPosition& p, uint16_t index);
/// Throws ecar::Error ("positions[i].index") when the index is not in `points`.
ecar::GraphPosition fromMsg(const ecar_msgs::PointPosition& msg,
                            const std::vector<ecar_msgs::TrackedPoint>& points);

ecar_msgs::MapPointFull toMsg(const ecar::GraphMapPoint& p);
ecar::GraphMapPoint fromMsg(const ecar_msgs::MapPointFull& msg);

/// `device_name`: the name of kf.device (KeyFrameInfo carries names).
ecar_msgs::KeyFrameInfo toMsg(const ecar::GraphKeyFrame& kf, const std::string& device_name);
/// The device id is left invalid; its name goes to *device_name when given.
ecar::GraphKeyFrame fromMsg(const ecar_msgs::KeyFrameInfo& msg, std::string* device_name = nullptr);

/// LocalGraph/TrackedFrame status of a tracking result: OK, RELOCALISED
/// (tracked by relocalisation or joining), LOST or NOT_INITIALISED.
uint8_t toStatus(const ecar::TrackResult& result);

/// Fills the payload fields of a LocalGraph (sync_mode, points, positions,
/// keyframes, map_points). `name_of` gives a device's name for keyframes.
template <typename NameOf>
void fillPayload(const ecar::LocalGraphData& data, NameOf&& name_of, ecar_msgs::LocalGraph* msg);
/// The payload of a LocalGraph (keyframe devices left invalid).
ecar::LocalGraphData payloadFromMsg(const ecar_msgs::LocalGraph& msg);

/// What a tracked frame carries besides the tracking result.
struct FrameMeta {
  std::string device;
  uint32_t frame_index = 0;
  ros::Time stamp;             ///< capture time (Upload.header.stamp)
  ros::Time upload_sent;       ///< Upload.sent
  ros::Time server_received;   ///< server clock at reception
  float tracking_time = 0.0f;  ///< seconds
};

/// TrackedFrame of a tracking result: status, pose, tracked points (ids and
/// quantised keypoints), local keyframes, new keyframe.
ecar_msgs::TrackedFrame toMsg(const ecar::TrackResult& result, const FrameMeta& meta);
/// The tracking result of a TrackedFrame: state, relocalised, T_w_c, tracked
/// (ids and keypoints; p_w zero), local_keyframes, new_keyframe. Throws
/// ecar::Error when point_ids and points disagree or the pose is not finite.
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

/// Gravity and odometry of an upload, checked: nullopt when the upload has
/// none; throws ecar::Error naming the field ("gravity", "odometry") when
/// present but not finite (or a zero quaternion).
struct UploadMotion {
  std::optional<Eigen::Vector3d> gravity_c;  ///< specific force, camera frame, points up
  std::optional<ecar::SE3> T_o_c;            ///< device odometry T_odom_camera
};
UploadMotion motionOf(const ecar_msgs::Upload& upload);
/// Inverse of motionOf (for tests and fake devices): fills gravity, odometry
/// and their has_ flags.
void setMotion(const UploadMotion& motion, ecar_msgs::Upload* upload);

/// The uploaded JPEG decoded to grey; throws ecar::Error ("image") when it
/// does not decode.
cv::Mat decodeImage(const ecar_msgs::Upload& upload);

/// Plane: field for field (ids, label, normal, offset, boundary, version, count).
ecar_msgs::Plane toMsg(const ecar::Plane& plane);
/// Throws ecar::Error ("plane.label") on an unknown label.
ecar::Plane fromMsg(const ecar_msgs::Plane& msg);

/// VirtualObject: field for field.
ecar_msgs::VirtualObject toMsg(const ecar::VirtualObject& vo);
/// Throws ecar::Error ("object.kind") on an unknown kind. Coordinates are not
/// checked here (the VoStore rejects NaN with a reason).
ecar::VirtualObject fromMsg(const ecar_msgs::VirtualObject& msg);

/// A device's Interaction, as the server applies it to its VoStore.
struct VoRequest {
  enum class Type { kRegister, kManipulate, kDelete };
  std::string device;
  uint32_t request_id = 0;
  Type type = Type::kRegister;
  ecar::ObjectId object;  ///< MANIPULATE / DELETE target
  ecar::VirtualObject state;
  uint32_t base_version = 0;
};
ecar_msgs::Interaction toMsg(const VoRequest& request);
/// Throws ecar::Error ("type", "object.kind") when the message cannot be used.
VoRequest fromMsg(const ecar_msgs::Interaction& msg);

/// The answer to a request: InteractionResult with the outcome's id, version, reason.
ecar_msgs::InteractionResult toMsg(const VoRequest& request, const ecar::VoOutcome& outcome);
/// The outcome carried by an InteractionResult (code kNone when accepted, else
/// left kNone too: the wire carries only the reason).
ecar::VoOutcome outcomeFromMsg(const ecar_msgs::InteractionResult& msg);

// ---- template implementation

template <typename NameOf>
void fillPayload(const ecar::LocalGraphData& data, NameOf&& name_of, ecar_msgs::LocalGraph* msg) {
  msg->sync_mode = data.mode == ecar::SyncMode::kEdgeSlam ? ecar_msgs::LocalGraph::SYNC_EDGESLAM
                                                          : ecar_msgs::LocalGraph::SYNC_ECAR;
  msg->points.clear();
  msg->points.reserve(data.points.size());
  for (const auto& p : data.points) msg->points.push_back(toMsg(p));
  // Positions are a subsequence of the points (the builder emits them in the
  // same order): one merge pass finds each position's index.
  if (data.points.size() > 0xFFFF) throw ecar::Error("local graph: more than 65535 points");
  msg->positions.clear();
  msg->positions.reserve(data.positions.size());
  size_t index = 0;
  for (const auto& p : data.positions) {
    while (index < data.points.size() && data.points[index].id != p.id) ++index;
    if (index == data.points.size()) {
      throw ecar::Error("local graph: a position for map point " + std::to_string(p.id.value) +
                        " that is not among its points (or out of their order)");
    }
    msg->positions.push_back(toMsg(p, static_cast<uint16_t>(index)));
  }
  msg->keyframes.clear();
  msg->keyframes.reserve(data.keyframes.size());
  for (const auto& k : data.keyframes) msg->keyframes.push_back(toMsg(k, name_of(k.device)));
  msg->map_points.clear();
  msg->map_points.reserve(data.map_points.size());
  for (const auto& p : data.map_points) msg->map_points.push_back(toMsg(p));
}

}  // namespace ecar_server
