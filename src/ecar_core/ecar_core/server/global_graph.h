// The edge server's global graph (DESIGN.md section 3): everything devices
// share, in one coordinate system, and the only object the server's modules
// share. The modules (slam/slam_system.h for tracking and local mapping,
// server/plane_segmentation.h, server/grid_connection.h,
// sync/local_graph_composer.h) work on it; per-upload data flows between them
// as messages.
//
//   GlobalGraph graph(config);                        // opens the VO database
//   DeviceConnectResult r = graph.connect("device_0", camera, "", 10, now);
//   TrackResult t = graph.track(r.device.id, image, stamp, frame, gravity, odometry);
//   std::shared_ptr<SlamSystem> slam = graph.map(t.map);  // the map it is in
//   MapCounts saved = graph.save("/tmp/corridor.ecarmap");
//
// What it holds, and the lock contract:
// - devices (DeviceRegistry): its own mutex.
// - the SLAM maps (an Atlas of SlamSystems: keyframes, map points), created
//   with the first device: each Map has its shared_mutex (map.h); read them
//   through the queries of slam/map_queries.h, which take the lock themselves.
//   Maps have ids; keyframe and point ids are unique across maps (id ranges).
// - planes (PlaneMap), grid links (GridMap: keyframe-cell and object-cell) and
//   virtual objects (VoStore): each thread-safe on its own. Planes and objects
//   carry their map's id and its coordinates; grid links hang on keyframes
//   (of one map) and objects.
// - a merge of two maps (Atlas) moves the merged map's planes and objects into
//   the kept map (versions + 1, in SQLite) while no upload is tracked, before
//   the merging upload is answered; grid links of its keyframes are re-cast
//   right after, outside the frozen structure.
// - the structure lock (structureLock()): shared by every module while it reads
//   or changes planes, grid links or VOs for one keyframe or upload, exclusive
//   only while load() swaps a loaded map in, so that no module sees half of a
//   load. Take it before any of the locks above, never while holding them.
// - the map epoch (epoch()): moves on with every load; a result aligned in an
//   older epoch refers to a replaced map and is dropped.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/server/device_registry.h"
#include "ecar_core/slam/atlas.h"
#include "ecar_core/slam/map_correction.h"
#include "ecar_core/slam/map_queries.h"
#include "ecar_core/slam/slam_system.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar {

struct GlobalGraphConfig {
  /// SLAM options; slam.first_epoch is the map epoch before any load (a server
  /// makes it differ between its starts).
  SlamConfig slam;
  PlaneConfig planes;
  GridConfig grid;
  /// VO store; its cell_size is taken from grid.cell_size.
  VoStoreConfig vo;
  /// m: the VO map bounds are the keyframe centres' bounding box grown by this
  /// (within vo.map_min / vo.map_max).
  double vo_map_margin = 10.0;
  /// Devices' cameras whose intrinsics differ by at most this fraction (fx, fy,
  /// cx, cy) and distortion coefficients by at most this much count as one
  /// camera (their keyframes share it; the map file stores it once). Any
  /// camera may connect: each device tracks with its own.
  double camera_tolerance = 0.005;
  DeviceRegistryConfig devices;
  /// Several maps, merged when they overlap (several_maps false: one map).
  AtlasConfig atlas;

  /// Throws ecar::Error naming the first invalid key.
  void validate() const;
};

/// What a map correction moved besides the SLAM map (applyMapCorrection).
struct MapCorrectionReport {
  MapId map;
  size_t keyframes = 0, points = 0, planes = 0, objects = 0;
  size_t planes_removed = 0;  ///< planes fused into another or left without points (refit)
  /// The planes' points at the refit: live, fused into another point (taken
  /// at that one's position), gone from the SLAM map (kept where they were).
  size_t plane_points_live = 0, plane_points_fused = 0, plane_points_gone = 0;
  size_t keyframes_recast = 0, keyframe_cells = 0;  ///< grid links re-made (moved > 1/4 cell)
  double milliseconds = 0.0;
};

