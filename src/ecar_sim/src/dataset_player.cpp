#include "dataset_player.h"

#include "ecar_bridge/camera.h"
#include "ecar_bridge/geometry.h"
#include "ecar_bridge/objects.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <thread>
#include <utility>

#include <geometry_msgs/PoseStamped.h>
#include <sensor_msgs/Imu.h>
#include <std_msgs/Bool.h>
#include <std_msgs/Time.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"

namespace ecar_sim {
namespace {

/// Longest sleep between two checks of ros::ok() and the callback queue.
constexpr std::chrono::milliseconds kPollPeriod(5);

/// cv::imread flags of the played images: as stored, or gray (~grayscale).
int imreadFlags(bool grayscale) {
  return grayscale ? cv::IMREAD_GRAYSCALE : cv::IMREAD_ANYCOLOR | cv::IMREAD_ANYDEPTH;
}

/// An IMU sample up to this much after a frame's stamp goes with that frame:
/// dataset lists round stamps differently (rgb.txt to 1 us, imu.txt to 1 ns),
/// so the sample taken with an image can read a few hundred ns later.
constexpr double kStampToleranceS = 1e-6;

/// Reads ~key into *value when it is set; throws ecar::Error naming the key
/// when it is set with a type getParam cannot convert to T.
template <typename T>
bool readParam(const ros::NodeHandle& pnh, const std::string& key, const char* type_name,
               T* value) {
  if (!pnh.hasParam(key)) return false;
  if (!pnh.getParam(key, *value)) {
    throw ecar::Error("~" + key + ": expected " + type_name);
  }
  return true;
}

/// getParam(int) silently rounds a double (1.5 -> 2): require an integer.
template <>
bool readParam<int>(const ros::NodeHandle& pnh, const std::string& key, const char* type_name,
                    int* value) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(key, v)) return false;
  if (v.getType() != XmlRpc::XmlRpcValue::TypeInt) {
    throw ecar::Error("~" + key + ": expected " + type_name);
  }
  *value = static_cast<int>(v);
  return true;
}

bool isDeviceName(const std::string& name) {
  if (name.empty() || !std::isalpha(static_cast<unsigned char>(name[0]))) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
  });
}

/// Resolves symlinks (ecar::Dataset normalises ".." lexically, which is wrong
/// under a symlinked package folder); leaves a path that does not exist as is,
/// so that Dataset::open reports it.
std::string resolvePath(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path resolved = std::filesystem::canonical(path, ec);
  return ec ? path : resolved.string();
}

ecar::Dataset openDataset(const DatasetPlayerConfig& config) {
  config.validate();
  return ecar::Dataset::open(resolvePath(config.dataset), config.format,
                             config.camera_file.empty() ? "" : resolvePath(config.camera_file));
}

}  // namespace

void DatasetPlayerConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) {
    throw ecar::Error("~" + key + ": " + why);
  };
  if (dataset.empty()) fail("dataset", "is required (the dataset folder)");
  if (!isDeviceName(device)) {
    fail("device", "\"" + device + "\" is not a device name (a letter, then letters, digits, _)");
  }
  if (world_frame.empty() || world_frame.front() == '/') {
    fail("world_frame", "must be a non-empty frame id without a leading slash");
  }
  if (!std::isfinite(rate) || rate < 0.0) fail("rate", "must be >= 0 (0 = as fast as possible)");
  if (!std::isfinite(ack_timeout) || ack_timeout <= 0.0) fail("ack_timeout", "must be > 0 s");
  if (!std::isfinite(start_delay) || start_delay < 0.0) fail("start_delay", "must be >= 0 s");
  if (!std::isfinite(wait_subscribers) || wait_subscribers < 0.0) {
    fail("wait_subscribers", "must be >= 0 s");
  }
  if (!std::isfinite(touch_settle) || touch_settle < 0.0) fail("touch_settle", "must be >= 0 s");
  if (first_frame < 0) fail("first_frame", "must be >= 0");
  if (max_frames < 0) fail("max_frames", "must be >= 0 (0 = all frames)");
  if (preload_mb < 0) fail("preload_mb", "must be >= 0 (0 = decode each frame when due)");
}

