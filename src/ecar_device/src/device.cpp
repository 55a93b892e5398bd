// Device: the camera, IMU and odometry callbacks, uploads and local graphs.
// Pacing and the connection are in device_connection.cpp, the virtual-object
// handlers in device_interaction.cpp, a light device's playback in
// device_light.cpp.
#include "ecar_device/device.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <utility>

#include <boost/make_shared.hpp>

#include <cv_bridge/cv_bridge.h>
#include <std_msgs/UInt32.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <ecar_msgs/DeviceFrame.h>
#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/RoundTripMetrics.h>
#include <ecar_msgs/Upload.h>

#include "device_internal.h"
#include "ecar_bridge/camera.h"
#include "ecar_bridge/device_messages.h"
#include "ecar_bridge/geometry.h"
#include "ecar_bridge/local_graph.h"
#include "ecar_core/common/error.h"

namespace ecar_device {
namespace {

using device_internal::kOdometryKept;
using device_internal::kWarnPeriod;

const char* stateName(ecar::TrackingState s) { return ecar::toString(s); }

ecar::UploadQualityConfig qualityConfig(const DeviceConfig& config) {
  ecar::UploadQualityConfig c;
  c.max_quality = std::clamp(config.jpeg_quality, 1, 100);
  c.min_quality = std::clamp(config.min_jpeg_quality, 1, c.max_quality);
  return c;
}

/// Runs a function once on the callback queue it is added to.
class CallOnce : public ros::CallbackInterface {
 public:
  explicit CallOnce(std::function<void()> fn) : fn_(std::move(fn)) {}
  CallResult call() override {
    fn_();
    return Success;
  }

 private:
  std::function<void()> fn_;
};

}  // namespace

Device::Device(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, const DeviceConfig& config)
    : config_(config),
      nh_(nh),
      pnh_(pnh),
      camera_frame_(config.device_id + "/camera"),
      upload_quality_(qualityConfig(config)),
      objects_(config.objects, config.device_id),
      image_transport_(nh),
      connect_nh_(nh) {
  config_.validate();
  // Conventional names until the server names others on connection: the
  // server's subscriber can connect before the first upload.
  upload_topic_ = nh_.resolveName("upload");
  local_graph_topic_ = nh_.resolveName("local_graph");
  upload_pub_ = nh_.advertise<ecar_msgs::Upload>(upload_topic_, 4);
  graph_sub_ = nh_.subscribe(local_graph_topic_, 8, &Device::onLocalGraph, this);
  interaction_topic_ = nh_.resolveName("interaction");
  interaction_pub_ = nh_.advertise<ecar_msgs::Interaction>(interaction_topic_, 50);
  touch_sub_ = nh_.subscribe("touch", 50, &Device::onTouch, this);
  result_sub_ = nh_.subscribe("interaction_result", 50, &Device::onInteractionResult, this);
  direct_objects_sub_ =
      nh_.subscribe(config_.direct_objects_topic, 100, &Device::onDirectObject, this);
  pose_pub_ = nh_.advertise<geometry_msgs::PoseStamped>("pose", 10);
  device_frame_pub_ = nh_.advertise<ecar_msgs::DeviceFrame>("device_frame", 30);
  metrics_pub_ = nh_.advertise<ecar_msgs::RoundTripMetrics>("metrics", 30);
  global_metrics_pub_ =
      nh_.advertise<ecar_msgs::RoundTripMetrics>(config_.global_metrics_topic, 30);
  ar_view_pub_ = image_transport_.advertise("ar_view", 1);
  frame_done_pub_ = nh_.advertise<std_msgs::UInt32>("frame_done", 10);
  if (config_.light.dataset.empty()) subscribeCamera();
  if (config_.pace_in_flight > 0) {
    pace_timer_ = nh_.createSteadyTimer(ros::WallDuration(0.01),
                                        [this](const ros::SteadyTimerEvent&) { onPaceTimer(); });
  }
  reconfigure_ =
      std::make_unique<dynamic_reconfigure::Server<DeviceTuningConfig>>(reconfigure_mutex_, pnh_);
  {
    DeviceTuningConfig tuning;
    tuning.every = config_.every;
    tuning.jpeg_quality = config_.jpeg_quality;
    tuning.draw_points = config_.ar_view.draw_points;
    tuning.draw_objects = config_.ar_view.draw_objects;
    tuning.draw_status = config_.ar_view.draw_status;
    std::lock_guard<boost::recursive_mutex> lock(reconfigure_mutex_);
    reconfigure_->updateConfig(tuning);
  }
  reconfigure_->setCallback(
      [this](const DeviceTuningConfig& tuning, uint32_t) { onReconfigure(tuning); });
  last_progress_ = ros::WallTime::now();
  connect_nh_.setCallbackQueue(&connect_queue_);
  connect_timer_ =
      connect_nh_.createSteadyTimer(ros::WallDuration(config_.connect_period),
                                    [this](const ros::SteadyTimerEvent&) { onConnectTimer(); });
  connect_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &connect_queue_);
  connect_spinner_->start();
  if (!config_.light.dataset.empty()) startLight();
  ROS_INFO("%s: device up (every %d, JPEG %d, sync_mode \"%s\", keyframe queue %d)",
           config_.device_id.c_str(), config_.every, config_.jpeg_quality,
           config_.sync_mode.c_str(), config_.tracker.keyframe_queue);
}

