// Device: pacing of a dataset player (frame_done), the device's congestion
// control (max_in_flight) and the connection to the server (connect,
// reconnect). The rest of Device is in device.cpp.
#include <algorithm>

#include <ecar_msgs/Connect.h>
#include <ecar_msgs/Interaction.h>
#include <std_msgs/UInt32.h>

#include "device_internal.h"
#include "ecar_device/device.h"

namespace ecar_device {
namespace {

using device_internal::kWarnPeriod;

/// Times ~reconnect_timeout without a graph after which a device connects
/// again although the server still joins its topics.
constexpr double kLinkedSilenceFactor = 5.0;

}  // namespace

// ---------------------------------------------------------------- pacing

bool Device::uploadsBlocked() const {
  if (config_.max_in_flight <= 0) return false;
  const ros::Time now = ros::Time::now();
  return std::count_if(pending_.begin(), pending_.end(), [&](const Pending& p) {
           return (now - p.sent).toSec() < config_.reconnect_timeout;
         }) >= config_.max_in_flight;
}

bool Device::linkedToServer() const {
  return upload_pub_.getNumSubscribers() > 0 && graph_sub_.getNumPublishers() > 0;
}

bool Device::holdsFrames() const {
  if (config_.pace_in_flight <= 0) return false;
  if (connect_requested_) return true;
  // An upload whose graph is later than ~pace_timeout is lost (or the server
  // is far behind): it no longer holds the camera.
  const ros::Time now = ros::Time::now();
  const int in_flight =
      static_cast<int>(std::count_if(pending_.begin(), pending_.end(), [&](const Pending& p) {
        return (now - p.sent).toSec() < config_.pace_timeout;
      }));
  return in_flight >= config_.pace_in_flight;
}

void Device::frameDone(uint32_t seq) {
  if (!holdsFrames()) {
    held_done_.reset();
    std_msgs::UInt32 done;
    done.data = seq;
    frame_done_pub_.publish(done);
    return;
  }
  if (!held_done_) held_since_ = ros::WallTime::now();
  held_done_ = seq;
}

void Device::releaseFrameDone(bool force) {
  if (!held_done_) return;
  if (!force && holdsFrames()) return;
  std_msgs::UInt32 done;
  done.data = *held_done_;
  held_done_.reset();
  frame_done_pub_.publish(done);
}

void Device::onPaceTimer() {
  std::lock_guard<std::mutex> lock(mutex_);
  prunePending(ros::Time::now());
  const bool timed_out =
      held_done_ && (ros::WallTime::now() - held_since_).toSec() >= config_.pace_timeout;
  // The server joins our topics on our connection: until it has, an upload or
  // its graph would go nowhere.
  if (connect_requested_ && connected_ && (timed_out || linkedToServer())) {
    connect_requested_ = false;
  }
  releaseFrameDone(timed_out);
}

// ---------------------------------------------------------------- connection

void Device::onConnectTimer() {
  connect();
  std::lock_guard<std::mutex> lock(mutex_);
  // When paced and connected, the frames wait on for the server's subscription
  // to our uploads (onPaceTimer).
  if (connect_requested_ && (!connected_ || config_.pace_in_flight <= 0)) {
    connect_requested_ = false;
    releaseFrameDone(true);
  }
}

void Device::connect() {
  ecar_msgs::Connect srv;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!has_camera_info_) return;
    if (connected_) {
      const double silent = (ros::WallTime::now() - last_progress_).toSec();
      if (!upload_due_since_progress_ || silent < config_.reconnect_timeout) return;
      // A server that still joins our topics is alive and knows us: its graphs
      // are late (a saturated link, a busy server), and connecting again would
      // only reset our tracking there. Only a much longer silence counts then.
      const bool linked = linkedToServer();
      if (linked && silent < kLinkedSilenceFactor * config_.reconnect_timeout) return;
      ROS_WARN("%s: no local graph for %.1f s while uploading%s: connecting again",
               config_.device_id.c_str(), silent,
               linked ? "" : " and the server no longer joins our topics");
      connected_ = false;
    }
    srv.request.device_id = config_.device_id;
    srv.request.camera_info = camera_info_;
    srv.request.sync_mode = config_.sync_mode;
    srv.request.keyframe_queue = static_cast<uint32_t>(config_.tracker.keyframe_queue);
    srv.request.session = session_;  // ours, if the server still holds our connection
  }
  if (!ros::service::exists(config_.connect_service, false)) {
    ROS_INFO_THROTTLE(10.0, "%s: waiting for %s", config_.device_id.c_str(),
                      config_.connect_service.c_str());
    return;
  }
  if (!ros::service::call(config_.connect_service, srv)) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: %s failed; retrying", config_.device_id.c_str(),
                      config_.connect_service.c_str());
    return;
  }
  if (!srv.response.accepted) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: connection refused: %s; retrying",
                      config_.device_id.c_str(), srv.response.message.c_str());
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  session_ = srv.response.session;
  upload_quality_.setBudget(srv.response.upload_budget);
  if (!srv.response.upload_topic.empty() && srv.response.upload_topic != upload_topic_) {
    upload_topic_ = srv.response.upload_topic;
    upload_pub_ = nh_.advertise<ecar_msgs::Upload>(upload_topic_, 4);
  }
  if (!srv.response.local_graph_topic.empty() &&
      srv.response.local_graph_topic != local_graph_topic_) {
    local_graph_topic_ = srv.response.local_graph_topic;
    graph_sub_ = nh_.subscribe(local_graph_topic_, 8, &Device::onLocalGraph, this);
  }
  if (!srv.response.interaction_topic.empty() &&
      srv.response.interaction_topic != interaction_topic_) {
    interaction_topic_ = srv.response.interaction_topic;
    interaction_pub_ = nh_.advertise<ecar_msgs::Interaction>(interaction_topic_, 50);
  }
  if (!has_epoch_ || srv.response.map_epoch != epoch_) {
    changeEpoch(srv.response.map_epoch, "the connection");
  }
  // Uploads sent before are not answered by a restarted server.
  for (auto& p : pending_) free_images_.push_back(std::move(p.gray));
  pending_.clear();
  held_upload_.reset();
  releaseFrameDone(true);
  connected_ = true;
  reset_next_ = true;
  last_progress_ = ros::WallTime::now();
  upload_due_since_progress_ = false;
  ROS_INFO("%s: connected (%s), map epoch %u, uploading on %s", config_.device_id.c_str(),
           srv.response.message.c_str(), epoch_, upload_topic_.c_str());
}

}  // namespace ecar_device
