// One eCAR device in its namespace, used by device_node and the nodelet
// ecar_device/Device (see launch/device.launch and config/device.yaml).
//
// Subscribes (relative to its namespace /<device>/): camera/image_raw,
// camera/camera_info, imu (sensor_msgs/Imu, specific force in the camera
// frame), odometry (geometry_msgs/PoseStamped T_odom_camera, same stamp as the
// image), and the local graph topic the server names on connection.
// Calls /ecar/connect (retrying until the service exists; again when no local
// graph came for ~reconnect_timeout s while uploading and the server no longer
// joins the device's topics, or for 5 times that while it still does).
// Publishes: the upload topic the server names (ecar_msgs/Upload, every
// ~every-th frame as JPEG), pose (geometry_msgs/PoseStamped, frame map), tf
// map -> <device>/camera, device_frame (ecar_msgs/DeviceFrame, every frame),
// metrics and /ecar/metrics (ecar_msgs/RoundTripMetrics, per local graph),
// ar_view (bgr8, only when subscribed), frame_done (std_msgs/UInt32: the
// header.seq of the frame just processed; with ~pace_in_flight > 0 only once
// fewer uploads than that wait for their local graph, or after ~pace_timeout s).
//
// Virtual objects: the device keeps the planes and VOs of its local graphs
// (ecar::DeviceObjects). A touch (ecar_msgs/Touch on `touch`) casts a ray from
// the device's latest tracked pose: a stroke begun on a plane becomes LINE VOs
// sent as REGISTER interactions, a touch on a held VO drags it (MANIPULATE per
// touch message) on the interaction topic the server names (default
// `interaction`, ecar_msgs/Interaction); answers on `interaction_result`
// (ecar_msgs/InteractionResult) are applied, rejections logged with their
// reason. VO states relayed straight to the device (vo_share: direct, on
// ~direct_objects_topic, ecar_msgs/VirtualObject) are held like those of local
// graphs. ar_view draws the held VOs and the strokes in flight. Touch rays
// start at the pose of the latest tracked frame, or of the latest OK local
// graph when that is later (the device's own tracking lost); a BEGIN needs one
// within ~touch_pose_timeout of the latest camera frame.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <dynamic_reconfigure/server.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <tf2_ros/transform_broadcaster.h>
#include <opencv2/core.hpp>

#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/Touch.h>
#include <ecar_msgs/Upload.h>
#include <ecar_msgs/VirtualObject.h>

#include "ecar_core/common/camera.h"
#include "ecar_core/device/device_objects.h"
#include "ecar_core/device/device_tracker.h"
#include "ecar_core/device/upload_cache.h"
#include "ecar_core/device/upload_quality.h"
#include "ecar_core/device/upload_schedule.h"
#include "ecar_device/DeviceTuningConfig.h"