void Device::subscribeCamera() {
  info_sub_ = nh_.subscribe("camera/camera_info", 1, &Device::onCameraInfo, this);
  imu_sub_ = nh_.subscribe("imu", 50, &Device::onImu, this);
  odometry_sub_ = nh_.subscribe("odometry", 10, &Device::onOdometry, this);
  // One frame queued, as behind a camera's driver: while tracking is busy, the
  // frames that come go but the newest (the gap in header.seq is reported).
  // The transport is image_transport's (~image_transport: raw, compressed, ...).
  try {
    image_sub_ = image_transport_.subscribe(
        "camera/image_raw", 1, &Device::onImage, this,
        image_transport::TransportHints(config_.image_transport, ros::TransportHints(), pnh_));
  } catch (const image_transport::TransportLoadException& e) {
    throw ecar::Error("image_transport \"" + config_.image_transport +
                      "\" cannot be loaded (raw and compressed are installed): " + e.what());
  }
}

void Device::onReconfigure(const DeviceTuningConfig& tuning) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (tuning.every != config_.every || tuning.jpeg_quality != config_.jpeg_quality) {
    ROS_INFO("%s: uploading every %d frames at JPEG %d (was every %d, JPEG %d)",
             config_.device_id.c_str(), tuning.every, tuning.jpeg_quality, config_.every,
             config_.jpeg_quality);
  }
  config_.every = tuning.every;
  config_.jpeg_quality = tuning.jpeg_quality;
  upload_quality_.setMaxQuality(tuning.jpeg_quality);
  config_.ar_view.draw_points = tuning.draw_points;
  config_.ar_view.draw_objects = tuning.draw_objects;
  config_.ar_view.draw_status = tuning.draw_status;
}

Device::~Device() {
  reconfigure_.reset();
  connect_timer_.stop();
  if (connect_spinner_) connect_spinner_->stop();
  pace_timer_.stop();
  light_timer_.stop();
}

// ---------------------------------------------------------------- sensors

void Device::onCameraInfo(const sensor_msgs::CameraInfoConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (has_camera_info_ && msg->width == camera_info_.width && msg->height == camera_info_.height &&
      msg->K == camera_info_.K && msg->D == camera_info_.D) {
    return;
  }
  try {
    const ecar::PinholeCamera camera = ecar_bridge::fromMsg(*msg);
    if (has_camera_info_) {
      ROS_WARN("%s: camera_info changed: local map dropped, reconnecting",
               config_.device_id.c_str());
      connected_ = false;
    }
    tracker_ = std::make_unique<ecar::DeviceTracker>(camera, config_.tracker);
    camera_ = camera;
    camera_info_ = *msg;
    has_camera_info_ = true;
    pending_.clear();
    // Connect now, not at the next tick: frames played before the connection
    // are not uploaded.
    if (!connect_requested_) {
      connect_requested_ = true;
      connect_queue_.addCallback(boost::make_shared<CallOnce>([this] { onConnectTimer(); }));
    }
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: camera_info dropped: %s", config_.device_id.c_str(),
                      e.what());
  }
}

