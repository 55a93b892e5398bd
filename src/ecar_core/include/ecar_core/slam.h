// Monocular ORB SLAM for the edge server: one shared Map, a Tracker per
// device, and a LocalMapper that takes keyframes from every device.
//
//   SlamSystem slam(camera, config);
//   TrackResult r = slam.track(device, image, timestamp, frame_index, gravity, odometry);
//
// Trackers of different devices may run concurrently (each on its own thread);
// the mapper runs on its own thread (startMapping()) or synchronously after
// each keyframe (the default, deterministic for tests and the offline runner's
// --sync mode).
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/camera.h"
#include "ecar_core/features.h"
#include "ecar_core/frame.h"
#include "ecar_core/map.h"
#include "ecar_core/matcher.h"
#include "ecar_core/optimizer.h"
#include "ecar_core/place_recognition.h"
#include "ecar_core/two_view.h"
#include "ecar_core/types.h"

namespace ecar {

struct SlamConfig {
  OrbConfig orb;
  TwoViewConfig two_view;
  PnpConfig pnp;
  PoseOptimizerConfig pose;
  BaConfig ba;
  PlaceIndexConfig place;
  KeypointIndexConfig keypoints;
  int init_min_matches = 100;  ///< correspondences needed to try two-view
  double init_window = 100.0;  ///< px search window between the two views
  int init_candidates = 10;    ///< recent views kept as first-view candidates
  int init_attempts = 5;       ///< two-view reconstructions tried per image
  /// A candidate view is skipped when 90% of the keypoints moved less (px).
  double init_min_displacement_px = 3.0;
  int min_inliers = 30;  ///< tracking OK needs this many inliers
  /// Below this fraction of the last image's inliers, the motion-model result
  /// is checked against tracking from the reference keyframe.
  double weak_tracking_ratio = 0.5;
  double projection_radius = 15.0;   ///< px (x pyramid scale) for motion-model search
  double local_map_radius = 4.0;     ///< px (x scale) for the local-map search
  int local_keyframes = 25;          ///< keyframes in the tracking local map
  int ba_keyframes = 10;             ///< free keyframes in local BA
  double keyframe_ratio = 0.75;      ///< new keyframe when tracked < ratio x reference's
  int keyframe_max_gap = 4;          ///< frames (uploads) after which a keyframe is due
  int covisible_triangulation = 10;  ///< neighbours searched for new points
  double relocalisation_ratio = 0.75;
  int relocalisation_candidates = 5;
  /// Relocalisation / joining by keypoint matches (when the whole-image
  /// candidates fail, e.g. a view from the opposite direction): ratio test
  /// between the two nearest distinct map points, and the neighbours of a
  /// candidate keyframe whose points are matched with it.
  double keypoint_ratio = 0.8;
  int keypoint_group = 15;
  /// With gravity in a gravity-aligned map: inliers a 2-point (yaw and
  /// translation) RANSAC over all keypoint matches at once needs before the
  /// pose is verified by projection (a view from the opposite direction has
  /// only about 10 correct matches among 60-90 when it first joins).
  int keypoint_gravity_min_inliers = 10;
  /// A relocalised pose must agree with the upload's gravity within this
  /// (degrees) where the map is gravity-aligned.
  double gravity_tolerance_deg = 5.0;
  bool synchronous_mapping = true;  ///< map each keyframe inside track()
};

enum class TrackingState { kNotInitialised = 0, kOk = 1, kLost = 2 };
const char* toString(TrackingState state);

struct TrackedPoint {
  MapPointId id;
  cv::KeyPoint keypoint;  ///< in the uploaded (distorted) image
  Eigen::Vector3d p_w;
};

struct TrackResult {
  TrackingState state = TrackingState::kNotInitialised;
  bool relocalised = false;  ///< this image was aligned by relocalisation / joining
  bool initialised = false;  ///< this image created the map
  SE3 T_w_c = SE3::Identity();
  std::vector<TrackedPoint> tracked;
  std::vector<KeyFrameId> local_keyframes;
  std::optional<KeyFrameId> new_keyframe;
  double orb_ms = 0.0, track_ms = 0.0;
  std::string message;  ///< why tracking failed, for logs
};

class LocalMapper;
class MapFileReader;
class MapFileWriter;

class Tracker {
 public:
  /// `keypoints` may be null (no relocalisation by keypoint matches).
  Tracker(DeviceId device, Map* map, PlaceIndex* index, LocalMapper* mapper,
          const PinholeCamera& camera, const SlamConfig& config,
          KeypointIndex* keypoints = nullptr);
  /// Aligns one grey image. Bad images (empty, wrong size, blank) give a
  /// NOT_INITIALISED/LOST result with a message; nothing throws.
  TrackResult track(const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt,
                    const std::optional<SE3>& T_o_c = std::nullopt);
  TrackingState state() const { return state_; }
  int relocalisations() const { return relocalisations_; }
  /// Forgets the tracking state (last image, motion model, local keyframes,
  /// initialisation views): the next image relocalises against the map, or
  /// initialises an empty one. The relocalisation count stays. Not while
  /// track() runs.
  void reset();

