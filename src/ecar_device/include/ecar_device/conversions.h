// Conversions between ecar_msgs and the device side of ecar_core, in one place.
//
// Each has its inverse or a field test in test/conversions_test.cpp. Functions
// that read a message throw ecar::Error naming the field (e.g.
// "positions[3]: non-finite") when it cannot be used; the Device logs that
// with a throttled warning and drops the message.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ros/serialization.h>
#include <ros/time.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <ecar_msgs/DeviceFrame.h>
#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/Plane.h>
#include <ecar_msgs/RoundTripMetrics.h>
#include <ecar_msgs/Touch.h>
#include <ecar_msgs/TrackedPoint.h>
#include <ecar_msgs/Upload.h>
#include <ecar_msgs/VirtualObject.h>

#include "ecar_core/device/device_objects.h"
#include "ecar_core/device/device_tracker.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar_device {

/// Bytes of a message on the wire, as ROS sends it (the "traffic" of the project).
template <typename Msg>
uint32_t wireBytes(const Msg& msg) {
  return ros::serialization::serializationLength(msg);
}

/// Keypoint in the wire encoding (1/8 px, angle in 256 steps, octave). Throws
/// ecar::Error when the keypoint lies outside [0, 8191.875] px or its octave
/// outside [0, 255].
ecar_msgs::TrackedPoint toTrackedPoint(const ecar::ReceivedPoint& point);
ecar::ReceivedPoint fromTrackedPoint(const ecar_msgs::TrackedPoint& msg);

/// ecar-mode graph: pose, points, positions (float32 on the wire). Throws
/// ecar::Error naming the field on a non-finite pose or position.
ecar::LocalGraphInput fromLocalGraph(const ecar_msgs::LocalGraph& msg);
/// Fills frame_index, pose, sync_mode SYNC_ECAR, points and positions of `msg`.
void toLocalGraph(const ecar::LocalGraphInput& graph, ecar_msgs::LocalGraph* msg);

/// edgeslam-mode graph: keyframes (with poses and point ids) and map points
/// with descriptors. Throws ecar::Error naming the field on a non-finite value.
ecar::FullLocalMap fromFullLocalGraph(const ecar_msgs::LocalGraph& msg);
/// Fills frame_index, pose, sync_mode SYNC_EDGESLAM, keyframes and map_points of `msg`.
void toFullLocalGraph(const ecar::FullLocalMap& map, ecar_msgs::LocalGraph* msg);

/// What an upload carries besides its header.
struct UploadContent {
  std::string device_id;
  std::string camera_frame;  ///< e.g. "device_0/camera"
  uint32_t frame_index = 0;
  ros::Time stamp;  ///< capture time (the camera image's stamp)
  ros::Time sent;   ///< device clock at publication
  std::vector<uint8_t> jpeg;
  std::optional<Eigen::Vector3d> gravity_c;  ///< specific force, camera frame, m/s^2
  std::optional<ecar::SE3> T_o_c;            ///< device odometry
  uint32_t last_graph_frame = 0;
  bool reset = false;
};

/// The Upload message (image format "jpeg", header stamp and frame on both
/// the upload and its image).
ecar_msgs::Upload toUpload(const UploadContent& content);
/// Inverse of toUpload. Throws ecar::Error naming the field on a non-finite
/// gravity or odometry that is flagged present.
UploadContent fromUpload(const ecar_msgs::Upload& msg);

/// One DeviceFrame for a tracked camera frame (stamp = capture time, frame "map"),
/// listing the VOs held (`objects`, live ones) with their versions.
ecar_msgs::DeviceFrame toDeviceFrame(const std::string& device_id, const ros::Time& stamp,
                                     const std::string& map_frame,
                                     const ecar::DeviceTrackResult& result, uint32_t keyframes,
                                     uint32_t local_points, bool uploaded,
                                     const std::map<ecar::ObjectId, ecar::VirtualObject>& objects);

/// What the device measured of one round trip.
struct RoundTrip {
  std::string device_id;
  uint32_t bytes_up = 0;
  ros::Time sent;                    ///< upload published (device clock)
  ros::Time received;                ///< local graph received (device clock)
  float tracking_time_device = 0.f;  ///< s, the device's tracking of the uploaded frame
};

/// Metrics of the round trip that `graph` ends: bytes (wireBytes of the graph
/// down), latency = received - sent, upload_time = server_received - sent,
/// server_time from the graph, download_time = received - server_sent;
/// points = points (ecar) or map_points (edgeslam).
ecar_msgs::RoundTripMetrics toRoundTripMetrics(const ecar_msgs::LocalGraph& graph,
                                               const RoundTrip& trip);

// ---------------------------------------------------------------- virtual objects

/// Field for field (position, start, end, normal as float64 points/vectors).
ecar_msgs::VirtualObject toVirtualObject(const ecar::VirtualObject& vo);
/// Inverse of toVirtualObject. Throws ecar::Error naming `field` and the member
/// (e.g. "objects[2].start: non-finite") on a non-finite coordinate, normal or
/// width, or a kind other than LINE / ANCHOR.
ecar::VirtualObject fromVirtualObject(const ecar_msgs::VirtualObject& msg,
                                      const std::string& field = "object");

/// Field for field (boundary as points).
ecar_msgs::Plane toPlane(const ecar::Plane& plane);
/// Inverse of toPlane. Throws ecar::Error naming `field` and the member on a
/// non-finite value, a normal that is not unit (within 1e-3) or a label beyond OTHER.
ecar::Plane fromPlane(const ecar_msgs::Plane& msg, const std::string& field = "plane");

/// The touch's pixel, phase, colour and width (header not kept).
ecar::TouchInput fromTouch(const ecar_msgs::Touch& msg);
/// Inverse of fromTouch; `header` as given.
ecar_msgs::Touch toTouch(const ecar::TouchInput& touch, const std_msgs::Header& header);
/// Throws ecar::Error naming the field on a non-finite pixel, a width that is
/// not finite and > 0, or a phase beyond END.
void validateTouch(const ecar_msgs::Touch& msg);

/// The Interaction of one request from `device_id` (header stamp and frame as given).
ecar_msgs::Interaction toInteraction(const ecar::VoRequest& request, const std::string& device_id,
                                     const std_msgs::Header& header);
/// Inverse of toInteraction (device id and header not kept). Throws ecar::Error
/// naming the field (e.g. "object.normal") on a bad object or type.
ecar::VoRequest fromInteraction(const ecar_msgs::Interaction& msg);

/// The answer to one request.
ecar::VoResult fromInteractionResult(const ecar_msgs::InteractionResult& msg);
/// Inverse of fromInteractionResult, for `device_id`.
ecar_msgs::InteractionResult toInteractionResult(const ecar::VoResult& result,
                                                 const std::string& device_id,
                                                 const std_msgs::Header& header);

}  // namespace ecar_device
