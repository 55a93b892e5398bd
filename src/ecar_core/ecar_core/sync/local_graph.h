// The local graph: the server's answer to one aligned upload, as both ends
// hold it (the paper's "small local graph"). The server's composer fills it
// (local_graph_composer.h), ecar_bridge encodes it as ecar_msgs/LocalGraph and
// decodes it on the device, and the device's tracker reads it
// (device/device_tracker.h). One type for both ends: the wire encoding (1/8 px
// keypoints, 256 angle steps, position indices) lives only in the bridge.
//
// ecar mode: the points tracked in the uploaded image (id, keypoint, angle,
// octave; no descriptor: the device computes it on its own image) and
// positions only for the points the device does not hold at their current
// version. edgeslam mode (the baseline): the aligned frame's local keyframes
// and every point they observe, with descriptors. Both modes: the planes near
// the pose and the virtual objects visible from it (and tombstones of objects
// the device was sent that were deleted since).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/structure/plane.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

enum class SyncMode { kEcar = 0, kEdgeSlam = 1 };

/// "ecar" or "edgeslam".
const char* toString(SyncMode mode);
/// Parses "ecar" / "edgeslam"; throws ecar::Error naming the value otherwise.
SyncMode parseSyncMode(const std::string& text);

/// Tracking status of the aligned upload; the values of ecar_msgs/LocalGraph's
/// (and TrackedFrame's) status constants.
enum class GraphStatus : uint8_t {
  kNotInitialised = 0,  ///< no map yet
  kOk = 1,
  kLost = 2,
  kRelocalised = 3,  ///< OK, aligned by relocalisation or joining
};

/// True for kOk and kRelocalised: the pose (and payload) is valid.
inline bool tracked(GraphStatus status) {
  return status == GraphStatus::kOk || status == GraphStatus::kRelocalised;
}

/// A tracked point as the device needs it (ecar mode): no descriptor.
struct GraphPoint {
  MapPointId id;
  float u = 0.0f, v = 0.0f;  ///< keypoint in the uploaded (distorted) image, level-0 pixels
  float angle = 0.0f;        ///< keypoint orientation, degrees in [0, 360)
  int octave = 0;            ///< pyramid level
};

/// A point position (ecar mode), map frame, m.
struct GraphPosition {
  MapPointId id;
  Eigen::Vector3f p_w = Eigen::Vector3f::Zero();
};

/// A keyframe of the edgeslam payload.
struct GraphKeyFrame {
  KeyFrameId id;
  std::string device;  ///< name of the device whose upload made it
  SE3 T_w_c = SE3::Identity();
  std::vector<MapPointId> points;  ///< live map points it observes, each once
};

/// A map point of the edgeslam payload.
struct GraphMapPoint {
  MapPointId id;
  Eigen::Vector3f p_w = Eigen::Vector3f::Zero();
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();  ///< mean viewing direction
  float min_distance = 0.0f, max_distance = 0.0f;     ///< metres
  std::array<uint8_t, 32> descriptor{};
};

/// One local graph (timing fields travel only on the wire).
struct LocalGraph {
  std::string device;
  uint32_t frame_index = 0;  ///< of the aligned upload
  GraphStatus status = GraphStatus::kNotInitialised;
  SE3 T_w_c = SE3::Identity();  ///< server pose of the aligned image (valid when tracked)
  uint32_t map_epoch = 0;       ///< changes when the server's map is replaced
  MapId map;                    ///< the server map of everything in it (0: not tracked)
  SyncMode mode = SyncMode::kEcar;
  std::vector<GraphPoint> points;         ///< ecar
  std::vector<GraphPosition> positions;   ///< ecar: each of a point in `points`, in their order
  std::vector<GraphKeyFrame> keyframes;   ///< edgeslam
  std::vector<GraphMapPoint> map_points;  ///< edgeslam
  std::vector<Plane> planes;              ///< near the pose, map frame
  std::vector<PlaneId> removed_planes;    ///< sent before, gone on the server since
  std::vector<VirtualObject> objects;     ///< visible VOs and tombstones
};

}  // namespace ecar