 private:
  bool initialise(TrackResult* result);
  int trackFromLastFrame();  ///< inliers after the local-map search
  bool trackWithMotionModel();
  bool trackReferenceKeyFrame();
  bool relocalise();
  bool relocaliseByPlace();
  bool relocaliseByKeypoints();
  /// One gravity RANSAC over all keypoint matches (points, pixels, ids and
  /// keypoint rows alike indexed); verified against the points of the
  /// keyframes that observe its inliers.
  bool relocaliseByGravity(const std::vector<Eigen::Vector3d>& points_w,
                           const std::vector<Eigen::Vector2d>& pixels,
                           const std::vector<MapPointId>& ids, const std::vector<int>& rows,
                           KeyFrameId reference);
  /// Projection search of candidate points (no viewing-angle check: the map
  /// may have seen them from the other side), pose refinement and the checks
  /// of a relocalised pose.
  bool verifyRelocalisation(std::vector<PointSample> samples);
  bool gravityConsistent() const;
  int trackLocalMap();
  bool needKeyFrame() const;
  KeyFrameId createKeyFrame();
  void fillResult(TrackResult* result) const;
  int optimiseCurrentPose();
  std::vector<PointSample> samplesOf(const std::vector<MapPointId>& ids) const;  // read lock held

  DeviceId device_;
  Map* map_;
  PlaceIndex* index_;
  KeypointIndex* keypoints_;
  LocalMapper* mapper_;
  PinholeCamera camera_;
  Intrinsics K_;
  SlamConfig config_;
  OrbExtractor extractor_;

  TrackingState state_ = TrackingState::kNotInitialised;
  Frame current_, last_;
  SE3 T_c_w_ = SE3::Identity(), last_T_c_w_ = SE3::Identity();
  std::vector<MapPointId> matches_, last_matches_;
  int last_inliers_ = 0;
  std::vector<bool> inliers_;
  std::optional<SE3> velocity_;  ///< T_c_last: motion from the last frame to the current
  KeyFrameId reference_kf_;
  std::vector<KeyFrameId> local_keyframes_;
  uint32_t frames_since_keyframe_ = 0;
  int relocalisations_ = 0;
  // Initialisation.
  std::deque<Frame> init_candidates_;
};

class LocalMapper {
 public:
  /// `keypoints` may be null.
  LocalMapper(Map* map, PlaceIndex* index, const PinholeCamera& camera, const SlamConfig& config,
              KeypointIndex* keypoints = nullptr);
  ~LocalMapper();
  void insert(KeyFrameId kf);
  /// Maps every queued keyframe now (synchronous mode).
  void processPending();
  void startThread();
  /// Maps the keyframes still queued, then stops the thread.
  void stopThread();
  /// Drops the queued keyframes and the new points awaiting culling (the map
  /// was replaced): waits for the keyframe being mapped, and leaves the thread
  /// running if it was. Call while no tracker can insert keyframes.
  void reset();
  bool idle() const;
  /// Times of the local bundle adjustments so far (ms).
  std::vector<double> baTimes() const;
  /// Called (on the mapping thread, or inside processPending()) after each
  /// keyframe was mapped, with its id; the keyframe may have been culled
  /// meanwhile. Set it before keyframes arrive; an empty function clears it.
  void setMappedCallback(std::function<void(KeyFrameId)> callback);
  /// Called (on the mapping thread, without the map lock) after a redundant
  /// keyframe was culled, with its id and its heir: the neighbour that shared
  /// the most points with it (invalid when it had none). Whatever hangs on
  /// the culled keyframe (plane and cell links, keyframe-attached objects)
  /// moves to the heir or goes. An empty function clears it.
  void setCulledCallback(std::function<void(KeyFrameId culled, KeyFrameId heir)> callback);

