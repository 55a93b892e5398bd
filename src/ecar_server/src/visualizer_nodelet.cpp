// Visualizer: /ecar/markers (throttled to marker_rate, only when subscribed)
// and tf map -> <device>/camera_server for every tracked frame. The markers
// show the map points, keyframes and cameras (markers.h mapMarkers, from the
// core's mapOverview), the planes coloured by label, the live virtual objects
// and the cells each device last saw (/ecar/visible_structure).
#include <algorithm>
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/TrackedFrame.h>
#include <ecar_msgs/VisibleStructure.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/geometry.h"
#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/slam/map_queries.h"
#include "ecar_server/markers.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class VisualizerNodelet : public nodelet::Nodelet, public ecar::GraphListener {
 public:
  ~VisualizerNodelet() override {
    timer_.stop();
    if (graph_) graph_->removeListener(this);
  }

  void onDeviceRemoved(const ecar::DeviceInfo& device) override {
    std::lock_guard<std::mutex> lock(mutex_);
    cameras_.erase(device.name);
    cells_.erase(device.name);
  }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config);
    cell_size_ = config.grid.cell_size;
    graph_->addListener(this);
    markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(ecar_bridge::kMarkersTopic, 2);
    tracked_sub_ = nh.subscribe(ecar_bridge::kTrackedFrameTopic, 100,
                                &VisualizerNodelet::onTrackedFrame, this);
    visible_sub_ =
        nh.subscribe(ecar_bridge::kVisibleStructureTopic, 100, &VisualizerNodelet::onVisible, this);
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
    const std::optional<ecar::DeviceInfo> info = graph_->devices().device(msg->device_id);
    if (!info) return;
    ecar::SE3 T_w_c;
    try {
      T_w_c = ecar_bridge::fromMsg(msg->pose);
    } catch (const ecar::Error&) {
      return;  // the tracker never produces one; nothing to show
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      cameras_[info->name] = {CameraMarker{info->id, T_w_c}, ecar::MapId(msg->map_id)};
    }
    std_msgs::Header header;
    header.stamp = msg->header.stamp;
    header.frame_id = ecar_bridge::kMapFrame;
    tf_.sendTransform(ecar_bridge::toTransformMsg(
        T_w_c, header, ecar_bridge::DeviceTopics{info->name}.camera_server_frame()));
  }

  // The cells each device saw from its last aligned upload.
  void onVisible(const ecar_msgs::VisibleStructure::ConstPtr& msg) {
    if (msg->stale || msg->cells.empty()) return;
    std::vector<ecar::CellKey> cells;
    try {
      cells = ecar_bridge::fromMsg(*msg).cells;
    } catch (const ecar::Error&) {
      return;  // GridConnection never sends one; nothing to show
    }
    std::lock_guard<std::mutex> lock(mutex_);
    cells_[msg->frame.device_id] = std::move(cells);
  }

  void onTimer(const ros::WallTimerEvent&) {
    if (markers_pub_.getNumSubscribers() == 0) return;
    // The largest map of the atlas, with the devices tracked in it (the
    // others' maps have coordinates of their own).
    const ecar::MapId shown = graph_->largestMap();
    const std::shared_ptr<ecar::SlamSystem> slam = graph_->map(shown);
    if (!slam) return;
    std::vector<CameraMarker> cameras;
    std::vector<DeviceCells> cells;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      for (const auto& kv : cameras_) {
        if (kv.second.second == shown) cameras.push_back(kv.second.first);
      }
      for (const auto& kv : cells_) {
        const auto camera = cameras_.find(kv.first);
        if (camera == cameras_.end() || camera->second.second != shown) continue;
        const std::optional<ecar::DeviceInfo> info = graph_->devices().device(kv.first);
        if (info) cells.push_back(DeviceCells{info->id, kv.second});
      }
    }
    const ros::Time now = ros::Time::now();
    auto markers = boost::make_shared<visualization_msgs::MarkerArray>();
    // Everything is republished each time: drop what is gone (deleted objects).
    visualization_msgs::Marker clear;
    clear.header.frame_id = ecar_bridge::kMapFrame;
    clear.action = visualization_msgs::Marker::DELETEALL;
    markers->markers.push_back(clear);
    visualization_msgs::MarkerArray map =
        mapMarkers(ecar::mapOverview(slam->map()), cameras, ecar_bridge::kMapFrame, now);
    markers->markers.insert(markers->markers.end(), map.markers.begin(), map.markers.end());
    std::vector<ecar::Plane> planes = graph_->planes().planes();
    planes.erase(std::remove_if(planes.begin(), planes.end(),
                                [&](const ecar::Plane& p) { return p.map != shown; }),
                 planes.end());
    std::vector<ecar::VirtualObject> objects = graph_->vos().allObjects();
    objects.erase(std::remove_if(objects.begin(), objects.end(),
                                 [&](const ecar::VirtualObject& vo) { return vo.map != shown; }),
                  objects.end());
    visualization_msgs::MarkerArray more =
        structureMarkers(planes, objects, cells, cell_size_, ecar_bridge::kMapFrame, now);
    markers->markers.insert(markers->markers.end(), more.markers.begin(), more.markers.end());
    markers_pub_.publish(markers);
  }

  std::shared_ptr<ecar::GlobalGraph> graph_;
  double cell_size_ = 0.1;
  ros::Publisher markers_pub_;
  ros::Subscriber tracked_sub_, visible_sub_;
  ros::WallTimer timer_;
  tf2_ros::TransformBroadcaster tf_;
  std::mutex mutex_;  // guards cameras_ and cells_
  /// Each device's last aligned pose and the map it is in.
  std::map<std::string, std::pair<CameraMarker, ecar::MapId>> cameras_;
  std::map<std::string, std::vector<ecar::CellKey>> cells_;  ///< per device, its last upload's
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::VisualizerNodelet, nodelet::Nodelet)
