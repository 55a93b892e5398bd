// Interactions: subscribes /<device>/interaction for every connected device,
// applies each REGISTER / MANIPULATE / DELETE to the shared VoStore (which
// commits it to SQLite before answering) and answers on
// /<device>/interaction_result: accepted with the object's id and version, or
// rejected with the store's reason. In vo_attach keyframe mode a registration
// hangs on the keyframe nearest to the object. A point from rviz's Publish
// Point tool (/clicked_point, frame "map") registers an ANCHOR owned by "rviz",
// and dragging a VO's interactive marker (/ecar/vo_markers) manipulates it as
// the user "rviz" (VoMarkerServer).
//
// Every accepted change's resulting state (tombstones included) is published
// on /ecar/objects, in version order per object (the timeline measurement
// tools read). With vo.share "direct" it is also relayed on /<device>/objects
// to every connected device but the one that made it (local graphs then carry
// no objects: GraphPublisher); a device subscribing to it (a late joiner)
// first gets every live object.
#include <atomic>
#include <limits>
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/VirtualObject.h>
#include <geometry_msgs/PointStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"
#include "ecar_server/vo_marker_server.h"

namespace ecar_server {

class InteractionsNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~InteractionsNodelet() override {
    clicked_sub_.shutdown();
    marker_timer_.stop();
    markers_.reset();
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
    if (share_ == VoShareMode::kDirect) {
      // A device that subscribes (joins, or reconnects) first gets every live
      // object; later changes follow by the relay in applyAndShare.
      t.objects = nh.advertise<ecar_msgs::VirtualObject>(
          topics.objects(), kObjectsQueue,
          [this, name](const ros::SingleSubscriberPublisher& pub) { sendLiveObjects(name, pub); });
    }
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
    ros::Publisher objects;  ///< vo_share direct: states relayed to the device
  };

  void onInit() override {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    ctx_ = ServerContext::get(nh.getNamespace(), config);
    share_ = ctx_->config().voShare();
    // Opens the database now: a bad file stops the server at start, naming it.
    const ecar::VoStore& store = ctx_->structure().vos();
    NODELET_INFO("virtual objects: %zu stored (%zu live) in %s, vo_attach %s", store.numObjects(),
                 store.numLive(), store.config().database_path.c_str(),
                 ecar::toString(store.attachMode()));
    NODELET_INFO("virtual objects: vo_share %s; every change on %s", toString(share_),
                 kObjectsTopic);
    objects_pub_ = nh.advertise<ecar_msgs::VirtualObject>(kObjectsTopic, kObjectsQueue);
    ctx_->addListener(this);
    clicked_sub_ = nh.subscribe(kClickedPointTopic, 10, &InteractionsNodelet::onClickedPoint, this);
    markers_ = std::make_unique<VoMarkerServer>(
        nh, kVoMarkersTopic, kMapFrame, ctx_->config().vo_marker_drag_rate,
        [this](ecar::ObjectId id) { return ctx_->structure().vos().get(id); },
        [this](ecar::ObjectId id, uint32_t base_version, const ecar::VirtualObject& state) {
          VoRequest request;
          request.device = kRvizUser;
          request.type = VoRequest::Type::kManipulate;
          request.object = id;
          request.base_version = base_version;
          request.state = state;
          return applyAndShare(request);
        });
    marker_timer_ = nh.createWallTimer(ros::WallDuration(kMarkerSyncPeriod),
                                       &InteractionsNodelet::onMarkerTimer, this);
  }

  // Markers follow the store: at once after changes, and now and then in any
  // case (the store may change by other means, e.g. a map load).
  void onMarkerTimer(const ros::WallTimerEvent&) {
    std::unique_lock<std::mutex> lock(timer_mutex_, std::try_to_lock);
    if (!lock) return;  // the previous check still runs
    const uint64_t changes = changes_.load();
    if (changes == synced_changes_ && ++idle_ticks_ < kMarkerFullSyncTicks) return;
    idle_ticks_ = 0;
    synced_changes_ = changes;
    markers_->sync(ctx_->structure().vos().allObjects());
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
    const ecar::VoOutcome outcome = applyAndShare(request);
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
        request.device = device;
        outcome = applyAndShare(request);
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

  // Direct sharing to a new subscriber of /<device>/objects: every live object,
  // by id. Under apply_mutex_, so each change is either in this snapshot or
  // relayed after it (the subscriber is connected by now).
  void sendLiveObjects(const std::string& device, const ros::SingleSubscriberPublisher& pub) {
    std::lock_guard<std::mutex> lock(apply_mutex_);
    size_t sent = 0;
    for (const auto& vo : ctx_->structure().vos().allObjects()) {
      if (vo.deleted) continue;
      pub.publish(toMsg(vo));
      ++sent;
    }
    NODELET_INFO("vo_share direct: sent %zu live objects to %s (subscriber %s)", sent,
                 device.c_str(), pub.getSubscriberName().c_str());
  }

  // Applies a request and shares the accepted change: the object's new state on
  // /ecar/objects and, with vo_share direct, on /<device>/objects of every
  // other connected device. Serialised, so an object's states go out in
  // version order.
  ecar::VoOutcome applyAndShare(const VoRequest& r) {
    std::lock_guard<std::mutex> lock(apply_mutex_);
    const ecar::VoOutcome outcome = apply(r);
    if (!outcome.accepted) return outcome;
    ++changes_;
    const std::optional<ecar::VirtualObject> vo = ctx_->structure().vos().get(outcome.id);
    if (!vo) return outcome;
    const auto msg = boost::make_shared<ecar_msgs::VirtualObject>(toMsg(*vo));
    objects_pub_.publish(msg);
    if (share_ == VoShareMode::kDirect) {
      std::lock_guard<std::mutex> devices_lock(mutex_);
      for (const auto& kv : devices_) {
        if (kv.first != r.device) kv.second.objects.publish(msg);
      }
    }
    return outcome;
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
  /// Publisher queues of /ecar/objects and /<device>/objects: a burst of drags
  /// from many devices must not drop states.
  static constexpr uint32_t kObjectsQueue = 1000;
  /// s between marker checks; every kMarkerFullSyncTicks-th check syncs even
  /// without a change seen here.
  static constexpr double kMarkerSyncPeriod = 0.1;
  static constexpr int kMarkerFullSyncTicks = 20;

  std::shared_ptr<ServerContext> ctx_;
  VoShareMode share_ = VoShareMode::kGraph;
  ros::Subscriber clicked_sub_;
  ros::Publisher objects_pub_;
  std::unique_ptr<VoMarkerServer> markers_;
  ros::WallTimer marker_timer_;
  std::atomic<uint64_t> changes_{0};  ///< accepted changes made here
  std::mutex timer_mutex_;            // guards the two below (the marker timer)
  uint64_t synced_changes_ = 0;
  int idle_ticks_ = 0;
  std::mutex apply_mutex_;  // serialises applyAndShare; taken before mutex_
  std::mutex mutex_;        // guards devices_
  std::map<std::string, Topics> devices_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::InteractionsNodelet, nodelet::Nodelet)
