// GridConnection (core: ecar::GridConnection): the 0.1 m grid that connects
// keyframes, virtual objects and aligned uploads.
// - /ecar/keyframe_planes: links each segmented keyframe to the cells it sees,
//   and narrows the VO map bounds to the map's extent.
// - /<device>/interaction (every connected device): REGISTER / MANIPULATE /
//   DELETE applied to the VO store (which commits it to SQLite before
//   answering) and attached to the object's cells; answered on
//   /<device>/interaction_result: accepted with the object's id and version, or
//   rejected with the store's reason. rviz's Publish Point tool
//   (/clicked_point, frame "map") registers an ANCHOR owned by "rviz", and
//   dragging a VO's interactive marker (/ecar/vo_markers) manipulates it as
//   "rviz" (VoMarkerServer), unless vo.rviz_user is false. Each interaction
//   must carry its device's session token (Connect.session).
// - /ecar/tracked_frame: the planes, objects and cells visible from each
//   aligned upload, on /ecar/visible_structure (the tracked frame inside) for
//   GraphPublisher and the Visualizer.
// Every accepted change's resulting state (tombstones included) is published
// on /ecar/objects, in version order per object. With vo.share "direct" it is
// also relayed on /<device>/objects to every connected device but the one that
// made it (and visible structure carries no objects); a device subscribing to
// it (a late joiner) first gets every live object.
#include <atomic>
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/KeyFramePlanes.h>
#include <ecar_msgs/TrackedFrame.h>
#include <ecar_msgs/VirtualObject.h>
#include <ecar_msgs/VisibleStructure.h>
#include <geometry_msgs/PointStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/geometry.h"
#include "ecar_bridge/objects.h"
#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/server/grid_connection.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/vo_marker_server.h"

namespace ecar_server {

class GridConnectionNodelet : public nodelet::Nodelet, public ecar::GraphListener {
 public:
  ~GridConnectionNodelet() override {
    clicked_sub_.shutdown();
    tracked_sub_.shutdown();
    planes_sub_.shutdown();
    marker_timer_.stop();
    markers_.reset();
    if (graph_) graph_->removeListener(this);
    std::lock_guard<std::mutex> lock(mutex_);
    devices_.clear();
  }

  void onDeviceAdded(const ecar::DeviceInfo& device) override {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ecar_bridge::DeviceTopics topics{device.name};
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

  void onDeviceRemoved(const ecar::DeviceInfo& device) override {
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
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config);
    grid_ = std::make_unique<ecar::GridConnection>(graph_.get(), config.gridConnectionConfig());
    share_ = config.voShare();
    const ecar::VoStore& store = graph_->vos();
    NODELET_INFO("virtual objects: %zu stored (%zu live) in %s, vo_attach %s", store.numObjects(),
                 store.numLive(), store.config().database_path.c_str(),
                 ecar::toString(store.attachMode()));
    NODELET_INFO("virtual objects: vo_share %s; every change on %s", toString(share_),
                 ecar_bridge::kObjectsTopic);
    objects_pub_ =
        nh.advertise<ecar_msgs::VirtualObject>(ecar_bridge::kObjectsTopic, kObjectsQueue);
    visible_pub_ =
        nh.advertise<ecar_msgs::VisibleStructure>(ecar_bridge::kVisibleStructureTopic, 100);
    graph_->addListener(this);
    rviz_user_ = config.vo_rviz_user;
    if (rviz_user_) {
      clicked_sub_ = nh.subscribe(ecar_bridge::kClickedPointTopic, 10,
                                  &GridConnectionNodelet::onClickedPoint, this);
    } else {
      NODELET_INFO("vo.rviz_user false: rviz shows the VOs but cannot register or move them");
    }
    // One subscription each: keyframes are linked in order; tracked frames one
    // at a time (each device's in order).
    planes_sub_ = nh.subscribe(ecar_bridge::kKeyFramePlanesTopic, 200,
                               &GridConnectionNodelet::onKeyFramePlanes, this);
    tracked_sub_ =
        nh.subscribe(ecar_bridge::kTrackedFrameTopic, 100, &GridConnectionNodelet::onTrackedFrame,
                     this, ros::TransportHints().tcpNoDelay());
    markers_ = std::make_unique<VoMarkerServer>(
        nh, ecar_bridge::kVoMarkersTopic, ecar_bridge::kMapFrame, config.vo_marker_drag_rate,
        [this](ecar::ObjectId id) { return graph_->vos().get(id); },
        [this](ecar::ObjectId id, uint32_t base_version, const ecar::VirtualObject& state) {
          if (!rviz_user_) {
            ecar::VoOutcome refused;
            refused.reason = "rviz may not move objects (vo.rviz_user false)";
            return refused;
          }
          ecar::VoRequest request;
          request.device = kRvizUser;
          request.type = ecar::VoRequestType::kManipulate;
          request.object_id = id;
          request.base_version = base_version;
          request.object = state;
          return applyAndShare(request);
        });
    marker_timer_ = nh.createWallTimer(ros::WallDuration(kMarkerSyncPeriod),
                                       &GridConnectionNodelet::onMarkerTimer, this);
  }

