// Visualizer: /ecar/markers (throttled to marker_rate, only when subscribed)
// and tf map -> <device>/camera_server for every tracked frame. The markers
// show the map points, keyframes and cameras (markers.h mapMarkers), the planes
// coloured by label, the live virtual objects and the cells each device last
// saw (structureMarkers).
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/TrackedFrame.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_server/markers.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"
#include "ecar_sim/conversions.h"

namespace ecar_server {

class VisualizerNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~VisualizerNodelet() override {
    timer_.stop();
    if (ctx_) ctx_->removeListener(this);
  }

  void onDeviceRemoved(const DeviceInfo& device) override {
    std::lock_guard<std::mutex> lock(mutex_);
    cameras_.erase(device.name);
    ctx_->structure().eraseDevice(device.name);
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    ctx_ = ServerContext::get(nh.getNamespace(), config);
    ctx_->addListener(this);
    markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(kMarkersTopic, 2);
    tracked_sub_ = nh.subscribe(kTrackedFrameTopic, 100, &VisualizerNodelet::onTrackedFrame, this);
    if (config.marker_rate > 0.0) {
      timer_ = nh.createWallTimer(ros::WallDuration(1.0 / config.marker_rate),
                                  &VisualizerNodelet::onTimer, this);
    }
  }

  void onTrackedFrame(const ecar_msgs::TrackedFrame::ConstPtr& msg) {
    if (msg->status != ecar_msgs::TrackedFrame::OK &&
        msg->status != ecar_msgs::TrackedFrame::RELOCALISED) {
      return;
    }
    const std::optional<DeviceInfo> info = ctx_->device(msg->device_id);
    if (!info) return;
    ecar::SE3 T_w_c;
    try {
      T_w_c = ecar_sim::fromPose(msg->pose);
    } catch (const ecar::Error&) {
      return;  // the tracker never produces one; nothing to show
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      cameras_[info->name] = CameraMarker{info->id, T_w_c};
    }
    std_msgs::Header header;
    header.stamp = msg->header.stamp;
    header.frame_id = kMapFrame;
    tf_.sendTransform(
        ecar_sim::toTransform(T_w_c, header, DeviceTopicNames{info->name}.cameraServerFrame()));
  }

  void onTimer(const ros::WallTimerEvent&) {
    if (markers_pub_.getNumSubscribers() == 0) return;
    const std::shared_ptr<ecar::SlamSystem> slam = ctx_->slam();
    if (!slam) return;
    std::vector<CameraMarker> cameras;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      for (const auto& kv : cameras_) cameras.push_back(kv.second);
    }
    const ros::Time now = ros::Time::now();
    auto markers = boost::make_shared<visualization_msgs::MarkerArray>();
    // Everything is republished each time: drop what is gone (deleted objects).
    visualization_msgs::Marker clear;
    clear.header.frame_id = kMapFrame;
    clear.action = visualization_msgs::Marker::DELETEALL;
    markers->markers.push_back(clear);
    visualization_msgs::MarkerArray map = mapMarkers(slam->map(), cameras, kMapFrame, now);
    markers->markers.insert(markers->markers.end(), map.markers.begin(), map.markers.end());
    Structure& structure = ctx_->structure();
    std::vector<DeviceCells> cells;
    for (auto& kv : structure.deviceCells()) {
      const std::optional<DeviceInfo> info = ctx_->device(kv.first);
      if (info) cells.push_back(DeviceCells{info->id, std::move(kv.second)});
    }
    visualization_msgs::MarkerArray more =
        structureMarkers(structure.planes().planes(), structure.vos().allObjects(), cells,
                         ctx_->config().grid.cell_size, kMapFrame, now);
    markers->markers.insert(markers->markers.end(), more.markers.begin(), more.markers.end());
    markers_pub_.publish(markers);
  }

  std::shared_ptr<ServerContext> ctx_;
  ros::Publisher markers_pub_;
  ros::Subscriber tracked_sub_;
  ros::WallTimer timer_;
  tf2_ros::TransformBroadcaster tf_;
  std::mutex mutex_;  // guards cameras_
  std::map<std::string, CameraMarker> cameras_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::VisualizerNodelet, nodelet::Nodelet)
