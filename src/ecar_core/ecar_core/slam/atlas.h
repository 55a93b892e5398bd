// An atlas of maps (issue 12): each map is a whole SlamSystem (map, indexes,
// local mapper, loop closer, a tracker per device) with its own id range, so
// that maps can be merged without renumbering.
//
// - A device whose uploads match no map starts its own map at once, while it
//   tries to relocalise into the others with every upload; the first to
//   succeed is its map (an unused fresh map is dropped).
// - A device lost for `new_map_after_lost` uploads starts a new map the same
//   way (a place it has never mapped).
// - Each new keyframe is looked up in the other maps' place indexes; a match
//   verified by a similarity (verifyPlace; SE(3) when both maps are metric)
//   merges the smaller map into the larger (mergeMaps): its keyframes and
//   points move through the similarity, duplicates fuse, the seam's keyframes
//   are mapped again (triangulation, fusion and local BA across the seam), and
//   its devices go on in the merged map (relocalising there with their next
//   upload).
//
//   Atlas atlas(default_camera, slam_config, atlas_config);
//   MapId map;
//   TrackResult r = atlas.track(device, image, stamp, frame, gravity, odometry, &map);
//
// Thread-safety: track() of different devices may run concurrently; a merge
// waits for every running track() and blocks new ones while it moves the map
// (then, outside, the merging device's track() indexes the moved keyframes
// and bundle-adjusts the merged map whole, or queues that on the merged map's
// loop-closer thread: background_merge_ba). The server's GlobalGraph and the offline runner use it.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <unordered_map>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map_correction.h"
#include "ecar_core/slam/seam_refit.h"
#include "ecar_core/slam/slam_system.h"

namespace ecar {

struct AtlasConfig {
  /// false: one map, as a single SlamSystem (every device joins the first map).
  bool several_maps = true;
  /// A device lost for this many uploads starts a new map (0: never).
  int new_map_after_lost = 8;
  bool merge = true;
  size_t merge_candidates = 3;  ///< place-recognition candidates per other map
  /// One of every this many uploads tracked in a map (of all its devices
  /// together; 0: never) tries to relocalise into another map, one map per
  /// probe in turn: a probe costs one relocalisation, however many maps there
  /// are, and a map's probes cost as much with twenty devices as with one
  /// (with one device each, as in the two-device joins, every second upload
  /// of each device probes). A view from the
  /// opposite direction shares too few words for place recognition, but
  /// relocalisation (keypoint matches, gravity RANSAC) finds it. The points
  /// matched in both maps give the similarity (at least
  /// relocalise_min_inliers inliers).
  int relocalise_every = 2;
  int relocalise_min_inliers = 20;
  /// Where the global bundle adjustment after a merge runs. true: on the
  /// merged map's loop-closer thread (the merging upload takes about 0.2 s on
  /// the small ring with threads; the next uploads track in the merged map
  /// for the 1-2 s before the adjustment lands). false: inside the merging
  /// upload's track(), which then waits 0.9-1.4 s. In atlas_merge.test both
  /// measured alike (three runs each: one-similarity RMSE 2.4-3.1 against
  /// 2.2-2.8 cm; a VO drawn before the merge seen at most 10-14 against
  /// 10-15 cm off on the first graphs after it).
  bool background_merge_ba = true;
  /// Ids of map k start at (k - 1) * id_range + 1.
  uint32_t id_range = 10000000;

