// LocalMapping (core: ecar::LocalMapper, started with the SLAM system, which
// maps every device's keyframes into the one map, and ecar::LoopCloser):
// reports each keyframe it finished on /ecar/keyframe_mapped, and logs every
// loop closed and what its correction moved. When the mapper culls a redundant
// keyframe, the global graph drops its plane and cell links and moves the
// objects hanging on it (vo_attach keyframe) to its heir, the neighbour that
// shared the most points with it.
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
    if (slam_) {
      slam_->mapper().setMappedCallback({});
      slam_->mapper().setCulledCallback({});
    }
  }

  void onSlamCreated(const std::shared_ptr<ecar::SlamSystem>& slam) override {
    std::lock_guard<std::mutex> lock(mutex_);
    slam_ = slam;
    ecar::SlamSystem* s = slam.get();
    slam->mapper().setMappedCallback([this, s](ecar::KeyFrameId id) { onMapped(*s, id); });
    slam->mapper().setCulledCallback(
        [this](ecar::KeyFrameId culled, ecar::KeyFrameId heir) { onCulled(culled, heir); });
  }

  // On the loop closer's thread, once planes and objects moved too.
  void onMapCorrected(const ecar::MapCorrectionReport& report) override {
    std::shared_ptr<ecar::SlamSystem> slam;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      slam = slam_;
    }
    const std::vector<ecar::LoopClosure> loops =
        slam ? slam->loopCloser().closures() : std::vector<ecar::LoopClosure>();
    if (!loops.empty() && loops.size() != reported_loops_) {
      reported_loops_ = loops.size();
      const ecar::LoopClosure& l = loops.back();
      NODELET_INFO(
          "loop closed: keyframe %u (%s) with keyframe %u, %d inliers, scale %.4f, it moved "
          "%.3f m; detection %.1f ms, correction %.1f ms; %zu points fused",
          l.query.value, graph_->devices().name(l.device).c_str(), l.match.value, l.inliers,
          l.scale, l.drift_m, l.detect_ms, l.correct_ms, l.points_fused);
    }
    NODELET_INFO(
        "map corrected: %zu keyframes, %zu points, %zu planes, %zu objects moved "
        "(grid links of %zu keyframes re-cast, %zu cells) in %.1f ms",
        report.keyframes, report.points, report.planes, report.objects, report.keyframes_recast,
        report.keyframe_cells, report.milliseconds);
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
  std::mutex mutex_;  // guards slam_
  std::shared_ptr<ecar::SlamSystem> slam_;
  size_t reported_loops_ = 0;  // loop closer's thread only
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::LocalMappingNodelet, nodelet::Nodelet)
