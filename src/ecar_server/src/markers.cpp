#include "ecar_server/markers.h"

#include <array>

#include <geometry_msgs/Point.h>

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

}  // namespace

std_msgs::ColorRGBA deviceColour(ecar::DeviceId id) {
  static const std::array<std::array<float, 3>, 8> kPalette = {{{0.90f, 0.20f, 0.20f},
                                                                {0.20f, 0.50f, 0.95f},
                                                                {0.20f, 0.80f, 0.30f},
                                                                {0.95f, 0.65f, 0.10f},
                                                                {0.70f, 0.30f, 0.90f},
                                                                {0.10f, 0.80f, 0.80f},
                                                                {0.95f, 0.40f, 0.70f},
                                                                {0.60f, 0.60f, 0.20f}}};
  const auto& c = kPalette[id.value % kPalette.size()];
  std_msgs::ColorRGBA colour;
  colour.r = c[0];
  colour.g = c[1];
  colour.b = c[2];
  colour.a = 1.0f;
  return colour;
}

visualization_msgs::MarkerArray mapMarkers(const ecar::Map& map,
                                           const std::vector<CameraMarker>& cameras,
                                           const std::string& frame, const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  auto points = marker("map_points", 0, visualization_msgs::Marker::POINTS, frame, stamp);
  points.scale.x = points.scale.y = 0.03;
  points.color.r = points.color.g = points.color.b = 0.6f;
  auto keyframes = marker("keyframes", 0, visualization_msgs::Marker::CUBE_LIST, frame, stamp);
  keyframes.scale.x = keyframes.scale.y = keyframes.scale.z = 0.08;
  {
    auto lock = map.readLock();
    const auto point_ids = map.pointIds();
    points.points.reserve(point_ids.size());
    for (const auto& id : point_ids) {
      if (const ecar::MapPoint* p = map.point(id)) points.points.push_back(toPoint(p->p_w));
    }
    for (const auto& id : map.keyframeIds()) {
      const ecar::KeyFrame* kf = map.keyframe(id);
      if (!kf) continue;
      keyframes.points.push_back(toPoint(kf->center()));
      keyframes.colors.push_back(deviceColour(kf->device));
    }
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

}  // namespace ecar_server
