// Publishes a dataset folder (sim, TUM, KITTI, EuRoC; see ecar_core/dataset.h)
// as one device's camera, so the rest of eCAR cannot tell it from a live device.
//
// Topics (relative to the node's namespace, <device> = ~device):
//   <device>/camera/image_raw    sensor_msgs/Image, mono8 / bgr8 / mono16
//   <device>/camera/camera_info  sensor_msgs/CameraInfo, same header as the image
//   <device>/imu                 sensor_msgs/Imu in the camera frame: every IMU
//                                sample up to the frame's time, published just
//                                before the image; for datasets without IMU but
//                                with per-frame gravity, one message per frame
//                                whose linear_acceleration is the gravity reading
//   <device>/odometry            geometry_msgs/PoseStamped T_o_c, frame <device>/odom
//                                (frames that have odometry)
//   tf <world_frame> -> <device>/camera_gt   ground truth T_w_c (frames that have it)
//   <device>/touch               ecar_msgs/Touch, the dataset's scripted touches
//                                (touches.txt, see ecar_core/dataset.h): those of
//                                frame i with header.stamp = frame i's image
//                                stamp, frame_id <device>/camera, in file order;
//                                with ~pace_by_consumer after the consumer's
//                                frame_done for frame i (or ~ack_timeout) and
//                                before frame i+1's image (~touch_settle s
//                                before it), so a device applies them at
//                                frame i's pose; otherwise right after
//                                frame i's image. Touches of a skipped
//                                (unreadable) frame are dropped with a warning.
//   <device>/player/finished     std_msgs/Bool, latched, true after the last frame
//   <device>/player/ready        std_msgs/Bool, latched, true once the frames are
//                                preloaded and the player waits for ~start_topic
//                                (only with ~start_topic)
// Subscribes (with ~pace_by_consumer) to <device>/frame_done, std_msgs/UInt32:
// the header.seq of the last image the consumer has processed; (with
// ~start_topic) to ~start_topic, std_msgs/Time: play from that time on.
//
// Image header: stamp = ros::Time::now() at publication, frame_id =
// <device>/camera, seq = the number of images published before this one (0, 1,
// 2, ... over the node's life, across ~loop passes). roscpp overwrites
// header.seq with its per-publisher counter on the wire, so seq cannot carry the
// dataset's frame index; the player sets the same counter so that intra-process
// (nodelet) subscribers see the same value. With ~first_frame 0 and no
// unreadable image, seq is the frame index. IMU samples get stamps
// interpolated between the previous and the current image stamp by their
// dataset time (before the first image of a pass: the image stamp minus the
// dataset time difference), so IMU and image stamps stay ordered at any ~rate.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>

#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <std_msgs/UInt32.h>
#include <tf2_ros/transform_broadcaster.h>

#include "ecar_bridge/topics.h"
#include "ecar_core/io/dataset.h"
#include "playback_clock.h"

namespace ecar_sim {

/// Private parameters of the player (~name), with their defaults.
struct DatasetPlayerConfig {
  std::string dataset;  ///< ~dataset: the dataset folder (required)
  ecar::DatasetFormat format = ecar::DatasetFormat::kAuto;  ///< ~format: auto|sim|tum|kitti|euroc
  std::string camera_file;  ///< ~camera_file: camera.yaml overriding the intrinsics ("" = none)
  std::string device = "device_0";  ///< ~device: the device's namespace, no slashes
  std::string world_frame = "map";  ///< ~world_frame: parent frame of the ground-truth tf
  /// ~rate: playback speed relative to the dataset stamps (1 = real time, 2 =
  /// twice as fast); 0 publishes as fast as possible.
  double rate = 1.0;
  /// ~pace_by_consumer: after each frame, wait for a frame_done >= the image's
  /// header.seq (or ~ack_timeout) before the next one.
  bool pace_by_consumer = false;
  double ack_timeout = 2.0;  ///< ~ack_timeout, seconds, > 0
  /// ~start_delay: seconds to wait before the first frame, after waiting up to
  /// ~wait_subscribers seconds for a subscriber on image_raw.
  double start_delay = 0.5;
  double wait_subscribers = 5.0;  ///< ~wait_subscribers, seconds, >= 0
  /// ~touch_settle: with ~pace_by_consumer, seconds to wait after a frame's
  /// touches before the next image (>= 0). Topics are not ordered with each
  /// other, so without it the next image can reach the device before them.
  double touch_settle = 0.05;
  int first_frame = 0;              ///< ~first_frame: index of the first frame played
  int max_frames = 0;               ///< ~max_frames: frames per pass, 0 = to the end
  bool loop = false;                ///< ~loop: start over after the last frame
  bool grayscale = false;           ///< ~grayscale: publish mono8 whatever the files hold
  bool shutdown_when_done = false;  ///< ~shutdown_when_done: ros::shutdown() after the last frame
  /// ~preload_mb: decode the played frames before the first one, up to this
  /// many MB of images (the rest are decoded when due); 0 = decode each frame
  /// when it is due. Decoding a PNG costs more than playing it.
  int preload_mb = 1024;
  /// ~start_topic: "" = play once the subscribers are there (after
  /// ~start_delay); else preload, publish player/ready, then wait for a
  /// std_msgs/Time on this topic and play from that time on, so that a test or
  /// a runner starts several players when it chooses, whatever their preloading
  /// took (the light devices' ~light/start_topic convention).
  std::string start_topic;