/// What a merge of two maps moved besides the SLAM maps.
struct MapMergeReport {
  MergeEvent merge;
  size_t planes = 0, objects = 0;
  size_t keyframes_recast = 0, keyframe_cells = 0;
  double structure_ms = 0.0;  ///< planes and objects moved (tracking paused)
  double recast_ms = 0.0;     ///< grid links re-cast (tracking goes on)
};

/// Receives device and SLAM events. Calls are serialised (one at a time) and
/// made without the graph's locks, so handlers may query the graph; they must
/// not connect or remove devices.
class GraphListener {
 public:
  virtual ~GraphListener() = default;
  /// A SLAM map was created (set its mapper's callbacks here), before anything
  /// is tracked in it.
  virtual void onMapCreated(MapId /*id*/, const std::shared_ptr<SlamSystem>& /*slam*/) {}
  /// A map went (merged into another, replaced by a load, or never used).
  virtual void onMapRemoved(MapId /*id*/) {}
  /// Two maps merged: planes, objects and grid links moved.
  virtual void onMapsMerged(const MapMergeReport& /*report*/) {}
  virtual void onDeviceAdded(const DeviceInfo& /*device*/) {}
  virtual void onDeviceRemoved(const DeviceInfo& /*device*/) {}
  /// The map was corrected (a loop closed, a global BA): keyframes, points,
  /// planes and VOs moved, all of it done (VOs in SQLite) before this call.
  virtual void onMapCorrected(const MapCorrectionReport& /*report*/) {}
};

/// What a map file holds (or held).
struct MapCounts {
  uint32_t keyframes = 0;
  uint32_t map_points = 0;
  uint32_t planes = 0;
  uint32_t objects = 0;  ///< tombstones included
  uint32_t maps = 0;
  /// Objects whose map is not in the file (kept in the store, shown to no
  /// device, listed by the load so that nothing is silently misplaced).
  std::vector<ObjectId> orphan_objects;
  double milliseconds = 0.0;
  size_t bytes = 0;  ///< size of the file
  /// VoLoad::kMergeNewer: objects taken from the file (newer there or only
  /// there) and kept as the database has them.
  size_t objects_from_file = 0, objects_kept = 0;
};

/// What a map file's VOs do to the store's (GlobalGraph::load).
enum class VoLoad {
  /// The file's objects replace the store's: a saved session loaded on purpose
  /// (/ecar/load_map, or a map_file of another database).
  kReplace,
  /// The file is an older snapshot of this very store (the server's own
  /// autosave, resumed after a crash): per object the newer version wins
  /// (VoStore::mergeNewer), so no change acknowledged since the autosave is lost.
  kMergeNewer,
};

class GlobalGraph {
 public:
  /// Validates `config` and opens the VO store (throws ecar::Error naming the
  /// key or the database file); the stored objects are attached to the grid.
  explicit GlobalGraph(const GlobalGraphConfig& config);
  GlobalGraph(const GlobalGraph&) = delete;
  GlobalGraph& operator=(const GlobalGraph&) = delete;

  const GlobalGraphConfig& config() const { return config_; }

  // ---- devices
  /// Registers (or re-registers) a device with its own camera (its tracker and
  /// keyframes use it). Refused: an invalid name or sync mode
  /// (DeviceRegistry::refusal), a live name without its `session` token, too
  /// many devices (DeviceRegistry::connect). The first device creates the atlas.
  DeviceConnectResult connect(const std::string& name, const PinholeCamera& camera,
                              const std::string& sync_mode, uint32_t keyframe_queue, double now,
                              uint64_t session = 0);
  /// Disconnects a device whose token is `session`; kOk when it did.
  SessionCheck disconnect(const std::string& name, uint64_t session);
  /// Drops the devices silent for longer than the timeout; returns their names.
  std::vector<std::string> removeSilent(double now);
  /// Marks a device as heard from when `session` is its token.
  SessionCheck touch(const std::string& name, uint64_t session, double now) {
    return devices_.touch(name, session, now);
  }
  const DeviceRegistry& devices() const { return devices_; }

