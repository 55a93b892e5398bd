// The server's planes (PlaneMap): every keyframe's plane observations merged
// into the planes they see again, refined, with keyframe-plane links.
//
//   PlaneMap planes(config);
//   PlaneMapUpdate u = planes.integrate(input, segmenter.segment(input));
//   std::vector<Plane> all = planes.planes();  // copies, for a tracker or the grid
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <shared_mutex>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/types.h"
#include "ecar_core/structure/plane.h"
#include "ecar_core/structure/plane_segmenter.h"

namespace ecar {

/// What PlaneMap::integrate changed.
struct PlaneMapUpdate {
  std::vector<PlaneId> created;          ///< new planes
  std::vector<PlaneId> updated;          ///< re-estimated planes (version incremented)
  std::vector<PlaneId> removed;          ///< planes merged into another one (gone)
  std::vector<PlaneId> keyframe_planes;  ///< the keyframe's planes after the update
};

/// Everything stored about one plane (for saving and loading the map).
struct PlaneRecord {
  Plane plane;
  std::vector<PlanePoint> points;  ///< inliers with their last known positions
  std::vector<KeyFrameId> keyframes;
};

/// The server's planes: merging, refinement, keyframe-plane links.
///
/// Thread-safety: every public method is safe to call concurrently. The map has
/// its own std::shared_mutex (independent of ecar::Map's): readers take it shared
/// and return copies; integrate(), eraseKeyFrame(), load() and clear() take it
/// exclusively. integrate() does its fitting (a few ms for thousands of points)
/// under the exclusive lock; segmentation (the expensive part) runs before, unlocked.
class PlaneMap {
 public:
  /// Throws ecar::Error when the config is invalid.
  explicit PlaneMap(const PlaneConfig& config);

  /// Merges the keyframe's observations: each one joins the existing plane it
  /// matches (normals within merge_angle_deg, median distance of its inliers to
  /// the plane within merge_distance, extents within merge_gap), or becomes a new
  /// plane. A joined plane takes the new inliers (a point belongs to one plane:
  /// points already held by another plane stay there), refreshes the positions of
  /// its points present in input.points, is refitted by least squares, drops
  /// points farther than keep_factor * distance_threshold, gets a new hull, label
  /// and version. A plane none of them joined but whose points in input.points
  /// moved (by more than distance_threshold / 4) is refitted as well, and goes
  /// when fewer than min_inliers points stay; so does a plane whose points in
  /// input.gone left it (points the SLAM map culled are no evidence: a
  /// "second floor" 13.5 cm up, fitted to noise points culled since, stood on
  /// the wall's and the cabinet's bottom rows alone). Two planes that now match are
  /// merged (the lower id survives). Links the keyframe to the planes its
  /// observations joined.
  PlaneMapUpdate integrate(const PlaneKeyFrameInput& input,
                           const std::vector<PlaneObservation>& observations);

  /// Copies of every plane, by increasing id.
  std::vector<Plane> planes() const;
  /// Copies of the given planes that exist, in the given order.
  std::vector<Plane> planes(const std::vector<PlaneId>& ids) const;
  std::optional<Plane> plane(PlaneId id) const;
  /// Whether the plane exists (not merged into another, not emptied).
  bool contains(PlaneId id) const;
  size_t size() const;
  /// Increments on every change; a reader can skip copying when it is unchanged.
  uint64_t revision() const;

  /// The keyframe's planes, by increasing id (empty when unknown).
  std::vector<PlaneId> planesOfKeyFrame(KeyFrameId keyframe) const;
  /// The keyframes linked to a plane, by increasing id.
  std::vector<KeyFrameId> keyframesOfPlane(PlaneId id) const;
  /// A plane's inlier map points, by increasing id.
  std::vector<MapPointId> pointsOfPlane(PlaneId id) const;
  /// Every point held by the planes of `map`, in no particular order.
  std::vector<MapPointId> pointsOfMap(MapId map) const;
  /// The plane holding a map point, if any.
  std::optional<PlaneId> planeOfPoint(MapPointId point) const;

