#include "ecar_bridge/device_messages.h"

#include <algorithm>

#include <cctype>

#include "ecar_bridge/geometry.h"
#include "ecar_core/common/error.h"
#include "ecar_core/io/jpeg.h"

namespace ecar_bridge {
namespace {

float seconds(const ros::Duration& d) { return static_cast<float>(d.toSec()); }

}  // namespace

ecar_msgs::Upload toMsg(const UploadContent& c) {
  ecar_msgs::Upload msg;
  msg.header.stamp = c.stamp;
  msg.header.frame_id = c.camera_frame;
  msg.device_id = c.device_id;
  msg.frame_index = c.frame_index;
  msg.sent = c.sent;
  msg.image.header = msg.header;
  msg.image.format = "jpeg";
  msg.image.data = c.jpeg;
  msg.has_gravity = c.gravity_c.has_value();
  if (c.gravity_c) msg.gravity = toVector3Msg(*c.gravity_c);
  msg.has_odometry = c.T_o_c.has_value();
  msg.odometry = toMsg(c.T_o_c.value_or(ecar::SE3::Identity()));
  msg.last_graph_frame = c.last_graph_frame;
  msg.reset = c.reset;
  return msg;
}

UploadContent fromMsg(const ecar_msgs::Upload& msg) {
  UploadContent c;
  c.device_id = msg.device_id;
  c.camera_frame = msg.header.frame_id;
  c.frame_index = msg.frame_index;
  c.stamp = msg.header.stamp;
  c.sent = msg.sent;
  if (msg.has_gravity) {
    const Eigen::Vector3d g = fromMsg(msg.gravity);
    if (!g.allFinite()) throw ecar::Error("gravity: non-finite value");
    c.gravity_c = g;
  }
  if (msg.has_odometry) c.T_o_c = fromMsg(msg.odometry, "odometry");
  c.last_graph_frame = msg.last_graph_frame;
  c.reset = msg.reset;
  return c;
}

bool isJpegFormat(const std::string& format) {
  std::string lower(format);
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return lower == "jpg" || lower.find("jpeg") != std::string::npos;
}

ecar::JpegHeader readImageHeader(const ecar_msgs::Upload& upload) {
  if (!isJpegFormat(upload.image.format)) {
    throw ecar::Error("image format '" + upload.image.format.substr(0, 64) +
                      "': uploads are JPEG only");
  }
  try {
    return ecar::readJpegHeader(upload.image.data.data(), upload.image.data.size());
  } catch (const ecar::Error& e) {
    throw ecar::Error(std::string("image: ") + e.what());
  }
}

void checkImageFits(const ecar_msgs::Upload& upload, const ecar::JpegHeader& header, int width,
                    int height) {
  try {
    ecar::checkJpegFits(header, upload.image.data.size(), width, height);
  } catch (const ecar::Error& e) {
    throw ecar::Error(std::string("image: ") + e.what());
  }
}

void decodeImage(const ecar_msgs::Upload& upload, const ecar::JpegHeader& header, cv::Mat* out) {
  try {
    ecar::decodeJpegGray(upload.image.data.data(), upload.image.data.size(), out, &header);
  } catch (const ecar::Error& e) {
    throw ecar::Error(std::string("image: ") + e.what());
  }
}

void decodeImage(const ecar_msgs::Upload& upload, int width, int height, cv::Mat* out) {
  const ecar::JpegHeader header = readImageHeader(upload);
  checkImageFits(upload, header, width, height);
  decodeImage(upload, header, out);
}

ecar_msgs::DeviceFrame toMsg(const std::string& device_id, const ros::Time& stamp,
                             const std::string& map_frame, const ecar::DeviceTrackResult& result,
                             uint32_t keyframes, uint32_t local_points, bool uploaded,
                             const std::map<ecar::ObjectId, ecar::VirtualObject>& objects) {
  ecar_msgs::DeviceFrame msg;
  msg.header.stamp = stamp;
  msg.header.frame_id = map_frame;
  msg.device_id = device_id;
  msg.frame_index = result.frame_index;
  msg.status = static_cast<uint8_t>(result.state);
  if (result.state == ecar::TrackingState::kOk) {
    msg.pose = toMsg(result.T_w_c);
  } else {
    msg.pose.orientation.w = 1.0;
  }
  msg.tracked_points = static_cast<uint32_t>(std::max(0, result.inliers));
  msg.local_points = local_points;
  msg.keyframes = keyframes;
  msg.uploaded = uploaded;
  msg.tracking_time = static_cast<float>(result.total_ms / 1000.0);
  msg.object_ids.reserve(objects.size());
  msg.object_versions.reserve(objects.size());
  for (const auto& [id, vo] : objects) {
    msg.object_ids.push_back(id.value);
    msg.object_versions.push_back(vo.version);
  }
  return msg;
}

ecar_msgs::RoundTripMetrics toMsg(const ecar_msgs::LocalGraph& graph, const RoundTrip& trip) {
  ecar_msgs::RoundTripMetrics m;
  m.header.stamp = trip.received;
  m.device_id = trip.device_id;
  m.frame_index = graph.frame_index;
  m.bytes_up = trip.bytes_up;
  m.bytes_down = wireBytes(graph);
  m.points = static_cast<uint32_t>(graph.sync_mode == ecar_msgs::LocalGraph::SYNC_EDGESLAM
                                       ? graph.map_points.size()
                                       : graph.points.size());
  m.positions = static_cast<uint32_t>(graph.positions.size());
  m.latency = seconds(trip.received - trip.sent);
  m.upload_time = seconds(graph.server_received - trip.sent);
  m.server_time = graph.server_time;
  m.server_cpu_time = graph.server_cpu_time;
  m.receive_time = graph.receive_time;
  m.align_time = graph.tracking_time;
  m.download_time = seconds(trip.received - graph.server_sent);
  m.tracking_time_device = trip.tracking_time_device;
  m.tracking_cpu_time_device = trip.tracking_cpu_time_device;
  m.jpeg_quality = trip.jpeg_quality;
  m.upload_budget = trip.upload_budget;
  return m;
}

}  // namespace ecar_bridge
