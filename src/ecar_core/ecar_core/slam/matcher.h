// Feature matching for tracking and mapping (ORB-SLAM's matcher, on our
// frames and map snapshots): search by projection, for initialisation, by
// descriptor, for triangulation along epipolar lines, and fusion.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/frame.h"
#include "ecar_core/slam/optimizer.h"

namespace ecar {

constexpr int kDescriptorThresholdLow = 50;
constexpr int kDescriptorThresholdHigh = 100;

/// What matching needs of a map point, copied out of the map under its lock.
struct PointSample {
  MapPointId id;
  Eigen::Vector3d p_w;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  ///< zero: no viewing-angle check
  float min_distance = 0.0f, max_distance = 0.0f;    ///< zero: no scale check
  int octave_hint = -1;  ///< level it was seen at in the last frame, -1 unknown
  std::array<uint8_t, 32> descriptor{};
};

/// Projects points into a frame at pose T_c_w and matches each to the best
/// keypoint in a window (radius * pyramid scale px) whose descriptor is within
/// the threshold. Only keypoints with no match yet (matches[i] invalid) are
/// used. Returns the number of new matches.
int searchByProjection(const Frame& frame, const SE3& T_c_w, const Intrinsics& K,
                       const ScaleInfo& scale, const std::vector<PointSample>& points,
                       double radius, std::vector<MapPointId>* matches,
                       std::vector<int>* match_point_index = nullptr);

/// Matches keypoints of f1 (pyramid levels 0-3) to keypoints of f2 at a similar
/// level near the same pixel (window px). matches12[i] = index in f2 or -1. Returns the count.
int searchForInitialization(const Frame& f1, const Frame& f2, double window,
                            std::vector<int>* matches12);

/// Brute-force descriptor matching of map points to a frame's free keypoints
/// with a ratio test. Returns the number of matches written into `matches`.
int searchByDescriptor(const Frame& frame, const std::vector<PointSample>& points, double ratio,
                       std::vector<MapPointId>* matches, std::vector<int>* match_point_index);

/// Pairs of free keypoints (i1 in f1, i2 in f2) that satisfy the epipolar
/// constraint between the two posed views (each with its own camera, K1 and
/// K2) and match by descriptor.
std::vector<std::pair<int, int>> searchForTriangulation(const Frame& f1, const SE3& T1_c_w,
                                                        const std::vector<bool>& used1,
                                                        const Frame& f2, const SE3& T2_c_w,
                                                        const std::vector<bool>& used2,
                                                        const Intrinsics& K1, const Intrinsics& K2,
                                                        const ScaleInfo& scale);

/// Keeps only the matches whose orientation change falls in the three most
/// common bins of a 30-bin histogram. `delta_deg[i]` < 0 for unused entries.
std::vector<bool> orientationConsistent(const std::vector<float>& delta_deg);

}  // namespace ecar