DatasetPlayerConfig loadDatasetPlayerConfig(const ros::NodeHandle& pnh) {
  DatasetPlayerConfig c;
  if (!readParam(pnh, "dataset", "a string", &c.dataset)) {
    throw ecar::Error("~dataset: is required (the dataset folder)");
  }
  std::string format = ecar::toString(c.format);
  readParam(pnh, "format", "a string", &format);
  try {
    c.format = ecar::parseDatasetFormat(format);
  } catch (const ecar::Error& e) {
    throw ecar::Error(std::string("~format: ") + e.what());
  }
  readParam(pnh, "camera_file", "a string", &c.camera_file);
  readParam(pnh, "device", "a string", &c.device);
  readParam(pnh, "world_frame", "a string", &c.world_frame);
  readParam(pnh, "rate", "a number", &c.rate);
  readParam(pnh, "pace_by_consumer", "a bool", &c.pace_by_consumer);
  readParam(pnh, "ack_timeout", "a number", &c.ack_timeout);
  readParam(pnh, "start_delay", "a number", &c.start_delay);
  readParam(pnh, "wait_subscribers", "a number", &c.wait_subscribers);
  readParam(pnh, "touch_settle", "a number", &c.touch_settle);
  readParam(pnh, "first_frame", "an integer", &c.first_frame);
  readParam(pnh, "max_frames", "an integer", &c.max_frames);
  readParam(pnh, "loop", "a bool", &c.loop);
  readParam(pnh, "grayscale", "a bool", &c.grayscale);
  readParam(pnh, "shutdown_when_done", "a bool", &c.shutdown_when_done);
  readParam(pnh, "preload_mb", "an integer", &c.preload_mb);
  readParam(pnh, "start_topic", "a string", &c.start_topic);
  c.validate();
  return c;
}

DatasetPlayer::DatasetPlayer(ros::NodeHandle nh, DatasetPlayerConfig config)
    : config_(std::move(config)),
      topics_{config_.device},
      dataset_(openDataset(config_)),
      camera_info_(ecar_bridge::toMsg(dataset_.camera(), std_msgs::Header())),
      nh_(std::move(nh)),
      it_(nh_),
      clock_(config_.rate > 0.0 ? config_.rate : 1.0) {
  if (static_cast<size_t>(config_.first_frame) >= dataset_.size()) {
    throw ecar::Error("~first_frame: " + std::to_string(config_.first_frame) +
                      " is past the last frame of " + dataset_.dir() + " (" +
                      std::to_string(dataset_.size()) + " frames)");
  }
  image_pub_ = it_.advertise(topics_.image_raw(), 10);
  info_pub_ = nh_.advertise<sensor_msgs::CameraInfo>(topics_.camera_info(), 10);
  imu_pub_ = nh_.advertise<sensor_msgs::Imu>(topics_.imu(), 2000);
  odom_pub_ = nh_.advertise<geometry_msgs::PoseStamped>(topics_.odometry(), 10);
  finished_pub_ = nh_.advertise<std_msgs::Bool>(topics_.player_finished(), 1, /*latch=*/true);
  touch_pub_ = nh_.advertise<ecar_msgs::Touch>(topics_.touch(), 100);
  if (!config_.start_topic.empty()) {
    ready_pub_ = nh_.advertise<std_msgs::Bool>(topics_.player_ready(), 1, /*latch=*/true);
    start_sub_ = nh_.subscribe<std_msgs::Time>(
        config_.start_topic, 1, [this](const std_msgs::TimeConstPtr& m) { start_at_ = m->data; });
  }
  if (config_.pace_by_consumer) {
    frame_done_sub_ = nh_.subscribe(topics_.frame_done(), 10, &DatasetPlayer::onFrameDone, this);
  }
}

