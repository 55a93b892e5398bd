// Structure planes (floor, walls, ceiling) segmented from the SLAM map points.
//
// Per mapped keyframe, the server nodelet
//   1. copies (under the Map's read lock) the map points of the keyframe and of
//      its covisible neighbours into a PlaneKeyFrameInput, with the camera
//      centre and the up direction from the upload's gravity (upFromGravity);
//   2. runs PlaneSegmenter::segment on that copy without any lock: sequential
//      RANSAC, least-squares refinement, a connectivity filter, labels;
//   3. hands the result to PlaneMap::integrate, which merges every observation
//      into the plane it sees again (or creates a plane), re-estimates it, and
//      links the keyframe to its planes.
//
//   PlaneSegmenter segmenter(config);
//   PlaneMap planes(config);
//   PlaneMapUpdate u = planes.integrate(input, segmenter.segment(input));
//   std::vector<Plane> all = planes.planes();  // copies, for a tracker or the grid
//
// Conventions: a plane is {x : n.x + d = 0} in the map frame with |n| = 1 and n
// pointing to the side the cameras saw it from (a floor's normal points up, a
// ceiling's down); its boundary is the convex hull of its inliers projected into
// the plane, ordered counter-clockwise seen from the normal side (Plane.msg).
#pragma once

#include <cstdint>
#include <optional>
#include <shared_mutex>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/geometry.h"
#include "ecar_core/types.h"

namespace ecar {

/// Semantic label; the values are ecar_msgs/Plane's constants.
enum class PlaneLabel : uint8_t { kFloor = 0, kWall = 1, kCeiling = 2, kOther = 3 };

/// "floor", "wall", "ceiling" or "other".
const char* toString(PlaneLabel label);

/// One plane as ecar_msgs/Plane carries it (fields map 1:1 onto the message).
struct Plane {
  PlaneId id;
  PlaneLabel label = PlaneLabel::kOther;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, map frame
  double offset = 0.0;                                ///< d in n.x + d = 0, m
  std::vector<Eigen::Vector3d> boundary;              ///< convex, counter-clockwise about n; map, m
  uint32_t version = 0;                               ///< 1 when created, +1 per re-estimate
  uint32_t num_points = 0;                            ///< inlier map points

  /// Signed distance of p_w to the plane (positive on the normal's side), m.
  double signedDistance(const Eigen::Vector3d& p_w) const { return normal.dot(p_w) + offset; }
};

/// A map point given to the segmentation: its id and position (map frame, m).
struct PlanePoint {
  MapPointId id;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
};

/// What the segmentation of one keyframe needs, copied out of the map.
struct PlaneKeyFrameInput {
  KeyFrameId keyframe;
  /// The map points of the keyframe and of its covisible neighbours, each once.
  std::vector<PlanePoint> points;
  Eigen::Vector3d camera_center_w = Eigen::Vector3d::Zero();  ///< map frame, m
  /// Up in the map frame (any length > 0; see upFromGravity). Not assumed to be +z.
  Eigen::Vector3d up_w = Eigen::Vector3d::UnitZ();
};

/// Up in the map frame from an accelerometer's specific force f_c in the camera
/// frame (at rest it points up): up_w = R_w_c f_c / |f_c|. Throws ecar::Error when
/// f_c is not finite or shorter than 1e-6.
Eigen::Vector3d upFromGravity(const SE3& T_w_c, const Eigen::Vector3d& f_c);

/// Configuration of PlaneSegmenter and PlaneMap (one struct: one yaml section).
struct PlaneConfig {
  // ---- segmentation (per keyframe)
  double distance_threshold = 0.04;  ///< m: a RANSAC inlier lies this close to the plane
  int min_inliers = 40;              ///< points a plane needs (after the connectivity filter)
  int iterations = 300;              ///< RANSAC hypotheses per plane
  int max_planes = 8;                ///< planes extracted per keyframe
  uint32_t seed = 1;                 ///< RANSAC seed (combined with the keyframe id)
  /// m: inliers are binned in the plane in squares of this size; only the largest
  /// 8-connected group of occupied squares is kept (drops far coplanar strays).
  double cluster_cell = 0.5;
  // ---- labels
  double horizontal_tolerance_deg = 15.0;  ///< floor/ceiling: normal within this of up
  double vertical_tolerance_deg = 15.0;    ///< wall: normal within this of horizontal
  // ---- merging (PlaneMap)
  double merge_angle_deg = 10.0;  ///< normals closer than this may be the same plane
  double merge_distance = 0.08;   ///< m: median distance of the new inliers to the plane
  double merge_gap = 0.5;         ///< m: extents closer than this (in the plane) overlap
  /// Stored points farther than keep_factor * distance_threshold from the refitted
  /// plane leave it (bundle adjustment moved them off).
  double keep_factor = 2.0;