  /// Throws ecar::Error naming the first invalid key.
  void validate() const;
};

/// One merge: which maps, found by which keyframe, at what cost.
struct MergeEvent {
  MapId into, from;
  KeyFrameId query, match;  ///< the keyframe that found it, and its match
  DeviceId device;          ///< whose keyframe it was
  int inliers = 0;
  double scale = 1.0;  ///< of the similarity
  double ms = 0.0;     ///< verification and merge
  size_t keyframes_moved = 0, points_fused = 0;
  /// The similarity refitted on the welded seam's reprojections (S includes
  /// refit.D when refit.applied).
  SeamRefit refit;
  /// The similarity from the merged map's world to the kept map's.
  Sim3 S;
  /// Every keyframe that moved, with S (its grid links are re-cast).
  MapCorrection correction;
};

/// Told about the maps' lives. Calls are made without the atlas's locks.
struct AtlasCallbacks {
  /// A new map, before anything is tracked in it (set its SLAM callbacks here).
  std::function<void(MapId, const std::shared_ptr<SlamSystem>&)> created;
  /// A map went: merged into another (after `merged`) or an unused fresh map.
  std::function<void(MapId)> removed;
  /// Two maps merged (their SLAM maps are one); called while no track() runs,
  /// before the merging device's upload is answered.
  std::function<void(const MergeEvent&)> merged;
};

class Atlas {
 public:
  Atlas(const PinholeCamera& camera, const SlamConfig& config,
        const AtlasConfig& atlas = AtlasConfig());
  ~Atlas();

  /// Before the first track().
  void setCallbacks(AtlasCallbacks callbacks);
  /// A new empty map (tools and tests fill it); announced before this returns.
  MapId addMap();
  /// Cameras within `tolerance` (PinholeCamera::difference) share one object.
  void setCamera(DeviceId device, const PinholeCamera& camera, double tolerance = 1e-9);
  /// The camera a device tracks with (the default camera when never set).
  PinholeCamera camera(DeviceId device) const;
  /// Tracks one upload of a device in its map (see the file comment); `map`
  /// receives the map the result is in (invalid when none).
  TrackResult track(DeviceId device, const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c,
                    const std::optional<SE3>& T_o_c, MapId* map);

  std::vector<MapId> mapIds() const;
  /// Null when `id` is not (or no longer) a map.
  std::shared_ptr<SlamSystem> map(MapId id) const;
  /// The map a device tracks in (invalid when none yet).
  MapId mapOf(DeviceId device) const;
  /// The live map holding a keyframe id (from its id range, through merges;
  /// invalid when that map is gone).
  MapId mapOfKeyFrame(KeyFrameId keyframe) const;
  /// The atlas epoch, shared by every map: moves on with every install().
  uint32_t epoch() const;
  /// Forgets a device (its trackers in every map).
  void removeDevice(DeviceId device);
  /// Whether a keyframe of any map was made by the device.
  bool hasKeyFramesOf(DeviceId device) const;
  /// Forgets everything about a device whose id is retired (it made no
  /// keyframe): its trackers and cameras.
  void forgetDevice(DeviceId device);
  /// Replaces every map by `maps` (a loaded atlas: ids and their maps): the
  /// old maps' threads finish, every device relocalises with its next upload,
  /// the epoch moves past every map's. `first` runs before anything changes,
  /// while no track() runs; when it throws, nothing changes. Throws
  /// ecar::Error on a duplicate or invalid id or a null map (then nothing
  /// changed).
  void install(std::vector<std::pair<MapId, std::unique_ptr<Map>>> maps,
               const std::function<void()>& first = {});
  std::vector<MergeEvent> merges() const;
  /// Where a map's coordinates went: the similarity from `id`'s world to the
  /// world of the map it was merged into (through every later merge), and
  /// that map. Identity and `id` itself for a live map.
  std::pair<MapId, Sim3> finalFrameOf(MapId id) const;
  /// A result aligned in a map that has merged into another since (by this
  /// upload's own merge, or another device's meanwhile): its pose and tracked
  /// points move into the live map's coordinates (finalFrameOf) and its map id
  /// becomes the live map's. The point ids stay (a merge keeps ids; fused
  /// ones are gone from the map and are skipped by the graph). Returns false
  /// (nothing changed) when r's map is live or invalid.
  bool toLiveMap(TrackResult* r) const;
  /// Every loop closed in any map.
  std::vector<LoopClosure> loopClosures() const;
  /// Stops every map's threads after finishing their queues.
  void finish();

