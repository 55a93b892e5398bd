// What a device publishes besides interactions: uploads (ecar_msgs/Upload),
// its per-frame record (DeviceFrame) and per-round-trip metrics
// (RoundTripMetrics), and the wire size of a message.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ecar_msgs/DeviceFrame.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/RoundTripMetrics.h>
#include <ecar_msgs/Upload.h>
#include <ros/serialization.h>
#include <ros/time.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/geometry.h"
#include "ecar_core/device/device_tracker.h"
#include "ecar_core/io/jpeg.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar_bridge {

/// Bytes of a message on the wire, as ROS sends it (the "traffic" of the project).
template <typename Msg>
uint32_t wireBytes(const Msg& msg) {
  return ros::serialization::serializationLength(msg);
}

/// What an upload carries.
struct UploadContent {
  std::string device_id;
  std::string camera_frame;  ///< e.g. "device_0/camera"
  uint32_t frame_index = 0;
  ros::Time stamp;  ///< capture time (the camera image's stamp)
  ros::Time sent;   ///< device clock at publication
  /// JPEG bytes (toMsg); fromMsg leaves it empty: decode Upload.image in
  /// place (decodeImage) rather than copying it.
  std::vector<uint8_t> jpeg;
  std::optional<Eigen::Vector3d> gravity_c;  ///< specific force, camera frame, m/s^2, points up
  std::optional<ecar::SE3> T_o_c;            ///< device odometry T_odom_camera
  uint32_t last_graph_frame = 0;
  bool reset = false;
};

/// The Upload message (image format "jpeg", header stamp and frame on both the
/// upload and its image; odometry identity when absent).
ecar_msgs::Upload toMsg(const UploadContent& content);
/// Everything but the image bytes. Throws ecar::Error naming the field
/// ("gravity", "odometry") on a non-finite gravity or a bad odometry that is
/// flagged present.
UploadContent fromMsg(const ecar_msgs::Upload& msg);
/// Whether an image format string names JPEG ("jpeg", "jpg", or
/// compressed_image_transport's "mono8; jpeg compressed mono8").
bool isJpegFormat(const std::string& format);
/// The uploaded JPEG decoded to grey into `out` (its buffer reused), after
/// checking, before any decoding, that the format names JPEG, that the bytes
/// start a JPEG whose header gives the camera's `width` x `height`, and that
/// they are not more than such an image takes (ecar/io/jpeg.h): no other
/// decoder is reached and no decompression bomb allocates. Throws ecar::Error
/// starting with "image" and naming what was wrong.
void decodeImage(const ecar_msgs::Upload& upload, int width, int height, cv::Mat* out);
/// decodeImage's three steps, for callers that report them apart: the format
/// and the JPEG header (nothing decoded) ...
ecar::JpegHeader readImageHeader(const ecar_msgs::Upload& upload);
/// ... the header's size against the camera's, and the byte count ...
void checkImageFits(const ecar_msgs::Upload& upload, const ecar::JpegHeader& header, int width,
                    int height);
/// ... and the decoding. Each throws ecar::Error starting with "image".
void decodeImage(const ecar_msgs::Upload& upload, const ecar::JpegHeader& header, cv::Mat* out);

/// One DeviceFrame for a tracked camera frame (stamp = capture time, frame
/// `map_frame`), listing the live VOs held with their versions.
ecar_msgs::DeviceFrame toMsg(const std::string& device_id, const ros::Time& stamp,
                             const std::string& map_frame, const ecar::DeviceTrackResult& result,
                             uint32_t keyframes, uint32_t local_points, bool uploaded,
                             const std::map<ecar::ObjectId, ecar::VirtualObject>& objects);

/// What the device measured of one round trip.
struct RoundTrip {
  std::string device_id;
  uint32_t bytes_up = 0;
  ros::Time sent;                        ///< upload published (device clock)
  ros::Time received;                    ///< local graph received (device clock)
  float tracking_time_device = 0.f;      ///< s, the device's tracking of the uploaded frame
  float tracking_cpu_time_device = 0.f;  ///< s of the device thread's CPU for that tracking
  uint8_t jpeg_quality = 0;              ///< the upload's JPEG quality
  uint32_t upload_budget = 0;            ///< bytes/s in force when it was sent (0: none)
};

/// Metrics of the round trip that `graph` ends: bytes (wireBytes of the graph
/// down), latency = received - sent, upload_time = server_received - sent,
/// server_time, server_cpu_time and align_time (its tracking_time) from the graph,
/// download_time = received - server_sent;
/// points = points (ecar) or map_points (edgeslam); the trip's own fields
/// (bytes_up, device times, jpeg_quality, upload_budget) as they are.
ecar_msgs::RoundTripMetrics toMsg(const ecar_msgs::LocalGraph& graph, const RoundTrip& trip);

}  // namespace ecar_bridge