  // ---- the SLAM maps
  /// Aligns one upload of a connected device in its map (Atlas::track; the
  /// result names the map); then re-casts the grid links a merge moved. A
  /// NOT_INITIALISED result with a message before any device connected.
  TrackResult track(DeviceId device, const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c,
                    const std::optional<SE3>& T_o_c);
  /// Forgets a device's trackers once it is gone (after its last upload's
  /// alignment); a device that made no keyframe and has not connected again
  /// is forgotten altogether: its id, name and cameras (what the server holds
  /// per name stays bounded by the devices that mapped).
  void removeDevice(DeviceId device);
  /// Null until the first device connected (or a map was loaded).
  std::shared_ptr<Atlas> atlas() const;
  /// A new empty map (the atlas is created with `camera` as its default camera
  /// when there is none): tools and tests fill it.
  std::shared_ptr<SlamSystem> addMap(const PinholeCamera& camera, MapId* id = nullptr);
  /// True once a map exists.
  bool hasMap() const;
  /// Null when `id` is not a live map.
  std::shared_ptr<SlamSystem> map(MapId id) const;
  /// The live map holding a keyframe (through merges); null when none.
  std::shared_ptr<SlamSystem> mapOfKeyFrame(KeyFrameId keyframe, MapId* id = nullptr) const;
  /// The map a device tracks in (invalid when none yet).
  MapId mapOf(DeviceId device) const;
  /// The map with the most keyframes (invalid when there is none): where rviz
  /// draws and registers.
  MapId largestMap() const;
  std::vector<MapId> mapIds() const;
  /// The camera a device's uploads are tracked with (the first camera for a
  /// name never connected); null before any device connected.
  CameraPtr camera(const std::string& device) const;
  /// The map epoch, shared by every map: first_epoch until a map file is
  /// loaded, then past every map's.
  uint32_t epoch() const;

  // ---- structure
  PlaneMap& planes() { return planes_; }
  const PlaneMap& planes() const { return planes_; }
  GridMap& grid() { return grid_; }
  const GridMap& grid() const { return grid_; }
  VoStore& vos() { return *vos_; }
  const VoStore& vos() const { return *vos_; }
  /// Shared while reading or changing planes, grid links or VOs for one
  /// keyframe or upload; load() takes it exclusively.
  std::shared_lock<std::shared_mutex> structureLock() const {
    return std::shared_lock<std::shared_mutex>(structure_mutex_);
  }
  /// Increments with every load.
  uint64_t generation() const;

  /// A culled keyframe's plane and cell links go; the objects hanging on it
  /// (keyframe attachment) move to its heir, in SQLite first. Returns how many
  /// moved; throws ecar::Error when the database write fails. Does nothing
  /// while a load runs (the keyframe belongs to the map being replaced).
  size_t eraseKeyFrame(KeyFrameId culled, KeyFrameId heir);
  /// Moves what hangs on the map with a correction the SLAM applied (loop
  /// closing, global BA): planes with the correction of their keyframes, VOs
  /// with that of the keyframe nearest to them (before the correction; version
  /// + 1, in SQLite before this returns), with the structure frozen so that no
  /// module sees half of it; then the grid links of keyframes that moved by
  /// more than a quarter cell are re-cast (modules go on meanwhile) and the
  /// listeners told. A
  /// correction of a replaced map (another epoch) is ignored. Called by the
  /// SLAM's loop closer (its thread, no SLAM lock held).
  MapCorrectionReport applyMapCorrection(MapId map, const MapCorrection& correction);
  /// Two maps of the atlas merged (the atlas calls it while no upload is
  /// tracked, before the merging upload is answered): the merged map's planes
  /// and objects move into the kept map through merge.S (versions + 1, the
  /// objects in SQLite first; a database failure leaves them in the old map,
  /// kept); the grid links of the moved keyframes wait for finishMerges().
  void applyMerge(const MergeEvent& merge);
  /// Re-casts the grid links of the keyframes merges moved (track() calls
  /// it, outside the atlas's session lock), then tells the listeners.
  void finishMerges();
  /// The VO map bounds: the keyframe centres' bounding box grown by
  /// vo_map_margin, within the configured bounds (unchanged without a map).
  void updateVoBounds();

