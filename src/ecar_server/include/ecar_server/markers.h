// rviz markers of the global graph: map points, keyframes coloured per
// device, each device's camera as the server aligned it, planes, cells and
// virtual objects; and the interactive markers that move virtual objects.
#pragma once

#include <string>
#include <vector>

#include <ros/time.h>
#include <std_msgs/ColorRGBA.h>
#include <visualization_msgs/InteractiveMarker.h>
#include <visualization_msgs/MarkerArray.h>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map_queries.h"
#include "ecar_core/structure/plane.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar_server {

/// A device's last server-aligned camera.
struct CameraMarker {
  ecar::DeviceId device;
  ecar::SE3 T_w_c = ecar::SE3::Identity();
};

/// A distinct colour per device id (a fixed palette, repeating after 8; none
/// is a plane label's colour).
std_msgs::ColorRGBA deviceColour(ecar::DeviceId id);

/// Markers in frame `frame`: ns "map_points" (POINTS, grey), ns "keyframes"
/// (CUBE_LIST of keyframe centres, per-device colours), ns "cameras" (one
/// ARROW along each camera's optical axis, id = device id).
visualization_msgs::MarkerArray mapMarkers(const ecar::MapOverview& map,
                                           const std::vector<CameraMarker>& cameras,
                                           const std::string& frame, const ros::Time& stamp);

/// Translucent colour of a plane label: floor green, wall blue, ceiling yellow, other grey.
std_msgs::ColorRGBA labelColour(ecar::PlaneLabel label);

/// Cells one device sees.
struct DeviceCells {
  ecar::DeviceId device;
  std::vector<ecar::CellKey> cells;
};

/// Markers of the structure in frame `frame`: ns "planes" (one TRIANGLE_LIST,
/// each plane's boundary as a fan, translucent, coloured by label), ns
/// "objects" (one marker per live object, id = object id: LINE_LIST of its
/// segment with its width and colour; an ANCHOR is a SPHERE), ns "cells" (one
/// CUBE_LIST per device, id = device id, in the device's colour). Deleted
/// objects are skipped: publish a DELETEALL before these to drop old ones.
visualization_msgs::MarkerArray structureMarkers(const std::vector<ecar::Plane>& planes,
                                                 const std::vector<ecar::VirtualObject>& objects,
                                                 const std::vector<DeviceCells>& cells,
                                                 double cell_size, const std::string& frame,
                                                 const ros::Time& stamp);

/// Name of a VO's interactive marker: "vo_<id>".
std::string voMarkerName(ecar::ObjectId id);
/// The object id named by a voMarkerName(); an invalid id (0) for any other name.
ecar::ObjectId voMarkerId(const std::string& name);

/// The interactive marker of a live VO in frame `frame`: named voMarkerName(),
/// posed at vo.position with the identity orientation, one always-visible
/// MOVE_PLANE control whose x axis (the plane normal) is vo.normal, showing a
/// flat translucent disc in the VO's colour in its plane (the line's length
/// across, within [0.15, 0.5] m). Description "vo <id>".
visualization_msgs::InteractiveMarker voInteractiveMarker(const ecar::VirtualObject& vo,
                                                          const std::string& frame);

/// `vo` translated within its plane (through vo.position, normal vo.normal) so
/// that its position is p_w projected onto that plane: position, start and end
/// move by the in-plane part of p_w - vo.position; the rest is kept.
ecar::VirtualObject movedInPlane(const ecar::VirtualObject& vo, const Eigen::Vector3d& p_w);

}  // namespace ecar_server
