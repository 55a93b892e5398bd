#include "ecar_bridge/objects.h"

#include <cmath>

#include "ecar_bridge/geometry.h"
#include "ecar_core/common/error.h"

namespace ecar_bridge {
namespace {

Eigen::Vector3d finitePoint(const geometry_msgs::Point& m, const std::string& field) {
  const Eigen::Vector3d p = fromMsg(m);
  if (!p.allFinite()) throw ecar::Error(field + ": non-finite value");
  return p;
}

Eigen::Vector3d finiteVector(const geometry_msgs::Vector3& m, const std::string& field) {
  const Eigen::Vector3d v = fromMsg(m);
  if (!v.allFinite()) throw ecar::Error(field + ": non-finite value");
  return v;
}

}  // namespace

ecar_msgs::Plane toMsg(const ecar::Plane& plane) {
  ecar_msgs::Plane m;
  m.id = plane.id.value;
  m.label = static_cast<uint8_t>(plane.label);
  m.normal = toVector3Msg(plane.normal);
  m.offset = plane.offset;
  m.boundary.reserve(plane.boundary.size());
  for (const auto& p : plane.boundary) m.boundary.push_back(toPointMsg(p));
  m.version = plane.version;
  m.num_points = plane.num_points;
  return m;
}

ecar::Plane fromMsg(const ecar_msgs::Plane& m, const std::string& field) {
  ecar::Plane plane;
  plane.id = ecar::PlaneId(m.id);
  if (m.label > ecar_msgs::Plane::OTHER) {
    throw ecar::Error(field + ".label: " + std::to_string(m.label) + " is not a label");
  }
  plane.label = static_cast<ecar::PlaneLabel>(m.label);
  plane.normal = finiteVector(m.normal, field + ".normal");
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

ecar_msgs::VirtualObject toMsg(const ecar::VirtualObject& vo) {
  ecar_msgs::VirtualObject m;
  m.id = vo.id.value;
  m.kind = static_cast<uint8_t>(vo.kind);
  m.position = toPointMsg(vo.position);
  m.start = toPointMsg(vo.start);
  m.end = toPointMsg(vo.end);
  m.r = vo.r;
  m.g = vo.g;
  m.b = vo.b;
  m.width = vo.width;
  m.normal = toVector3Msg(vo.normal);
  m.plane_id = vo.plane.value;
  m.owner = vo.owner;
  m.version = vo.version;
  m.deleted = vo.deleted;
  m.map_id = vo.map.value;
  return m;
}

ecar::VirtualObject fromMsg(const ecar_msgs::VirtualObject& m, const std::string& field) {
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
  vo.normal = finiteVector(m.normal, field + ".normal");
  if (vo.normal.norm() < 1e-9) throw ecar::Error(field + ".normal: zero vector");
  vo.plane = ecar::PlaneId(m.plane_id);
  vo.owner = m.owner;
  vo.version = m.version;
  vo.map = ecar::MapId(m.map_id);
  vo.deleted = m.deleted;
  return vo;
}

ecar_msgs::Interaction toMsg(const ecar::VoRequest& request, const std_msgs::Header& header) {
  ecar_msgs::Interaction m;
  m.header = header;
  m.device_id = request.device;
  m.request_id = request.request_id;
  m.type = static_cast<uint8_t>(request.type);
  m.object_id = request.object_id.value;
  m.object = toMsg(request.object);
  m.base_version = request.base_version;
  return m;
}

ecar::VoRequest fromMsg(const ecar_msgs::Interaction& msg) {
  ecar::VoRequest r;
  r.device = msg.device_id;
  r.request_id = msg.request_id;
  if (msg.type > ecar_msgs::Interaction::DELETE) {
    throw ecar::Error("type: " + std::to_string(msg.type) + " is not an interaction type");
  }
  r.type = static_cast<ecar::VoRequestType>(msg.type);
  r.object_id = ecar::ObjectId(msg.object_id);
  if (r.type != ecar::VoRequestType::kDelete) r.object = fromMsg(msg.object, "object");
  r.base_version = msg.base_version;
  return r;
}

ecar_msgs::InteractionResult toMsg(const ecar::VoResult& result, const std_msgs::Header& header) {
  ecar_msgs::InteractionResult m;
  m.header = header;
  m.device_id = result.device;
  m.request_id = result.request_id;
  m.accepted = result.accepted;
  m.object_id = result.object_id.value;
  m.version = result.version;
  m.reason = result.reason;
  return m;
}

ecar::VoResult fromMsg(const ecar_msgs::InteractionResult& msg) {
  ecar::VoResult r;
  r.device = msg.device_id;
  r.request_id = msg.request_id;
  r.accepted = msg.accepted;
  r.object_id = ecar::ObjectId(msg.object_id);
  r.version = msg.version;
  r.reason = msg.reason;
  return r;
}

ecar_msgs::Touch toMsg(const ecar::Touch& touch, const std_msgs::Header& header) {
  ecar_msgs::Touch m;
  m.header = header;
  m.u = static_cast<float>(touch.uv.x());
  m.v = static_cast<float>(touch.uv.y());
  m.phase = static_cast<uint8_t>(touch.phase);
  m.r = touch.r;
  m.g = touch.g;
  m.b = touch.b;
  m.width = static_cast<float>(touch.width);
  return m;
}

ecar::Touch fromMsg(const ecar_msgs::Touch& msg) {
  if (!std::isfinite(msg.u) || !std::isfinite(msg.v)) throw ecar::Error("u, v: non-finite value");
  if (!std::isfinite(msg.width) || msg.width <= 0.0f) {
    throw ecar::Error("width: must be finite and > 0");
  }
  if (msg.phase > ecar_msgs::Touch::END) {
    throw ecar::Error("phase: " + std::to_string(msg.phase) + " is not BEGIN, MOVE or END");
  }
  ecar::Touch t;
  t.uv = Eigen::Vector2d(msg.u, msg.v);
  t.phase = static_cast<ecar::TouchPhase>(msg.phase);
  t.r = msg.r;
  t.g = msg.g;
  t.b = msg.b;
  t.width = msg.width;
  return t;
}

}  // namespace ecar_bridge