void Device::onImu(const sensor_msgs::ImuConstPtr& msg) {
  try {
    const ecar::ImuSample sample = ecar_bridge::fromMsg(*msg);
    std::lock_guard<std::mutex> lock(mutex_);
    gravity_c_ = sample.acc_c;
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: imu dropped: %s", config_.device_id.c_str(), e.what());
  }
}

void Device::onOdometry(const geometry_msgs::PoseStampedConstPtr& msg) {
  try {
    const ecar::SE3 T_o_c = ecar_bridge::fromMsg(msg->pose, "odometry");
    std::lock_guard<std::mutex> lock(mutex_);
    odometry_.emplace_back(msg->header.stamp, T_o_c);
    if (odometry_.size() > kOdometryKept) odometry_.pop_front();
    odometry_seen_ = true;
    if (held_upload_ && held_upload_->header.stamp == msg->header.stamp) {
      held_upload_->odometry = ecar_bridge::toMsg(T_o_c);
      held_upload_->has_odometry = true;
      publishHeldUpload();
    }
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: odometry dropped: %s", config_.device_id.c_str(), e.what());
  }
}

// ---------------------------------------------------------------- frames

void Device::onImage(const sensor_msgs::ImageConstPtr& msg) {
  const uint32_t seq = msg->header.seq;
  std::lock_guard<std::mutex> lock(mutex_);
  if (!tracker_) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: image dropped: no camera_info yet",
                      config_.device_id.c_str());
    frameDone(seq);
    return;
  }
  cv::Mat gray;
  try {
    gray = ecar_bridge::grayOf(msg);
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: image dropped: %s", config_.device_id.c_str(), e.what());
    frameDone(seq);
    return;
  }
  if (gray.cols != static_cast<int>(camera_info_.width) ||
      gray.rows != static_cast<int>(camera_info_.height)) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: image dropped: size %dx%d, camera_info says %ux%u",
                      config_.device_id.c_str(), gray.cols, gray.rows, camera_info_.width,
                      camera_info_.height);
    frameDone(seq);
    return;
  }
  if (has_last_seq_ && seq > last_seq_ + 1) {
    ROS_WARN_THROTTLE(kWarnPeriod,
                      "%s: falling behind the camera: %u frames skipped before frame %u",
                      config_.device_id.c_str(), seq - last_seq_ - 1, seq);
  }
  has_last_seq_ = true;
  last_seq_ = seq;
  if (held_upload_) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: no odometry with the stamp of frame %u: uploaded without",
                      config_.device_id.c_str(), held_upload_->frame_index);
    publishHeldUpload();
  }
  const ros::Time now = ros::Time::now();
  prunePending(now);

  bool uploaded = false;
  if (connected_ && upload_schedule_.due(seq, config_.every) && !uploadsBlocked()) {
    // The topics are joined on our connection: until they are, an upload or
    // its graph would go nowhere and hold the pacing for nothing.
    if (linkedToServer()) {
      upload(gray, msg->header);
      uploaded = true;
      upload_schedule_.uploaded(seq, config_.every);
    } else {
      upload_due_since_progress_ = true;  // a server gone for good: connect again
      ROS_WARN_THROTTLE(kWarnPeriod,
                        "%s: the server is not yet subscribed to %s or publishing %s: frame %u "
                        "not uploaded",
                        config_.device_id.c_str(), upload_topic_.c_str(),
                        local_graph_topic_.c_str(), seq);
    }
  }
  const ecar::DeviceTrackResult& r = tracker_->track(gray, msg->header.stamp.toSec(), seq);
  if (uploaded && !pending_.empty() && pending_.back().frame_index == seq) {
    pending_.back().tracking_time = static_cast<float>(r.total_ms / 1000.0);
    pending_.back().tracking_cpu_time = static_cast<float>(r.cpu_ms / 1000.0);
  }
  publishResult(msg->header, gray, r, uploaded);
  const double behind = (ros::Time::now() - msg->header.stamp).toSec();
  if (behind > 0.5) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: falling behind the camera: frame %u done %.2f s late",
                      config_.device_id.c_str(), seq, behind);
  }
  frameDone(seq);
}

