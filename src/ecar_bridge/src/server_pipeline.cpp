#include "ecar_bridge/server_pipeline.h"

#include <algorithm>

#include "ecar_bridge/geometry.h"
#include "ecar_bridge/local_graph.h"
#include "ecar_bridge/objects.h"
#include "ecar_core/common/error.h"
#include "ecar_core/sync/local_graph_composer.h"

namespace ecar_bridge {

ecar_msgs::TrackedFrame toMsg(const ecar::TrackResult& result, const FrameMeta& meta) {
  ecar_msgs::TrackedFrame m;
  m.header.stamp = meta.stamp;
  m.header.frame_id = "map";
  m.device_id = meta.device;
  m.frame_index = meta.frame_index;
  m.status = static_cast<uint8_t>(ecar::graphStatus(result));
  m.pose = toMsg(result.T_w_c);
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
  m.receive_time = meta.receive_time;
  m.tracking_time = meta.tracking_time;
  m.cpu_time = meta.cpu_time;
  m.map_epoch = result.map_epoch;
  m.map_id = result.map.value;
  m.reset = meta.reset;
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
  r.T_w_c = fromMsg(msg.pose);
  r.tracked.reserve(msg.points.size());
  for (size_t i = 0; i < msg.points.size(); ++i) {
    const ecar::GraphPoint g = fromMsg(msg.points[i]);
    cv::KeyPoint kp(g.u, g.v, 31.0f, g.angle, 0.0f, g.octave);
    r.tracked.push_back({ecar::MapPointId(msg.point_ids[i]), kp, Eigen::Vector3d::Zero()});
  }
  for (uint32_t k : msg.local_keyframes) r.local_keyframes.push_back(ecar::KeyFrameId(k));
  if (msg.new_keyframe) r.new_keyframe = ecar::KeyFrameId(msg.keyframe_id);
  r.map_epoch = msg.map_epoch;
  r.map = ecar::MapId(msg.map_id);
  if (meta) {
    meta->device = msg.device_id;
    meta->frame_index = msg.frame_index;
    meta->stamp = msg.header.stamp;
    meta->upload_sent = msg.upload_sent;
    meta->server_received = msg.server_received;
    meta->receive_time = msg.receive_time;
    meta->tracking_time = msg.tracking_time;
    meta->cpu_time = msg.cpu_time;
    meta->reset = msg.reset;
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
  if (kf.gravity_c) m.gravity = toVector3Msg(*kf.gravity_c);
  return m;
}

MappedKeyFrame fromMsg(const ecar_msgs::KeyFrameEvent& msg) {
  MappedKeyFrame kf;
  kf.id = ecar::KeyFrameId(msg.keyframe_id);
  kf.device = msg.device_id;
  kf.frame_index = msg.frame_index;
  kf.timestamp = msg.header.stamp.toSec();
  if (msg.has_gravity) kf.gravity_c = fromMsg(msg.gravity);
  return kf;
}

ecar_msgs::KeyFramePlanes toMsg(const ecar::KeyFramePlanes& planes,
                                const std::string& device_name) {
  ecar_msgs::KeyFramePlanes m;
  m.header.stamp.fromSec(std::max(0.0, planes.timestamp));
  m.header.frame_id = "map";
  m.keyframe_id = planes.keyframe.value;
  m.device_id = device_name;
  m.frame_index = planes.frame_index;
  m.pose = toMsg(planes.T_w_c);
  m.map_epoch = planes.map_epoch;
  m.plane_ids.reserve(planes.planes.size());
  for (const auto& id : planes.planes) m.plane_ids.push_back(id.value);
  m.planes_created = static_cast<uint32_t>(planes.update.created.size());
  m.planes_updated = static_cast<uint32_t>(planes.update.updated.size());
  return m;
}

ecar::KeyFramePlanes fromMsg(const ecar_msgs::KeyFramePlanes& msg) {
  ecar::KeyFramePlanes k;
  k.keyframe = ecar::KeyFrameId(msg.keyframe_id);
  k.frame_index = msg.frame_index;
  k.timestamp = msg.header.stamp.toSec();
  k.T_w_c = fromMsg(msg.pose, "pose");
  k.map_epoch = msg.map_epoch;
  for (uint32_t id : msg.plane_ids) k.planes.push_back(ecar::PlaneId(id));
  return k;
}

void toMsg(const ecar::VisibleStructure& v, ecar_msgs::VisibleStructure* msg) {
  msg->planes.clear();
  msg->planes.reserve(v.planes.size());
  for (const auto& p : v.planes) msg->planes.push_back(toMsg(p));
  msg->objects.clear();
  msg->objects.reserve(v.objects.size());
  for (const auto& o : v.objects) msg->objects.push_back(toMsg(o));
  msg->objects_in_graph = v.objects_computed;
  msg->cells.clear();
  msg->cells.reserve(3 * v.cells.size());
  for (const auto& c : v.cells) {
    msg->cells.push_back(c.x);
    msg->cells.push_back(c.y);
    msg->cells.push_back(c.z);
  }
  msg->stale = v.stale;
  msg->grid_time = static_cast<float>(v.milliseconds / 1000.0);
  msg->grid_cpu_time = static_cast<float>(v.cpu_ms / 1000.0);
}

ecar::VisibleStructure fromMsg(const ecar_msgs::VisibleStructure& msg) {
  ecar::VisibleStructure v;
  v.planes.reserve(msg.planes.size());
  for (size_t i = 0; i < msg.planes.size(); ++i) {
    v.planes.push_back(fromMsg(msg.planes[i], "planes[" + std::to_string(i) + "]"));
  }
  v.objects.reserve(msg.objects.size());
  for (size_t i = 0; i < msg.objects.size(); ++i) {
    v.objects.push_back(fromMsg(msg.objects[i], "objects[" + std::to_string(i) + "]"));
  }
  v.objects_computed = msg.objects_in_graph;
  if (msg.cells.size() % 3 != 0) {
    throw ecar::Error("cells: " + std::to_string(msg.cells.size()) + " values, not triples");
  }
  v.cells.reserve(msg.cells.size() / 3);
  for (size_t i = 0; i + 2 < msg.cells.size(); i += 3) {
    v.cells.push_back(ecar::CellKey{msg.cells[i], msg.cells[i + 1], msg.cells[i + 2]});
  }
  v.stale = msg.stale;
  v.milliseconds = 1000.0 * msg.grid_time;
  v.cpu_ms = 1000.0 * msg.grid_cpu_time;
  return v;
}

}  // namespace ecar_bridge
