// The server's structure state for planes, grid cells and virtual objects,
// shared by the nodelets through ServerContext::structure(). ROS-free.
//
//   Structure& s = ctx->structure();
//   s.integrateKeyFrame(input, grid);              // PlaneSegmentation nodelet, per keyframe
//   VisibleStructure v = s.visible(T_w_c, local_keyframes, *grid);  // GraphPublisher, per upload
//   VoOutcome r = s.vos().registerObject(vo, nearest);              // Interactions nodelet
//
// The planes are a PlaneMap; ray casting reads an immutable GridPlanes snapshot
// that integrateKeyFrame() swaps when the planes changed, so casting never waits
// for plane updates. The VoStore is opened on the first vos() call.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"
#include "ecar_server/config.h"

namespace ecar_server {

/// What a local graph carries besides points: planes and objects.
struct VisibleStructure {
  std::vector<ecar::Plane> planes;           ///< by increasing id
  std::vector<ecar::VirtualObject> objects;  ///< live, by increasing id
  std::vector<ecar::CellKey> cells;          ///< cells hit by the sampled rays, sorted
  double milliseconds = 0.0;                 ///< time of the whole computation
  std::string error;  ///< why objects are missing (the VO store could not be opened)
};

/// What integrateKeyFrame() did.
struct KeyFrameStructure {
  ecar::PlaneMapUpdate update;
  size_t observations = 0;  ///< planes segmented in the keyframe's points
  size_t cells = 0;         ///< cells linked to the keyframe
  double segment_ms = 0.0, integrate_ms = 0.0, grid_ms = 0.0;
  /// The input was copied from a map that was replaced since: nothing changed.
  bool stale = false;
};

class Structure {
 public:
  /// Throws ecar::Error when the plane or grid config is invalid.
  explicit Structure(const ServerConfig& config);

  const ecar::PlaneMap& planes() const { return planes_; }
  const ecar::GridMap& grid() const { return grid_; }
  /// The VO store, opened on the first call. Throws ecar::Error naming the file
  /// when it cannot be opened (then on every later call, without retrying).
  ecar::VoStore& vos();

  /// The grid caster of a camera (created once; later cameras are assumed the same).
  std::shared_ptr<const ecar::GridCaster> gridConnection(const ecar::PinholeCamera& camera);
  /// The current planes prepared for casting (never null).
  std::shared_ptr<const ecar::GridPlanes> gridPlanes() const;

  /// Segments one keyframe's copied points, merges them into the planes,
  /// refreshes the GridPlanes snapshot when the planes changed, and links the
  /// keyframe to the cells visible from T_w_c (its pose). `generation`: the
  /// generation() read before the input was copied from the SLAM map; when a
  /// map was loaded since, the input is dropped (result.stale) so that no
  /// plane of the old map's coordinates enters the new one.
  KeyFrameStructure integrateKeyFrame(const ecar::PlaneKeyFrameInput& input, const ecar::SE3& T_w_c,
                                      const ecar::GridCaster& grid,
                                      std::optional<uint64_t> generation = std::nullopt);
  /// Forgets a keyframe's plane and cell links.
  void eraseKeyFrame(ecar::KeyFrameId id);

  // ---- saving and loading the map (MapStorage)
  /// Increments each time replace() swapped a loaded map in.
  uint64_t generation() const { return generation_.load(); }
  /// Holds every change of the planes and grid (integrateKeyFrame,
  /// eraseKeyFrame) and visible() off while alive: take it around save() for
  /// a consistent copy, and around the SLAM map's install and replace() so no
  /// reader sees half of a load. Blocks until running changes finish.
  std::unique_lock<std::shared_mutex> lockForReplace();
  /// Planes, grid links and VOs as a map file stores them (hold lockForReplace()).
  ecar::StructureState save();
  /// Swaps decoded structure in (hold lockForReplace()): the VO store first
  /// (its database rewritten in one transaction; when that throws ecar::Error,
  /// nothing changed), then `install_slam` (which swaps the SLAM map in), then
  /// planes and grid links, the GridPlanes snapshot, the per-device visible
  /// cells (cleared), and last generation() + 1: an integrateKeyFrame input
  /// copied under the new generation comes from the new SLAM map.
  void replace(const ecar::StructureState& state, const std::function<void()>& install_slam);

  /// Planes and objects for a frame aligned at T_w_c with these local keyframes:
  /// planes hit by the sampled rays (and those of the local keyframes when
  /// graph_keyframe_planes); objects (none, with `error` set, when the VO store
  /// cannot be opened): grid mode, the live VOs attached to a
  /// visible cell (radius 1) or whose position, start or end passes
  /// GridCaster::isVisible; keyframe mode, the VOs of the local keyframes.
  VisibleStructure visible(const ecar::SE3& T_w_c,
                           const std::vector<ecar::KeyFrameId>& local_keyframes,
                           const ecar::GridCaster& grid);

  /// The cells last found visible per device (for rviz).
  void setDeviceCells(const std::string& device, std::vector<ecar::CellKey> cells);
  std::map<std::string, std::vector<ecar::CellKey>> deviceCells() const;
  void eraseDevice(const std::string& device);

 private:
  const ServerConfig config_;
  ecar::PlaneSegmenter segmenter_;
  ecar::PlaneMap planes_;
  ecar::GridMap grid_;
  /// Shared by integrateKeyFrame/eraseKeyFrame/visible, exclusive around a
  /// save or a load (lockForReplace). Taken before mutex_, never inside it.
  std::shared_mutex replace_mutex_;
  std::atomic<uint64_t> generation_{0};

  mutable std::mutex mutex_;  // guards the members below
  std::shared_ptr<const ecar::GridPlanes> grid_planes_;
  uint64_t grid_planes_revision_ = 0;
  std::shared_ptr<const ecar::GridCaster> caster_;
  std::unique_ptr<ecar::VoStore> vos_;
  std::string vos_error_;  ///< why the store could not be opened
  std::map<std::string, std::vector<ecar::CellKey>> device_cells_;
};

}  // namespace ecar_server