  /// Throws ecar::Error naming the first invalid key (e.g. "planes.min_inliers").
  void validate() const;
};

/// A plane found in one keyframe's points, before it is merged into the map.
struct PlaneObservation {
  PlaneLabel label = PlaneLabel::kOther;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, towards the camera
  double offset = 0.0;                                ///< m
  std::vector<PlanePoint> inliers;
  std::vector<Eigen::Vector3d> boundary;  ///< convex hull of the inliers, as in Plane
  double rms = 0.0;                       ///< RMS point-plane distance of the inliers, m
};

/// Least-squares plane through points (smallest eigenvector of their covariance):
/// normal (unit, sign arbitrary) and offset. Needs at least 3 points.
void fitPlane(const std::vector<Eigen::Vector3d>& points_w, Eigen::Vector3d* normal,
              double* offset);

/// Convex hull of points projected into the plane (n, d): ordered counter-clockwise
/// seen from n, lying on the plane. Fewer than 3 distinct points: those points.
std::vector<Eigen::Vector3d> planeHull(const std::vector<Eigen::Vector3d>& points_w,
                                       const Eigen::Vector3d& normal, double offset);

/// Label of a plane with unit normal n seen from camera_center_w, for unit up_w.
PlaneLabel labelPlane(const Eigen::Vector3d& normal, double offset,
                      const Eigen::Vector3d& camera_center_w, const Eigen::Vector3d& up_w,
                      const PlaneConfig& config);

/// Sequential RANSAC on one keyframe's points. Stateless after construction:
/// segment() is const and safe to call from several threads at once.
class PlaneSegmenter {
 public:
  /// Throws ecar::Error when the config is invalid.
  explicit PlaneSegmenter(const PlaneConfig& config);
  const PlaneConfig& config() const { return config_; }

  /// The planes in input.points, largest first. Each plane's inliers are removed
  /// before the next is searched, so a point supports at most one observation.
  /// Deterministic for a given input, config and keyframe id. Throws ecar::Error
  /// when up_w or the camera centre is not finite or up_w is zero.
  std::vector<PlaneObservation> segment(const PlaneKeyFrameInput& input) const;

 private:
  PlaneConfig config_;
};

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
  /// and version. Two planes that now match are merged (the lower id survives).
  /// Links the keyframe to the planes its observations joined.
  PlaneMapUpdate integrate(const PlaneKeyFrameInput& input,
                           const std::vector<PlaneObservation>& observations);

  /// Copies of every plane, by increasing id.
  std::vector<Plane> planes() const;
  /// Copies of the given planes that exist, in the given order.
  std::vector<Plane> planes(const std::vector<PlaneId>& ids) const;
  std::optional<Plane> plane(PlaneId id) const;
  size_t size() const;
  /// Increments on every change; a reader can skip copying when it is unchanged.
  uint64_t revision() const;

  /// The keyframe's planes, by increasing id (empty when unknown).
  std::vector<PlaneId> planesOfKeyFrame(KeyFrameId keyframe) const;
  /// The keyframes linked to a plane, by increasing id.
  std::vector<KeyFrameId> keyframesOfPlane(PlaneId id) const;
  /// A plane's inlier map points, by increasing id.
  std::vector<MapPointId> pointsOfPlane(PlaneId id) const;
  /// The plane holding a map point, if any.
  std::optional<PlaneId> planeOfPoint(MapPointId point) const;

  /// Removes a keyframe's links (planes stay).
  void eraseKeyFrame(KeyFrameId keyframe);

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
  void absorb(Entry* into, Entry* from);

  PlaneConfig config_;
  mutable std::shared_mutex mutex_;
  std::unordered_map<PlaneId, Entry> planes_;                             // GUARDED_BY(mutex_)
  std::unordered_map<MapPointId, PlaneId> point_owner_;                   // GUARDED_BY(mutex_)
  std::unordered_map<KeyFrameId, std::vector<PlaneId>> keyframe_planes_;  // GUARDED_BY(mutex_)
  uint32_t next_id_ = 1;                                                  // GUARDED_BY(mutex_)
  uint64_t revision_ = 0;                                                 // GUARDED_BY(mutex_)
};

}  // namespace ecar