size_t DatasetPlayer::run() {
  const size_t begin = static_cast<size_t>(config_.first_frame);
  const size_t available = dataset_.size() - begin;
  const size_t count = config_.max_frames > 0
                           ? std::min(available, static_cast<size_t>(config_.max_frames))
                           : available;
  const ecar::CameraParams& cam = dataset_.camera().params();
  ROS_INFO(
      "%s: playing %s (%s, frames %zu..%zu of %zu, %dx%d, fx %.2f) at rate %g%s%s",
      config_.device.c_str(), dataset_.dir().c_str(), ecar::toString(dataset_.format()).c_str(),
      begin, begin + count - 1, dataset_.size(), cam.width, cam.height, cam.fx, config_.rate,
      config_.pace_by_consumer ? ", paced by frame_done" : "", config_.loop ? ", looping" : "");
  if (!dataset_.touches().empty()) {
    ROS_INFO("%s: %zu scripted touches on %s", config_.device.c_str(), dataset_.touches().size(),
             touch_pub_.getTopic().c_str());
  }

  preload(begin, begin + count);
  waitForSubscribers();
  if (!waitForStart()) return 0;
  const Clock::time_point start = Clock::now();
  size_t published = 0;
  do {
    const size_t in_pass = playPass(begin, begin + count);
    published += in_pass;
    if (in_pass == 0 && ros::ok()) {
      ROS_ERROR("%s: no frame of %s could be published; stopping", config_.device.c_str(),
                dataset_.dir().c_str());
      break;
    }
  } while (config_.loop && ros::ok());

  if (!ros::ok()) return published;
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  ROS_INFO("%s: finished, %zu frames published in %.2f s", config_.device.c_str(), published,
           seconds);
  std_msgs::Bool finished;
  finished.data = true;
  finished_pub_.publish(finished);
  if (config_.shutdown_when_done) {
    ros::Duration(0.2).sleep();  // let the latched message and the last frames go out
    ros::shutdown();
  }
  return published;
}

void DatasetPlayer::preload(size_t begin, size_t end) {
  if (config_.preload_mb == 0) return;
  const Clock::time_point start = Clock::now();
  const size_t budget = static_cast<size_t>(config_.preload_mb) << 20;
  preloaded_.assign(end, cv::Mat());
  size_t bytes = 0, frames = 0;
  for (size_t i = begin; i < end && ros::ok(); ++i) {
    cv::Mat decoded;
    try {
      decoded = dataset_.loadImage(i, imreadFlags(config_.grayscale));
    } catch (const ecar::Error&) {
      continue;  // reported (and skipped) when due
    }
    const size_t size = decoded.total() * decoded.elemSize();
    if (bytes + size > budget) {
      ROS_WARN("%s: ~preload_mb %d holds frames %zu..%zu; the rest are decoded when due",
               config_.device.c_str(), config_.preload_mb, begin, i - 1);
      break;
    }
    bytes += size;
    ++frames;
    preloaded_[i] = std::move(decoded);
  }
  ROS_INFO("%s: preloaded %zu frames (%.0f MB) in %.2f s", config_.device.c_str(), frames,
           bytes / 1048576.0, std::chrono::duration<double>(Clock::now() - start).count());
}

cv::Mat DatasetPlayer::image(size_t i) const {
  if (i < preloaded_.size() && !preloaded_[i].empty()) return preloaded_[i];
  return dataset_.loadImage(i, imreadFlags(config_.grayscale));
}