  /// Throws ecar::Error naming the parameter (e.g. "~rate") of the first bad value.
  void validate() const;
};

/// Reads every parameter above from the private node handle, then validates.
/// Throws ecar::Error naming the parameter when one is missing (~dataset),
/// has the wrong type or an invalid value.
DatasetPlayerConfig loadDatasetPlayerConfig(const ros::NodeHandle& pnh);

class DatasetPlayer {
 public:
  /// Opens the dataset and advertises the topics. Throws ecar::Error when the
  /// config or the dataset is invalid (including ~first_frame past the end).
  DatasetPlayer(ros::NodeHandle nh, DatasetPlayerConfig config);

  /// Plays the frames (every pass when ~loop), then publishes `finished` and,
  /// with ~shutdown_when_done, shuts the node down. Blocks; services callbacks
  /// with ros::spinOnce() while it waits. Returns the number of frames published
  /// (fewer than planned when ROS shut down early or images were unreadable).
  size_t run();

  const DatasetPlayerConfig& config() const { return config_; }
  const ecar::Dataset& dataset() const { return dataset_; }

 private:
  using Clock = std::chrono::steady_clock;

  /// Decodes frames [begin, end) into preloaded_ within ~preload_mb.
  void preload(size_t begin, size_t end);
  /// Frame i, preloaded or read now; throws ecar::Error when unreadable.
  cv::Mat image(size_t i) const;
  /// Plays frames [begin, end) once; returns how many were published.
  size_t playPass(size_t begin, size_t end);
  /// Publishes frame i (image already loaded); returns its header.
  std_msgs::Header publishFrame(size_t i, const cv::Mat& image);
  void publishImu(size_t i, const std_msgs::Header& header);
  /// Indices [first, last) into dataset_.touches() of frame i's touches.
  std::pair<size_t, size_t> touchesOf(size_t i) const;
  /// Publishes the scripted touches of frame i with the stamp of its image;
  /// returns how many.
  size_t publishTouches(size_t i, const std_msgs::Header& image_header);
  void warnDroppedTouches(size_t i) const;
  /// Stamp of an IMU sample at dataset time t_imu for a frame at t_frame.
  ros::Time imuStamp(double t_imu, double t_frame, const ros::Time& frame_stamp) const;

  void waitForSubscribers();
  /// With ~start_topic: publishes player/ready and waits for the start time;
  /// false when ROS shut down first.
  bool waitForStart();
  /// Sleeps until `until` (servicing callbacks); false when ROS shut down.
  bool sleepUntil(Clock::time_point until);
  /// Waits for a frame_done >= seq, at most ~ack_timeout; false on timeout.
  bool waitForAck(uint32_t seq);
  void onFrameDone(const std_msgs::UInt32& msg);

  DatasetPlayerConfig config_;
  ecar_bridge::DeviceTopics topics_;
  ecar::Dataset dataset_;
  sensor_msgs::CameraInfo camera_info_;  ///< header filled per frame

  ros::NodeHandle nh_;
  image_transport::ImageTransport it_;
  image_transport::Publisher image_pub_;
  ros::Publisher info_pub_;
  ros::Publisher imu_pub_;
  ros::Publisher odom_pub_;
  ros::Publisher finished_pub_;
  ros::Publisher ready_pub_;
  ros::Subscriber start_sub_;
  std::optional<ros::Time> start_at_;  ///< from ~start_topic
  ros::Publisher touch_pub_;
  ros::Subscriber frame_done_sub_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;

  // Playback state. Single-threaded: only touched from run() and from callbacks
  // that run inside its ros::spinOnce() calls.
  uint32_t image_seq_ = 0;  ///< header.seq of the next image (= roscpp's counter)
  size_t imu_cursor_ = 0;   ///< next IMU sample to publish
  /// Decoded frames by index (empty Mats: not preloaded).
  std::vector<cv::Mat> preloaded_;
  /// When each frame of the current pass is due (used when ~rate > 0).
  PlaybackClock clock_;
  /// Stamp and dataset time of the previous published frame of the pass.
  std::optional<std::pair<ros::Time, double>> previous_;
  /// Largest frame_done received (image seqs only grow, so this never resets).
  std::optional<uint32_t> acked_;
};

}  // namespace ecar_sim