namespace ecar_device {

/// Private parameters (~name) of a device, with their defaults; documented in config/device.yaml.
struct DeviceConfig {
  std::string device_id;  ///< ~device_id: default the node's namespace without '/'
  int every = 4;          ///< ~every: upload every Nth camera frame (header.seq % every == 0)
  int jpeg_quality = 70;  ///< ~jpeg_quality: 1..100
  /// ~min_jpeg_quality: 1..100, the floor of an uplink budget (LocalGraph.upload_budget)
  int min_jpeg_quality = 10;
  std::string sync_mode;  ///< ~sync_mode: "" (server default), "ecar" or "edgeslam"
  int max_pending = 8;    ///< ~max_pending: uploaded frames kept waiting for their graph
  /// ~max_in_flight: an upload that is due waits (its slot's later frames stay
  /// due) while this many uploads younger than ~reconnect_timeout await their
  /// graph: the device's own congestion control (0 = no limit)
  int max_in_flight = 2;
  double connect_period = 0.5;     ///< ~connect_period: s between connection attempts
  double reconnect_timeout = 3.0;  ///< ~reconnect_timeout: s without a local graph while uploading
  int pace_in_flight = 0;          ///< ~pace_in_flight: 0 = frame_done at once
  double pace_timeout = 1.0;       ///< ~pace_timeout: s to hold a frame_done at most
  std::string map_frame = "map";   ///< ~map_frame: frame of poses and the tf parent
  bool publish_tf = true;          ///< ~publish_tf: tf map -> <device>/camera
  std::string connect_service = "/ecar/connect";       ///< ~connect_service
  std::string global_metrics_topic = "/ecar/metrics";  ///< ~global_metrics_topic
  /// ~touch_pose_timeout: s; a touch BEGIN needs a pose (tracked frame or local
  /// graph) at most this much older than the latest camera frame
  double touch_pose_timeout = 1.0;
  /// ~direct_objects_topic: VO states the server relays straight to this device
  /// (vo_share: direct), relative to the device's namespace
  std::string direct_objects_topic = "objects";
  /// ~image_transport: transport of camera/image_raw ("raw", "compressed", ...;
  /// any image_transport plugin installed)
  std::string image_transport = "raw";
  /// What ar_view draws over the camera image.
  struct ArView {
    bool draw_points = true;   ///< ~draw_points: the tracked keypoints
    bool draw_objects = true;  ///< ~draw_objects: the VOs held and strokes in flight
    bool draw_status = true;   ///< ~draw_status: the status line on top
  } ar_view;
  ecar::DeviceTrackerConfig tracker;  ///< ~keyframe_queue, ~tracking/..., ~orb/...
  ecar::DeviceObjectsConfig objects;  ///< ~objects/... (touches, VOs, drawing)
  /// A light device (the paper's device simulator): no camera topics; it plays
  /// the uploads of a dataset (ecar::UploadCache: JPEGs encoded once) at
  /// ~light/rate, uploads them as a device does and tracks only those frames.
  struct Light {
    std::string dataset;    ///< ~light/dataset: "" = a full device on its camera topics
    double rate = 1.0;      ///< ~light/rate: playback speed (> 0)
    int max_frames = 0;     ///< ~light/max_frames: frames of the dataset played (0 = all)
    std::string cache_dir;  ///< ~light/cache_dir: "" = <dataset>/jpeg_q<jpeg_quality>
    /// ~light/wait_subscribers: s to wait, once joined to the server, for a
    /// subscriber on device_frame and on the metrics topic before playing (>= 0)
    double wait_subscribers = 5.0;
    /// ~light/start_topic: "" = play once joined (and listened to); else also
    /// wait for a std_msgs/Time on this topic and play from that wall time on,
    /// so that many light devices start together. Each then delays its first
    /// upload by a fraction of the upload period fixed by its name, as phones
    /// whose cameras were not started in step: devices in step would all wait
    /// a whole period for a VO accepted just after their uploads.
    std::string start_topic;
    /// ~light/loop: false = play the uploads once and publish player/finished;
    /// true = walk the route back and forth for ever (the uploads forwards,
    /// then backwards, ...), replaying the scripted touches on every forward
    /// pass: soak runs (scripts/soak.sh). Never finished.
    bool loop = false;
  } light;

  /// Throws ecar::Error naming the parameter (e.g. "~every") of the first bad value.
  void validate() const;
};

/// The config from a struct of parameters (as rosparam holds the node's
/// private namespace; an invalid value = none set). `ns` is the node's namespace
/// (the default device id). Members it does not know go to *unknown (may be
/// null). Throws ecar::Error naming the parameter on a wrong type or value.
DeviceConfig parseDeviceConfig(const XmlRpc::XmlRpcValue& params, const std::string& ns,
                               std::vector<std::string>* unknown);

/// Reads every parameter above from the private node handle, then validates.
/// `ns` is the node's namespace (the default device id). Throws ecar::Error
/// naming the parameter on a wrong type or value.
DeviceConfig loadDeviceConfig(const ros::NodeHandle& pnh, const std::string& ns);

class Device {
 public:
  /// `nh` resolves topics in the device's namespace, `pnh` is its private
  /// namespace (parameters). Starts the connection thread (its own callback
  /// queue) at once.
  Device(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, const DeviceConfig& config);
  ~Device();
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

 private:
  /// An uploaded frame waiting for its local graph.
  struct Pending {
    uint32_t frame_index = 0;
    ros::Time sent;
    cv::Mat gray;  ///< the device's own uncompressed image
    uint32_t bytes_up = 0;
    int jpeg_quality = 0;           ///< its JPEG's quality
    uint32_t upload_budget = 0;     ///< bytes/s in force when it was sent (0: none)
    float tracking_time = 0.f;      ///< s, the device's tracking of this frame
    float tracking_cpu_time = 0.f;  ///< s of the tracking thread's CPU for it
  };

