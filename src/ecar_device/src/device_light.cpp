// A light device (~light/dataset), as the paper's device simulators: no camera
// topics, and no image encoding unless an upload budget asks for a quality
// below the cache's (the cached image is then encoded again at that quality,
// about 2 ms). It plays the uploads of a dataset, encoded once into an
// ecar::UploadCache, at the dataset's upload rate (times ~light/rate),
// uploads each exactly as a full device does, and tracks only those frames, so
// its keyframe queue is built from the local graphs as on a full device. The
// dataset's scripted touches are replayed at the uploaded frames (those of the
// frames in between at the next one), so light devices draw VOs too. Many fit
// in one nodelet manager.
#include <std_msgs/Bool.h>
#include <std_msgs/Time.h>
#include <opencv2/imgcodecs.hpp>

#include <boost/make_shared.hpp>

#include "device_internal.h"
#include "ecar_bridge/camera.h"
#include "ecar_core/common/error.h"
#include "ecar_device/device.h"

namespace ecar_device {

using device_internal::kOdometryKept;
using device_internal::kWarnPeriod;

namespace {
constexpr double kTicksPerUpload = 10.0;

/// A fraction in [0, 1) fixed by the device's name (FNV-1a): its upload phase.
double phaseOf(const std::string& name) {
  uint32_t h = 2166136261u;
  for (const unsigned char c : name) h = (h ^ c) * 16777619u;
  return static_cast<double>(h % 1000u) / 1000.0;
}
}  // namespace

void Device::startLight() {
  const DeviceConfig::Light& light = config_.light;
  const ros::WallTime started = ros::WallTime::now();
  const ecar::Dataset dataset = ecar::Dataset::open(light.dataset);
  ecar::UploadCacheConfig cache;
  cache.every = config_.every;
  cache.jpeg_quality = config_.jpeg_quality;
  cache.max_frames = static_cast<size_t>(light.max_frames);
  cache.dir = light.cache_dir;
  light_cache_ = ecar::UploadCache::build(dataset, cache);
  light_cache_quality_ = cache.jpeg_quality;
  const auto& uploads = light_cache_->uploads();
  if (uploads.empty()) throw ecar::Error("~light/dataset: " + light.dataset + " has no frames");
  light_touches_ = dataset.touches();
  // The camera, as a camera_info would bring it (this also connects).
  onCameraInfo(boost::make_shared<sensor_msgs::CameraInfo>(
      ecar_bridge::toMsg(dataset.camera(), std_msgs::Header())));
  const double span = uploads.back().timestamp - uploads.front().timestamp;
  const double period =
      (uploads.size() > 1 ? span / static_cast<double>(uploads.size() - 1) : 0.1) / light.rate;
  // As a player in this namespace would (DeviceTopics' names are relative).
  light_finished_pub_ = nh_.advertise<std_msgs::Bool>("player/finished", 1, /*latch=*/true);
  if (!light.start_topic.empty()) {
    light_start_sub_ = nh_.subscribe<std_msgs::Time>(light.start_topic, 1,
                                                     [this](const std_msgs::TimeConstPtr& msg) {
                                                       std::lock_guard<std::mutex> lock(mutex_);
                                                       light_start_ = msg->data;
                                                     });
  }
  light_period_ = ros::WallDuration(period);
  upload_quality_.setNominalRate(1.0 / period);
  upload_quality_.observe(light_cache_quality_, uploads.front().jpeg.size());
  // Ticks a tenth of the period: the uploads keep their phase within that.
  light_timer_ = nh_.createSteadyTimer(ros::WallDuration(period / kTicksPerUpload),
                                       [this](const ros::SteadyTimerEvent&) { onLightTimer(); });
  ROS_INFO(
      "%s: light device on %s: %zu uploads every %.1f ms, %zu scripted touches (%zu encoded "
      "now, %.1f MB in %s, %.2f s)",
      config_.device_id.c_str(), light.dataset.c_str(), uploads.size(), 1000.0 * period,
      light_touches_.size(), light_cache_->encoded(), light_cache_->bytes() / 1e6,
      light_cache_->dir().c_str(), (ros::WallTime::now() - started).toSec());
}

void Device::onLightTimer() {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto& uploads = light_cache_->uploads();
  if (light_next_ >= uploads.size()) return;
  // Playback starts once the server has joined our topics and someone listens
  // to what we measure (or ~light/wait_subscribers later), as a player waits.
  if (!light_started_) {
    // The server may drop us (device_timeout) while we wait to play, e.g.
    // while the other light devices encode their caches: unlinked, we count
    // as a device with an upload due, so the connection thread connects again
    // after ~reconnect_timeout (linked, nothing is due: no reconnection).
    upload_due_since_progress_ = connected_ && !linkedToServer();
    if (!tracker_ || !connected_ || !linkedToServer()) return;
    const ros::WallTime now = ros::WallTime::now();
    if (light_joined_.isZero()) light_joined_ = now;
    const bool listened =
        device_frame_pub_.getNumSubscribers() > 0 && global_metrics_pub_.getNumSubscribers() > 0;
    if (!listened && (now - light_joined_).toSec() < config_.light.wait_subscribers) return;
    if (!config_.light.start_topic.empty() && (!light_start_ || ros::Time::now() < *light_start_)) {
      return;
    }
    light_started_ = true;
    // Started together on the start topic: each device at its own phase.
    const double phase = config_.light.start_topic.empty() ? 0.0 : phaseOf(config_.device_id);
    light_next_due_ = now + ros::WallDuration(phase * light_period_.toSec());
    ROS_INFO("%s: joined the server: playing%s, phase %.0f%% of the upload period",
             config_.device_id.c_str(),
             listened ? "" : " (nobody subscribes device_frame and the metrics yet)",
             100.0 * phase);
  }
  const ros::WallTime now = ros::WallTime::now();
  if (now < light_next_due_) return;
  // On schedule; after a stall, go on from now rather than catch up in a burst.
  light_next_due_ =
      now - light_next_due_ > light_period_ ? now + light_period_ : light_next_due_ + light_period_;
  const bool forwards = !light_backwards_;
  const ecar::CachedUpload& u = uploads[light_next_];
  advanceLight(uploads.size());
  std_msgs::Header header;
  // The dataset's frame index on the first pass (what the ground truth is
  // indexed by); on the passes of a loop, on from there, so that frame
  // numbers never repeat.
  light_seq_ = light_passes_ == 0 ? static_cast<uint32_t>(u.index)
                                  : light_seq_ + static_cast<uint32_t>(config_.every);
  header.seq = light_seq_;
  header.stamp = ros::Time::now();
  header.frame_id = camera_frame_;
  cv::imdecode(u.jpeg, cv::IMREAD_GRAYSCALE, &light_gray_);
  if (light_gray_.cols != static_cast<int>(camera_info_.width) ||
      light_gray_.rows != static_cast<int>(camera_info_.height)) {
    ROS_WARN_THROTTLE(kWarnPeriod,
                      "%s: cached upload of frame %zu in %s is not a %ux%u JPEG: "
                      "skipped",
                      config_.device_id.c_str(), u.index, light_cache_->dir().c_str(),
                      camera_info_.width, camera_info_.height);
  } else if (uploadsBlocked()) {
    ++light_blocked_;  // as a full device's due upload waits: this one goes
  } else {
    if (u.gravity_c) gravity_c_ = *u.gravity_c;
    if (u.T_o_c) {
      odometry_.emplace_back(header.stamp, *u.T_o_c);
      if (odometry_.size() > kOdometryKept) odometry_.pop_front();
    }
    prunePending(header.stamp);
    const bool uploaded = connected_ && linkedToServer();
    if (uploaded) {
      upload(light_gray_, header, &u.jpeg);
    } else {
      upload_due_since_progress_ = true;  // a server gone for good: connect again
    }
    const ecar::DeviceTrackResult& r =
        tracker_->track(light_gray_, header.stamp.toSec(), header.seq);
    if (uploaded && !pending_.empty() && pending_.back().frame_index == header.seq) {
      pending_.back().tracking_time = static_cast<float>(r.total_ms / 1000.0);
      pending_.back().tracking_cpu_time = static_cast<float>(r.cpu_ms / 1000.0);
    }
    publishResult(header, light_gray_, r, uploaded);
    // The touches scripted up to this frame, at its pose (forwards only).
    for (; forwards && light_next_touch_ < light_touches_.size() &&
           light_touches_[light_next_touch_].frame <= u.index;
         ++light_next_touch_) {
      applyTouch(light_touches_[light_next_touch_], header.stamp);
    }
  }
  if (!config_.light.loop && light_next_ == uploads.size()) {
    std_msgs::Bool finished;
    finished.data = true;
    light_finished_pub_.publish(finished);
    ROS_INFO("%s: played the %zu uploads of %s (%zu not sent: %d in flight)",
             config_.device_id.c_str(), uploads.size(), config_.light.dataset.c_str(),
             light_blocked_, config_.max_in_flight);
  }
}

void Device::advanceLight(size_t count) {
  if (!config_.light.loop) {
    ++light_next_;
    return;
  }
  // Back and forth: ... n-2, n-1, n-2, ... 1, 0, 1, ...
  const size_t last = count - 1;
  if (!light_backwards_ && light_next_ < last) {
    ++light_next_;
  } else if (light_backwards_ && light_next_ > 0) {
    --light_next_;
  } else {
    light_backwards_ = !light_backwards_;
    light_next_ = count < 2 ? 0 : (light_backwards_ ? last - 1 : 1);
    if (!light_backwards_) light_next_touch_ = 0;  // the touches again
    ++light_passes_;
    ROS_INFO("%s: looping: pass %zu (%s)", config_.device_id.c_str(), light_passes_ + 1,
             light_backwards_ ? "backwards" : "forwards");
  }
}

}  // namespace ecar_device
