// DeviceRegistry: /ecar/connect and /ecar/disconnect, and the device timeout.
// The registry is the global graph's (ecar::GlobalGraph::connect checks the
// name, the sync mode and the camera, which creates the SLAM map); the other
// nodelets subscribe and advertise per device when it reports a device added.
// Each connection gets a session token (Connect.session); a disconnect must
// carry it, and so must the uploads and interactions the other nodelets check.
// With a known uplink_capacity the answer gives the device its first upload
// budget (then every local graph does, GraphPublisher).
#include <algorithm>
#include <memory>

#include <ecar_msgs/Connect.h>
#include <ecar_msgs/Disconnect.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/camera.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class DeviceRegistryNodelet : public nodelet::Nodelet {
 public:
  ~DeviceRegistryNodelet() override {
    timer_.stop();
    connect_srv_.shutdown();
    disconnect_srv_.shutdown();
  }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    uplink_ = config.uplinkShareConfig();
    graph_ = sharedGraph(nh.getNamespace(), config);
    connect_srv_ =
        nh.advertiseService(ecar_bridge::kConnectService, &DeviceRegistryNodelet::onConnect, this);
    disconnect_srv_ = nh.advertiseService(ecar_bridge::kDisconnectService,
                                          &DeviceRegistryNodelet::onDisconnect, this);
    const double period = std::max(0.1, std::min(1.0, config.device_timeout / 4.0));
    timer_ = nh.createWallTimer(ros::WallDuration(period), &DeviceRegistryNodelet::onTimer, this);
    NODELET_INFO("device registry: %s, sync_mode %s, device_timeout %.1f s",
                 ecar_bridge::kConnectService, config.sync_mode.c_str(), config.device_timeout);
  }

  bool onConnect(ecar_msgs::Connect::Request& req, ecar_msgs::Connect::Response& res) {
    ecar::PinholeCamera camera;
    try {
      camera = ecar_bridge::fromMsg(req.camera_info);
    } catch (const ecar::Error& e) {
      res.accepted = false;
      res.message = std::string("camera_info refused: ") + e.what();
      NODELET_WARN("device %s: %s", req.device_id.c_str(), res.message.c_str());
      return true;
    }
    const ecar::DeviceConnectResult r = graph_->connect(
        req.device_id, camera, req.sync_mode, req.keyframe_queue, steadySeconds(), req.session);
    res.accepted = r.accepted;
    res.message = r.message;
    if (r.accepted) res.session = r.device.session;
    res.map_epoch = graph_->epoch();
    if (r.accepted) res.upload_budget = uplink_.budgetFor(graph_->devices().devices().size());
    if (r.accepted) {
      const ecar_bridge::DeviceTopics topics{req.device_id};
      res.upload_topic = topics.upload();
      res.local_graph_topic = topics.localGraph();
      res.interaction_topic = topics.interaction();
      NODELET_INFO("device %s: %s", req.device_id.c_str(), r.message.c_str());
    } else {
      NODELET_WARN_THROTTLE(1.0, "device %s: connect refused: %s",
                            req.device_id.substr(0, 80).c_str(), r.message.c_str());
    }
    return true;
  }

  bool onDisconnect(ecar_msgs::Disconnect::Request& req, ecar_msgs::Disconnect::Response& res) {
    const ecar::SessionCheck check = graph_->disconnect(req.device_id, req.session);
    res.ok = check == ecar::SessionCheck::kOk;
    const std::string name = req.device_id.substr(0, 80);
    if (res.ok) {
      res.message = "disconnected";
      NODELET_INFO("device %s: disconnected", name.c_str());
    } else {
      res.message = "device '" + name + "': " + ecar::toString(check) + ": not disconnected";
      NODELET_WARN_THROTTLE(1.0, "%s", res.message.c_str());
    }
    return true;
  }

  void onTimer(const ros::WallTimerEvent&) {
    for (const auto& name : graph_->removeSilent(steadySeconds())) {
      NODELET_WARN("device %s: silent for %.1f s (device_timeout): dropped", name.c_str(),
                   graph_->devices().config().device_timeout);
    }
  }

  std::shared_ptr<ecar::GlobalGraph> graph_;
  ros::ServiceServer connect_srv_, disconnect_srv_;
  ros::WallTimer timer_;
  /// The first upload budget (Connect.upload_budget): the startup config's
  /// share over the connected devices.
  ecar::UplinkShareConfig uplink_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::DeviceRegistryNodelet, nodelet::Nodelet)
