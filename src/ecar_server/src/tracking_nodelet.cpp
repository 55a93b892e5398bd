// Tracking (the paper's coordinate alignment; core: ecar::GlobalGraph::track,
// which aligns in the device's map of the atlas):
// subscribes /<device>/upload for every registered device, checks each
// upload, and aligns it on a worker pool (DeviceWorkQueue: one device's
// uploads in order); publishes the result on /ecar/tracked_frame (zero-copy to
// GridConnection and the Visualizer).
#include <chrono>
#include <map>
#include <memory>
#include <mutex>

#include <ecar_msgs/TrackedFrame.h>
#include <ecar_msgs/Upload.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/device_messages.h"
#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_server/device_work_queue.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class TrackingNodelet : public nodelet::Nodelet, public ecar::GraphListener {
 public:
  ~TrackingNodelet() override {
    if (graph_) graph_->removeListener(this);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      subscribers_.clear();
    }
    pool_.reset();  // joins the workers before the members they use go
  }

  void onDeviceAdded(const ecar::DeviceInfo& device) override {
    const std::string name = device.name;
    const boost::function<void(const ecar_msgs::Upload::ConstPtr&)> callback =
        [this, name](const ecar_msgs::Upload::ConstPtr& msg) { onUpload(name, msg); };
    ros::Subscriber sub = getMTNodeHandle().subscribe<ecar_msgs::Upload>(
        ecar_bridge::DeviceTopics{name}.upload(), static_cast<uint32_t>(config_.upload_queue_size),
        callback, ros::VoidConstPtr(), ros::TransportHints().tcpNoDelay());
    std::lock_guard<std::mutex> lock(mutex_);
    subscribers_[name] = sub;
  }

  void onDeviceRemoved(const ecar::DeviceInfo& device) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      subscribers_.erase(device.name);
    }
    const ecar::DeviceId id = device.id;
    const std::shared_ptr<ecar::GlobalGraph> graph = graph_;
    pool_->removeDevice(device.name, [graph, id] { graph->removeDevice(id); });
  }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    config_ = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config_);
    pool_ = std::make_unique<DeviceWorkQueue>(config_.workers,
                                              static_cast<size_t>(config_.device_queue_size));
    tracked_pub_ = nh.advertise<ecar_msgs::TrackedFrame>(ecar_bridge::kTrackedFrameTopic, 100);
    graph_->addListener(this);
    NODELET_INFO("tracking: %d workers, %d uploads queued per device", config_.workers,
                 config_.device_queue_size);
  }

  // Checks on the manager's thread; the alignment runs on the pool.
  void onUpload(const std::string& device, const ecar_msgs::Upload::ConstPtr& msg) {
    const ros::Time received = ros::Time::now();
    const uint32_t bytes = ros::serialization::serializationLength(*msg);
    if (bytes > static_cast<uint32_t>(config_.max_upload_bytes)) {
      NODELET_WARN_THROTTLE(2.0,
                            "device %s: upload of %u bytes (field image) exceeds "
                            "max_upload_bytes %d: dropped",
                            device.c_str(), bytes, config_.max_upload_bytes);
      return;
    }
    if (msg->device_id != device) {
      NODELET_WARN_THROTTLE(2.0,
                            "device %s: upload with device_id '%s' (field device_id) on "
                            "%s: dropped",
                            device.c_str(), msg->device_id.c_str(),
                            ecar_bridge::DeviceTopics{device}.upload().c_str());
      return;
    }
    const ecar::SessionCheck session = graph_->touch(device, msg->session, steadySeconds());
    if (session == ecar::SessionCheck::kNotConnected) {
      NODELET_WARN_THROTTLE(2.0, "device %s: upload from a device not connected: dropped",
                            device.c_str());
      return;
    }
    if (session == ecar::SessionCheck::kWrongSession) {
      NODELET_WARN_THROTTLE(2.0,
                            "device %s: upload with a wrong session token (field session; "
                            "another node on its topic?): dropped",
                            device.c_str());
      return;
    }
    ecar_bridge::UploadContent content;
    try {
      content = ecar_bridge::fromMsg(*msg);  // checks gravity and odometry; leaves the image
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: upload frame %u: %s: dropped", device.c_str(),
                            msg->frame_index, e.what());
      return;
    }
    const bool dropped = pool_->push(
        device, [this, device, msg, content, received] { align(device, msg, content, received); });
    if (dropped) {
      NODELET_WARN_THROTTLE(2.0,
                            "device %s: %d uploads wait for alignment "
                            "(device_queue_size): dropped the oldest",
                            device.c_str(), config_.device_queue_size);
    }
  }

  // On a worker: decode, align, publish.
  void align(const std::string& device, const ecar_msgs::Upload::ConstPtr& msg,
             const ecar_bridge::UploadContent& content, const ros::Time& received) {
    const double cpu_start = ecar::threadCpuMs();
    const std::optional<ecar::DeviceInfo> info = graph_->devices().device(device);
    if (!info) return;  // disconnected meanwhile
    const ecar::CameraPtr camera = graph_->camera(device);
    if (!camera) return;
    // Three steps with a warning each (a throttled warning hides the others of its line):
    // nothing is decoded before the format, the header and the size are checked.
    ecar::JpegHeader header;
    try {
      header = ecar_bridge::readImageHeader(*msg);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: upload frame %u: %s: dropped", device.c_str(),
                            msg->frame_index, e.what());
      return;
    }
    try {
      ecar_bridge::checkImageFits(*msg, header, camera->width(), camera->height());
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: upload frame %u: %s: dropped", device.c_str(),
                            msg->frame_index, e.what());
      return;
    }
    cv::Mat image;
    try {
      ecar_bridge::decodeImage(*msg, header, &image);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(2.0, "device %s: upload frame %u: %s: dropped", device.c_str(),
                            msg->frame_index, e.what());
      return;
    }
    const ros::Time t_start = ros::Time::now();
    const auto t0 = std::chrono::steady_clock::now();
    const ecar::TrackResult result =
        graph_->track(info->id, image, msg->header.stamp.toSec(), msg->frame_index,
                      content.gravity_c, content.T_o_c);
    ecar_bridge::FrameMeta meta;
    meta.device = device;
    meta.frame_index = msg->frame_index;
    meta.stamp = msg->header.stamp;
    meta.upload_sent = msg->sent;
    meta.server_received = received;
    meta.receive_time = static_cast<float>((t_start - received).toSec());
    meta.tracking_time =
        std::chrono::duration<float>(std::chrono::steady_clock::now() - t0).count();
    meta.reset = content.reset;
    meta.cpu_time = static_cast<float>((ecar::threadCpuMs() - cpu_start) / 1000.0);
    if (!result.message.empty()) {
      NODELET_DEBUG("device %s: frame %u: %s", device.c_str(), msg->frame_index,
                    result.message.c_str());
    }
    tracked_pub_.publish(
        boost::make_shared<ecar_msgs::TrackedFrame>(ecar_bridge::toMsg(result, meta)));
  }

  ServerConfig config_;
  std::shared_ptr<ecar::GlobalGraph> graph_;
  std::unique_ptr<DeviceWorkQueue> pool_;
  ros::Publisher tracked_pub_;
  std::mutex mutex_;  // guards subscribers_
  std::map<std::string, ros::Subscriber> subscribers_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::TrackingNodelet, nodelet::Nodelet)
