// The local graph the edge server answers each aligned upload with, built
// without ROS (ecar_server converts it to ecar_msgs/LocalGraph).
//
//   DeviceMirror mirror(10);          // one per device: what it holds
//   LocalGraphBuilder builder(config);
//   LocalGraphData g = builder.build(slam.map(), result, SyncMode::kEcar, &mirror);
//
// ecar mode: every point tracked in the image (id, keypoint, angle, octave)
// and positions only for points the device does not hold, or holds at an
// older version whose position moved noticeably since it was sent: by more
// than position_tolerance, and (when the view tolerances are set) by more than
// an angle seen from the aligned camera or a fraction of its distance along
// the ray. Local bundle adjustment moves most local points at each keyframe,
// mostly in depth (centimetres at 4 m, under half a pixel in the image);
// resending all of those would resend nearly every point. The server cannot see the device's map,
// so it mirrors it: each graph with a tracked pose is one keyframe on the device holding all its
// points; the device keeps the last `queue_length` such keyframes; a point leaves the device when
// no queued keyframe holds it any more.
//
// edgeslam mode (the baseline): the aligned frame's local keyframes with
// their poses and point ids, and every point they observe with position,
// normal, distance range and descriptor. No mirror: the device replaces its
// local map by this one each time.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/geometry.h"
#include "ecar_core/map.h"
#include "ecar_core/slam.h"
#include "ecar_core/types.h"

namespace ecar {

enum class SyncMode { kEcar = 0, kEdgeSlam = 1 };

/// "ecar" or "edgeslam".
const char* toString(SyncMode mode);
/// Parses "ecar" / "edgeslam"; throws ecar::Error naming the value otherwise.
SyncMode parseSyncMode(const std::string& text);

/// A tracked point as the device needs it (ecar mode): no descriptor.
struct GraphPoint {
  MapPointId id;
  float u = 0.0f, v = 0.0f;  ///< keypoint in the uploaded image, level-0 pixels
  float angle = 0.0f;        ///< keypoint orientation, degrees in [0, 360)
  int octave = 0;            ///< pyramid level
};

struct GraphPosition {
  MapPointId id;
  Eigen::Vector3f p_w = Eigen::Vector3f::Zero();
};

/// A keyframe of the edgeslam payload.
struct GraphKeyFrame {
  KeyFrameId id;
  DeviceId device;
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

/// The payload of one local graph (pose and status travel beside it).
struct LocalGraphData {
  SyncMode mode = SyncMode::kEcar;
  std::vector<GraphPoint> points;         ///< ecar
  std::vector<GraphPosition> positions;   ///< ecar
  std::vector<GraphKeyFrame> keyframes;   ///< edgeslam
  std::vector<GraphMapPoint> map_points;  ///< edgeslam
};

/// Mirror of one device's keyframe queue: which map points it holds, at which
/// version. Not thread-safe: the caller serialises the calls for one device.
class DeviceMirror {
 public:
  /// `queue_length` keyframes (0 = 10).
  explicit DeviceMirror(size_t queue_length = 10);

  /// Forgets everything (the device reset or reconnected): all positions are sent again.
  void reset();
  /// Whether the device holds `id`; `version` and `p_w` receive the version
  /// and position it holds.
  bool holds(MapPointId id, uint32_t* version = nullptr, Eigen::Vector3f* p_w = nullptr) const;
  /// Records that the device now holds `id` at `version`, position `p_w` (it was sent).
  void setHeld(MapPointId id, uint32_t version,
               const Eigen::Vector3f& p_w = Eigen::Vector3f::Zero());
  /// One keyframe on the device holding `points`; evicts the oldest keyframe
  /// beyond the queue length, and with it the points no queued keyframe holds.
  /// Every point must have been recorded with setHeld() (others are ignored).
  void pushKeyFrame(const std::vector<MapPointId>& points);

  size_t queueLength() const { return queue_length_; }
  size_t numKeyFrames() const { return queue_.size(); }
  size_t numPoints() const { return held_.size(); }

 private:
  struct Held {
    Eigen::Vector3f p_w = Eigen::Vector3f::Zero();
    uint32_t version = 0;
    int keyframes = 0;  ///< queued keyframes holding the point
  };
  size_t queue_length_;
  std::deque<std::vector<MapPointId>> queue_;
  std::unordered_map<MapPointId, Held> held_;
};

struct LocalGraphConfig {
  /// ecar: a held point whose version changed is sent again only when it
  /// moved more than this (metres) from the position the device holds; 0 =
  /// on every version change.
  double position_tolerance = 0.001;
  /// ecar: besides, a moved point is resent only when the move, seen from the
  /// aligned camera, exceeds this angle (degrees, across the ray) or this
  /// fraction of its distance (along the ray). Either <= 0: no view test.
  double position_tolerance_deg = 0.0;
  double position_tolerance_depth = 0.0;
  /// edgeslam: at most this many local keyframes (the best ones first); 0 = all.
  int edgeslam_keyframes = 10;
};

/// Builds local graphs from the shared map. Stateless apart from its config:
/// one builder may serve every device (the mirror carries the state).
class LocalGraphBuilder {
 public:
  explicit LocalGraphBuilder(const LocalGraphConfig& config = LocalGraphConfig())
      : config_(config) {}

  /// The payload for one tracked upload. Takes the map's read lock. Points
  /// culled since tracking are left out. In ecar mode, when the result is
  /// tracked (kOk), the graph becomes one keyframe of `mirror` (which may be
  /// null in edgeslam mode); a graph of a lost frame is empty.
  LocalGraphData build(const Map& map, const TrackResult& result, SyncMode mode,
                       DeviceMirror* mirror) const;

 private:
  void buildEcar(const Map& map, const TrackResult& result, DeviceMirror* mirror,
                 LocalGraphData* out) const;
  void buildEdgeSlam(const Map& map, const TrackResult& result, LocalGraphData* out) const;
  /// Whether a held point's move from `held` to `now` is visible from a
  /// camera at `center` (the view tolerances; true when they are off).
  bool movedInView(const Eigen::Vector3f& held, const Eigen::Vector3f& now,
                   const Eigen::Vector3f& center) const;

  LocalGraphConfig config_;
};

}  // namespace ecar
