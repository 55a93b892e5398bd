#include "ecar_server/markers.h"

#include <algorithm>
#include <array>
#include <cctype>

#include <geometry_msgs/Point.h>
#include <visualization_msgs/InteractiveMarkerControl.h>
#include <Eigen/Geometry>

#include "ecar_core/structure/grid_cells.h"

namespace ecar_server {
namespace {

geometry_msgs::Point toPoint(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

visualization_msgs::Marker marker(const std::string& ns, int id, int type, const std::string& frame,
                                  const ros::Time& stamp) {
  visualization_msgs::Marker m;
  m.header.frame_id = frame;
  m.header.stamp = stamp;
  m.ns = ns;
  m.id = id;
  m.type = type;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.color.a = 1.0f;
  return m;
}

// The orientation taking the unit axis `from` onto the direction `to`.
geometry_msgs::Quaternion rotationFromTo(const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
  Eigen::Vector3d dir = to;
  if (!(dir.norm() > 1e-9) || !dir.allFinite()) dir = from;
  const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(from, dir.normalized());
  geometry_msgs::Quaternion m;
  m.x = q.x();
  m.y = q.y();
  m.z = q.z();
  m.w = q.w();
  return m;
}

}  // namespace

std_msgs::ColorRGBA deviceColour(ecar::DeviceId id) {
  // Unlike the plane label colours (green, blue, yellow, grey), so that a
  // device's cells stand out on the planes; device ids start at 1.
  static const std::array<std::array<float, 3>, 8> kPalette = {{{1.00f, 1.00f, 1.00f},
                                                                {1.00f, 0.25f, 0.20f},
                                                                {1.00f, 0.55f, 0.00f},
                                                                {0.95f, 0.25f, 0.85f},
                                                                {0.10f, 0.90f, 0.95f},
                                                                {0.60f, 0.35f, 1.00f},
                                                                {1.00f, 0.65f, 0.75f},
                                                                {0.65f, 0.40f, 0.15f}}};
  const auto& c = kPalette[id.value % kPalette.size()];
  std_msgs::ColorRGBA colour;
  colour.r = c[0];
  colour.g = c[1];
  colour.b = c[2];
  colour.a = 1.0f;
  return colour;
}

visualization_msgs::MarkerArray mapMarkers(const ecar::MapOverview& map,
                                           const std::vector<CameraMarker>& cameras,
                                           const std::string& frame, const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  auto points = marker("map_points", 0, visualization_msgs::Marker::POINTS, frame, stamp);
  points.scale.x = points.scale.y = 0.03;
  points.color.r = points.color.g = points.color.b = 0.6f;
  auto keyframes = marker("keyframes", 0, visualization_msgs::Marker::CUBE_LIST, frame, stamp);
  keyframes.scale.x = keyframes.scale.y = keyframes.scale.z = 0.08;
  points.points.reserve(map.points.size());
  for (const auto& p : map.points) points.points.push_back(toPoint(p));
  keyframes.points.reserve(map.keyframes.size());
  for (const auto& kf : map.keyframes) {
    keyframes.points.push_back(toPoint(kf.center));
    keyframes.colors.push_back(deviceColour(kf.device));
  }
  out.markers.push_back(std::move(points));
  out.markers.push_back(std::move(keyframes));
  for (const auto& c : cameras) {
    auto arrow = marker("cameras", static_cast<int>(c.device.value),
                        visualization_msgs::Marker::ARROW, frame, stamp);
    arrow.scale.x = 0.05;  // shaft diameter
    arrow.scale.y = 0.10;  // head diameter
    arrow.scale.z = 0.10;  // head length
    arrow.color = deviceColour(c.device);
    const Eigen::Vector3d centre = c.T_w_c.translation();
    arrow.points.push_back(toPoint(centre));
    arrow.points.push_back(toPoint(centre + 0.4 * c.T_w_c.linear().col(2)));
    out.markers.push_back(std::move(arrow));
  }
  return out;
}

std_msgs::ColorRGBA labelColour(ecar::PlaneLabel label) {
  std_msgs::ColorRGBA c;
  c.a = 0.35f;
  switch (label) {
    case ecar::PlaneLabel::kFloor:
      c.r = 0.2f, c.g = 0.8f, c.b = 0.2f;
      break;
    case ecar::PlaneLabel::kWall:
      c.r = 0.2f, c.g = 0.4f, c.b = 0.9f;
      break;
    case ecar::PlaneLabel::kCeiling:
      c.r = 0.9f, c.g = 0.8f, c.b = 0.2f;
      break;
    case ecar::PlaneLabel::kOther:
      c.r = c.g = c.b = 0.6f;
      break;
  }
  return c;
}

visualization_msgs::MarkerArray structureMarkers(const std::vector<ecar::Plane>& planes,
                                                 const std::vector<ecar::VirtualObject>& objects,
                                                 const std::vector<DeviceCells>& cells,
                                                 double cell_size, const std::string& frame,
                                                 const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  auto polygons = marker("planes", 0, visualization_msgs::Marker::TRIANGLE_LIST, frame, stamp);
  polygons.scale.x = polygons.scale.y = polygons.scale.z = 1.0;
  for (const auto& p : planes) {
    const std_msgs::ColorRGBA colour = labelColour(p.label);
    for (size_t i = 1; i + 1 < p.boundary.size(); ++i) {
      for (size_t k : {size_t{0}, i, i + 1}) {
        polygons.points.push_back(toPoint(p.boundary[k]));
        polygons.colors.push_back(colour);
      }
    }
  }
  if (!polygons.points.empty()) out.markers.push_back(std::move(polygons));
  for (const auto& vo : objects) {
    if (vo.deleted) continue;
    const bool line = vo.kind == ecar::VoKind::kLine;
    auto m =
        marker("objects", static_cast<int>(vo.id.value),
               line ? visualization_msgs::Marker::LINE_LIST : visualization_msgs::Marker::SPHERE,
               frame, stamp);
    m.color.r = vo.r / 255.0f;
    m.color.g = vo.g / 255.0f;
    m.color.b = vo.b / 255.0f;
    if (line) {
      m.scale.x = std::max(0.005f, vo.width);
      m.points.push_back(toPoint(vo.start));
      m.points.push_back(toPoint(vo.end));
    } else {
      m.scale.x = m.scale.y = m.scale.z = std::max(0.05f, vo.width);
      m.pose.position = toPoint(vo.position);
    }
    out.markers.push_back(std::move(m));
  }
  for (const auto& d : cells) {
    auto cubes = marker("cells", static_cast<int>(d.device.value),
                        visualization_msgs::Marker::CUBE_LIST, frame, stamp);
    cubes.scale.x = cubes.scale.y = cubes.scale.z = 0.9 * cell_size;
    cubes.color = deviceColour(d.device);
    cubes.color.a = 0.7f;
    cubes.points.reserve(d.cells.size());
    for (const auto& c : d.cells) cubes.points.push_back(toPoint(ecar::cellCenter(c, cell_size)));
    out.markers.push_back(std::move(cubes));
  }
  return out;
}

std::string voMarkerName(ecar::ObjectId id) { return "vo_" + std::to_string(id.value); }

ecar::ObjectId voMarkerId(const std::string& name) {
  const std::string prefix = "vo_";
  if (name.size() <= prefix.size() || name.size() > prefix.size() + 10 ||
      name.compare(0, prefix.size(), prefix) != 0) {
    return {};
  }
  uint64_t value = 0;
  for (size_t i = prefix.size(); i < name.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(name[i]))) return {};
    value = value * 10 + static_cast<uint64_t>(name[i] - '0');
  }
  if (value == 0 || value > 0xFFFFFFFFull) return {};
  return ecar::ObjectId(static_cast<uint32_t>(value));
}