  // Keyframe-cell links of a segmented keyframe; the VO bounds follow the map.
  void onKeyFramePlanes(const ecar_msgs::KeyFramePlanes::ConstPtr& msg) {
    try {
      const size_t cells = grid_->linkKeyFrame(ecar_bridge::fromMsg(*msg));
      NODELET_DEBUG("keyframe %u: %zu cells", msg->keyframe_id, cells);
      graph_->updateVoBounds();
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "device %s: keyframe %u: %s", msg->device_id.c_str(),
                            msg->keyframe_id, e.what());
    }
  }

  // What an aligned upload sees, forwarded with its tracked frame.
  void onTrackedFrame(const ecar_msgs::TrackedFrame::ConstPtr& msg) {
    auto out = boost::make_shared<ecar_msgs::VisibleStructure>();
    out->frame = *msg;
    try {
      ecar_bridge::FrameMeta meta;
      const ecar::TrackResult frame = ecar_bridge::fromMsg(*msg, &meta);
      const ecar::VisibleStructure v = grid_->visible(frame, meta.device);
      ecar_bridge::toMsg(v, out.get());
      ++stats_count_;
      stats_sum_ms_ += v.milliseconds;
      stats_max_ms_ = std::max(stats_max_ms_, v.milliseconds);
      NODELET_INFO_THROTTLE(5.0,
                            "planes and objects per upload: %.2f ms mean, %.2f ms max over %zu "
                            "uploads (last: %s frame %u, %zu planes, %zu objects visible)",
                            stats_sum_ms_ / stats_count_, stats_max_ms_, stats_count_,
                            msg->device_id.c_str(), msg->frame_index, v.planes.size(),
                            v.objects.size());
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "device %s: no planes or objects for frame %u: %s",
                            msg->device_id.c_str(), msg->frame_index, e.what());
      out->objects_in_graph = false;
    }
    visible_pub_.publish(out);
  }

  // Markers follow the store: at once after changes, and now and then in any
  // case (the store may change by other means, e.g. a map load).
  void onMarkerTimer(const ros::WallTimerEvent&) {
    std::unique_lock<std::mutex> lock(timer_mutex_, std::try_to_lock);
    if (!lock) return;  // the previous check still runs
    const uint64_t changes = changes_.load();
    if (changes == synced_changes_ && ++idle_ticks_ < kMarkerFullSyncTicks) return;
    idle_ticks_ = 0;
    // Now and then, tombstones past vo.tombstone_retention go.
    if (const size_t n = graph_->vos().compactTombstones(ecar::steadySeconds()); n > 0) {
      NODELET_INFO("vo: %zu tombstones older than vo.tombstone_retention compacted", n);
    }
    synced_changes_ = changes;
    markers_->sync(graph_->vos().allObjects());
  }

  // rviz's Publish Point tool: a new ANCHOR at the clicked point.
  void onClickedPoint(const geometry_msgs::PointStamped::ConstPtr& msg) {
    if (!msg->header.frame_id.empty() && msg->header.frame_id != ecar_bridge::kMapFrame) {
      NODELET_WARN_THROTTLE(2.0, "rviz: clicked point in frame '%s', not '%s': ignored",
                            msg->header.frame_id.c_str(), ecar_bridge::kMapFrame);
      return;
    }
    ecar::VoRequest request;
    request.device = kRvizUser;
    request.object.kind = ecar::VoKind::kAnchor;
    request.object.position = ecar_bridge::fromMsg(msg->point);
    request.object.r = 255;
    request.object.g = 200;
    request.object.b = 0;
    request.object.width = 0.1f;
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
    ecar::VoRequest request;
    request.device = device;
    request.request_id = msg.request_id;
    ecar::VoOutcome outcome;
    if (msg.device_id != device) {
      outcome.reason = "device_id '" + msg.device_id.substr(0, 80) + "' is not this topic's device";
    } else if (const ecar::SessionCheck check = graph_->devices().check(device, msg.session);
               check != ecar::SessionCheck::kOk) {
      outcome.reason = std::string("session: ") + ecar::toString(check) +
                       " (field session; another node on this device's topic?)";
    } else {
      try {
        request = ecar_bridge::fromMsg(msg);
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
    std_msgs::Header header;
    header.frame_id = ecar_bridge::kMapFrame;
    header.stamp = ros::Time::now();
    pub.publish(boost::make_shared<ecar_msgs::InteractionResult>(
        ecar_bridge::toMsg(ecar::resultOf(request, outcome), header)));
  }

  // Direct sharing to a new subscriber of /<device>/objects: every live object,
  // by id. Under apply_mutex_, so each change is either in this snapshot or
  // relayed after it (the subscriber is connected by now).
  void sendLiveObjects(const std::string& device, const ros::SingleSubscriberPublisher& pub) {
    std::lock_guard<std::mutex> lock(apply_mutex_);
    size_t sent = 0;
    for (const auto& vo : graph_->vos().allObjects()) {
      if (vo.deleted) continue;
      pub.publish(ecar_bridge::toMsg(vo));
      ++sent;
    }
    NODELET_INFO("vo_share direct: sent %zu live objects to %s (subscriber %s)", sent,
                 device.c_str(), pub.getSubscriberName().c_str());
  }

  // Applies a request and shares the accepted change: the object's new state on
  // /ecar/objects and, with vo_share direct, on /<device>/objects of every
  // other connected device. Serialised, so an object's states go out in
  // version order.
  ecar::VoOutcome applyAndShare(const ecar::VoRequest& r) {
    std::lock_guard<std::mutex> lock(apply_mutex_);
    const ecar::VoOutcome outcome = grid_->apply(r);
    if (!outcome.accepted) return outcome;
    ++changes_;
    const std::optional<ecar::VirtualObject> vo = graph_->vos().get(outcome.id);
    if (!vo) return outcome;
    const auto msg = boost::make_shared<ecar_msgs::VirtualObject>(ecar_bridge::toMsg(*vo));
    objects_pub_.publish(msg);
    if (share_ == VoShareMode::kDirect) {
      std::lock_guard<std::mutex> devices_lock(mutex_);
      for (const auto& kv : devices_) {
        if (kv.first != r.device) kv.second.objects.publish(msg);
      }
    }
    return outcome;
  }

  static constexpr const char* kRvizUser = "rviz";
  /// Publisher queues of /ecar/objects and /<device>/objects: a burst of drags
  /// from many devices must not drop states.
  static constexpr uint32_t kObjectsQueue = 1000;
  /// s between marker checks; every kMarkerFullSyncTicks-th check syncs even
  /// without a change seen here.
  static constexpr double kMarkerSyncPeriod = 0.1;
  static constexpr int kMarkerFullSyncTicks = 20;

  std::shared_ptr<ecar::GlobalGraph> graph_;
  std::unique_ptr<ecar::GridConnection> grid_;
  VoShareMode share_ = VoShareMode::kGraph;
  ros::Subscriber clicked_sub_, planes_sub_, tracked_sub_;
  ros::Publisher objects_pub_, visible_pub_;
  std::unique_ptr<VoMarkerServer> markers_;
  bool rviz_user_ = true;  ///< vo.rviz_user
  ros::WallTimer marker_timer_;
  std::atomic<uint64_t> changes_{0};  ///< accepted changes made here
  std::mutex timer_mutex_;            // guards the two below (the marker timer)
  uint64_t synced_changes_ = 0;
  int idle_ticks_ = 0;
  std::mutex apply_mutex_;  // serialises applyAndShare; taken before mutex_
  std::mutex mutex_;        // guards devices_
  std::map<std::string, Topics> devices_;
  // Timing of visible() (the tracked-frame callback runs one at a time).
  size_t stats_count_ = 0;
  double stats_sum_ms_ = 0.0, stats_max_ms_ = 0.0;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::GridConnectionNodelet, nodelet::Nodelet)
