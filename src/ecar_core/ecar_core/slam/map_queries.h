// Queries on the shared SLAM map for the server's modules, each taking the
// map's read lock itself and returning copies (map.h's lock contract), so no
// code outside ecar_core takes the lock or walks the keyframes.
//
//   KeyFrameId kf = nearestKeyFrame(slam.map(), vo.position);    // keyframe-attached VOs
//   std::optional<KeyFrameNeighbourhood> n = keyframeNeighbourhood(slam.map(), id, 10);
//   std::optional<Bounds> b = keyframeBounds(slam.map());        // VO map bounds
//   MapOverview o = mapOverview(slam.map());                      // rviz markers
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"

namespace ecar {

/// The live keyframe whose camera centre is nearest to p_w; invalid when the
/// map has none or p_w is not finite.
KeyFrameId nearestKeyFrame(const Map& map, const Eigen::Vector3d& p_w);

/// What a keyframe is, copied out of the map.
struct KeyFrameSummary {
  KeyFrameId id;
  DeviceId device;
  uint32_t frame_index = 0;
  double timestamp = 0.0;  ///< capture time, s
  SE3 T_w_c = SE3::Identity();
  std::optional<Eigen::Vector3d> gravity_c;  ///< its upload's specific force, camera frame
  uint32_t map_epoch = 0;
};

/// nullopt when the keyframe is unknown or was culled.
std::optional<KeyFrameSummary> keyframeSummary(const Map& map, KeyFrameId id);

/// The camera a keyframe was made with; null when it is not in the map.
CameraPtr keyframeCamera(const Map& map, KeyFrameId id);

/// A keyframe and the map points around it, copied in one read.
struct KeyFrameNeighbourhood : KeyFrameSummary {
  /// Live map points of the keyframe and of its `neighbours` best covisible
  /// keyframes, each once: (id, position).
  std::vector<std::pair<MapPointId, Eigen::Vector3d>> points;
};

/// nullopt when the keyframe is unknown or was culled.
std::optional<KeyFrameNeighbourhood> keyframeNeighbourhood(const Map& map, KeyFrameId id,
                                                           size_t neighbours);

/// An axis-aligned box, map frame, m.
struct Bounds {
  Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();
};
/// The bounding box of the live keyframes' camera centres; nullopt without any.
std::optional<Bounds> keyframeBounds(const Map& map);

/// What rviz shows of the map.
struct MapOverview {
  std::vector<Eigen::Vector3d> points;  ///< positions of the map points
  struct KeyFrameMark {
    KeyFrameId id;
    DeviceId device;
    Eigen::Vector3d center = Eigen::Vector3d::Zero();
  };
  std::vector<KeyFrameMark> keyframes;
  size_t num_keyframes = 0, num_points = 0;  ///< as Map::numKeyFrames / numPoints
};
MapOverview mapOverview(const Map& map);

/// The map's epoch (Map::epoch).
uint32_t mapEpoch(const Map& map);

}  // namespace ecar