visualization_msgs::InteractiveMarker voInteractiveMarker(const ecar::VirtualObject& vo,
                                                          const std::string& frame) {
  visualization_msgs::InteractiveMarker im;
  im.header.frame_id = frame;
  im.name = voMarkerName(vo.id);
  im.description = "vo " + std::to_string(vo.id.value);
  im.pose.position = toPoint(vo.position);
  im.pose.orientation.w = 1.0;
  const double length = (vo.end - vo.start).norm();
  const double size = std::min(0.5, std::max(0.15, length));
  im.scale = static_cast<float>(size);

  visualization_msgs::Marker disc;
  disc.type = visualization_msgs::Marker::CYLINDER;  // its axis is its z
  disc.pose.orientation = rotationFromTo(Eigen::Vector3d::UnitZ(), vo.normal);
  disc.scale.x = disc.scale.y = size;
  disc.scale.z = 0.01;
  disc.color.r = vo.r / 255.0f;
  disc.color.g = vo.g / 255.0f;
  disc.color.b = vo.b / 255.0f;
  disc.color.a = 0.45f;

  visualization_msgs::InteractiveMarkerControl move;
  move.name = "move_in_plane";
  move.interaction_mode = visualization_msgs::InteractiveMarkerControl::MOVE_PLANE;
  move.orientation_mode = visualization_msgs::InteractiveMarkerControl::FIXED;
  // MOVE_PLANE moves in the plane orthogonal to the control's x axis.
  move.orientation = rotationFromTo(Eigen::Vector3d::UnitX(), vo.normal);
  move.always_visible = true;
  move.markers.push_back(disc);
  im.controls.push_back(move);
  return im;
}

ecar::VirtualObject movedInPlane(const ecar::VirtualObject& vo, const Eigen::Vector3d& p_w) {
  Eigen::Vector3d d = p_w - vo.position;
  const double n_norm = vo.normal.norm();
  if (n_norm > 1e-9) {
    const Eigen::Vector3d n = vo.normal / n_norm;
    d -= n.dot(d) * n;
  }
  ecar::VirtualObject moved = vo;
  moved.position += d;
  moved.start += d;
  moved.end += d;
  return moved;
}

}  // namespace ecar_server
