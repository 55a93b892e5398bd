// GraphPublisher (the paper's graph publishing; core: ecar::LocalGraphComposer):
// for each aligned upload with what is visible from it (/ecar/visible_structure,
// from GridConnection), composes the device's local graph from what the device
// holds (its DeviceSyncState, kept here) and publishes it on
// /<device>/local_graph with the timing fields. A graph of an upload aligned in
// a map that was loaded since is not sent. Each graph carries its device's
// share of the devices' uplink (upload_budget, ecar::UplinkShare) when the
// server knows the link's capacity (uplink_capacity). The resend tolerances,
// the plane refresh and the uplink keys are live-tunable (dynamic_reconfigure
// on this nodelet's namespace, /edge_server/graph_publisher; cfg/GraphPublisher.cfg).
#include <map>
#include <memory>
#include <mutex>

#include <dynamic_reconfigure/server.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/VisibleStructure.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/local_graph.h"
#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/slam/atlas.h"
#include "ecar_core/sync/local_graph_composer.h"
#include "ecar_server/GraphPublisherConfig.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class GraphPublisherNodelet : public nodelet::Nodelet, public ecar::GraphListener {
 public:
  ~GraphPublisherNodelet() override {
    if (graph_) graph_->removeListener(this);
    visible_sub_.shutdown();
  }

  void onDeviceAdded(const ecar::DeviceInfo& device) override {
    ros::Publisher pub = getMTNodeHandle().advertise<ecar_msgs::LocalGraph>(
        ecar_bridge::DeviceTopics{device.name}.localGraph(),
        static_cast<uint32_t>(config_.graph_queue_size));
    std::lock_guard<std::mutex> lock(mutex_);
    devices_[device.name] = Device{pub, ecar::DeviceSyncState(device.keyframe_queue)};
  }

  void onDeviceRemoved(const ecar::DeviceInfo& device) override {
    std::lock_guard<std::mutex> lock(mutex_);
    devices_.erase(device.name);
    uplink_.remove(device.name);
  }

 private:
  struct Device {
    ros::Publisher pub;
    ecar::DeviceSyncState state;  ///< what the device holds
  };

  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    config_ = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config_);
    composer_ = std::make_shared<const ecar::LocalGraphComposer>(config_.composerConfig());
    reconfigure_ = std::make_unique<dynamic_reconfigure::Server<GraphPublisherConfig>>(
        reconfigure_mutex_, getMTPrivateNodeHandle());
    {
      // The startup values are config/server.yaml's, as the composer holds them.
      const ecar::LocalGraphComposerConfig& c = composer_->config();
      GraphPublisherConfig initial;
      initial.position_tolerance = c.position_tolerance;
      initial.position_tolerance_deg = c.position_tolerance_deg;
      initial.position_tolerance_depth = c.position_tolerance_depth;
      initial.edgeslam_keyframes = c.edgeslam_keyframes;
      initial.graph_plane_refresh = c.plane_refresh;
      initial.plane_resend_angle_deg = c.plane_resend_angle_deg;
      initial.plane_resend_offset = c.plane_resend_offset;
      initial.plane_resend_extent = c.plane_resend_extent;
      initial.uplink_capacity = config_.uplink_capacity;
      initial.uplink_utilisation = config_.uplink_utilisation;
      uplink_ = ecar::UplinkShare(config_.uplinkShareConfig());
      std::lock_guard<boost::recursive_mutex> lock(reconfigure_mutex_);
      reconfigure_->updateConfig(initial);
    }
    reconfigure_->setCallback(
        [this](const GraphPublisherConfig& c, uint32_t) { onReconfigure(c); });
    graph_->addListener(this);
    // One subscription: its callbacks run one at a time, in order.
    visible_sub_ =
        nh.subscribe(ecar_bridge::kVisibleStructureTopic, 100, &GraphPublisherNodelet::onVisible,
                     this, ros::TransportHints().tcpNoDelay());
  }

  void onReconfigure(const GraphPublisherConfig& c) {
    ecar::LocalGraphComposerConfig next = composer()->config();
    next.position_tolerance = c.position_tolerance;
    next.position_tolerance_deg = c.position_tolerance_deg;
    next.position_tolerance_depth = c.position_tolerance_depth;
    next.edgeslam_keyframes = c.edgeslam_keyframes;
    next.plane_refresh = c.graph_plane_refresh;
    next.plane_resend_angle_deg = c.plane_resend_angle_deg;
    next.plane_resend_offset = c.plane_resend_offset;
    next.plane_resend_extent = c.plane_resend_extent;
    ecar::UplinkShareConfig uplink = config_.uplinkShareConfig();
    uplink.capacity = c.uplink_capacity;
    uplink.utilisation = c.uplink_utilisation;
    try {
      auto composer = std::make_shared<const ecar::LocalGraphComposer>(next);
      ecar::UplinkShare share(uplink);
      std::lock_guard<std::mutex> lock(mutex_);
      composer_ = std::move(composer);
      if (uplink.capacity != uplink_.config().capacity ||
          uplink.utilisation != uplink_.config().utilisation) {
        uplink_ = std::move(share);
      }
      NODELET_INFO(
          "local graphs: position tolerance %.4f m / %.3f deg / %.3f of depth, plane "
          "refresh every %d graphs; uplink %.0f B/s at utilisation %.2f",
          next.position_tolerance, next.position_tolerance_deg, next.position_tolerance_depth,
          next.plane_refresh, uplink.capacity, uplink.utilisation);
    } catch (const ecar::Error& e) {
      NODELET_WARN("reconfigure refused: %s", e.what());
    }
  }

  std::shared_ptr<const ecar::LocalGraphComposer> composer() {
    std::lock_guard<std::mutex> lock(mutex_);
    return composer_;
  }

  void onVisible(const ecar_msgs::VisibleStructure::ConstPtr& msg) {
    const double cpu_start = ecar::threadCpuMs();
    const ecar_msgs::TrackedFrame& frame_msg = msg->frame;
    const std::string& device = frame_msg.device_id;
    ecar::TrackResult frame;
    ecar_bridge::FrameMeta meta;
    ecar::VisibleStructure visible;
    try {
      frame = ecar_bridge::fromMsg(frame_msg, &meta);
      visible = ecar_bridge::fromMsg(*msg);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: tracked frame %u: %s: dropped", device.c_str(),
                            frame_msg.frame_index, e.what());
      return;
    }
    const std::optional<ecar::DeviceInfo> info = graph_->devices().device(device);
    if (!info) return;  // disconnected meanwhile
    // Its map merged into another since it was aligned (another device's
    // merge): answered in the merged map, as the device's next upload would be.
    if (frame.map.valid() && !graph_->map(frame.map)) {
      if (const std::shared_ptr<ecar::Atlas> atlas = graph_->atlas()) atlas->toLiveMap(&frame);
    }
    // Not tracked: any map answers the epoch check (the graph has no points).
    const std::shared_ptr<ecar::SlamSystem> slam =
        graph_->map(frame.map.valid() ? frame.map : graph_->largestMap());
    if (!slam) {
      NODELET_WARN_THROTTLE(2.0, "device %s: tracked frame %u: map %u is gone: not answered",
                            device.c_str(), frame_msg.frame_index, frame.map.value);
      return;
    }
    const std::shared_ptr<const ecar::LocalGraphComposer> composer = this->composer();
    ecar::ComposerInput in;
    in.device = device;
    in.frame_index = frame_msg.frame_index;
    in.mode = info->mode;
    in.map_epoch = frame.map_epoch;
    in.reset = meta.reset;
    in.frame = &frame;
    in.planes = &visible.planes;
    if (visible.objects_computed) in.objects = &visible.objects;
    ecar::ComposerLookups lookups;
    lookups.objects = [this](const std::vector<ecar::ObjectId>& ids) {
      return graph_->vos().objects(ids);
    };
    lookups.device_name = [this](ecar::DeviceId id) { return graph_->devices().name(id); };
    lookups.plane_exists = [this](ecar::PlaneId id) { return graph_->planes().contains(id); };
    std::optional<ecar::LocalGraph> graph;
    ros::Publisher pub;
    uint32_t budget = 0;
    try {
      // The device's state is used by this one callback at a time; the lock
      // only guards the map of devices against connects and removals.
      std::lock_guard<std::mutex> lock(mutex_);
      const auto it = devices_.find(device);
      if (it == devices_.end()) return;
      pub = it->second.pub;
      if (it->second.state.points().queueLength() != info->keyframe_queue) {
        it->second.state = ecar::DeviceSyncState(info->keyframe_queue);  // reconnected, new queue
      }
      graph = composer->compose(slam->map(), in, lookups, &it->second.state);
      budget = uplink_.onUpload(device, frame_msg.server_received.toSec());
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: local graph %u not composed: %s: dropped",
                            device.c_str(), frame_msg.frame_index, e.what());
      return;
    }
    if (!graph) return;  // aligned in a map that was loaded since
    auto out = boost::make_shared<ecar_msgs::LocalGraph>();
    try {
      ecar_bridge::toMsg(*graph, out.get());
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: local graph %u not encodable: %s: dropped",
                            device.c_str(), frame_msg.frame_index, e.what());
      return;
    }
    out->header.stamp = frame_msg.header.stamp;
    out->upload_budget = budget;
    out->upload_sent = frame_msg.upload_sent;
    out->server_received = frame_msg.server_received;
    out->receive_time = frame_msg.receive_time;
    out->tracking_time = frame_msg.tracking_time;
    out->server_sent = ros::Time::now();
    out->server_time = static_cast<float>((out->server_sent - frame_msg.server_received).toSec());
    out->server_cpu_time = frame_msg.cpu_time + msg->grid_cpu_time +
                           static_cast<float>((ecar::threadCpuMs() - cpu_start) / 1000.0);
    pub.publish(out);
  }

  ServerConfig config_;
  std::shared_ptr<ecar::GlobalGraph> graph_;
  ros::Subscriber visible_sub_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<GraphPublisherConfig>> reconfigure_;
  std::mutex mutex_;  // guards devices_, composer_ and uplink_
  std::map<std::string, Device> devices_;
  ecar::UplinkShare uplink_;
  std::shared_ptr<const ecar::LocalGraphComposer> composer_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::GraphPublisherNodelet, nodelet::Nodelet)