  /// Removes a keyframe's links (planes stay).
  void eraseKeyFrame(KeyFrameId keyframe);

  /// Moves planes with the map (a loop closure or merge moved its keyframes):
  /// `correction` gives a plane's similarity from the keyframes linked to it,
  /// or nullopt to leave it. A moved plane's normal, offset, boundary and
  /// stored points are transformed and its version moves on. Returns how many
  /// moved.
  size_t transformPlanes(
      const std::function<std::optional<Sim3>(const std::vector<KeyFrameId>&)>& correction);
  /// Moves the planes of map `from` into map `into` through S (a merge):
  /// transformed as above, version + 1. Returns how many moved.
  size_t moveMap(MapId from, MapId into, const Sim3& S);
  /// After a map was bundle-adjusted (a loop, a merge): the planes of `map`
  /// take their points' adjusted positions (`position`; nullopt: not in the
  /// SLAM map any more (culled), the point leaves its plane) and are refitted
  /// (labels kept; points that ended far from the plane leave it, and a plane
  /// left with fewer than min_inliers points goes), then planes
  /// of the map that now match (as in integrate) become one, the lower id
  /// surviving. Moving planes by their keyframes'
  /// corrections alone left a merged map's planes where the smaller map had
  /// estimated them (a second floor 8-10 cm off the first in the demo).
  /// Returns the updated and removed planes. Hold the SLAM map's read lock
  /// for `position`.
  PlaneMapUpdate refit(MapId map,
                       const std::function<std::optional<Eigen::Vector3d>(MapPointId)>& position);

  /// Every plane with its points and links, by increasing id.
  std::vector<PlaneRecord> save() const;
  /// The id the next new plane gets (above every id ever given out, also of
  /// planes merged away since).
  uint32_t nextId() const;
  /// Replaces the contents by saved records; new ids continue at `next_id` or
  /// after the largest record id, whichever is higher. Throws ecar::Error on an
  /// invalid id, a duplicate id, a non-unit normal or a point held by two
  /// planes; then nothing is changed.
  void load(const std::vector<PlaneRecord>& records, uint32_t next_id = 1);
  void clear();

 private:
  struct Entry {
    Plane plane;
    std::unordered_map<MapPointId, Eigen::Vector3d> points;
    std::unordered_set<KeyFrameId> keyframes;
  };

  // All below: hold mutex_ exclusively.
  bool matches(const Entry& entry, const std::vector<Eigen::Vector3d>& points_w,
               const std::vector<Eigen::Vector3d>& hull, const Eigen::Vector3d& normal,
               double* median_distance) const;
  void reestimate(Entry* entry, const Eigen::Vector3d& camera_center_w,
                  const Eigen::Vector3d& up_w);
  /// reestimate without the label: fit, drop far points, hull, version + 1.
  void refitGeometry(Entry* entry);
  void absorb(Entry* into, Entry* from);
  /// Removes a plane with its point owners and keyframe links; records it in update->removed.
  void erase(PlaneId id, PlaneMapUpdate* update);
  /// Moves one plane through S (normal, offset, boundary, points; version + 1).
  void transform(Entry* entry, const Sim3& S);

  PlaneConfig config_;
  mutable std::shared_mutex mutex_;
  std::unordered_map<PlaneId, Entry> planes_;                             // GUARDED_BY(mutex_)
  std::unordered_map<MapPointId, PlaneId> point_owner_;                   // GUARDED_BY(mutex_)
  std::unordered_map<KeyFrameId, std::vector<PlaneId>> keyframe_planes_;  // GUARDED_BY(mutex_)
  uint32_t next_id_ = 1;                                                  // GUARDED_BY(mutex_)
  uint64_t revision_ = 0;                                                 // GUARDED_BY(mutex_)
};

}  // namespace ecar
