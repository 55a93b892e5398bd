// The one place where the server's parameters are read from rosparam.
#pragma once

#include <ros/node_handle.h>

#include "ecar_server/config.h"

namespace ecar_server {

/// Reads every ServerConfig key from `nh` (the manager's namespace, e.g.
/// /edge_server), keeping the in-class default for absent keys, and validates.
/// Throws ecar::Error naming the key when a value has the wrong type or range.
ServerConfig loadServerConfig(const ros::NodeHandle& nh);

/// Topic names of one device, built in one place (absolute, as Connect answers them).
struct DeviceTopicNames {
  std::string device;
  std::string upload() const { return "/" + device + "/upload"; }
  std::string localGraph() const { return "/" + device + "/local_graph"; }
  std::string interaction() const { return "/" + device + "/interaction"; }
  std::string interactionResult() const { return "/" + device + "/interaction_result"; }
  /// vo_share direct: VO states relayed to the device (its ~direct_objects_topic).
  std::string objects() const { return "/" + device + "/objects"; }
  std::string cameraServerFrame() const { return device + "/camera_server"; }
};

/// Server-wide topics and services (absolute; remappable).
constexpr const char* kConnectService = "/ecar/connect";
constexpr const char* kDisconnectService = "/ecar/disconnect";
constexpr const char* kTrackedFrameTopic = "/ecar/tracked_frame";
constexpr const char* kKeyFrameMappedTopic = "/ecar/keyframe_mapped";
constexpr const char* kMarkersTopic = "/ecar/markers";
/// Every accepted VO change (the state after it, tombstones included), in order.
constexpr const char* kObjectsTopic = "/ecar/objects";
/// Namespace of the interactive marker server of the VOs (rviz InteractiveMarkers display).
constexpr const char* kVoMarkersTopic = "/ecar/vo_markers";
constexpr const char* kMapFrame = "map";

/// Seconds on a monotonic clock (device timeouts).
double steadySeconds();

}  // namespace ecar_server
