// Topic, service and frame names of eCAR, built in one place. Per device
// (`ns` = the device name, e.g. "device_0"): names relative to the node's
// namespace for the device's own topics (a node in `/` resolves them under
// /device_0/), absolute ones for what the server names on connection; frame
// ids have no leading slash, as tf2 expects.
#pragma once

#include <string>

namespace ecar_bridge {

struct DeviceTopics {
  std::string ns;

  // ---- camera driver, dataset player (relative)
  std::string image_raw() const { return ns + "/camera/image_raw"; }
  std::string camera_info() const { return ns + "/camera/camera_info"; }
  std::string imu() const { return ns + "/imu"; }
  /// geometry_msgs/PoseStamped: T_o_c, the camera in the device's odometry frame.
  std::string odometry() const { return ns + "/odometry"; }
  /// std_msgs/UInt32 from a consumer: the header.seq of the last image it has processed.
  std::string frame_done() const { return ns + "/frame_done"; }
  /// std_msgs/Bool, latched: true once the player has published every frame.
  std::string player_finished() const { return ns + "/player/finished"; }
  /// std_msgs/Bool, latched: the player preloaded and waits for its start topic.
  std::string player_ready() const { return ns + "/player/ready"; }
  /// ecar_msgs/Touch: the user's touches on the camera image (scripted ones from the player).
  std::string touch() const { return ns + "/touch"; }

  // ---- device <-> server (absolute, as Connect answers them)
  std::string upload() const { return "/" + ns + "/upload"; }
  std::string localGraph() const { return "/" + ns + "/local_graph"; }
  std::string interaction() const { return "/" + ns + "/interaction"; }
  std::string interactionResult() const { return "/" + ns + "/interaction_result"; }
  /// vo_share direct: VO states relayed to the device (its ~direct_objects_topic).
  std::string objects() const { return "/" + ns + "/objects"; }

  // ---- frames
  /// The device's optical frame (x right, y down, z forward), as the device estimates it.
  std::string camera_frame() const { return ns + "/camera"; }
  /// The camera as the server aligned it.
  std::string camera_server_frame() const { return ns + "/camera_server"; }
  /// The ground-truth camera pose of the dataset, a child of the world frame.
  std::string gt_frame() const { return ns + "/camera_gt"; }
  /// The device's odometry frame (the parent of odometry poses).
  std::string odom_frame() const { return ns + "/odom"; }
};

/// Server-wide topics and services (absolute; remappable).
constexpr const char* kConnectService = "/ecar/connect";
constexpr const char* kDisconnectService = "/ecar/disconnect";
constexpr const char* kSaveMapService = "/ecar/save_map";
constexpr const char* kLoadMapService = "/ecar/load_map";
constexpr const char* kTrackedFrameTopic = "/ecar/tracked_frame";
constexpr const char* kKeyFrameMappedTopic = "/ecar/keyframe_mapped";
constexpr const char* kKeyFramePlanesTopic = "/ecar/keyframe_planes";
constexpr const char* kVisibleStructureTopic = "/ecar/visible_structure";
constexpr const char* kMarkersTopic = "/ecar/markers";
constexpr const char* kMetricsTopic = "/ecar/metrics";
/// Every accepted VO change (the state after it, tombstones included), in order.
constexpr const char* kObjectsTopic = "/ecar/objects";
/// Namespace of the interactive marker server of the VOs (rviz InteractiveMarkers display).
constexpr const char* kVoMarkersTopic = "/ecar/vo_markers";
/// rviz's Publish Point tool.
constexpr const char* kClickedPointTopic = "/clicked_point";
constexpr const char* kMapFrame = "map";

}  // namespace ecar_bridge