size_t DatasetPlayer::playPass(size_t begin, size_t end) {
  // IMU samples after the frame before `begin` belong to this pass.
  imu_cursor_ = 0;
  if (begin > 0) {
    const double t_before = dataset_.frame(begin - 1).timestamp;
    const auto& imu = dataset_.imu();
    imu_cursor_ =
        std::upper_bound(imu.begin(), imu.end(), t_before + kStampToleranceS,
                         [](double t, const ecar::ImuSample& s) { return t < s.timestamp; }) -
        imu.begin();
  }
  previous_.reset();
  clock_.restart(Clock::now(), dataset_.frame(begin).timestamp);

  size_t published = 0;
  for (size_t i = begin; i < end && ros::ok(); ++i) {
    const ecar::DatasetFrame& frame = dataset_.frame(i);
    cv::Mat image;
    try {
      image = this->image(i);
    } catch (const ecar::Error& e) {
      const std::string why = e.what();
      ROS_WARN("%s: skipping frame %zu, unreadable image: %s", config_.device.c_str(), i,
               why.find(frame.image_path) == std::string::npos
                   ? (frame.image_path + ": " + why).c_str()
                   : why.c_str());
      warnDroppedTouches(i);
      continue;
    }

    if (config_.rate > 0.0 && !sleepUntil(clock_.dueAt(frame.timestamp))) break;

    std_msgs::Header header;
    try {
      header = publishFrame(i, image);
    } catch (const ecar::Error& e) {  // an image type toImageMsg cannot carry
      ROS_WARN("%s: skipping frame %zu (%s): %s", config_.device.c_str(), i,
               frame.image_path.c_str(), e.what());
      warnDroppedTouches(i);
      continue;
    }
    ++published;
    previous_ = std::make_pair(header.stamp, frame.timestamp);
    ROS_INFO_THROTTLE(5.0, "%s: frame %zu (%zu of %zu in this pass), dataset time %.3f s",
                      config_.device.c_str(), i, i - begin + 1, end - begin, frame.timestamp);

    if (config_.pace_by_consumer) {
      if (!waitForAck(header.seq) && ros::ok()) {
        ROS_WARN_THROTTLE(5.0, "%s: no %s >= %u (frame %zu) within %.2f s, going on",
                          config_.device.c_str(), frame_done_sub_.getTopic().c_str(), header.seq, i,
                          config_.ack_timeout);
      }
      // As a camera: the next frame stays due one interval after this one was
      // due; a consumer done after that gets it at once (PlaybackClock).
      if (config_.rate > 0.0 && i + 1 < end) {
        clock_.consumerDone(Clock::now(), dataset_.frame(i + 1).timestamp);
      }
    }
    // After the consumer's frame_done when paced: the device touches at this frame's pose.
    if (publishTouches(i, header) > 0 && config_.pace_by_consumer && config_.touch_settle > 0.0) {
      const auto settle = std::chrono::duration<double>(config_.touch_settle);
      if (!sleepUntil(Clock::now() + std::chrono::duration_cast<Clock::duration>(settle))) break;
      if (i + 1 < end) clock_.restart(Clock::now(), dataset_.frame(i + 1).timestamp);
    }
  }
  return published;
}

std::pair<size_t, size_t> DatasetPlayer::touchesOf(size_t i) const {
  const auto& touches = dataset_.touches();
  const auto by_frame = [](const ecar::TouchEvent& e, size_t frame) { return e.frame < frame; };
  const auto first = std::lower_bound(touches.begin(), touches.end(), i, by_frame);
  const auto last = std::lower_bound(first, touches.end(), i + 1, by_frame);
  return {static_cast<size_t>(first - touches.begin()),
          static_cast<size_t>(last - touches.begin())};
}

size_t DatasetPlayer::publishTouches(size_t i, const std_msgs::Header& image_header) {
  const auto [first, last] = touchesOf(i);
  std_msgs::Header header;
  header.stamp = image_header.stamp;
  header.frame_id = topics_.camera_frame();
  for (size_t k = first; k < last; ++k) {
    touch_pub_.publish(ecar_bridge::toMsg(dataset_.touches()[k], header));
  }
  return last - first;
}

void DatasetPlayer::warnDroppedTouches(size_t i) const {
  const auto [first, last] = touchesOf(i);
  if (last > first) {
    ROS_WARN("%s: %zu scripted touch(es) of skipped frame %zu dropped", config_.device.c_str(),
             last - first, i);
  }
}

std_msgs::Header DatasetPlayer::publishFrame(size_t i, const cv::Mat& image) {
  const ecar::DatasetFrame& frame = dataset_.frame(i);
  std_msgs::Header header;
  header.seq = image_seq_;
  header.stamp = ros::Time::now();
  header.frame_id = topics_.camera_frame();

  const sensor_msgs::ImagePtr image_msg =
      ecar_bridge::toImageMsg(image, header);  // throws before publishing
  publishImu(i, header);
  camera_info_.header = header;
  info_pub_.publish(camera_info_);
  image_pub_.publish(image_msg);
  ++image_seq_;

  if (frame.T_w_c_gt) {
    std_msgs::Header tf_header = header;
    tf_header.frame_id = config_.world_frame;
    tf_broadcaster_.sendTransform(
        ecar_bridge::toTransformMsg(*frame.T_w_c_gt, tf_header, topics_.gt_frame()));
  }
  if (frame.T_o_c_odom) {
    geometry_msgs::PoseStamped odom;
    odom.header = header;
    odom.header.frame_id = topics_.odom_frame();
    odom.pose = ecar_bridge::toMsg(*frame.T_o_c_odom);
    odom_pub_.publish(odom);
  }
  return header;
}

