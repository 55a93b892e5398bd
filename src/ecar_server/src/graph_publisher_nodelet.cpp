// GraphPublisher: for each tracked frame, builds the device's local graph
// (ecar_core's LocalGraphBuilder with the device's mirror) and publishes it on
// /<device>/local_graph with the timing fields. A tracked frame's graph also
// carries the planes near the aligned pose and the virtual objects that reach
// it (Structure::visible), plus, once, the tombstone of every object the
// device was sent and that was deleted since. With vo.share "direct" the
// graphs carry no objects (the Interactions nodelet relays each change).
#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>
#include <vector>

#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/TrackedFrame.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/sync/local_graph.h"
#include "ecar_server/conversions.h"
#include "ecar_server/ros_params.h"
#include "ecar_server/server_context.h"

namespace ecar_server {

class GraphPublisherNodelet : public nodelet::Nodelet, public ContextListener {
 public:
  ~GraphPublisherNodelet() override {
    if (ctx_) ctx_->removeListener(this);
    tracked_sub_.shutdown();
  }

  void onDeviceAdded(const DeviceInfo& device) override {
    ros::Publisher pub = getMTNodeHandle().advertise<ecar_msgs::LocalGraph>(
        DeviceTopicNames{device.name}.localGraph(),
        static_cast<uint32_t>(config_.graph_queue_size));
    std::lock_guard<std::mutex> lock(mutex_);
    publishers_[device.name] = pub;
  }

  void onDeviceRemoved(const DeviceInfo& device) override {
    std::lock_guard<std::mutex> lock(mutex_);
    publishers_.erase(device.name);
    sent_objects_.erase(device.name);
    sent_planes_.erase(device.name);
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getMTNodeHandle();
    config_ = loadServerConfig(nh);
    ctx_ = ServerContext::get(nh.getNamespace(), config_);
    builder_ = ecar::LocalGraphBuilder(config_.localGraphConfig());
    share_ = config_.voShare();
    ctx_->addListener(this);
    // One subscription: its callbacks run one at a time, in order.
    tracked_sub_ = nh.subscribe(kTrackedFrameTopic, 100, &GraphPublisherNodelet::onTrackedFrame,
                                this, ros::TransportHints().tcpNoDelay());
  }

  void onTrackedFrame(const ecar_msgs::TrackedFrame::ConstPtr& msg) {
    ecar::TrackResult result;
    try {
      result = fromMsg(*msg);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: tracked frame %u: %s: dropped", msg->device_id.c_str(),
                            msg->frame_index, e.what());
      return;
    }
    const std::optional<DeviceInfo> info = ctx_->device(msg->device_id);
    const std::shared_ptr<ecar::SlamSystem> slam = ctx_->slam();
    ros::Publisher pub;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      const auto it = publishers_.find(msg->device_id);
      if (it != publishers_.end()) pub = it->second;
    }
    if (!info || !slam || !pub) return;  // disconnected meanwhile

