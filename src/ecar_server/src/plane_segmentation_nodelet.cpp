// PlaneSegmentation: for each keyframe the mapper finished (/ecar/keyframe_mapped),
// copies the points of the keyframe and its covisible neighbours out of the SLAM
// map under its read lock, segments planes (labelled with the up direction from
// the keyframe's gravity), merges them into the shared PlaneMap, refreshes the
// GridPlanes snapshot and links the keyframe to the grid cells visible from it.
// Plane segmentation and grid connection run in this one nodelet: a keyframe's
// cells must be cast against the planes its own points just produced, so the
// two steps are one sequence per keyframe (two nodelets would need a second
// event and a second copy of the keyframe's pose).
#include <algorithm>
#include <limits>
#include <memory>
#include <unordered_set>

#include <ecar_msgs/KeyFrameEvent.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"

namespace ecar_server {

/// Covisible neighbours whose points join the keyframe's for segmentation.
constexpr size_t kNeighbours = 10;

class PlaneSegmentationNodelet : public nodelet::Nodelet {
 public:
  ~PlaneSegmentationNodelet() override { mapped_sub_.shutdown(); }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getMTNodeHandle();
    ctx_ = ServerContext::get(nh.getNamespace(), loadServerConfig(nh));
    // One subscription: keyframes are integrated one at a time, in order.
    mapped_sub_ =
        nh.subscribe(kKeyFrameMappedTopic, 200, &PlaneSegmentationNodelet::onMapped, this);
  }

  void onMapped(const ecar_msgs::KeyFrameEvent::ConstPtr& msg) {
    const std::shared_ptr<ecar::SlamSystem> slam = ctx_->slam();
    if (!slam) return;
    const MappedKeyFrame event = fromMsg(*msg);
    // Read before the copy: a map loaded meanwhile makes the copy stale.
    const uint64_t generation = ctx_->structure().generation();
    ecar::PlaneKeyFrameInput input;
    input.keyframe = event.id;
    ecar::SE3 T_w_c;
    std::optional<Eigen::Vector3d> gravity_c = event.gravity_c;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
    Eigen::Vector3d hi = -lo;
    {
      const ecar::Map& map = slam->map();
      auto lock = map.readLock();
      const ecar::KeyFrame* kf = map.keyframe(event.id);
      if (!kf || kf->bad) return;  // culled meanwhile
      T_w_c = kf->T_w_c();
      if (!gravity_c) gravity_c = kf->features.gravity_c;
      std::vector<ecar::KeyFrameId> kfs = map.bestCovisible(event.id, kNeighbours);
      kfs.push_back(event.id);
      std::unordered_set<ecar::MapPointId> seen;
      for (const auto& id : kfs) {
        const ecar::KeyFrame* k = map.keyframe(id);
        if (!k || k->bad) continue;
        for (const auto& pid : k->points) {
          if (!pid.valid() || !seen.insert(pid).second) continue;
          const ecar::MapPoint* p = map.point(pid);
          if (p && !p->bad) input.points.push_back({pid, p->p_w});
        }
      }
      for (const auto& id : map.keyframeIds()) {
        const ecar::KeyFrame* k = map.keyframe(id);
        if (!k || k->bad) continue;
        lo = lo.cwiseMin(k->center());
        hi = hi.cwiseMax(k->center());
      }
    }
    if (!gravity_c) {
      NODELET_WARN_THROTTLE(5.0, "device %s: keyframe %u has no gravity: no planes from it",
                            event.device.c_str(), event.id.value);
      return;
    }
    input.camera_center_w = T_w_c.translation();
    Structure& structure = ctx_->structure();
    try {
      input.up_w = ecar::upFromGravity(T_w_c, *gravity_c);
      const KeyFrameStructure r = structure.integrateKeyFrame(
          input, T_w_c, *structure.gridConnection(slam->camera()), generation);
      if (r.stale) return;  // copied from a map replaced since
      NODELET_DEBUG(
          "keyframe %u: %zu points, %zu planes found, %zu created, %zu updated, "
          "%zu cells; segment %.1f ms, integrate %.1f ms, grid %.1f ms",
          event.id.value, input.points.size(), r.observations, r.update.created.size(),
          r.update.updated.size(), r.cells, r.segment_ms, r.integrate_ms, r.grid_ms);
      NODELET_INFO_THROTTLE(5.0,
                            "planes: %zu in the map; keyframe %u: %zu points, %zu planes, %zu "
                            "cells in %.1f + %.1f + %.1f ms (segment, integrate, grid)",
                            structure.planes().size(), event.id.value, input.points.size(),
                            r.observations, r.cells, r.segment_ms, r.integrate_ms, r.grid_ms);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "device %s: keyframe %u: plane segmentation failed: %s",
                            event.device.c_str(), event.id.value, e.what());
    }
    if (lo.x() > hi.x()) return;
    const double margin = ctx_->config().vo_map_margin;
    const ecar::VoStoreConfig& vo = ctx_->config().vo;
    try {
      // The configured bounds are the limit; the map's extent narrows them.
      structure.vos().setMapBounds((lo - Eigen::Vector3d::Constant(margin)).cwiseMax(vo.map_min),
                                   (hi + Eigen::Vector3d::Constant(margin)).cwiseMin(vo.map_max));
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "VO map bounds not updated: %s", e.what());
    }
  }

  std::shared_ptr<ServerContext> ctx_;
  ros::Subscriber mapped_sub_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::PlaneSegmentationNodelet, nodelet::Nodelet)
