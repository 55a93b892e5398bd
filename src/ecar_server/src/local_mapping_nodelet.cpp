// LocalMapping (core: ecar::LocalMapper, started with the SLAM system, which
// maps every device's keyframes into the one map): reports each keyframe it
// finished on /ecar/keyframe_mapped. When the mapper culls a redundant
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
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::LocalMappingNodelet, nodelet::Nodelet)