  void onImage(const sensor_msgs::ImageConstPtr& msg);
  void onCameraInfo(const sensor_msgs::CameraInfoConstPtr& msg);
  void onImu(const sensor_msgs::ImuConstPtr& msg);
  void onOdometry(const geometry_msgs::PoseStampedConstPtr& msg);
  void onLocalGraph(const ecar_msgs::LocalGraphConstPtr& msg);
  void onTouch(const ecar_msgs::TouchConstPtr& msg);
  /// A touch at the latest pose (mutex_ held): the interactions it makes go
  /// to the server stamped `stamp`.
  void applyTouch(const ecar::Touch& touch, const ros::Time& stamp);
  /// Records when each held VO's version arrived (mutex_ held; after every
  /// change of objects_), for DeviceFrame.object_received.
  void noteObjectArrivals();
  void onInteractionResult(const ecar_msgs::InteractionResultConstPtr& msg);
  void onDirectObject(const ecar_msgs::VirtualObjectConstPtr& msg);
  /// A connection attempt (from the connection thread), then the frame held
  /// for it, if any, goes on.
  void onConnectTimer();
  /// A full device's camera, IMU and odometry subscriptions.
  void subscribeCamera();
  // A light device (device_light.cpp).
  /// Builds the upload cache and the camera, then starts the playback timer.
  void startLight();
  /// Plays the next cached upload once the server is joined: uploads it and
  /// tracks it; after the last one publishes player/finished.
  void onLightTimer();
  /// Moves light_next_ to the upload after the one just played (~light/loop:
  /// turning at either end of the route).
  void advanceLight(size_t count);
  /// Calls ~connect_service when not connected (or silent too long).
  void connect();
  void onPaceTimer();
  /// dynamic_reconfigure: every, jpeg_quality, the ar_view drawing options.
  void onReconfigure(const DeviceTuningConfig& tuning);

  // The following helpers need mutex_ held.
  /// JPEG-encodes an upload of `gray` at upload_quality_'s quality (or takes
  /// `jpeg`, already encoded at light_cache_quality_, when that quality is
  /// not lower) and keeps the frame pending; publishes it at once, or holds it
  /// until the odometry with the image's stamp comes.
  void upload(const cv::Mat& gray, const std_msgs::Header& header,
              const std::vector<uint8_t>* jpeg = nullptr);
  /// Publishes the held upload (sent = now) and records its bytes.
  void publishHeldUpload();
  void publishResult(const std_msgs::Header& image_header, const cv::Mat& gray,
                     const ecar::DeviceTrackResult& result, bool uploaded);
  /// frame_done now, or held while ~pace_in_flight uploads are in flight or
  /// while the connection asked for by a new camera_info is being made.
  void frameDone(uint32_t seq);
  /// Whether a frame_done waits now: a connection asked for by a new
  /// camera_info is being made (connect_requested_), or ~pace_in_flight uploads younger than
  /// ~pace_timeout wait for their graph.
  bool holdsFrames() const;
  /// Whether the server subscribes to our uploads and we to its local graphs.
  bool linkedToServer() const;
  /// Whether ~max_in_flight uploads await their graph (an upload due waits).
  bool uploadsBlocked() const;
  void releaseFrameDone(bool force);
  /// Drops pending frames older than ~reconnect_timeout (their graph is lost).
  void prunePending(const ros::Time& now);
  void changeEpoch(uint32_t epoch, const char* why);
  /// Drops the keyframes, points, objects and pose held (epoch or map change).
  void dropLocalMap();
  /// Draws the held VOs and pending strokes into ar_image_ from T_w_c (bgr8).
  void drawObjects(const ecar::SE3& T_w_c);
  /// Draws the status line (device, frame, tracking, counts) on top of ar_image_.
  void drawStatus(const ecar::DeviceTrackResult& r);

  DeviceConfig config_;
  ros::NodeHandle nh_, pnh_;
  std::string camera_frame_;