void Device::upload(const cv::Mat& gray, const std_msgs::Header& header,
                    const std::vector<uint8_t>* jpeg) {
  ecar_bridge::UploadContent c;
  c.device_id = config_.device_id;
  c.camera_frame = camera_frame_;
  c.frame_index = header.seq;
  c.stamp = header.stamp;
  int quality = upload_quality_.next();
  const bool cached = jpeg && quality >= light_cache_quality_;
  if (cached) {
    c.jpeg = *jpeg;
  } else {
    cv::imencode(".jpg", gray, jpeg_, {cv::IMWRITE_JPEG_QUALITY, quality});
    if (upload_quality_.budget() > 0.0 && !upload_quality_.hasSize()) {
      // The first upload within a budget: its size at this quality tells the
      // quality that fits.
      upload_quality_.observe(quality, jpeg_.size());
      if (upload_quality_.next() < quality) {
        quality = upload_quality_.next();
        cv::imencode(".jpg", gray, jpeg_, {cv::IMWRITE_JPEG_QUALITY, quality});
      }
    }
    c.jpeg = jpeg_;
  }
  c.gravity_c = gravity_c_;
  for (auto it = odometry_.rbegin(); it != odometry_.rend(); ++it) {
    if (it->first == header.stamp) {
      c.T_o_c = it->second;
      break;
    }
  }
  c.last_graph_frame = last_graph_frame_;
  c.reset = reset_next_;
  if (reset_next_) last_reset_frame_ = c.frame_index;
  reset_next_ = false;
  Pending p;
  p.frame_index = c.frame_index;
  p.jpeg_quality = cached ? light_cache_quality_ : quality;
  p.upload_budget = static_cast<uint32_t>(upload_quality_.budget());
  if (!free_images_.empty()) {
    p.gray = std::move(free_images_.back());
    free_images_.pop_back();
  }
  gray.copyTo(p.gray);
  if (static_cast<int>(pending_.size()) >= config_.max_pending) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: %zu uploads without a local graph: frame %u forgotten",
                      config_.device_id.c_str(), pending_.size(), pending_.front().frame_index);
    free_images_.push_back(std::move(pending_.front().gray));
    pending_.pop_front();
  }
  p.sent = ros::Time::now();
  pending_.push_back(std::move(p));
  held_upload_ = ecar_bridge::toMsg(c);
  // A device with odometry whose pose for this stamp has not arrived yet
  // (published after the image) holds the upload until it comes.
  if (c.T_o_c || !odometry_seen_) publishHeldUpload();
}

void Device::publishHeldUpload() {
  if (!held_upload_) return;
  ecar_msgs::Upload& msg = *held_upload_;
  msg.sent = ros::Time::now();
  msg.session = session_;
  for (auto it = pending_.rbegin(); it != pending_.rend(); ++it) {
    if (it->frame_index != msg.frame_index) continue;
    it->sent = msg.sent;
    it->bytes_up = ecar_bridge::wireBytes(msg);
    upload_quality_.sent(it->jpeg_quality, it->bytes_up, ros::WallTime::now().toSec());
    break;
  }
  upload_pub_.publish(msg);
  held_upload_.reset();
  upload_due_since_progress_ = true;
}

