#include "ecar_server/conversions.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_sim/conversions.h"

namespace ecar_server {
namespace {

uint16_t quantiseUv(float px) {
  const float q = std::round(px * ecar_msgs::TrackedPoint::UV_SCALE);
  if (!(q > 0.0f)) return 0;
  return static_cast<uint16_t>(std::min(q, 65535.0f));
}

uint8_t quantiseAngle(float degrees) {
  if (!std::isfinite(degrees)) return 0;
  const long steps = std::lround(degrees / ecar_msgs::TrackedPoint::ANGLE_SCALE);
  return static_cast<uint8_t>(((steps % 256) + 256) % 256);
}

void toArray(const Eigen::Vector3f& v, boost::array<float, 3>* a) {
  for (int i = 0; i < 3; ++i) (*a)[i] = v[i];
}

Eigen::Vector3f fromArray(const boost::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

}  // namespace

ecar_msgs::TrackedPoint toMsg(const ecar::GraphPoint& p) {
  ecar_msgs::TrackedPoint m;
  m.id = p.id.value;
  m.u = quantiseUv(p.u);
  m.v = quantiseUv(p.v);
  m.angle = quantiseAngle(p.angle);
  m.octave = static_cast<uint8_t>(std::clamp(p.octave, 0, 255));
  return m;
}

ecar::GraphPoint fromMsg(const ecar_msgs::TrackedPoint& msg) {
  ecar::GraphPoint p;
  p.id = ecar::MapPointId(msg.id);
  p.u = msg.u / ecar_msgs::TrackedPoint::UV_SCALE;
  p.v = msg.v / ecar_msgs::TrackedPoint::UV_SCALE;
  p.angle = msg.angle * ecar_msgs::TrackedPoint::ANGLE_SCALE;
  p.octave = msg.octave;
  return p;
}

ecar_msgs::PointPosition toMsg(const ecar::GraphPosition& p, uint16_t index) {
  ecar_msgs::PointPosition m;
  m.index = index;
  m.x = p.p_w.x();
  m.y = p.p_w.y();
  m.z = p.p_w.z();
  return m;
}

ecar::GraphPosition fromMsg(const ecar_msgs::PointPosition& msg,
                            const std::vector<ecar_msgs::TrackedPoint>& points) {
  if (msg.index >= points.size()) {
    throw ecar::Error("positions: index " + std::to_string(msg.index) + " is not among the " +
                      std::to_string(points.size()) + " points");
  }
  return {ecar::MapPointId(points[msg.index].id), Eigen::Vector3f(msg.x, msg.y, msg.z)};
}

ecar_msgs::MapPointFull toMsg(const ecar::GraphMapPoint& p) {
  ecar_msgs::MapPointFull m;
  m.id = p.id.value;
  toArray(p.p_w, &m.position);
  toArray(p.normal, &m.normal);
  m.min_distance = p.min_distance;
  m.max_distance = p.max_distance;
  std::copy(p.descriptor.begin(), p.descriptor.end(), m.descriptor.begin());
  return m;
}

ecar::GraphMapPoint fromMsg(const ecar_msgs::MapPointFull& msg) {
  ecar::GraphMapPoint p;
  p.id = ecar::MapPointId(msg.id);
  p.p_w = fromArray(msg.position);
  p.normal = fromArray(msg.normal);
  p.min_distance = msg.min_distance;
  p.max_distance = msg.max_distance;
  std::copy(msg.descriptor.begin(), msg.descriptor.end(), p.descriptor.begin());
  return p;
}

ecar_msgs::KeyFrameInfo toMsg(const ecar::GraphKeyFrame& kf, const std::string& device_name) {
  ecar_msgs::KeyFrameInfo m;
  m.id = kf.id.value;
  m.device_id = device_name;
  m.pose = ecar_sim::toPose(kf.T_w_c);
  m.point_ids.reserve(kf.points.size());
  for (const auto& p : kf.points) m.point_ids.push_back(p.value);
  return m;
}

ecar::GraphKeyFrame fromMsg(const ecar_msgs::KeyFrameInfo& msg, std::string* device_name) {
  ecar::GraphKeyFrame kf;
  kf.id = ecar::KeyFrameId(msg.id);
  kf.T_w_c = ecar_sim::fromPose(msg.pose);
  kf.points.reserve(msg.point_ids.size());
  for (uint32_t id : msg.point_ids) kf.points.push_back(ecar::MapPointId(id));
  if (device_name) *device_name = msg.device_id;
  return kf;
}

uint8_t toStatus(const ecar::TrackResult& result) {
  switch (result.state) {
    case ecar::TrackingState::kOk:
      return result.relocalised ? ecar_msgs::LocalGraph::RELOCALISED : ecar_msgs::LocalGraph::OK;
    case ecar::TrackingState::kLost:
      return ecar_msgs::LocalGraph::LOST;
    default:
      return ecar_msgs::LocalGraph::NOT_INITIALISED;
  }
}

ecar::LocalGraphData payloadFromMsg(const ecar_msgs::LocalGraph& msg) {
  ecar::LocalGraphData d;
  d.mode = msg.sync_mode == ecar_msgs::LocalGraph::SYNC_EDGESLAM ? ecar::SyncMode::kEdgeSlam
                                                                 : ecar::SyncMode::kEcar;
  for (const auto& p : msg.points) d.points.push_back(fromMsg(p));
  for (const auto& p : msg.positions) d.positions.push_back(fromMsg(p, msg.points));
  for (const auto& k : msg.keyframes) d.keyframes.push_back(fromMsg(k));
  for (const auto& p : msg.map_points) d.map_points.push_back(fromMsg(p));
  return d;
}

ecar_msgs::TrackedFrame toMsg(const ecar::TrackResult& result, const FrameMeta& meta) {
  ecar_msgs::TrackedFrame m;
  m.header.stamp = meta.stamp;
  m.header.frame_id = "map";
  m.device_id = meta.device;
  m.frame_index = meta.frame_index;
  m.status = toStatus(result);
  m.pose = ecar_sim::toPose(result.T_w_c);
  m.point_ids.reserve(result.tracked.size());
  m.points.reserve(result.tracked.size());
  for (const auto& t : result.tracked) {
    ecar::GraphPoint g;
    g.id = t.id;
    g.u = t.keypoint.pt.x;
    g.v = t.keypoint.pt.y;
    g.angle = t.keypoint.angle;
    g.octave = t.keypoint.octave;
    m.point_ids.push_back(t.id.value);
    m.points.push_back(toMsg(g));
  }
  m.local_keyframes.reserve(result.local_keyframes.size());
  for (const auto& k : result.local_keyframes) m.local_keyframes.push_back(k.value);
  m.new_keyframe = result.new_keyframe.has_value();
  m.keyframe_id = result.new_keyframe ? result.new_keyframe->value : 0;
  m.upload_sent = meta.upload_sent;
  m.server_received = meta.server_received;
  m.tracking_time = meta.tracking_time;
  return m;
}

ecar::TrackResult fromMsg(const ecar_msgs::TrackedFrame& msg, FrameMeta* meta) {
  if (msg.point_ids.size() != msg.points.size()) {
    throw ecar::Error("TrackedFrame: point_ids and points differ in length");
  }
  ecar::TrackResult r;
  switch (msg.status) {
    case ecar_msgs::TrackedFrame::OK:
    case ecar_msgs::TrackedFrame::RELOCALISED:
      r.state = ecar::TrackingState::kOk;
      break;
    case ecar_msgs::TrackedFrame::LOST:
      r.state = ecar::TrackingState::kLost;
      break;
    default:
      r.state = ecar::TrackingState::kNotInitialised;
  }
  r.relocalised = msg.status == ecar_msgs::TrackedFrame::RELOCALISED;
  r.T_w_c = ecar_sim::fromPose(msg.pose);
  r.tracked.reserve(msg.points.size());
  for (size_t i = 0; i < msg.points.size(); ++i) {
    const ecar::GraphPoint g = fromMsg(msg.points[i]);
    cv::KeyPoint kp(g.u, g.v, 31.0f, g.angle, 0.0f, g.octave);
    r.tracked.push_back({ecar::MapPointId(msg.point_ids[i]), kp, Eigen::Vector3d::Zero()});
  }
  for (uint32_t k : msg.local_keyframes) r.local_keyframes.push_back(ecar::KeyFrameId(k));
  if (msg.new_keyframe) r.new_keyframe = ecar::KeyFrameId(msg.keyframe_id);
  if (meta) {
    meta->device = msg.device_id;
    meta->frame_index = msg.frame_index;
    meta->stamp = msg.header.stamp;
    meta->upload_sent = msg.upload_sent;
    meta->server_received = msg.server_received;
    meta->tracking_time = msg.tracking_time;
  }
  return r;
}

ecar_msgs::KeyFrameEvent toMsg(const MappedKeyFrame& kf) {
  ecar_msgs::KeyFrameEvent m;
  m.header.stamp.fromSec(std::max(0.0, kf.timestamp));
  m.header.frame_id = "map";
  m.keyframe_id = kf.id.value;
  m.device_id = kf.device;
  m.frame_index = kf.frame_index;
  m.has_gravity = kf.gravity_c.has_value();
  if (kf.gravity_c) m.gravity = ecar_sim::toVector3(*kf.gravity_c);
  return m;
}

MappedKeyFrame fromMsg(const ecar_msgs::KeyFrameEvent& msg) {
  MappedKeyFrame kf;
  kf.id = ecar::KeyFrameId(msg.keyframe_id);
  kf.device = msg.device_id;
  kf.frame_index = msg.frame_index;
  kf.timestamp = msg.header.stamp.toSec();
  if (msg.has_gravity) kf.gravity_c = ecar_sim::fromVector3(msg.gravity);
  return kf;
}

UploadMotion motionOf(const ecar_msgs::Upload& upload) {
  UploadMotion m;
  if (upload.has_gravity) {
    const Eigen::Vector3d g = ecar_sim::fromVector3(upload.gravity);
    if (!g.allFinite()) throw ecar::Error("gravity is not finite");
    m.gravity_c = g;
  }
  if (upload.has_odometry) {
    try {
      m.T_o_c = ecar_sim::fromPose(upload.odometry);
    } catch (const ecar::Error& e) {
      throw ecar::Error(std::string("odometry: ") + e.what());
    }
  }
  return m;
}

void setMotion(const UploadMotion& motion, ecar_msgs::Upload* upload) {
  upload->has_gravity = motion.gravity_c.has_value();
  upload->gravity = ecar_sim::toVector3(motion.gravity_c.value_or(Eigen::Vector3d::Zero()));
  upload->has_odometry = motion.T_o_c.has_value();
  upload->odometry = ecar_sim::toPose(motion.T_o_c.value_or(ecar::SE3::Identity()));
}

cv::Mat decodeImage(const ecar_msgs::Upload& upload) {
  const auto& data = upload.image.data;
  if (data.empty()) throw ecar::Error("image is empty");
  cv::Mat image;
  try {
    image = cv::imdecode(
        cv::Mat(1, static_cast<int>(data.size()), CV_8U, const_cast<uint8_t*>(data.data())),
        cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception&) {
    image.release();
  }
  if (image.empty()) {
    throw ecar::Error("image does not decode (" + std::to_string(data.size()) + " bytes, format '" +
                      upload.image.format + "')");
  }
  return image;
}

ecar_msgs::Plane toMsg(const ecar::Plane& plane) { return ecar_sim::toPlaneMsg(plane); }

ecar::Plane fromMsg(const ecar_msgs::Plane& msg) {
  if (msg.label > ecar_msgs::Plane::OTHER) {
    throw ecar::Error("plane.label: unknown value " + std::to_string(msg.label));
  }
  ecar::Plane p;
  p.id = ecar::PlaneId(msg.id);
  p.label = static_cast<ecar::PlaneLabel>(msg.label);
  p.normal = ecar_sim::fromVector3(msg.normal);
  p.offset = msg.offset;
  p.boundary.reserve(msg.boundary.size());
  for (const auto& b : msg.boundary) p.boundary.push_back(ecar_sim::fromPoint(b));
  p.version = msg.version;
  p.num_points = msg.num_points;
  return p;
}

ecar_msgs::VirtualObject toMsg(const ecar::VirtualObject& vo) {
  return ecar_sim::toVirtualObjectMsg(vo);
}

ecar::VirtualObject fromMsg(const ecar_msgs::VirtualObject& msg) {
  if (msg.kind > ecar_msgs::VirtualObject::ANCHOR) {
    throw ecar::Error("object.kind: unknown value " + std::to_string(msg.kind));
  }
  ecar::VirtualObject vo;
  vo.id = ecar::ObjectId(msg.id);
  vo.kind = static_cast<ecar::VoKind>(msg.kind);
  vo.position = ecar_sim::fromPoint(msg.position);
  vo.start = ecar_sim::fromPoint(msg.start);
  vo.end = ecar_sim::fromPoint(msg.end);
  vo.r = msg.r;
  vo.g = msg.g;
  vo.b = msg.b;
  vo.width = msg.width;
  vo.normal = ecar_sim::fromVector3(msg.normal);
  vo.plane = ecar::PlaneId(msg.plane_id);
  vo.owner = msg.owner;
  vo.version = msg.version;
  vo.deleted = msg.deleted;
  return vo;
}

ecar_msgs::Interaction toMsg(const VoRequest& request) {
  ecar_msgs::Interaction m;
  m.header.frame_id = "map";
  m.device_id = request.device;
  m.request_id = request.request_id;
  switch (request.type) {
    case VoRequest::Type::kRegister:
      m.type = ecar_msgs::Interaction::REGISTER;
      break;
    case VoRequest::Type::kManipulate:
      m.type = ecar_msgs::Interaction::MANIPULATE;
      break;
    case VoRequest::Type::kDelete:
      m.type = ecar_msgs::Interaction::DELETE;
      break;
  }
  m.object_id = request.object.value;
  m.object = toMsg(request.state);
  m.base_version = request.base_version;
  return m;
}

VoRequest fromMsg(const ecar_msgs::Interaction& msg) {
  VoRequest r;
  r.device = msg.device_id;
  r.request_id = msg.request_id;
  switch (msg.type) {
    case ecar_msgs::Interaction::REGISTER:
      r.type = VoRequest::Type::kRegister;
      break;
    case ecar_msgs::Interaction::MANIPULATE:
      r.type = VoRequest::Type::kManipulate;
      break;
    case ecar_msgs::Interaction::DELETE:
      r.type = VoRequest::Type::kDelete;
      break;
    default:
      throw ecar::Error("type: unknown value " + std::to_string(msg.type));
  }
  r.object = ecar::ObjectId(msg.object_id);
  if (r.type != VoRequest::Type::kDelete) r.state = fromMsg(msg.object);
  r.base_version = msg.base_version;
  return r;
}

ecar_msgs::InteractionResult toMsg(const VoRequest& request, const ecar::VoOutcome& outcome) {
  ecar_msgs::InteractionResult m;
  m.header.frame_id = "map";
  m.device_id = request.device;
  m.request_id = request.request_id;
  m.accepted = outcome.accepted;
  m.object_id = outcome.id.value;
  m.version = outcome.version;
  m.reason = outcome.reason;
  return m;
}

ecar::VoOutcome outcomeFromMsg(const ecar_msgs::InteractionResult& msg) {
  ecar::VoOutcome o;
  o.accepted = msg.accepted;
  o.id = ecar::ObjectId(msg.object_id);
  o.version = msg.version;
  o.reason = msg.reason;
  return o;
}

}  // namespace ecar_server
