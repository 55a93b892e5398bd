// LocalMapping (core: ecar::LocalMapper and ecar::LoopCloser, one of each per
// map of the atlas, started with the map): reports each keyframe a mapper
// finished on /ecar/keyframe_mapped, and logs every loop closed, every merge
// of two maps and what they moved. When the mapper culls a redundant
// keyframe, the global graph drops its plane and cell links and moves the
// objects hanging on it (vo_attach keyframe) to its heir, the neighbour that
// shared the most points with it.
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <optional>

#include <ecar_msgs/KeyFrameEvent.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/slam/map_queries.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class LocalMappingNodelet : public nodelet::Nodelet, public ecar::GraphListener {
 public:
  ~LocalMappingNodelet() override {
    if (graph_) graph_->removeListener(this);
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& kv : maps_) {
      kv.second->mapper().setMappedCallback({});
      kv.second->mapper().setCulledCallback({});
    }
  }

  void onMapCreated(ecar::MapId id, const std::shared_ptr<ecar::SlamSystem>& slam) override {
    std::lock_guard<std::mutex> lock(mutex_);
    maps_[id] = slam;
    ecar::SlamSystem* s = slam.get();
    slam->mapper().setMappedCallback([this, s](ecar::KeyFrameId id) { onMapped(*s, id); });
    slam->mapper().setCulledCallback(
        [this](ecar::KeyFrameId culled, ecar::KeyFrameId heir) { onCulled(culled, heir); });
  }

  void onMapRemoved(ecar::MapId id) override {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = maps_.find(id);
    if (it == maps_.end()) return;
    it->second->mapper().setMappedCallback({});
    it->second->mapper().setCulledCallback({});
    maps_.erase(it);
  }

  // On the merging device's tracking worker, once planes, objects and grid
  // links moved.
  void onMapsMerged(const ecar::MapMergeReport& r) override {
    const ecar::MergeEvent& m = r.merge;
    NODELET_INFO(
        "maps merged: map %u into map %u, found by %s (keyframe %u with keyframe %u, %d inliers, "
        "scale %.4f): %zu keyframes moved, %zu points fused, seam refit %s (%d of %d "
        "reprojections, %.2f -> %.2f px, %.2f deg, scale %.4f) in %.1f ms; %zu planes and %zu "
        "objects moved in %.1f ms, grid links of %zu keyframes re-cast in %.1f ms",
        m.from.value, m.into.value, graph_->devices().name(m.device).c_str(), m.query.value,
        m.match.value, m.inliers, m.scale, m.keyframes_moved, m.points_fused,
        m.refit.applied ? "applied" : "not applied", m.refit.inliers, m.refit.observations,
        m.refit.rms_before_px, m.refit.rms_after_px,
        ecar::rotationAngle(m.refit.D.R) * 180.0 / M_PI, m.refit.D.scale, m.ms, r.planes, r.objects,
        r.structure_ms, r.keyframes_recast, r.recast_ms);
  }

  // On the loop closer's thread, once planes and objects moved too.
  void onMapCorrected(const ecar::MapCorrectionReport& report) override {
    const std::shared_ptr<ecar::Atlas> atlas = graph_->atlas();
    const std::vector<ecar::LoopClosure> loops =
        atlas ? atlas->loopClosures() : std::vector<ecar::LoopClosure>();
    if (!loops.empty() && loops.size() != reported_loops_) {
      reported_loops_ = loops.size();
      const ecar::LoopClosure& l = loops.back();
      char odometry[160] = "";
      if (l.by_odometry) {
        std::snprintf(odometry, sizeof(odometry),
                      " (by odometry: off by %.3f m after a tracking gap, %d covisibility links "
                      "apart)",
                      l.odometry_disagreement_m, l.links);
      }
      NODELET_INFO(
          "loop closed%s: keyframe %u (%s) with keyframe %u, %d inliers, scale %.4f, it moved "
          "%.3f m; detection %.1f ms, correction %.1f ms; %zu points fused",
          odometry, l.query.value, graph_->devices().name(l.device).c_str(), l.match.value,
          l.inliers, l.scale, l.drift_m, l.detect_ms, l.correct_ms, l.points_fused);
    }
    NODELET_INFO(
        "map %u corrected: %zu keyframes, %zu points, %zu planes, %zu objects moved, %zu "
        "planes fused or emptied (their points: %zu live, %zu fused, %zu gone; grid links of %zu "
        "keyframes re-cast, %zu cells) in %.1f ms",
        report.map.value, report.keyframes, report.points, report.planes, report.objects,
        report.planes_removed, report.plane_points_live, report.plane_points_fused,
        report.plane_points_gone, report.keyframes_recast, report.keyframe_cells,
        report.milliseconds);
  }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    graph_ = sharedGraph(nh.getNamespace(), loadServerConfig(nh));
    mapped_pub_ = nh.advertise<ecar_msgs::KeyFrameEvent>(ecar_bridge::kKeyFrameMappedTopic, 100);
    graph_->addListener(this);
  }

  // On the mapping thread.
  void onMapped(const ecar::SlamSystem& slam, ecar::KeyFrameId id) {
    const std::optional<ecar::KeyFrameSummary> kf = ecar::keyframeSummary(slam.map(), id);
    if (!kf) return;  // culled already
    ecar_bridge::MappedKeyFrame event;
    event.id = id;
    event.device = graph_->devices().name(kf->device);
    event.frame_index = kf->frame_index;
    event.timestamp = kf->timestamp;
    event.gravity_c = kf->gravity_c;
    mapped_pub_.publish(boost::make_shared<ecar_msgs::KeyFrameEvent>(ecar_bridge::toMsg(event)));
  }

  // On the mapping thread.
  void onCulled(ecar::KeyFrameId culled, ecar::KeyFrameId heir) {
    try {
      const size_t moved = graph_->eraseKeyFrame(culled, heir);
      if (moved > 0) {
        NODELET_INFO("keyframe %u culled: %zu virtual objects now hang on keyframe %u",
                     culled.value, moved, heir.value);
      }
    } catch (const ecar::Error& e) {
      NODELET_ERROR("keyframe %u culled: %s", culled.value, e.what());
    }
  }

  std::shared_ptr<ecar::GlobalGraph> graph_;
  ros::Publisher mapped_pub_;
  std::mutex mutex_;  // guards maps_
  std::map<ecar::MapId, std::shared_ptr<ecar::SlamSystem>> maps_;
  size_t reported_loops_ = 0;  // guarded by the graph's event serialisation
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::LocalMappingNodelet, nodelet::Nodelet)