void Device::publishResult(const std_msgs::Header& image_header, const cv::Mat& gray,
                           const ecar::DeviceTrackResult& r, bool uploaded) {
  ecar_msgs::DeviceFrame frame = ecar_bridge::toMsg(
      config_.device_id, image_header.stamp, config_.map_frame, r,
      static_cast<uint32_t>(tracker_->numKeyFrames()), static_cast<uint32_t>(tracker_->numPoints()),
      uploaded, objects_.objects());
  frame.map_id = map_id_;  // the map of the graphs tracked against
  frame.object_received.reserve(frame.object_ids.size());
  for (size_t i = 0; i < frame.object_ids.size(); ++i) {
    const auto it = object_arrival_.find(frame.object_ids[i]);
    frame.object_received.push_back(it != object_arrival_.end() &&
                                            it->second.first == frame.object_versions[i]
                                        ? it->second.second
                                        : ros::Time());
  }
  device_frame_pub_.publish(frame);
  std_msgs::Header header;
  header.stamp = image_header.stamp;
  header.frame_id = config_.map_frame;
  tracking_ok_ = r.state == ecar::TrackingState::kOk;
  last_image_stamp_ = image_header.stamp;
  if (tracking_ok_) {
    T_w_c_ = r.T_w_c;
    pose_stamp_ = image_header.stamp;
  }
  if (r.state == ecar::TrackingState::kOk) {
    geometry_msgs::PoseStamped pose;
    pose.header = header;
    pose.pose = ecar_bridge::toMsg(r.T_w_c);
    pose_pub_.publish(pose);
    if (config_.publish_tf)
      tf_.sendTransform(ecar_bridge::toTransformMsg(r.T_w_c, header, camera_frame_));
  }
  if (ar_view_pub_.getNumSubscribers() == 0) return;
  cv::cvtColor(gray, ar_image_, cv::COLOR_GRAY2BGR);
  if (config_.ar_view.draw_points) {
    for (const cv::Point2f& p : r.tracked_pixels) {
      cv::circle(ar_image_, p, 3, cv::Scalar(0, 255, 0), 1, cv::LINE_AA);
    }
  }
  // VOs at the pose touches use (this frame's when tracked), unless it is stale.
  if (config_.ar_view.draw_objects && T_w_c_ &&
      (image_header.stamp - pose_stamp_).toSec() <= config_.touch_pose_timeout) {
    drawObjects(*T_w_c_);
  }
  if (config_.ar_view.draw_status) drawStatus(r);
  std_msgs::Header view_header = image_header;
  view_header.frame_id = camera_frame_;
  ar_view_pub_.publish(cv_bridge::CvImage(view_header, "bgr8", ar_image_).toImageMsg());
}

void Device::drawStatus(const ecar::DeviceTrackResult& r) {
  char status[200];
  std::snprintf(status, sizeof(status),
                "%s  frame %u  %s  %d pts  %zu kf  %zu map pts  %zu VOs  %.1f ms%s",
                config_.device_id.c_str(), r.frame_index, stateName(r.state), r.inliers,
                tracker_->numKeyFrames(), tracker_->numPoints(), objects_.objects().size(),
                r.total_ms, connected_ ? "" : "  (not connected)");
  cv::rectangle(ar_image_, cv::Rect(0, 0, ar_image_.cols, 22), cv::Scalar(0, 0, 0), cv::FILLED);
  cv::putText(ar_image_, status, cv::Point(6, 16), cv::FONT_HERSHEY_SIMPLEX, 0.45,
              r.state == ecar::TrackingState::kOk ? cv::Scalar(0, 255, 0) : cv::Scalar(0, 0, 255),
              1, cv::LINE_AA);
}

// ---------------------------------------------------------------- local graphs

