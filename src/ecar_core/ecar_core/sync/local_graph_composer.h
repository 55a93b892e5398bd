// The paper's graph publishing, as one unit: what the local graph of one
// aligned upload holds, given the tracked frame, the structure visible from
// its pose (grid connection) and what the device already holds.
//
//   LocalGraphComposer composer(config);
//   DeviceSyncState state(keyframe_queue);          // one per device
//   ComposerInput in;                               // the tracked frame, its epoch,
//   in.frame = &track_result;                       // the visible planes and objects
//   std::optional<LocalGraph> g = composer.compose(slam.map(), in, lookups, &state);
//   if (g) publish(*g);                             // nullopt: aligned in a replaced map
//
// What goes in, and when:
// - status and pose, always; the payload only for a tracked frame.
// - ecar mode: every point tracked in the image (id, keypoint, angle, octave)
//   and a position only for points the device does not hold, or holds at an
//   older version whose position moved visibly since it was sent: by more than
//   position_tolerance, and (when the view tolerances are set) by more than an
//   angle seen from the aligned camera or a fraction of its distance along the
//   ray. Local bundle adjustment moves most local points at each keyframe,
//   mostly in depth; resending all of those would resend nearly every point.
//   The state mirrors the device's keyframe queue (DeviceMirror).
// - edgeslam mode (the baseline): the frame's best local keyframes and every
//   point they observe, with descriptors; no mirror (the device replaces its
//   local map each time).
// - planes near the pose: a plane the device was sent is sent again only when
//   it changed visibly (normal, offset or extent beyond the resend
//   thresholds), or as a refresh every plane_refresh graphs; and once the id
//   of every plane the device was sent that the server no longer holds (fused
//   into another, e.g. a merged map's floor into the floor it met), so that
//   the device drops it instead of keeping its last, stale shape.
// - objects visible from the pose (none when VOs are not shared through local
//   graphs), and once the tombstone of every object the device was sent that
//   was deleted since.
// A reset forgets what the device holds, so the next graph carries every
// position and plane again: Upload.reset (the device lost its local map or
// reconnected; it keeps its objects) forgets points and planes; a new map
// epoch (a map was loaded: the device drops everything) forgets everything.
//
// Thread-safety: compose() is const; it takes the map's read lock while it
// reads points and keyframes. One device's state must not be used from two
// threads at once.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/tracker.h"
#include "ecar_core/structure/plane.h"
#include "ecar_core/structure/virtual_object.h"
#include "ecar_core/sync/device_mirror.h"
#include "ecar_core/sync/local_graph.h"

namespace ecar {

struct LocalGraphComposerConfig {
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
  /// A plane the device was sent at its current shape is sent again after
  /// this many of its local graphs (a refresh in case a graph was lost); 1 =
  /// in every graph.
  int plane_refresh = 10;
  /// A plane the device holds is resent at once when its normal turned by
  /// more than this (degrees), its offset moved more than plane_resend_offset
  /// (m) or a corner of its bounding box more than plane_resend_extent (m).
  double plane_resend_angle_deg = 1.0;
  double plane_resend_offset = 0.02;
  double plane_resend_extent = 0.25;
  /// Points in one graph at most (positions index them with 16 bits on the wire).
  size_t max_points = 65535;

  /// Throws ecar::Error naming the first invalid key (e.g. "plane_refresh").
  void validate() const;
};

/// What the server knows one device holds: the points (a mirror of its
/// keyframe queue), the planes and objects it was sent, and the map epoch
/// these belong to.
class DeviceSyncState {
 public:
  /// `keyframe_queue`: the device's queue length (0 = 10).
  explicit DeviceSyncState(size_t keyframe_queue = 10) : points_(keyframe_queue) {}

  /// Forgets everything the device holds (a new map epoch): the next graph
  /// carries every position and plane again, and no tombstones.
  void reset();
  /// Forgets the points and planes the device holds (it lost its local map
  /// and asked for every position again); the objects it was sent stay.
  void resetMap();