void DatasetPlayer::publishImu(size_t i, const std_msgs::Header& header) {
  const ecar::DatasetFrame& frame = dataset_.frame(i);
  const auto& imu = dataset_.imu();
  if (imu.empty()) {
    if (!frame.gravity_c) return;
    ecar::ImuSample gravity_only;
    gravity_only.timestamp = frame.timestamp;
    gravity_only.acc_c = *frame.gravity_c;
    sensor_msgs::Imu msg = ecar_bridge::toMsg(gravity_only, header);
    msg.angular_velocity_covariance[0] = -1.0;  // no angular rate in this dataset
    imu_pub_.publish(msg);
    return;
  }
  std_msgs::Header imu_header = header;
  for (;
       imu_cursor_ < imu.size() && imu[imu_cursor_].timestamp <= frame.timestamp + kStampToleranceS;
       ++imu_cursor_) {
    const ecar::ImuSample& sample = imu[imu_cursor_];
    imu_header.stamp = imuStamp(sample.timestamp, frame.timestamp, header.stamp);
    imu_pub_.publish(ecar_bridge::toMsg(sample, imu_header));
  }
}

ros::Time DatasetPlayer::imuStamp(double t_imu, double t_frame,
                                  const ros::Time& frame_stamp) const {
  // Never after the image: samples within kStampToleranceS get its stamp.
  if (previous_ && t_frame > previous_->second) {
    const double alpha = std::min((t_imu - previous_->second) / (t_frame - previous_->second), 1.0);
    return previous_->first + ros::Duration(alpha * (frame_stamp - previous_->first).toSec());
  }
  const double before_s = std::max(t_frame - t_imu, 0.0);
  if (before_s >= frame_stamp.toSec()) return ros::Time(0, 0);  // ros::Time cannot go negative
  return frame_stamp - ros::Duration(before_s);
}

void DatasetPlayer::waitForSubscribers() {
  const Clock::time_point deadline =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(
                         std::chrono::duration<double>(config_.wait_subscribers));
  while (ros::ok() && image_pub_.getNumSubscribers() == 0 && Clock::now() < deadline) {
    ros::spinOnce();
    std::this_thread::sleep_for(kPollPeriod);
  }
  if (image_pub_.getNumSubscribers() == 0 && config_.wait_subscribers > 0.0) {
    ROS_INFO("%s: no subscriber on %s after %.1f s, starting anyway", config_.device.c_str(),
             image_pub_.getTopic().c_str(), config_.wait_subscribers);
  }
  // Give the subscribers of the other topics (camera_info, tf, ...) time to connect.
  sleepUntil(Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                std::chrono::duration<double>(config_.start_delay)));
}

bool DatasetPlayer::waitForStart() {
  if (config_.start_topic.empty()) return true;
  std_msgs::Bool ready;
  ready.data = true;
  ready_pub_.publish(ready);
  ROS_INFO("%s: ready, waiting for a start time on %s", config_.device.c_str(),
           start_sub_.getTopic().c_str());
  while (ros::ok() && !start_at_) {
    ros::spinOnce();
    std::this_thread::sleep_for(kPollPeriod);
  }
  if (!start_at_) return false;
  const double wait = (*start_at_ - ros::Time::now()).toSec();
  if (wait <= 0.0) return true;
  return sleepUntil(Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                       std::chrono::duration<double>(wait)));
}

bool DatasetPlayer::sleepUntil(Clock::time_point until) {
  while (ros::ok()) {
    ros::spinOnce();
    const Clock::time_point now = Clock::now();
    if (now >= until) return true;
    std::this_thread::sleep_for(std::min<Clock::duration>(until - now, kPollPeriod));
  }
  return false;
}

bool DatasetPlayer::waitForAck(uint32_t seq) {
  const Clock::time_point deadline =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(
                         std::chrono::duration<double>(config_.ack_timeout));
  while (ros::ok()) {
    ros::spinOnce();
    if (acked_ && *acked_ >= seq) return true;
    if (Clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return false;
}

void DatasetPlayer::onFrameDone(const std_msgs::UInt32& msg) {
  if (!acked_ || msg.data > *acked_) acked_ = msg.data;
}

}  // namespace ecar_sim