void Device::onLocalGraph(const ecar_msgs::LocalGraphConstPtr& msg) {
  const ros::Time received = ros::Time::now();
  std::lock_guard<std::mutex> lock(mutex_);
  const char* id = config_.device_id.c_str();
  if (msg->device_id != config_.device_id) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: local graph dropped: device_id \"%s\" is another device",
                      id, msg->device_id.c_str());
    return;
  }
  if (!tracker_) return;
  ecar::LocalGraph graph;
  std::vector<std::string> skipped;
  try {
    graph = ecar_bridge::fromMsg(*msg, &skipped);
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: local graph for frame %u dropped: %s", id, msg->frame_index,
                      e.what());
    return;
  }
  for (const std::string& why : skipped) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: local graph of frame %u: skipped %s", id, msg->frame_index,
                      why.c_str());
  }
  const bool ok_status = ecar::tracked(graph.status);
  const bool edgeslam = graph.mode == ecar::SyncMode::kEdgeSlam;
  auto it = std::find_if(pending_.begin(), pending_.end(),
                         [&](const Pending& p) { return p.frame_index == msg->frame_index; });
  if (it == pending_.end()) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: local graph dropped: frame %u is not an upload in flight",
                      id, msg->frame_index);
    return;
  }
  if (!has_epoch_ || msg->map_epoch != epoch_) {
    changeEpoch(msg->map_epoch, "a local graph");
  } else if (msg->map_id != 0 && map_id_ != 0 && msg->map_id != map_id_) {
    // Our map was merged into another: everything comes again in its
    // coordinates (this graph brings the pose, points, planes and objects).
    ROS_INFO("%s: server map %u -> %u (merged): local map dropped", id, map_id_, msg->map_id);
    dropLocalMap();
    reset_next_ = false;  // the server forgot what we held too: this graph has it all
  }
  if (msg->map_id != 0) map_id_ = msg->map_id;
  upload_quality_.setBudget(msg->upload_budget);
  // Logged when the quality moves by 10 or more, or back to ~jpeg_quality.
  const int quality = upload_quality_.next();
  if (reported_quality_ == 0) reported_quality_ = config_.jpeg_quality;
  if (quality != reported_quality_ &&
      (std::abs(quality - reported_quality_) >= 10 || quality == config_.jpeg_quality)) {
    const std::string budget =
        msg->upload_budget > 0 ? std::to_string(msg->upload_budget / 1000) + " kB/s" : "none";
    ROS_INFO("%s: uploading at JPEG %d (budget %s, %.1f uploads/s, %.1f kB each%s)", id, quality,
             budget.c_str(), upload_quality_.rate(),
             upload_quality_.predictedBytes(quality) / 1000.0,
             upload_quality_.overBudget() ? "; over the budget at ~min_jpeg_quality" : "");
    reported_quality_ = quality;
  }
  if (!graph.planes.empty() || !graph.objects.empty() || !graph.removed_planes.empty()) {
    objects_.applyGraph(graph.planes, graph.objects, graph.removed_planes);
    noteObjectArrivals();
  }
  if (ok_status && (!T_w_c_ || msg->header.stamp > pose_stamp_)) {
    T_w_c_ = graph.T_w_c;
    pose_stamp_ = msg->header.stamp;
  }
  last_graph_frame_ = msg->frame_index;
  last_progress_ = ros::WallTime::now();
  upload_due_since_progress_ = false;

  ecar_bridge::RoundTrip trip;
  trip.device_id = config_.device_id;
  trip.bytes_up = it->bytes_up;
  trip.sent = it->sent;
  trip.received = received;
  trip.tracking_time_device = it->tracking_time;
  trip.tracking_cpu_time_device = it->tracking_cpu_time;
  trip.jpeg_quality = static_cast<uint8_t>(std::clamp(it->jpeg_quality, 0, 100));
  trip.upload_budget = it->upload_budget;
  const ecar_msgs::RoundTripMetrics metrics = ecar_bridge::toMsg(*msg, trip);
  metrics_pub_.publish(metrics);
  global_metrics_pub_.publish(metrics);

  if (ok_status && edgeslam) {
    tracker_->replaceLocalMap(graph);
  } else if (ok_status) {
    const ecar::GraphUpdate u = tracker_->addLocalGraph(it->gray, graph);
    if (!u.queue.missing.empty() && msg->frame_index >= last_reset_frame_ && !reset_next_) {
      ROS_WARN_THROTTLE(kWarnPeriod,
                        "%s: local graph of frame %u named %zu points without a position: asking "
                        "the server for every position again",
                        id, msg->frame_index, u.queue.missing.size());
      reset_next_ = true;
    }
  }
  free_images_.push_back(std::move(it->gray));
  pending_.erase(it);
  releaseFrameDone(false);
}

void Device::changeEpoch(uint32_t epoch, const char* why) {
  if (has_epoch_) {
    ROS_INFO("%s: map epoch %u -> %u (from %s): local map dropped", config_.device_id.c_str(),
             epoch_, epoch, why);
    dropLocalMap();
  }
  has_epoch_ = true;
  epoch_ = epoch;
  map_id_ = 0;
}

void Device::dropLocalMap() {
  if (tracker_) tracker_->clear();
  objects_.clear();
  object_arrival_.clear();
  T_w_c_.reset();
  reset_next_ = true;
}

void Device::prunePending(const ros::Time& now) {
  while (!pending_.empty() && (now - pending_.front().sent).toSec() > config_.reconnect_timeout) {
    free_images_.push_back(std::move(pending_.front().gray));
    pending_.pop_front();
  }
}

}  // namespace ecar_device
