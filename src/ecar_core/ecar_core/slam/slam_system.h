// Monocular ORB SLAM for the edge server: one shared Map, a Tracker per
// device, a LocalMapper that takes keyframes from every device, and a
// LoopCloser that closes loops in the map. Each
// device has its own camera (setCamera; the constructor's camera is the
// default); its keyframes carry it, and mapping uses each keyframe's own.
//
//   SlamSystem slam(default_camera, config);
//   slam.setCamera(device, camera);   // optional
//   TrackResult r = slam.track(device, image, timestamp, frame_index, gravity, odometry);
//
// Trackers of different devices may run concurrently (each on its own thread);
// the mapper runs on its own thread (startMapping()) or synchronously after
// each keyframe (the default, deterministic for tests and the offline runner's
// --sync mode).
#pragma once

#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>

#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/loop_closer.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/place_recognition.h"
#include "ecar_core/slam/slam_config.h"
#include "ecar_core/slam/tracker.h"

namespace ecar {

class MapFileReader;
class MapFileWriter;

class SlamSystem {
 public:
  /// `camera`: the camera of devices that have none of their own (setCamera).
  SlamSystem(const PinholeCamera& camera, const SlamConfig& config = SlamConfig());
  ~SlamSystem();
  /// Tracker of a device, created on first use. Different devices may be
  /// tracked from different threads at once; one device from one thread.
  /// Track through SlamSystem::track(), which installMap() waits for.
  Tracker& tracker(DeviceId device);
  /// Sets a device's camera. Cameras that differ by at most `tolerance`
  /// (PinholeCamera::difference) count as one and are shared. A change
  /// restarts the device's tracker (it relocalises; a track() running on the
  /// old one finishes); the keyframes it made keep the camera they were made
  /// with. The camera stays with the device id when removeDevice() drops its
  /// tracker (a reconnect sets it again).
  void setCamera(DeviceId device, const PinholeCamera& camera, double tolerance = 1e-9);
  /// The camera a device's images are tracked with (the default camera when
  /// it has none of its own).
  CameraPtr camera(DeviceId device) const;
  /// Forgets a device's tracker (its motion model, lost state, initialisation
  /// views); its keyframes stay in the map. The caller makes sure no thread is
  /// inside track() for that device. The next track() starts a new tracker.
  void removeDevice(DeviceId device);
  /// Whether any keyframe of the map was made by the device.
  bool hasKeyFramesOf(DeviceId device) const;
  /// Forgets everything about a device that made no keyframe here: its tracker
  /// and its camera (a device connecting under many names must not grow the
  /// server's state for good).
  void forgetDevice(DeviceId device);
  /// Tracks one image of a device (see Tracker::track, also for `features`).
  /// Runs alongside other devices' track() calls; installMap() waits for it
  /// and blocks it.
  TrackResult track(DeviceId device, const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt,
                    const std::optional<SE3>& T_o_c = std::nullopt,
                    ImageFeatures* features = nullptr);

  // ---- saving and loading the map (io/map_file.h, io/slam_map_codec.h). Thread-safe with track().
  /// Writes the map to a file with one section, "slam" (atomically: a
  /// temporary file renamed). A snapshot under the map's read lock: trackers
  /// and the mapper go on. Throws ecar::Error naming the file on I/O errors.
  void saveMap(const std::string& path) const;
  /// Replaces the map by the one saved in `path` (readMapSection, then
  /// installMap). Throws ecar::Error naming the file, section and field when
  /// the file is missing, foreign, of another version, truncated, corrupted
  /// (CRC) or inconsistent, or made with another ORB pyramid; the current map
  /// is then untouched. Keyframes keep the cameras they were saved with.
  void loadMap(const std::string& path);
  /// Adds the "slam" section (keyframes, points, id counters, epoch, cameras)
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
  /// Rebuilds the place and keypoint indexes from the map (after a map was
  /// installed). Not while keyframes are being added.
  void reindex();
  /// Adds keyframes of the map to the place and keypoint indexes (moved in
  /// from another map); safe while tracking and mapping go on.
  void indexKeyFrames(const std::vector<KeyFrameId>& ids);

  Map& map() { return map_; }
  const Map& map() const { return map_; }
  LocalMapper& mapper() { return mapper_; }
  LoopCloser& loopCloser() { return loops_; }
  const PlaceIndex& placeIndex() const { return index_; }
  /// The default camera (of devices with none of their own).
  const PinholeCamera& camera() const { return *camera_; }

 private:
  CameraPtr camera_;
  SlamConfig config_;
  Map map_;
  PlaceIndex index_;
  KeypointIndex keypoint_index_;
  LocalMapper mapper_;
  LoopCloser loops_;
  /// Shared by track() calls, exclusive while a map is installed.
  std::shared_mutex session_mutex_;
  mutable std::mutex trackers_mutex_;  // guards trackers_ and cameras_
  std::shared_ptr<Tracker> sharedTracker(DeviceId device);
  std::unordered_map<DeviceId, std::shared_ptr<Tracker>> trackers_;
  std::unordered_map<DeviceId, CameraPtr> cameras_;
};

}  // namespace ecar