  mutable std::mutex mutex_;                      ///< guards everything below
  std::unique_ptr<ecar::DeviceTracker> tracker_;  ///< built on the first camera_info
  sensor_msgs::CameraInfo camera_info_;
  bool has_camera_info_ = false;
  std::optional<Eigen::Vector3d> gravity_c_;
  std::deque<std::pair<ros::Time, ecar::SE3>> odometry_;  ///< recent T_o_c by stamp
  bool odometry_seen_ = false;
  std::optional<ecar_msgs::Upload> held_upload_;  ///< waiting for its odometry
  bool connected_ = false;
  uint64_t session_ = 0;  ///< Connect's token, in every upload and interaction (0: none yet)
  /// A new camera_info asked the connection thread to connect now; when paced,
  /// frames wait for that attempt and for the topics to be joined both ways
  /// (linkedToServer; else the first uploads go unsent), ~pace_timeout at most.
  bool connect_requested_ = false;
  bool has_epoch_ = false;
  uint32_t epoch_ = 0;
  uint32_t map_id_ = 0;            ///< the server map of the last graph (0: none yet)
  bool reset_next_ = true;         ///< the next upload asks for every position again
  uint32_t last_reset_frame_ = 0;  ///< frame of the last upload with reset
  uint32_t last_graph_frame_ = 0;
  ros::WallTime last_progress_;  ///< connection or last local graph
  /// An upload was due since last_progress_ (sent, or not sent because the
  /// server had not joined our topics): silence then means a lost server.
  bool upload_due_since_progress_ = false;
  std::string upload_topic_, local_graph_topic_;
  std::deque<Pending> pending_;
  std::vector<cv::Mat> free_images_;  ///< buffers of released pending frames
  ecar::UploadSchedule upload_schedule_;
  /// Each upload's JPEG quality, within the server's budget (LocalGraph.upload_budget).
  ecar::UploadQuality upload_quality_;
  int reported_quality_ = 0;  ///< the quality last logged
  bool has_last_seq_ = false;
  uint32_t last_seq_ = 0;
  std::optional<uint32_t> held_done_;
  ros::WallTime held_since_;
  std::vector<uint8_t> jpeg_;
  cv::Mat ar_image_;
  std::optional<ecar::PinholeCamera> camera_;  ///< from camera_info
  /// Touch rays start here: the pose of the latest tracked frame or of the
  /// latest OK local graph, whichever has the later stamp (pose_stamp_).
  std::optional<ecar::SE3> T_w_c_;
  ros::Time pose_stamp_;
  ros::Time last_image_stamp_;
  bool tracking_ok_ = false;  ///< the latest frame was tracked
  ecar::DeviceObjects objects_;
  std::vector<ecar::VoRequest> requests_;           ///< scratch of onTouch
  std::vector<ecar::ScreenLine> draw_lines_;        ///< scratch of drawObjects
  std::vector<ecar::VirtualObject> graph_objects_;  ///< scratch of onDirectObject
  /// Object id -> (version held, device clock when that version arrived).
  std::unordered_map<uint32_t, std::pair<uint32_t, ros::Time>> object_arrival_;
  std::string interaction_topic_;

  image_transport::ImageTransport image_transport_;
  ros::Publisher upload_pub_, pose_pub_, device_frame_pub_, metrics_pub_, global_metrics_pub_,
      frame_done_pub_, interaction_pub_;
  image_transport::Publisher ar_view_pub_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber info_sub_, imu_sub_, odometry_sub_, graph_sub_, touch_sub_, result_sub_,
      direct_objects_sub_;
  tf2_ros::TransformBroadcaster tf_;
  ros::SteadyTimer pace_timer_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<DeviceTuningConfig>> reconfigure_;

  // Connection attempts run on their own queue and thread, so a slow or
  // missing server never stalls the camera callbacks.
  ros::CallbackQueue connect_queue_;
  ros::NodeHandle connect_nh_;
  ros::SteadyTimer connect_timer_;
  std::unique_ptr<ros::AsyncSpinner> connect_spinner_;
  // A light device's playback (~light/dataset); touched on its timer only.
  std::optional<ecar::UploadCache> light_cache_;
  size_t light_next_ = 0;         ///< index into light_cache_->uploads()
  bool light_backwards_ = false;  ///< ~light/loop: on a backward pass
  size_t light_passes_ = 0;       ///< ~light/loop: passes begun after the first
  uint32_t light_seq_ = 0;        ///< header.seq of the upload just played
  bool light_started_ = false;
  size_t light_blocked_ = 0;              ///< uploads not sent for ~max_in_flight
  int light_cache_quality_ = 0;           ///< the cached JPEGs' quality (lower: encoded again)
  ros::WallTime light_joined_;            ///< when the server joined our topics (0: not yet)
  std::optional<ros::Time> light_start_;  ///< from ~light/start_topic
  ros::Subscriber light_start_sub_;
  cv::Mat light_gray_;
  ros::SteadyTimer light_timer_;
  ros::Publisher light_finished_pub_;
  ros::WallDuration light_period_;               ///< between uploads
  ros::WallTime light_next_due_;                 ///< when the next upload is played
  std::vector<ecar::TouchEvent> light_touches_;  ///< the dataset's scripted touches
  size_t light_next_touch_ = 0;                  ///< index into light_touches_
};

}  // namespace ecar_device