  // ---- saving and loading
  /// Writes the whole atlas (every map's keyframes and points, with the
  /// cameras; planes, grid links, VOs with their maps) to `path` atomically. A consistent copy: the
  /// structure is frozen while the SLAM map is encoded under its read lock; the file is written
  /// after the locks are released. Throws ecar::Error naming the path and the problem.
  MapCounts save(const std::string& path);
  /// Replaces the whole atlas by the one in `path` (a one-map file of an
  /// older build is map 1). Every section is read, CRC-checked and decoded
  /// first (nothing changes when one fails); then, with the structure frozen:
  /// the VO store and its database are replaced (one transaction), the maps
  /// are installed (running alignments finish first, new ones wait; every
  /// device relocalises; the epoch moves on), planes and grid links are
  /// swapped and the objects re-attached to the grid. Before any device
  /// connected, the atlas is created with the file's first camera as its
  /// default. Keyframes keep their saved cameras; connected devices keep
  /// theirs. Objects of a map the file does not hold are kept and listed in
  /// orphan_objects. Throws ecar::Error naming the path, the section and the
  /// field; a file that is not a regular file or is larger than `max_bytes` is
  /// refused unread (MapFileReader::open). `vos`: replace the store's objects
  /// or merge the newer of each (see VoLoad).
  MapCounts load(const std::string& path, size_t max_bytes = kMaxMapFileBytes,
                 VoLoad vos = VoLoad::kReplace);

  /// Adds a listener and replays the current state to it (onMapCreated for
  /// each map, onDeviceAdded for each device). It must outlive its registration.
  void addListener(GraphListener* listener);
  void removeListener(GraphListener* listener);

 private:
  /// The atlas, created with `camera` as its default when missing.
  std::shared_ptr<Atlas> atlasFor(const PinholeCamera& camera);
  // Atlas callbacks.
  void onMapCreated(MapId id, const std::shared_ptr<SlamSystem>& slam);
  void onMapRemoved(MapId id);
  /// Re-casts the grid links of keyframes that `correction` moved by more
  /// than a quarter cell, on the planes of `map`. The structure lock shared.
  void recast(MapId map, const MapCorrection& correction,
              const std::unordered_map<KeyFrameId, Eigen::Vector3d>& centres_before,
              size_t* keyframes, size_t* cells);

  const GlobalGraphConfig config_;
  DeviceRegistry devices_;
  PlaneMap planes_;
  GridMap grid_;
  std::unique_ptr<VoStore> vos_;
  mutable std::shared_mutex structure_mutex_;

  mutable std::mutex mutex_;  // guards atlas_, cameras_, generation_, merged_
  std::shared_ptr<Atlas> atlas_;
  /// Each device's camera (devices with one camera share the object).
  std::unordered_map<DeviceId, CameraPtr> cameras_;
  CameraPtr first_camera_;
  uint64_t generation_ = 0;
  /// Merges whose grid links wait to be re-cast, with the keyframe centres
  /// before the merge.
  struct PendingMerge {
    MapMergeReport report;
    std::unordered_map<KeyFrameId, Eigen::Vector3d> centres_before;
  };
  std::vector<PendingMerge> merged_;

  std::mutex events_mutex_;  // serialises event delivery; guards listeners_
  std::vector<GraphListener*> listeners_;
};

}  // namespace ecar