  const DeviceMirror& points() const { return points_; }
  /// Planes sent and not forgotten.
  size_t numPlanes() const { return planes_.size(); }
  /// Objects sent (id -> version) whose tombstone the device has not been sent.
  const std::map<ObjectId, uint32_t>& objects() const { return objects_; }
  /// Local graphs composed with a tracked pose since the last reset.
  uint64_t graphs() const { return graphs_; }

 private:
  friend class LocalGraphComposer;
  /// A plane as it was sent, and the graph count then.
  struct SentPlane {
    uint64_t graph = 0;
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    double offset = 0.0;
    Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();
    uint8_t label = 0;
  };

  DeviceMirror points_;
  uint64_t graphs_ = 0;
  std::map<PlaneId, SentPlane> planes_;
  std::map<ObjectId, uint32_t> objects_;
  bool has_epoch_ = false;
  uint32_t epoch_ = 0;
  MapId map_;  ///< of the last tracked frame
};

/// The frame a local graph is composed for.
struct ComposerInput {
  std::string device;
  uint32_t frame_index = 0;
  SyncMode mode = SyncMode::kEcar;
  /// The map epoch the frame was aligned in (TrackResult::map_epoch).
  uint32_t map_epoch = 0;
  /// The device asked for every position again (Upload.reset).
  bool reset = false;
  /// The alignment: state, pose, tracked points, local keyframes. Required.
  const TrackResult* frame = nullptr;
  /// Planes near the pose (grid connection), by increasing id; null = none.
  const std::vector<Plane>* planes = nullptr;
  /// Objects visible from the pose, by increasing id; null when VOs do not
  /// travel in local graphs (then no tombstones either).
  const std::vector<VirtualObject>* objects = nullptr;
};

/// What compose() looks up besides the map.
struct ComposerLookups {
  /// The current states (tombstones included) of the given objects that exist.
  std::function<std::vector<VirtualObject>(const std::vector<ObjectId>&)> objects;
  /// A device's name (edgeslam keyframes name the device that made them).
  std::function<std::string(DeviceId)> device_name;
  /// Whether the server still holds a plane; null: planes are never removed.
  std::function<bool(PlaneId)> plane_exists;
};

class LocalGraphComposer {
 public:
  /// Throws ecar::Error when the config is invalid.
  explicit LocalGraphComposer(const LocalGraphComposerConfig& config = LocalGraphComposerConfig());

  const LocalGraphComposerConfig& config() const { return config_; }

  /// The local graph of one aligned upload, recording in `state` what the
  /// device will hold. nullopt when the frame was aligned in another map epoch
  /// than the map's (a map was loaded since): such a graph must not be sent,
  /// and `state` is reset(). Throws ecar::Error (after resetting `state`) when
  /// the graph cannot be encoded (more than max_points points; resetMap()).
  std::optional<LocalGraph> compose(const Map& map, const ComposerInput& in,
                                    const ComposerLookups& lookups, DeviceSyncState* state) const;

 private:
  void addEcarPoints(const Map& map, const TrackResult& frame, DeviceMirror* mirror,
                     LocalGraph* out) const;
  void addEdgeSlamPoints(const Map& map, const TrackResult& frame, const ComposerLookups& lookups,
                         LocalGraph* out) const;
  void addPlanes(const std::vector<Plane>& planes, const ComposerLookups& lookups,
                 DeviceSyncState* state, LocalGraph* out) const;
  void addObjects(const std::vector<VirtualObject>& objects, const ComposerLookups& lookups,
                  DeviceSyncState* state, LocalGraph* out) const;
  /// Whether a held point's move from `held` to `now` is visible from a
  /// camera at `center` (the view tolerances; true when they are off).
  bool movedInView(const Eigen::Vector3f& held, const Eigen::Vector3f& now,
                   const Eigen::Vector3f& center) const;

  LocalGraphComposerConfig config_;
};

/// The status a tracking result is sent with.
GraphStatus graphStatus(const TrackResult& result);

}  // namespace ecar
