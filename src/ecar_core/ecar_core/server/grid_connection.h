// The paper's grid connection module: the 0.1 m grid on the structure planes
// connects keyframes, virtual objects and aligned uploads.
//
//   GridConnection grid(&graph, config);
//   grid.linkKeyFrame(planes_of_keyframe);            // per segmented keyframe
//   VoOutcome r = grid.apply(request);                 // per interaction
//   VisibleStructure v = grid.visible(track_result);   // per aligned upload
//
// - Keyframe-cell links: the cells the sampled rays of a keyframe's own camera
//   hit on the current planes (GridCaster, every `window` px).
// - Object-cell links: a VO change is checked and stored by the VO store
//   (rules, SQLite), then the object is attached to the cells its geometry
//   crosses (attachmentCells), re-attached when it moves, detached when deleted.
//   In keyframe mode (the baseline) a registration hangs on the keyframe
//   nearest to the object instead.
// - Visibility of an aligned upload: the cells its sampled rays hit, the
//   planes they hit (and the planes of its local keyframes), and the live
//   objects attached to a hit cell (radius 1) or passing the exact per-point
//   test (GridCaster::isVisible: the samples hit only a few percent of the
//   far floor cells of a corridor); keyframe mode: the objects of its local
//   keyframes.
// Ray casting reads an immutable GridPlanes snapshot, rebuilt when the planes
// change. Every method holds the graph's structure lock while it reads or
// changes the graph; thread-safe (apply() calls are serialised).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "ecar_core/common/rate_limiter.h"
#include "ecar_core/common/types.h"
#include "ecar_core/server/global_graph.h"
#include "ecar_core/server/plane_segmentation.h"
#include "ecar_core/slam/tracker.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

struct GridConnectionConfig {
  /// Besides the planes hit from the aligned pose, a frame sees the planes
  /// linked to its local keyframes.
  bool keyframe_planes = true;
  /// Find the visible objects (false when VOs reach devices another way:
  /// vo_share direct).
  bool objects = true;
  /// Interactions a second one device (or rviz) may send on average (0 =
  /// unlimited), and at once; beyond, they are rejected (kRateLimited).
  double max_interaction_rate = 50.0;
  double interaction_burst = 100.0;
};

/// What is visible from one aligned upload.
struct VisibleStructure {
  std::vector<Plane> planes;           ///< by increasing id
  std::vector<VirtualObject> objects;  ///< live, by increasing id
  bool objects_computed = false;       ///< false: objects are not looked for
  std::vector<CellKey> cells;          ///< cells hit by the sampled rays, sorted
  double milliseconds = 0.0;           ///< time of the whole computation
  double cpu_ms = 0.0;                 ///< the calling thread's CPU time for it
  /// The frame was aligned in a map that was replaced since: nothing computed.
  bool stale = false;
};

class GridConnection {
 public:
  GridConnection(GlobalGraph* graph, const GridConnectionConfig& config);

  /// Links a segmented keyframe to the cells visible from its pose on the
  /// current planes; returns how many (0 when it was not segmented or a map was
  /// loaded since).
  size_t linkKeyFrame(const KeyFramePlanes& keyframe);

  /// Applies one interaction to the VO store (its rules decide; accepted
  /// changes are in SQLite before this returns) and attaches the changed object
  /// to its cells. REGISTER: the object's owner is the request's device.
  VoOutcome apply(const VoRequest& request);

  /// What the aligned upload `frame` of `device` sees through the device's
  /// camera (nothing unless it was tracked).
  VisibleStructure visible(const TrackResult& frame, const std::string& device);

  const GridConnectionConfig& config() const { return config_; }

 private:
  /// The caster of a camera (built once per camera; null for a null camera).
  std::shared_ptr<const GridCaster> caster(const CameraPtr& camera);
  /// The current planes of a map prepared for casting (rebuilt when they
  /// changed).
  std::shared_ptr<const GridPlanes> gridPlanes(MapId map);

  GlobalGraph* graph_;
  const GridConnectionConfig config_;
  std::mutex apply_mutex_;  // serialises apply(); guards limiter_
  RateLimiter limiter_;
  std::mutex mutex_;  // guards the members below
  /// One caster per camera (a few cameras: a short list).
  std::vector<std::pair<CameraPtr, std::shared_ptr<const GridCaster>>> casters_;
  struct Snapshot {
    std::shared_ptr<const GridPlanes> planes;
    uint64_t revision = 0, generation = 0;
  };
  std::unordered_map<MapId, Snapshot> grid_planes_;
};

}  // namespace ecar
