#include "ecar_device/conversions.h"

#include <algorithm>
#include <cmath>

#include "ecar_core/common/error.h"
#include "ecar_sim/conversions.h"

namespace ecar_device {
namespace {

const float kUvScale = ecar_msgs::TrackedPoint::UV_SCALE;
const float kAngleScale = ecar_msgs::TrackedPoint::ANGLE_SCALE;

/// fromPose with the field named in the error.
ecar::SE3 poseField(const geometry_msgs::Pose& pose, const std::string& field) {
  try {
    return ecar_sim::fromPose(pose);
  } catch (const ecar::Error& e) {
    throw ecar::Error(field + ": " + e.what());
  }
}

Eigen::Vector3d finiteVector(const float* v, const std::string& field) {
  const Eigen::Vector3d out(v[0], v[1], v[2]);
  if (!out.allFinite()) throw ecar::Error(field + ": non-finite value");
  return out;
}

float seconds(const ros::Duration& d) { return static_cast<float>(d.toSec()); }

}  // namespace

ecar_msgs::TrackedPoint toTrackedPoint(const ecar::ReceivedPoint& point) {
  const cv::KeyPoint& kp = point.keypoint;
  const float max_px = 65535.0f / kUvScale;
  if (!(kp.pt.x >= 0.0f && kp.pt.x <= max_px && kp.pt.y >= 0.0f && kp.pt.y <= max_px)) {
    throw ecar::Error("TrackedPoint: keypoint outside [0, 8191.875] px");
  }
  if (kp.octave < 0 || kp.octave > 255) throw ecar::Error("TrackedPoint: octave outside [0, 255]");
  ecar_msgs::TrackedPoint msg;
  msg.id = point.id.value;
  msg.u = static_cast<uint16_t>(std::lround(kp.pt.x * kUvScale));
  msg.v = static_cast<uint16_t>(std::lround(kp.pt.y * kUvScale));
  float angle = std::isfinite(kp.angle) ? std::fmod(kp.angle, 360.0f) : 0.0f;
  if (angle < 0.0f) angle += 360.0f;
  msg.angle = static_cast<uint8_t>(std::lround(angle / kAngleScale) % 256);
  msg.octave = static_cast<uint8_t>(kp.octave);
  return msg;
}

ecar::ReceivedPoint fromTrackedPoint(const ecar_msgs::TrackedPoint& msg) {
  ecar::ReceivedPoint p;
  p.id = ecar::MapPointId(msg.id);
  p.keypoint.pt = cv::Point2f(msg.u / kUvScale, msg.v / kUvScale);
  p.keypoint.angle = msg.angle * kAngleScale;
  p.keypoint.octave = msg.octave;
  p.keypoint.size = 31.0f;
  return p;
}

ecar::LocalGraphInput fromLocalGraph(const ecar_msgs::LocalGraph& msg) {
  ecar::LocalGraphInput g;
  g.frame_index = msg.frame_index;
  g.T_w_c = poseField(msg.pose, "pose");
  g.points.reserve(msg.points.size());
  for (const auto& p : msg.points) g.points.push_back(fromTrackedPoint(p));
  g.positions.reserve(msg.positions.size());
  for (size_t i = 0; i < msg.positions.size(); ++i) {
    const auto& p = msg.positions[i];
    const float xyz[3] = {p.x, p.y, p.z};
    const std::string field = "positions[" + std::to_string(i) + "]";
    if (p.index >= g.points.size()) {
      throw ecar::Error(field + ".index " + std::to_string(p.index) + " is not among the " +
                        std::to_string(g.points.size()) + " points");
    }
    g.positions.push_back({g.points[p.index].id, finiteVector(xyz, field)});
  }
  return g;
}

void toLocalGraph(const ecar::LocalGraphInput& graph, ecar_msgs::LocalGraph* msg) {
  msg->frame_index = graph.frame_index;
  msg->pose = ecar_sim::toPose(graph.T_w_c);
  msg->sync_mode = ecar_msgs::LocalGraph::SYNC_ECAR;
  msg->points.clear();
  for (const auto& p : graph.points) msg->points.push_back(toTrackedPoint(p));
  msg->positions.clear();
  for (const auto& p : graph.positions) {
    const auto it = std::find_if(graph.points.begin(), graph.points.end(),
                                 [&](const ecar::ReceivedPoint& q) { return q.id == p.id; });
    if (it == graph.points.end()) {
      throw ecar::Error("positions: map point " + std::to_string(p.id.value) +
                        " is not among the points");
    }
    ecar_msgs::PointPosition m;
    m.index = static_cast<uint16_t>(it - graph.points.begin());
    m.x = static_cast<float>(p.p_w.x());
    m.y = static_cast<float>(p.p_w.y());
    m.z = static_cast<float>(p.p_w.z());
    msg->positions.push_back(m);
  }
}

ecar::FullLocalMap fromFullLocalGraph(const ecar_msgs::LocalGraph& msg) {
  ecar::FullLocalMap map;
  map.frame_index = msg.frame_index;
  map.T_w_c = poseField(msg.pose, "pose");
  for (size_t i = 0; i < msg.keyframes.size(); ++i) {
    const auto& k = msg.keyframes[i];
    ecar::FullLocalMap::KeyFrame kf;
    kf.id = ecar::KeyFrameId(k.id);
    kf.T_w_c = poseField(k.pose, "keyframes[" + std::to_string(i) + "].pose");
    for (uint32_t id : k.point_ids) kf.point_ids.push_back(ecar::MapPointId(id));
    map.keyframes.push_back(std::move(kf));
  }
  map.points.reserve(msg.map_points.size());
  for (size_t i = 0; i < msg.map_points.size(); ++i) {
    const auto& m = msg.map_points[i];
    const std::string field = "map_points[" + std::to_string(i) + "]";
    ecar::PointSample s;
    s.id = ecar::MapPointId(m.id);
    s.p_w = finiteVector(m.position.data(), field + ".position");
    s.normal = finiteVector(m.normal.data(), field + ".normal");
    if (!std::isfinite(m.min_distance) || !std::isfinite(m.max_distance) || m.min_distance < 0.0f ||
        m.max_distance < m.min_distance) {
      throw ecar::Error(field + ": invalid distance range");
    }
    s.min_distance = m.min_distance;
    s.max_distance = m.max_distance;
    std::copy(m.descriptor.begin(), m.descriptor.end(), s.descriptor.begin());
    map.points.push_back(s);
  }
  return map;
}

void toFullLocalGraph(const ecar::FullLocalMap& map, ecar_msgs::LocalGraph* msg) {
  msg->frame_index = map.frame_index;
  msg->pose = ecar_sim::toPose(map.T_w_c);
  msg->sync_mode = ecar_msgs::LocalGraph::SYNC_EDGESLAM;
  msg->keyframes.clear();
  for (const auto& kf : map.keyframes) {
    ecar_msgs::KeyFrameInfo k;
    k.id = kf.id.value;
    k.pose = ecar_sim::toPose(kf.T_w_c);
    for (const auto& id : kf.point_ids) k.point_ids.push_back(id.value);
    msg->keyframes.push_back(std::move(k));
  }
  msg->map_points.clear();
  for (const auto& p : map.points) {
    ecar_msgs::MapPointFull m;
    m.id = p.id.value;
    for (int k = 0; k < 3; ++k) {
      m.position[k] = static_cast<float>(p.p_w[k]);
      m.normal[k] = static_cast<float>(p.normal[k]);
    }
    m.min_distance = p.min_distance;
    m.max_distance = p.max_distance;
    std::copy(p.descriptor.begin(), p.descriptor.end(), m.descriptor.begin());
    msg->map_points.push_back(m);
  }
}

ecar_msgs::Upload toUpload(const UploadContent& c) {
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
  if (c.gravity_c) msg.gravity = ecar_sim::toVector3(*c.gravity_c);
  msg.has_odometry = c.T_o_c.has_value();
  if (c.T_o_c) {
    msg.odometry = ecar_sim::toPose(*c.T_o_c);
  } else {
    msg.odometry.orientation.w = 1.0;
  }
  msg.last_graph_frame = c.last_graph_frame;
  msg.reset = c.reset;
  return msg;
}

UploadContent fromUpload(const ecar_msgs::Upload& msg) {
  UploadContent c;
  c.device_id = msg.device_id;
  c.camera_frame = msg.header.frame_id;
  c.frame_index = msg.frame_index;
  c.stamp = msg.header.stamp;
  c.sent = msg.sent;
  c.jpeg = msg.image.data;
  if (msg.has_gravity) {
    const Eigen::Vector3d g = ecar_sim::fromVector3(msg.gravity);
    if (!g.allFinite()) throw ecar::Error("gravity: non-finite value");
    c.gravity_c = g;
  }
  if (msg.has_odometry) c.T_o_c = poseField(msg.odometry, "odometry");
  c.last_graph_frame = msg.last_graph_frame;
  c.reset = msg.reset;
  return c;
}

ecar_msgs::DeviceFrame toDeviceFrame(const std::string& device_id, const ros::Time& stamp,
                                     const std::string& map_frame,
                                     const ecar::DeviceTrackResult& result, uint32_t keyframes,
                                     uint32_t local_points, bool uploaded,
                                     const std::map<ecar::ObjectId, ecar::VirtualObject>& objects) {
  ecar_msgs::DeviceFrame msg;
  msg.header.stamp = stamp;
  msg.header.frame_id = map_frame;
  msg.device_id = device_id;
  msg.frame_index = result.frame_index;
  msg.status = static_cast<uint8_t>(result.state);
  if (result.state == ecar::TrackingState::kOk) {
    msg.pose = ecar_sim::toPose(result.T_w_c);
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

ecar_msgs::RoundTripMetrics toRoundTripMetrics(const ecar_msgs::LocalGraph& graph,
                                               const RoundTrip& trip) {
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
  m.download_time = seconds(trip.received - graph.server_sent);
  m.tracking_time_device = trip.tracking_time_device;
  return m;
}

// ---------------------------------------------------------------- virtual objects

namespace {

Eigen::Vector3d finitePoint(const geometry_msgs::Point& m, const std::string& field) {
  const Eigen::Vector3d p(m.x, m.y, m.z);
  if (!p.allFinite()) throw ecar::Error(field + ": non-finite value");
  return p;
}

Eigen::Vector3d finiteVector3(const geometry_msgs::Vector3& m, const std::string& field) {
  const Eigen::Vector3d v(m.x, m.y, m.z);
  if (!v.allFinite()) throw ecar::Error(field + ": non-finite value");
  return v;
}

}  // namespace

ecar_msgs::VirtualObject toVirtualObject(const ecar::VirtualObject& vo) {
  return ecar_sim::toVirtualObjectMsg(vo);
}

ecar::VirtualObject fromVirtualObject(const ecar_msgs::VirtualObject& m, const std::string& field) {
  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(m.id);
  if (m.kind != ecar_msgs::VirtualObject::LINE && m.kind != ecar_msgs::VirtualObject::ANCHOR) {
    throw ecar::Error(field + ".kind: " + std::to_string(m.kind) + " is neither LINE nor ANCHOR");
  }
  vo.kind = static_cast<ecar::VoKind>(m.kind);
  vo.position = finitePoint(m.position, field + ".position");
  vo.start = finitePoint(m.start, field + ".start");
  vo.end = finitePoint(m.end, field + ".end");
  vo.r = m.r;
  vo.g = m.g;
  vo.b = m.b;
  if (!std::isfinite(m.width) || m.width < 0.0f) {
    throw ecar::Error(field + ".width: must be finite and >= 0");
  }
  vo.width = m.width;
  vo.normal = finiteVector3(m.normal, field + ".normal");
  if (vo.normal.norm() < 1e-9) throw ecar::Error(field + ".normal: zero vector");
  vo.plane = ecar::PlaneId(m.plane_id);
  vo.owner = m.owner;
  vo.version = m.version;
  vo.deleted = m.deleted;
  return vo;
}

ecar_msgs::Plane toPlane(const ecar::Plane& plane) { return ecar_sim::toPlaneMsg(plane); }

ecar::Plane fromPlane(const ecar_msgs::Plane& m, const std::string& field) {
  ecar::Plane plane;
  plane.id = ecar::PlaneId(m.id);
  if (m.label > ecar_msgs::Plane::OTHER) {
    throw ecar::Error(field + ".label: " + std::to_string(m.label) + " is not a label");
  }
  plane.label = static_cast<ecar::PlaneLabel>(m.label);
  plane.normal = finiteVector3(m.normal, field + ".normal");
  if (std::abs(plane.normal.norm() - 1.0) > 1e-3) throw ecar::Error(field + ".normal: not unit");
  plane.normal.normalize();
  if (!std::isfinite(m.offset)) throw ecar::Error(field + ".offset: non-finite value");
  plane.offset = m.offset;
  plane.boundary.reserve(m.boundary.size());
  for (size_t i = 0; i < m.boundary.size(); ++i) {
    plane.boundary.push_back(
        finitePoint(m.boundary[i], field + ".boundary[" + std::to_string(i) + "]"));
  }
  plane.version = m.version;
  plane.num_points = m.num_points;
  return plane;
}

void validateTouch(const ecar_msgs::Touch& msg) {
  if (!std::isfinite(msg.u) || !std::isfinite(msg.v)) throw ecar::Error("u, v: non-finite value");
  if (!std::isfinite(msg.width) || msg.width <= 0.0f) {
    throw ecar::Error("width: must be finite and > 0");
  }
  if (msg.phase > ecar_msgs::Touch::END) {
    throw ecar::Error("phase: " + std::to_string(msg.phase) + " is not BEGIN, MOVE or END");
  }
}

ecar::TouchInput fromTouch(const ecar_msgs::Touch& msg) {
  ecar::TouchInput t;
  t.uv = Eigen::Vector2d(msg.u, msg.v);
  t.phase = static_cast<ecar::TouchInput::Phase>(msg.phase);
  t.r = msg.r;
  t.g = msg.g;
  t.b = msg.b;
  t.width = msg.width;
  return t;
}

ecar_msgs::Touch toTouch(const ecar::TouchInput& touch, const std_msgs::Header& header) {
  ecar_msgs::Touch m;
  m.header = header;
  m.u = static_cast<float>(touch.uv.x());
  m.v = static_cast<float>(touch.uv.y());
  m.phase = static_cast<uint8_t>(touch.phase);
  m.r = touch.r;
  m.g = touch.g;
  m.b = touch.b;
  m.width = touch.width;
  return m;
}

ecar_msgs::Interaction toInteraction(const ecar::VoRequest& request, const std::string& device_id,
                                     const std_msgs::Header& header) {
  ecar_msgs::Interaction m;
  m.header = header;
  m.device_id = device_id;
  m.request_id = request.request_id;
  m.type = static_cast<uint8_t>(request.type);
  m.object_id = request.object_id.value;
  m.object = toVirtualObject(request.object);
  m.base_version = request.base_version;
  return m;
}

ecar::VoRequest fromInteraction(const ecar_msgs::Interaction& msg) {
  ecar::VoRequest r;
  r.request_id = msg.request_id;
  if (msg.type > ecar_msgs::Interaction::DELETE) {
    throw ecar::Error("type: " + std::to_string(msg.type) + " is not an interaction type");
  }
  r.type = static_cast<ecar::VoRequestType>(msg.type);
  r.object_id = ecar::ObjectId(msg.object_id);
  r.object = fromVirtualObject(msg.object, "object");
  r.base_version = msg.base_version;
  return r;
}

ecar::VoResult fromInteractionResult(const ecar_msgs::InteractionResult& msg) {
  ecar::VoResult r;
  r.request_id = msg.request_id;
  r.accepted = msg.accepted;
  r.object_id = ecar::ObjectId(msg.object_id);
  r.version = msg.version;
  r.reason = msg.reason;
  return r;
}

ecar_msgs::InteractionResult toInteractionResult(const ecar::VoResult& result,
                                                 const std::string& device_id,
                                                 const std_msgs::Header& header) {
  ecar_msgs::InteractionResult m;
  m.header = header;
  m.device_id = device_id;
  m.request_id = result.request_id;
  m.accepted = result.accepted;
  m.object_id = result.object_id.value;
  m.version = result.version;
  m.reason = result.reason;
  return m;
}

}  // namespace ecar_device
