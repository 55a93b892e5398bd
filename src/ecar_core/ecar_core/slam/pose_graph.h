// Pose-graph optimisation over similarities (Ceres), for loop closing and map
// merging: keyframe poses as world-to-camera similarities S_c_w (x_c = s R x_w
// + t), edges as measured relative similarities S_i_j = S_i_w S_j_w^-1 (the
// essential graph: spanning tree, strong covisibility, loop edges). Each edge
// adds 7 residuals: rotation error (angle-axis of R_m^T R_ij, rad), translation
// error (t_ij - t_m, in camera i's frame) and log-scale error, times its weight.
//
//   std::vector<PoseGraphEdge> edges = ...;
//   PoseGraphResult r = optimizePoseGraph(poses, fixed, edges);
//   SE3 T_c_w = metricPose(r.S_c_w[k]);
#pragma once

#include <vector>

#include "ecar_core/common/geometry.h"

namespace ecar {

struct PoseGraphEdge {
  int from = 0, to = 0;  ///< node indices
  Sim3 S_from_to;        ///< measured S_from_w * S_to_w^-1
  double weight = 1.0;   ///< multiplies the residuals (sqrt of the information)
};

struct PoseGraphConfig {
  int iterations = 20;
  /// SE(3) only: every node keeps scale 1 (both sides metric).
  bool fix_scale = false;
  int threads = 1;
};

struct PoseGraphResult {
  bool converged = false;
  std::vector<Sim3> S_c_w;  ///< optimised nodes (the input where it failed)
  double initial_cost = 0.0, final_cost = 0.0;
};

/// Optimises the nodes not marked fixed (at least one node must be fixed: the
/// gauge; none fixed: the first is). Edges with a bad index, a non-finite
/// measurement or a non-positive weight are ignored.
PoseGraphResult optimizePoseGraph(const std::vector<Sim3>& S_c_w, const std::vector<bool>& fixed,
                                  const std::vector<PoseGraphEdge>& edges,
                                  const PoseGraphConfig& config = PoseGraphConfig());

/// The similarity of a metric pose (scale 1), and the metric pose (rotation,
/// translation / scale) of a similarity: where the camera is once the map
/// around it was scaled.
Sim3 similarityOf(const SE3& T_c_w);
SE3 metricPose(const Sim3& S_c_w);
/// The relative measurement S_a_w * S_b_w^-1.
Sim3 relative(const Sim3& S_a_w, const Sim3& S_b_w);

}  // namespace ecar