 private:
  void process(KeyFrameId kf);
  void cullRecentPoints(KeyFrameId kf);
  int triangulateNewPoints(KeyFrameId kf);
  int fuseDuplicates(KeyFrameId kf);
  int fuseInto(KeyFrameId target, const std::vector<MapPointId>& points);  // write lock held
  void localBundleAdjustment(KeyFrameId kf);
  void cullKeyFrames(KeyFrameId kf);
  void run();

  Map* map_;
  PlaceIndex* index_;
  KeypointIndex* keypoints_;
  PinholeCamera camera_;
  Intrinsics K_;
  SlamConfig config_;
  mutable std::mutex queue_mutex_;
  std::condition_variable queue_cv_;
  std::deque<KeyFrameId> queue_;
  std::vector<MapPointId> recent_points_;
  std::vector<double> ba_ms_;
  std::function<void(KeyFrameId)> mapped_callback_;              // guarded by queue_mutex_
  std::function<void(KeyFrameId, KeyFrameId)> culled_callback_;  // guarded by queue_mutex_
  std::atomic<bool> busy_{false}, stop_{false};
  std::thread thread_;
};

class SlamSystem {
 public:
  SlamSystem(const PinholeCamera& camera, const SlamConfig& config = SlamConfig());
  ~SlamSystem();
  /// Tracker of a device, created on first use. Different devices may be
  /// tracked from different threads at once; one device from one thread.
  /// Track through SlamSystem::track(), which installMap() waits for.
  Tracker& tracker(DeviceId device);
  /// Forgets a device's tracker (its motion model, lost state, initialisation
  /// views); its keyframes stay in the map. The caller makes sure no thread is
  /// inside track() for that device. The next track() starts a new tracker.
  void removeDevice(DeviceId device);
  /// Tracks one image of a device (see Tracker::track). Runs alongside other
  /// devices' track() calls; installMap() waits for it and blocks it.
  TrackResult track(DeviceId device, const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt,
                    const std::optional<SE3>& T_o_c = std::nullopt);

  // ---- saving and loading the map (map_io.h). Thread-safe with track().
  /// Writes the map to a file with one section, "slam" (atomically: a
  /// temporary file renamed). A snapshot under the map's read lock: trackers
  /// and the mapper go on. Throws ecar::Error naming the file on I/O errors.
  void saveMap(const std::string& path) const;
  /// Replaces the map by the one saved in `path` (readMapSection, then
  /// installMap). Throws ecar::Error naming the file, section and field when
  /// the file is missing, foreign, of another version, truncated, corrupted
  /// (CRC) or inconsistent, or made with another camera; the current map is
  /// then untouched.
  void loadMap(const std::string& path);
  /// Adds the "slam" section (keyframes, points, id counters, epoch, camera)
  /// to a map file being assembled, so other components can add theirs.
  void writeMapSection(MapFileWriter* writer) const;
  /// Decodes the "slam" section of a map file into a new map, with everything
  /// derived rebuilt (undistorted keypoints, feature grids, covisibility) and
  /// its consistency checked. Touches nothing of this system; throws
  /// ecar::Error as loadMap() does.
  std::unique_ptr<Map> readMapSection(const MapFileReader& reader) const;
  /// Swaps a decoded map in: waits for running track() calls and blocks new
  /// ones, drops the mapper's queue, takes the map's contents, moves the epoch
  /// past both maps', rebuilds the place and keypoint indexes, and resets
  /// every tracker so that it relocalises against the new map. Not from the
  /// mapped callback (it may run inside track()).
  void installMap(std::unique_ptr<Map> map);

  Map& map() { return map_; }
  const Map& map() const { return map_; }
  LocalMapper& mapper() { return mapper_; }
  const PinholeCamera& camera() const { return camera_; }

 private:
  PinholeCamera camera_;
  SlamConfig config_;
  Map map_;
  PlaceIndex index_;
  KeypointIndex keypoint_index_;
  LocalMapper mapper_;
  /// Shared by track() calls, exclusive while a map is installed.
  std::shared_mutex session_mutex_;
  std::mutex trackers_mutex_;
  std::unordered_map<DeviceId, std::unique_ptr<Tracker>> trackers_;
};

}  // namespace ecar
