// Interactions: subscribes /<device>/interaction for every connected device,
// applies each REGISTER / MANIPULATE / DELETE to the shared VoStore (which
// commits it to SQLite before answering) and answers on
// /<device>/interaction_result: accepted with the object's id and version, or
// rejected with the store's reason. In vo_attach keyframe mode a registration
// hangs on the keyframe nearest to the object. A point from rviz's Publish
// Point tool (/clicked_point, frame "map") registers an ANCHOR owned by "rviz".
#include <limits>
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <geometry_msgs/PointStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/error.h"
#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"

namespace ecar_server {

class InteractionsNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~InteractionsNodelet() override {
    clicked_sub_.shutdown();
    if (ctx_) ctx_->removeListener(this);
    std::lock_guard<std::mutex> lock(mutex_);
    devices_.clear();
  }

  void onDeviceAdded(const DeviceInfo& device) override {
    ros::NodeHandle& nh = getMTNodeHandle();
    const DeviceTopicNames topics{device.name};
    Topics t;
    t.result = nh.advertise<ecar_msgs::InteractionResult>(topics.interactionResult(), 50);
    const std::string name = device.name;
    t.sub = nh.subscribe<ecar_msgs::Interaction>(
        topics.interaction(), 50,
        [this, name](const ecar_msgs::Interaction::ConstPtr& msg) { onInteraction(name, *msg); },
        ros::VoidConstPtr(), ros::TransportHints().tcpNoDelay());
    std::lock_guard<std::mutex> lock(mutex_);
    devices_[device.name] = t;
  }

  void onDeviceRemoved(const DeviceInfo& device) override {
    std::lock_guard<std::mutex> lock(mutex_);
    devices_.erase(device.name);
  }

 private:
  struct Topics {
    ros::Subscriber sub;
    ros::Publisher result;
  };

  void onInit() override {
    ros::NodeHandle& nh = getMTNodeHandle();
    ctx_ = ServerContext::get(nh.getNamespace(), loadServerConfig(nh));
    // Opens the database now: a bad file stops the server at start, naming it.
    const ecar::VoStore& store = ctx_->structure().vos();
    NODELET_INFO("virtual objects: %zu stored (%zu live) in %s, vo_attach %s", store.numObjects(),
                 store.numLive(), store.config().database_path.c_str(),
                 ecar::toString(store.attachMode()));
    ctx_->addListener(this);
    clicked_sub_ = nh.subscribe(kClickedPointTopic, 10, &InteractionsNodelet::onClickedPoint, this);
  }

  // rviz's Publish Point tool: a new ANCHOR at the clicked point.
  void onClickedPoint(const geometry_msgs::PointStamped::ConstPtr& msg) {
    if (!msg->header.frame_id.empty() && msg->header.frame_id != kMapFrame) {
      NODELET_WARN_THROTTLE(2.0, "rviz: clicked point in frame '%s', not '%s': ignored",
                            msg->header.frame_id.c_str(), kMapFrame);
      return;
    }
    VoRequest request;
    request.device = kRvizUser;
    request.state.kind = ecar::VoKind::kAnchor;
    request.state.position = Eigen::Vector3d(msg->point.x, msg->point.y, msg->point.z);
    request.state.r = 255;
    request.state.g = 200;
    request.state.b = 0;
    request.state.width = 0.1f;
    const ecar::VoOutcome outcome = apply(request);
    if (outcome.accepted) {
      NODELET_INFO("rviz: object %u registered at (%.2f, %.2f, %.2f)", outcome.id.value,
                   msg->point.x, msg->point.y, msg->point.z);
    } else {
      NODELET_WARN("rviz: clicked point rejected: %s", outcome.reason.c_str());
    }
  }

  void onInteraction(const std::string& device, const ecar_msgs::Interaction& msg) {
    ros::Publisher pub;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      const auto it = devices_.find(device);
      if (it == devices_.end()) return;  // disconnected meanwhile
      pub = it->second.result;
    }
    VoRequest request;
    request.device = device;
    request.request_id = msg.request_id;
    ecar::VoOutcome outcome;
    if (msg.device_id != device) {
      outcome.reason = "device_id '" + msg.device_id + "' is not this topic's device";
    } else {
      try {
        request = fromMsg(msg);
        outcome = apply(request);
      } catch (const ecar::Error& e) {
        outcome.reason = e.what();
      }
    }
    if (!outcome.accepted) {
      NODELET_WARN_THROTTLE(1.0, "device %s: interaction %u (type %u, object %u) rejected: %s",
                            device.c_str(), msg.request_id, msg.type, msg.object_id,
                            outcome.reason.c_str());
    }
    auto result = boost::make_shared<ecar_msgs::InteractionResult>(toMsg(request, outcome));
    result->device_id = device;
    result->header.stamp = ros::Time::now();
    pub.publish(result);
  }

  ecar::VoOutcome apply(const VoRequest& r) {
    ecar::VoStore& store = ctx_->structure().vos();
    switch (r.type) {
      case VoRequest::Type::kRegister: {
        ecar::VirtualObject vo = r.state;
        vo.owner = r.device;
        ecar::KeyFrameId keyframe;
        if (store.attachMode() == ecar::VoAttachMode::kKeyFrame) keyframe = nearestKeyFrame(vo);
        return store.registerObject(vo, keyframe);
      }
      case VoRequest::Type::kManipulate:
        return store.manipulate(r.object, r.base_version, r.state, r.device);
      case VoRequest::Type::kDelete:
        return store.remove(r.object, r.base_version, r.device);
    }
    return {};
  }

  // The live keyframe whose camera centre is nearest to the object's position
  // (invalid when there is none or the position is not finite).
  ecar::KeyFrameId nearestKeyFrame(const ecar::VirtualObject& vo) const {
    const std::shared_ptr<ecar::SlamSystem> slam = ctx_->slam();
    if (!slam || !vo.position.allFinite()) return {};
    const ecar::Map& map = slam->map();
    auto lock = map.readLock();
    ecar::KeyFrameId best;
    double best_d2 = std::numeric_limits<double>::max();
    for (const auto& id : map.keyframeIds()) {
      const ecar::KeyFrame* kf = map.keyframe(id);
      if (!kf || kf->bad) continue;
      const double d2 = (kf->center() - vo.position).squaredNorm();
      if (d2 < best_d2) {
        best_d2 = d2;
        best = id;
      }
    }
    return best;
  }

  static constexpr const char* kClickedPointTopic = "/clicked_point";
  static constexpr const char* kRvizUser = "rviz";

  std::shared_ptr<ServerContext> ctx_;
  ros::Subscriber clicked_sub_;
  std::mutex mutex_;  // guards devices_
  std::map<std::string, Topics> devices_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::InteractionsNodelet, nodelet::Nodelet)
