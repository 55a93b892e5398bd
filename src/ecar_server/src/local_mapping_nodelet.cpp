// LocalMapping: the SLAM's mapping thread (started with the SlamSystem, which
// maps every device's keyframes into the one map) reports each keyframe it
// finished; this nodelet publishes it on /ecar/keyframe_mapped.
#include <memory>
#include <mutex>

#include <ecar_msgs/KeyFrameEvent.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"

namespace ecar_server {

class LocalMappingNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~LocalMappingNodelet() override {
    if (ctx_) ctx_->removeListener(this);
    std::lock_guard<std::mutex> lock(mutex_);
    if (slam_) slam_->mapper().setMappedCallback({});
  }

  void onSlamCreated(const std::shared_ptr<ecar::SlamSystem>& slam) override {
    std::lock_guard<std::mutex> lock(mutex_);
    slam_ = slam;
    ecar::SlamSystem* s = slam.get();
    slam->mapper().setMappedCallback([this, s](ecar::KeyFrameId id) { onMapped(*s, id); });
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

  std::shared_ptr<ServerContext> ctx_;
  ros::Publisher mapped_pub_;
  std::mutex mutex_;  // guards slam_
  std::shared_ptr<ecar::SlamSystem> slam_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::LocalMappingNodelet, nodelet::Nodelet)
