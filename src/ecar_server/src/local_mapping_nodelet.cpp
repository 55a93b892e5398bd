// LocalMapping: the SLAM's mapping thread (started with the SlamSystem, which
// maps every device's keyframes into the one map) reports each keyframe it
// finished; this nodelet publishes it on /ecar/keyframe_mapped. When the
// mapper culls a redundant keyframe, its plane and cell links go and the
// objects hanging on it (vo_attach keyframe) move to its heir, the neighbour
// that shared the most points with it.
#include <memory>
#include <mutex>

#include <ecar_msgs/KeyFrameEvent.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"

namespace ecar_server {

class LocalMappingNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~LocalMappingNodelet() override {
    if (ctx_) ctx_->removeListener(this);
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
    ros::NodeHandle& nh = getMTNodeHandle();
    ctx_ = ServerContext::get(nh.getNamespace(), loadServerConfig(nh));
    mapped_pub_ = nh.advertise<ecar_msgs::KeyFrameEvent>(kKeyFrameMappedTopic, 100);
    ctx_->addListener(this);
  }

  // On the mapping thread.
  void onMapped(const ecar::SlamSystem& slam, ecar::KeyFrameId id) {
    MappedKeyFrame kf;
    ecar::DeviceId device;
    {
      auto lock = slam.map().readLock();
      const ecar::KeyFrame* k = slam.map().keyframe(id);
      if (!k) return;  // culled already
      kf.id = id;
      device = k->device;
      kf.frame_index = k->frame_index;
      kf.timestamp = k->timestamp;
      kf.gravity_c = k->features.gravity_c;
    }
    kf.device = ctx_->deviceName(device);
    mapped_pub_.publish(boost::make_shared<ecar_msgs::KeyFrameEvent>(toMsg(kf)));
  }

  // On the mapping thread.
  void onCulled(ecar::KeyFrameId culled, ecar::KeyFrameId heir) {
    Structure& structure = ctx_->structure();
    structure.eraseKeyFrame(culled);
    try {
      const size_t moved = structure.vos().moveKeyFrame(culled, heir);
      if (moved > 0) {
        NODELET_INFO("keyframe %u culled: %zu virtual objects now hang on keyframe %u",
                     culled.value, moved, heir.value);
      }
    } catch (const ecar::Error& e) {
      NODELET_ERROR("keyframe %u culled: %s", culled.value, e.what());
    }
  }

  std::shared_ptr<ServerContext> ctx_;
  ros::Publisher mapped_pub_;
  std::mutex mutex_;  // guards slam_
  std::shared_ptr<ecar::SlamSystem> slam_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::LocalMappingNodelet, nodelet::Nodelet)
