#include "ecar_core/server/plane_segmentation.h"

#include <chrono>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/slam/map_queries.h"

namespace ecar {
PlaneSegmentation::PlaneSegmentation(GlobalGraph* graph, const PlaneConfig& config,
                                     size_t neighbours)
    : graph_(graph), segmenter_(config), neighbours_(neighbours) {
  if (!graph_) throw Error("PlaneSegmentation: no global graph");
}

KeyFramePlanes PlaneSegmentation::process(KeyFrameId keyframe,
                                          const std::optional<Eigen::Vector3d>& gravity_c) const {
  KeyFramePlanes out;
  out.keyframe = keyframe;
  MapId map;
  const std::shared_ptr<SlamSystem> slam = graph_->mapOfKeyFrame(keyframe, &map);
  if (!slam) {
    out.skipped = "its map is gone";
    return out;
  }
  const std::optional<KeyFrameNeighbourhood> around =
      keyframeNeighbourhood(slam->map(), keyframe, neighbours_);
  if (!around) {
    out.skipped = "culled";
    return out;
  }
  out.device = around->device;
  out.frame_index = around->frame_index;
  out.timestamp = around->timestamp;
  out.T_w_c = around->T_w_c;
  out.map_epoch = around->map_epoch;
  const std::optional<Eigen::Vector3d> gravity = gravity_c ? gravity_c : around->gravity_c;
  if (!gravity) {
    out.skipped = "no gravity";
    return out;
  }
  PlaneKeyFrameInput input;
  input.keyframe = keyframe;
  input.map = map;
  input.camera_center_w = around->T_w_c.translation();
  input.up_w = upFromGravity(around->T_w_c, *gravity);
  input.points.reserve(around->points.size());
  for (const auto& [id, p_w] : around->points) input.points.push_back({id, p_w});
  out.points = input.points.size();

  auto structure = graph_->structureLock();
  if (graph_->epoch() != out.map_epoch) {
    out.skipped = "a map was loaded meanwhile";
    return out;
  }
  {
    // The planes' points the SLAM map has culled or fused since (a few
    // thousand lookups, well under a millisecond).
    const std::vector<MapPointId> held = graph_->planes().pointsOfMap(map);
    auto lock = slam->map().readLock();
    for (const MapPointId id : held) {
      if (!slam->map().point(id)) input.gone.push_back(id);
    }
  }
  out.points_gone = input.gone.size();
  auto start = std::chrono::steady_clock::now();
  const std::vector<PlaneObservation> observations = segmenter_.segment(input);
  out.observations = observations.size();
  out.segment_ms = msSince(start);
  start = std::chrono::steady_clock::now();
  out.update = graph_->planes().integrate(input, observations);
  out.planes = out.update.keyframe_planes;
  out.integrate_ms = msSince(start);
  return out;
}

}  // namespace ecar
