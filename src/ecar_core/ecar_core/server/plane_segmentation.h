// The paper's plane segmentation module: for each keyframe the local mapper
// finished, the planes in the points of the keyframe and its covisible
// neighbours (RANSAC, labelled with the up direction from the keyframe's
// gravity), merged into the global graph's planes.
//
//   PlaneSegmentation segmentation(&graph, config);
//   KeyFramePlanes r = segmentation.process(keyframe_id);   // per mapped keyframe
//   if (r.done()) publish(r);   // the grid connection links the keyframe's cells next
//
// The points are copied out of the SLAM map under its read lock
// (map_queries.h); segmentation runs on the copy, and the merge into the
// PlaneMap holds the graph's structure lock, so a map loaded meanwhile is
// noticed (its epoch differs) and nothing of the old map enters the new one.
// process() may be called from several threads (the PlaneMap serialises merges).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/server/global_graph.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/plane_segmenter.h"

namespace ecar {

/// What plane segmentation did for one keyframe.
struct KeyFramePlanes {
  KeyFrameId keyframe;
  DeviceId device;
  uint32_t frame_index = 0;
  double timestamp = 0.0;  ///< capture time, s
  SE3 T_w_c = SE3::Identity();
  uint32_t map_epoch = 0;
  /// The keyframe's planes after the merge, by increasing id.
  std::vector<PlaneId> planes;
  PlaneMapUpdate update;
  size_t points = 0;        ///< map points segmented
  size_t observations = 0;  ///< planes found in them
  size_t points_gone = 0;   ///< points that left the planes (no longer in the SLAM map)
  double segment_ms = 0.0, integrate_ms = 0.0;
  /// Why nothing was done ("" when it was): the keyframe was culled, had no
  /// gravity, or a map was loaded meanwhile.
  std::string skipped;

  bool done() const { return skipped.empty(); }
};

class PlaneSegmentation {
 public:
  /// `neighbours`: covisible keyframes whose points join the keyframe's.
  /// Throws ecar::Error when the plane config is invalid.
  PlaneSegmentation(GlobalGraph* graph, const PlaneConfig& config, size_t neighbours = 10);

  /// Segments one mapped keyframe and merges its planes into the graph's.
  /// `gravity_c` (its upload's specific force, camera frame) when known, else
  /// the keyframe's own reading. Throws ecar::Error when the gravity or the
  /// camera centre is not finite.
  KeyFramePlanes process(KeyFrameId keyframe,
                         const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt) const;

 private:
  GlobalGraph* graph_;
  PlaneSegmenter segmenter_;
  size_t neighbours_;
};

}  // namespace ecar