 private:
  static bool initialised(const SlamSystem& slam);  ///< its map has keyframes
  struct Device {
    MapId current;  ///< the map it tracks in
    MapId fresh;    ///< a map of its own being initialised
    int lost = 0;   ///< uploads not tracked in `current` in a row
  };
  struct Entry {
    MapId id;
    std::shared_ptr<SlamSystem> slam;
    /// Uploads tracked in this map, of all its devices (one of every
    /// relocalise_every probes another map), and the map probed last.
    int tracked = 0;
    MapId probed;
  };
  std::shared_ptr<SlamSystem> slamOf(MapId id) const;  // mutex_ held
  Entry* entryOf(MapId id);                            // mutex_ held; null if none
  /// A new empty map (`id` invalid: the next free id); queued for the
  /// `created` callback (announce()). mutex_ held.
  MapId newMap(MapId id = MapId());
  /// Drops a map (queued for `removed`). mutex_ held.
  void dropMap(MapId id);
  /// Tells the callbacks about the maps created and removed. mutex_ not held.
  void announce();
  /// Two maps found to overlap: a's world -> b's world, and the pairs of
  /// their points that are one physical point (a's, b's).
  struct MergeCandidate {
    MapId a, b;
    Sim3 S;
    std::vector<std::pair<MapPointId, MapPointId>> duplicates;
    KeyFrameId query, match;  ///< seam keyframes mapped again after the merge (may be invalid)
    DeviceId device;
    int inliers = 0;
  };
  /// The overlap a device's upload shows when it was tracked in map a and
  /// relocalised in map b: the points matched to the same keypoints in both.
  std::optional<MergeCandidate> relocalisedOverlap(MapId a_id, const SlamSystem& a,
                                                   const TrackResult& in_a, MapId b_id,
                                                   const SlamSystem& b, const TrackResult& in_b,
                                                   DeviceId device) const;
  /// Looks for the keyframe's place in the other maps; merges on a match.
  void tryMerge(MapId map, KeyFrameId keyframe, DeviceId device);
  /// tryMerge's search (place recognition and verification in the other
  /// maps), the session lock held shared: tracking goes on meanwhile.
  std::optional<MergeCandidate> findMerge(MapId map, KeyFrameId keyframe, DeviceId device) const;
  /// Merges the smaller of the candidate's maps into the larger. The session
  /// lock held exclusively. Returns the merged map (null when nothing merged)
  /// and the keyframes moved into it, for adjustMerged().
  std::shared_ptr<SlamSystem> doMerge(const MergeCandidate& c,
                                      std::chrono::steady_clock::time_point start,
                                      std::vector<KeyFrameId>* moved);
  /// After a merge, without the session lock: indexes the moved keyframes in
  /// the merged map, then bundle-adjusts it whole (or queues that).
  void adjustMerged(const std::shared_ptr<SlamSystem>& merged,
                    const std::vector<KeyFrameId>& moved) const;

  PinholeCamera camera_;
  SlamConfig config_;
  AtlasConfig atlas_;
  /// Shared by track(), exclusive while a merge moves a map.
  mutable std::shared_mutex session_mutex_;
  mutable std::mutex mutex_;  // guards everything below
  std::vector<Entry> maps_;
  std::unordered_map<DeviceId, Device> devices_;
  std::unordered_map<DeviceId, PinholeCamera> cameras_;
  double camera_tolerance_ = 1e-9;
  std::vector<MergeEvent> merges_;
  std::vector<LoopClosure> closed_loops_;  ///< of maps merged away
  std::unordered_map<MapId, std::pair<MapId, Sim3>> merged_into_;
  uint32_t next_map_ = 1;
  uint32_t epoch_;
  AtlasCallbacks callbacks_;
  std::vector<Entry> created_;  ///< not announced yet
  std::vector<MapId> removed_;  ///< not announced yet
  std::mutex announce_mutex_;   // keeps announcements in order
};

}  // namespace ecar