    auto graph = boost::make_shared<ecar_msgs::LocalGraph>();
    ecar::LocalGraphData data;
    ctx_->withMirror(info->name, [&](ecar::DeviceMirror& mirror) {
      data = builder_.build(slam->map(), result, info->mode, &mirror);
    });
    graph->header.stamp = msg->header.stamp;
    graph->header.frame_id = kMapFrame;
    graph->device_id = msg->device_id;
    graph->frame_index = msg->frame_index;
    graph->status = msg->status;
    graph->pose = msg->pose;
    graph->map_epoch = ctx_->mapEpoch();
    try {
      fillPayload(
          data, [this](ecar::DeviceId id) { return ctx_->deviceName(id); }, graph.get());
    } catch (const ecar::Error& e) {
      // The mirror counted positions the device will not get: forget it, so
      // the next graph carries every position again.
      ctx_->resetMirror(info->name);
      NODELET_WARN_THROTTLE(2.0, "device %s: local graph %u not encodable: %s: dropped",
                            msg->device_id.c_str(), msg->frame_index, e.what());
      return;
    }
    if (msg->status == ecar_msgs::LocalGraph::OK ||
        msg->status == ecar_msgs::LocalGraph::RELOCALISED) {
      addStructure(*slam, result, msg->device_id, graph.get());
    }
    graph->upload_sent = msg->upload_sent;
    graph->server_received = msg->server_received;
    graph->tracking_time = msg->tracking_time;
    graph->server_sent = ros::Time::now();
    graph->server_time = static_cast<float>((graph->server_sent - msg->server_received).toSec());
    // Built while a map was loaded, or from an alignment in the old map: dropped
    // (and what it counted as sent, positions and planes, forgotten).
    if (ctx_->mapStale(msg->server_received.toSec())) {
      ctx_->resetMirror(info->name);
      std::lock_guard<std::mutex> lock(mutex_);
      sent_planes_.erase(info->name);
      return;
    }
    pub.publish(graph);
  }

  // Planes and objects for the aligned pose, tombstones of objects the device
  // holds that were deleted, and the computation's timing statistics.
  void addStructure(const ecar::SlamSystem& slam, const ecar::TrackResult& result,
                    const std::string& device, ecar_msgs::LocalGraph* graph) {
    Structure& structure = ctx_->structure();
    VisibleStructure v;
    try {
      v = structure.visible(result.T_w_c, result.local_keyframes,
                            *structure.gridConnection(slam.camera()));
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "device %s: no planes or objects in local graph %u: %s",
                            device.c_str(), graph->frame_index, e.what());
      return;
    }
    if (!v.error.empty()) {
      NODELET_WARN_THROTTLE(5.0, "device %s: no objects in local graph %u: %s", device.c_str(),
                            graph->frame_index, v.error.c_str());
    }
    {
      // Planes the device holds at this version are refreshed only now and then.
      std::lock_guard<std::mutex> lock(mutex_);
      if (structure.generation() != sent_generation_) {  // a map was loaded: send every plane
        sent_planes_.clear();
        sent_generation_ = structure.generation();
      }
      SentPlanes& sent = sent_planes_[device];
      ++sent.graphs;
      for (const auto& p : v.planes) {
        const SentPlanes::Sent now = SentPlanes::of(p, sent.graphs);
        auto it = sent.planes.find(p.id);
        if (it != sent.planes.end() && !it->second.differs(now) &&
            sent.graphs - it->second.graph < static_cast<uint64_t>(config_.graph_plane_refresh)) {
          continue;
        }
        sent.planes[p.id] = now;
        graph->planes.push_back(toMsg(p));
      }
    }
    structure.setDeviceCells(device, std::move(v.cells));
    ++stats_count_;
    stats_sum_ms_ += v.milliseconds;
    stats_max_ms_ = std::max(stats_max_ms_, v.milliseconds);
    NODELET_INFO_THROTTLE(5.0,
                          "planes and objects per upload: %.2f ms mean, %.2f ms max over %zu "
                          "uploads (last: %s frame %u, %zu planes, %zu objects visible)",
                          stats_sum_ms_ / stats_count_, stats_max_ms_, stats_count_, device.c_str(),
                          graph->frame_index, graph->planes.size(), v.objects.size());
    if (share_ == VoShareMode::kDirect) return;
    addObjects(structure, v.objects, device, graph);
  }

  // The visible objects, and the tombstones of objects the device was sent
  // that were deleted since.
  void addObjects(Structure& structure, const std::vector<ecar::VirtualObject>& objects,
                  const std::string& device, ecar_msgs::LocalGraph* graph) {
    graph->objects.reserve(objects.size());
    std::vector<ecar::ObjectId> gone;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      std::map<ecar::ObjectId, uint32_t>& sent = sent_objects_[device];
      for (const auto& vo : objects) sent[vo.id] = vo.version;
      for (const auto& kv : sent) {
        if (!std::binary_search(objects.begin(), objects.end(), kv.first,
                                [](const auto& a, const auto& b) { return idOf(a) < idOf(b); })) {
          gone.push_back(kv.first);
        }
      }
    }
    for (const auto& vo : objects) graph->objects.push_back(toMsg(vo));
    if (!gone.empty()) {
      std::vector<ecar::ObjectId> done;
      for (const auto& vo : structure.vos().objects(gone)) {
        if (!vo.deleted) continue;  // still live, out of view: the device keeps it
        graph->objects.push_back(toMsg(vo));
        done.push_back(vo.id);
      }
      std::lock_guard<std::mutex> lock(mutex_);
      std::map<ecar::ObjectId, uint32_t>& sent = sent_objects_[device];
      for (const auto& id : done) sent.erase(id);
    }
  }

  static ecar::ObjectId idOf(const ecar::VirtualObject& vo) { return vo.id; }
  static ecar::ObjectId idOf(ecar::ObjectId id) { return id; }

  ServerConfig config_;
  VoShareMode share_ = VoShareMode::kGraph;
  std::shared_ptr<ServerContext> ctx_;
  ecar::LocalGraphBuilder builder_;
  ros::Subscriber tracked_sub_;
  std::mutex mutex_;  // guards publishers_
  std::map<std::string, ros::Publisher> publishers_;
  /// Per device: objects sent to it (id -> version), to send their tombstones.
  std::map<std::string, std::map<ecar::ObjectId, uint32_t>> sent_objects_;
  /// Per device: each plane as it was sent and the graph count at sending. A
  /// plane is re-estimated at nearly every keyframe (its version moves on), so
  /// it is sent again only when it changed visibly: its normal by more than
  /// 1 degree, its offset by more than 2 cm, or its extent by more than 0.25 m.
  struct SentPlanes {
    struct Sent {
      uint64_t graph = 0;
      Eigen::Vector3d normal = Eigen::Vector3d::Zero();
      double offset = 0.0;
      Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();
      uint8_t label = 0;

      bool differs(const Sent& o) const {
        return label != o.label || normal.dot(o.normal) < std::cos(M_PI / 180.0) ||
               std::abs(offset - o.offset) > 0.02 || (min - o.min).cwiseAbs().maxCoeff() > 0.25 ||
               (max - o.max).cwiseAbs().maxCoeff() > 0.25;
      }
    };
    static Sent of(const ecar::Plane& p, uint64_t graph) {
      Sent s;
      s.graph = graph;
      s.normal = p.normal;
      s.offset = p.offset;
      s.label = static_cast<uint8_t>(p.label);
      if (!p.boundary.empty()) {
        s.min = s.max = p.boundary.front();
        for (const auto& b : p.boundary) {
          s.min = s.min.cwiseMin(b);
          s.max = s.max.cwiseMax(b);
        }
      }
      return s;
    }
    uint64_t graphs = 0;
    std::map<ecar::PlaneId, Sent> planes;
  };
  std::map<std::string, SentPlanes> sent_planes_;
  uint64_t sent_generation_ = 0;  ///< Structure::generation() sent_planes_ belongs to
  // Timing of Structure::visible (the tracked-frame callback runs one at a time).
  size_t stats_count_ = 0;
  double stats_sum_ms_ = 0.0, stats_max_ms_ = 0.0;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::GraphPublisherNodelet, nodelet::Nodelet)
