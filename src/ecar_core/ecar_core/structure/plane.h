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
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"

namespace ecar {

/// Semantic label; the values are ecar_msgs/Plane's constants.
enum class PlaneLabel : uint8_t { kFloor = 0, kWall = 1, kCeiling = 2, kOther = 3 };

/// "floor", "wall", "ceiling" or "other".
const char* toString(PlaneLabel label);

/// One plane as ecar_msgs/Plane carries it (fields map 1:1 onto the message).
struct Plane {
  PlaneId id;
  /// The atlas map the plane belongs to (its coordinates are that map's); 0
  /// where there is one map.
  MapId map;
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
  MapId map;  ///< the keyframe's map: its observations join planes of that map only
  /// The map points of the keyframe and of its covisible neighbours, each once.
  std::vector<PlanePoint> points;
  /// Points held by the map's planes that the SLAM map no longer has (culled
  /// as bad triangulations, or fused into another): they leave their planes.
  std::vector<MapPointId> gone;
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
  /// m: a plane found in a keyframe nearly parallel (normals within
  /// merge_angle_deg) to one found before it in the same keyframe, with its
  /// inliers' median distance to that one below this, is that plane's noise,
  /// not a surface: its points are left out. Monocular depth noise puts a tail
  /// of a surface's points up to ~20 cm off it, on the cameras' side, and
  /// RANSAC on that tail found a "second floor" 5-19 cm above the floor, over
  /// the whole room (the room scene's E8: strokes drawn on it, 9 cm up). Steps
  /// lower than this are not told from their floor.
  double min_separation = 0.12;
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

/// A 2D frame in the plane n.x + d = 0: origin -d n, orthonormal axes e1, e2
/// with e1 x e2 = n.
struct PlaneFrame {
  Eigen::Vector3d origin, e1, e2;
  PlaneFrame(const Eigen::Vector3d& n, double d);
  /// The in-plane coordinates of p (projected along n).
  Eigen::Vector2d to2d(const Eigen::Vector3d& p) const {
    return Eigen::Vector2d(e1.dot(p - origin), e2.dot(p - origin));
  }
};

}  // namespace ecar
