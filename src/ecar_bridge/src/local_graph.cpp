#include "ecar_bridge/local_graph.h"

#include <algorithm>
#include <cmath>

#include "ecar_bridge/geometry.h"
#include "ecar_bridge/objects.h"
#include "ecar_core/common/error.h"

namespace ecar_bridge {
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

Eigen::Vector3f finiteArray(const boost::array<float, 3>& a, const std::string& field) {
  const Eigen::Vector3f v(a[0], a[1], a[2]);
  if (!v.allFinite()) throw ecar::Error(field + ": non-finite value");
  return v;
}

std::string at(const char* array, size_t i) {
  return std::string(array) + "[" + std::to_string(i) + "]";
}

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

ecar::GraphMapPoint fromMsg(const ecar_msgs::MapPointFull& m, const std::string& field) {
  ecar::GraphMapPoint p;
  p.id = ecar::MapPointId(m.id);
  p.p_w = finiteArray(m.position, field + ".position");
  p.normal = finiteArray(m.normal, field + ".normal");
  if (!std::isfinite(m.min_distance) || !std::isfinite(m.max_distance) || m.min_distance < 0.0f ||
      m.max_distance < m.min_distance) {
    throw ecar::Error(field + ": invalid distance range");
  }
  p.min_distance = m.min_distance;
  p.max_distance = m.max_distance;
  std::copy(m.descriptor.begin(), m.descriptor.end(), p.descriptor.begin());
  return p;
}

ecar_msgs::KeyFrameInfo toMsg(const ecar::GraphKeyFrame& kf) {
  ecar_msgs::KeyFrameInfo m;
  m.id = kf.id.value;
  m.device_id = kf.device;
  m.pose = toMsg(kf.T_w_c);
  m.point_ids.reserve(kf.points.size());
  for (const auto& p : kf.points) m.point_ids.push_back(p.value);
  return m;
}

ecar::GraphKeyFrame fromMsg(const ecar_msgs::KeyFrameInfo& msg, const std::string& field) {
  ecar::GraphKeyFrame kf;
  kf.id = ecar::KeyFrameId(msg.id);
  kf.device = msg.device_id;
  kf.T_w_c = fromMsg(msg.pose, field + ".pose");
  kf.points.reserve(msg.point_ids.size());
  for (uint32_t id : msg.point_ids) kf.points.push_back(ecar::MapPointId(id));
  return kf;
}

void toMsg(const ecar::LocalGraph& g, ecar_msgs::LocalGraph* msg) {
  msg->header.frame_id = "map";
  msg->device_id = g.device;
  msg->frame_index = g.frame_index;
  msg->status = static_cast<uint8_t>(g.status);
  msg->pose = toMsg(g.T_w_c);
  msg->map_epoch = g.map_epoch;
  msg->map_id = g.map.value;
  msg->sync_mode = g.mode == ecar::SyncMode::kEdgeSlam ? ecar_msgs::LocalGraph::SYNC_EDGESLAM
                                                       : ecar_msgs::LocalGraph::SYNC_ECAR;
  if (g.points.size() > 0xFFFF) throw ecar::Error("local graph: more than 65535 points");
  msg->points.clear();
  msg->points.reserve(g.points.size());
  for (const auto& p : g.points) msg->points.push_back(toMsg(p));
  // Positions are a subsequence of the points: one merge pass finds each index.
  msg->positions.clear();
  msg->positions.reserve(g.positions.size());
  size_t index = 0;
  for (const auto& p : g.positions) {
    while (index < g.points.size() && g.points[index].id != p.id) ++index;
    if (index == g.points.size()) {
      throw ecar::Error("local graph: a position for map point " + std::to_string(p.id.value) +
                        " that is not among its points (or out of their order)");
    }
    ecar_msgs::PointPosition m;
    m.index = static_cast<uint16_t>(index);
    m.x = p.p_w.x();
    m.y = p.p_w.y();
    m.z = p.p_w.z();
    msg->positions.push_back(m);
  }
  msg->keyframes.clear();
  msg->keyframes.reserve(g.keyframes.size());
  for (const auto& k : g.keyframes) msg->keyframes.push_back(toMsg(k));
  msg->map_points.clear();
  msg->map_points.reserve(g.map_points.size());
  for (const auto& p : g.map_points) msg->map_points.push_back(toMsg(p));
  msg->planes.clear();
  msg->planes.reserve(g.planes.size());
  for (const auto& p : g.planes) msg->planes.push_back(toMsg(p));
  msg->removed_planes.clear();
  msg->removed_planes.reserve(g.removed_planes.size());
  for (const ecar::PlaneId id : g.removed_planes) msg->removed_planes.push_back(id.value);
  msg->objects.clear();
  msg->objects.reserve(g.objects.size());
  for (const auto& o : g.objects) msg->objects.push_back(toMsg(o));
}

ecar::LocalGraph fromMsg(const ecar_msgs::LocalGraph& msg, std::vector<std::string>* skipped) {
  ecar::LocalGraph g;
  g.device = msg.device_id;
  g.frame_index = msg.frame_index;
  if (msg.status > ecar_msgs::LocalGraph::RELOCALISED) {
    throw ecar::Error("status: " + std::to_string(msg.status) + " is not a status");
  }
  g.status = static_cast<ecar::GraphStatus>(msg.status);
  if (ecar::tracked(g.status)) g.T_w_c = fromMsg(msg.pose, "pose");
  g.map_epoch = msg.map_epoch;
  g.map = ecar::MapId(msg.map_id);
  if (msg.sync_mode > ecar_msgs::LocalGraph::SYNC_EDGESLAM) {
    throw ecar::Error("sync_mode: " + std::to_string(msg.sync_mode) + " is not a sync mode");
  }
  g.mode = msg.sync_mode == ecar_msgs::LocalGraph::SYNC_EDGESLAM ? ecar::SyncMode::kEdgeSlam
                                                                 : ecar::SyncMode::kEcar;
  // Bounds on every list (a graph of a real session is far below them): a hostile or broken
  // server cannot make the device hold or process without limit.
  const auto bound = [](const char* field, size_t n, size_t max) {
    if (n > max) {
      throw ecar::Error(std::string(field) + ": " + std::to_string(n) + " entries, more than " +
                        std::to_string(max));
    }
  };
  bound("points", msg.points.size(), kMaxGraphPoints);
  bound("positions", msg.positions.size(), msg.points.size());
  bound("keyframes", msg.keyframes.size(), kMaxGraphKeyFrames);
  bound("map_points", msg.map_points.size(), kMaxGraphMapPoints);
  bound("planes", msg.planes.size(), kMaxGraphPlanes);
  bound("removed_planes", msg.removed_planes.size(), kMaxGraphPlanes);
  bound("objects", msg.objects.size(), kMaxGraphObjects);
  for (size_t i = 0; i < msg.keyframes.size(); ++i) {
    bound("keyframes[].point_ids", msg.keyframes[i].point_ids.size(), kMaxGraphMapPoints);
  }
  for (size_t i = 0; i < msg.planes.size(); ++i) {
    bound("planes[].boundary", msg.planes[i].boundary.size(), kMaxPlaneBoundary);
  }
  g.points.reserve(msg.points.size());
  for (const auto& p : msg.points) g.points.push_back(fromMsg(p));
  g.positions.reserve(msg.positions.size());
  for (size_t i = 0; i < msg.positions.size(); ++i) {
    const auto& p = msg.positions[i];
    const std::string field = at("positions", i);
    if (p.index >= g.points.size()) {
      throw ecar::Error(field + ".index " + std::to_string(p.index) + " is not among the " +
                        std::to_string(g.points.size()) + " points");
    }
    const Eigen::Vector3f p_w(p.x, p.y, p.z);
    if (!p_w.allFinite()) throw ecar::Error(field + ": non-finite value");
    g.positions.push_back({g.points[p.index].id, p_w});
  }
  g.keyframes.reserve(msg.keyframes.size());
  for (size_t i = 0; i < msg.keyframes.size(); ++i) {
    g.keyframes.push_back(fromMsg(msg.keyframes[i], at("keyframes", i)));
  }
  g.map_points.reserve(msg.map_points.size());
  for (size_t i = 0; i < msg.map_points.size(); ++i) {
    g.map_points.push_back(fromMsg(msg.map_points[i], at("map_points", i)));
  }
  const auto read = [skipped](auto&& convert, const auto& items, const char* name, auto* out) {
    out->reserve(items.size());
    for (size_t i = 0; i < items.size(); ++i) {
      try {
        out->push_back(convert(items[i], at(name, i)));
      } catch (const ecar::Error& e) {
        if (!skipped) throw;
        skipped->push_back(e.what());
      }
    }
  };
  read([](const ecar_msgs::Plane& m, const std::string& f) { return fromMsg(m, f); }, msg.planes,
       "planes", &g.planes);
  g.removed_planes.reserve(msg.removed_planes.size());
  for (size_t i = 0; i < msg.removed_planes.size(); ++i) {
    if (msg.removed_planes[i] == 0) throw ecar::Error(at("removed_planes", i) + ": plane id 0");
    g.removed_planes.push_back(ecar::PlaneId(msg.removed_planes[i]));
  }
  read([](const ecar_msgs::VirtualObject& m, const std::string& f) { return fromMsg(m, f); },
       msg.objects, "objects", &g.objects);
  return g;
}

}  // namespace ecar_bridge
