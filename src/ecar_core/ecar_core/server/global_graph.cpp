#include "ecar_core/server/global_graph.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <sstream>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"
#include "ecar_core/structure/grid_caster.h"

namespace ecar {
namespace {

VoStoreConfig voConfigOf(const GlobalGraphConfig& config) {
  VoStoreConfig c = config.vo;
  c.cell_size = config.grid.cell_size;
  return c;
}

}  // namespace

void GlobalGraphConfig::validate() const {
  const auto fail = [](const std::string& key, const std::string& why) {
    throw Error(key + ": " + why);
  };
  if (slam.first_epoch < 1) fail("first_epoch", "must be >= 1");
  planes.validate();
  grid.validate();
  try {
    voConfigOf(*this).validate();
  } catch (const Error& e) {
    fail("vo", e.what());
  }
  if (!(vo_map_margin >= 0.0)) fail("vo.map_margin", "must be >= 0 m");
  if (!(camera_tolerance >= 0.0 && camera_tolerance < 1.0)) {
    fail("camera_tolerance", "must be in [0, 1)");
  }
  if (!(devices.device_timeout > 0.0)) fail("device_timeout", "must be > 0 s");
}

GlobalGraph::GlobalGraph(const GlobalGraphConfig& config)
    : config_((config.validate(), config)),
      devices_(config.devices),
      planes_(config.planes),
      vos_(std::make_unique<VoStore>(voConfigOf(config))) {
  grid_.attachObjects(vos_->allObjects(), vos_->config().cell_size, vos_->config().attach_margin);
}

std::shared_ptr<Atlas> GlobalGraph::atlasFor(const PinholeCamera& camera) {
  std::shared_ptr<Atlas> atlas;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (atlas_) return atlas_;
    SlamConfig c = config_.slam;
    c.synchronous_mapping = false;
    atlas_ = std::make_shared<Atlas>(camera, c, config_.atlas);
    first_camera_ = std::make_shared<const PinholeCamera>(camera);
    atlas = atlas_;
  }
  AtlasCallbacks callbacks;
  callbacks.created = [this](MapId id, const std::shared_ptr<SlamSystem>& slam) {
    onMapCreated(id, slam);
  };
  callbacks.removed = [this](MapId id) { onMapRemoved(id); };
  callbacks.merged = [this](const MergeEvent& merge) { applyMerge(merge); };
  atlas->setCallbacks(std::move(callbacks));
  return atlas;
}

void GlobalGraph::onMapCreated(MapId id, const std::shared_ptr<SlamSystem>& slam) {
  // What hangs on the map moves with every loop correction.
  slam->loopCloser().setCorrectedCallback([this, id](const MapCorrection& correction) {
    try {
      applyMapCorrection(id, correction);
    } catch (const Error&) {
      // A VO database write failed: the objects stay where they were (still
      // stored), the planes moved; the next correction or change retries.
    }
  });
  std::lock_guard<std::mutex> events(events_mutex_);
  for (GraphListener* l : listeners_) l->onMapCreated(id, slam);
}

void GlobalGraph::onMapRemoved(MapId id) {
  std::lock_guard<std::mutex> events(events_mutex_);
  for (GraphListener* l : listeners_) l->onMapRemoved(id);
}

std::shared_ptr<Atlas> GlobalGraph::atlas() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return atlas_;
}

std::shared_ptr<SlamSystem> GlobalGraph::addMap(const PinholeCamera& camera, MapId* id) {
  const std::shared_ptr<Atlas> atlas = atlasFor(camera);
  const MapId m = atlas->addMap();
  if (id) *id = m;
  return atlas->map(m);
}

bool GlobalGraph::hasMap() const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  return atlas && !atlas->mapIds().empty();
}

TrackResult GlobalGraph::track(DeviceId device, const cv::Mat& image, double timestamp,
                               uint32_t frame_index,
                               const std::optional<Eigen::Vector3d>& gravity_c,
                               const std::optional<SE3>& T_o_c) {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  if (!atlas) {
    TrackResult r;
    r.message = "no device connected";
    r.map_epoch = epoch();
    return r;
  }
  MapId map;
  TrackResult r = atlas->track(device, image, timestamp, frame_index, gravity_c, T_o_c, &map);
  finishMerges();
  return r;
}

std::shared_ptr<SlamSystem> GlobalGraph::map(MapId id) const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  return atlas ? atlas->map(id) : nullptr;
}

std::shared_ptr<SlamSystem> GlobalGraph::mapOfKeyFrame(KeyFrameId keyframe, MapId* id) const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  const MapId m = atlas ? atlas->mapOfKeyFrame(keyframe) : MapId();
  if (id) *id = m;
  return m.valid() ? atlas->map(m) : nullptr;
}

MapId GlobalGraph::mapOf(DeviceId device) const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  return atlas ? atlas->mapOf(device) : MapId();
}

std::vector<MapId> GlobalGraph::mapIds() const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  return atlas ? atlas->mapIds() : std::vector<MapId>();
}

MapId GlobalGraph::largestMap() const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  if (!atlas) return MapId();
  MapId best;
  size_t most = 0;
  for (const MapId id : atlas->mapIds()) {
    const std::shared_ptr<SlamSystem> slam = atlas->map(id);
    if (!slam) continue;
    auto lock = slam->map().readLock();
    const size_t n = slam->map().numKeyFrames();
    if (!best.valid() || n > most) {
      best = id;
      most = n;
    }
  }
  return best;
}

uint32_t GlobalGraph::epoch() const {
  const std::shared_ptr<Atlas> atlas = this->atlas();
  return atlas ? atlas->epoch() : config_.slam.first_epoch;
}

uint64_t GlobalGraph::generation() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return generation_;
}

size_t GlobalGraph::eraseKeyFrame(KeyFrameId culled, KeyFrameId heir) {
  // Not waiting for a load: it may be waiting for the mapping thread this is
  // called on, and the culled keyframe belongs to the map being replaced.
  std::shared_lock<std::shared_mutex> structure(structure_mutex_, std::try_to_lock);
  if (!structure) return 0;
  planes_.eraseKeyFrame(culled);
  grid_.eraseKeyFrame(culled);
  return vos_->moveKeyFrame(culled, heir);
}

namespace {

/// The nearest of `centres` to p within sqrt(reach2); null when none.
const Sim3* nearestCorrection(const std::vector<std::pair<Eigen::Vector3d, Sim3>>& centres,
                              const Eigen::Vector3d& p, double reach2) {
  const Sim3* nearest = nullptr;
  double best = reach2;
  for (const auto& [c, S] : centres) {
    const double d2 = (c - p).squaredNorm();
    if (d2 < best) {
      best = d2;
      nearest = &S;
    }
  }
  return nearest;
}

}  // namespace

MapCorrectionReport GlobalGraph::applyMapCorrection(MapId map_id, const MapCorrection& correction) {
  const auto start = std::chrono::steady_clock::now();
  MapCorrectionReport report;
  report.map = map_id;
  const std::shared_ptr<SlamSystem> slam = map(map_id);
  if (!slam || correction.empty()) return report;
  // Where the moved keyframes were before (VOs take the correction of the
  // nearest; their grid links are re-cast when they moved far enough).
  std::vector<std::pair<Eigen::Vector3d, Sim3>> moved;
  std::unordered_map<KeyFrameId, Eigen::Vector3d> centres_before;
  {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    {
      auto lock = slam->map().readLock();
      if (slam->map().epoch() != correction.epoch) return report;  // a replaced map
      for (const auto& [id, S] : correction.keyframes) {
        const KeyFrame* kf = slam->map().keyframe(id);
        if (!kf) continue;
        const Eigen::Vector3d before = S.inverse() * kf->center();
        moved.emplace_back(before, S);
        centres_before.emplace(id, before);
      }
    }
    report.keyframes = moved.size();
    report.points = correction.points_moved;
    report.planes = planes_.transformPlanes(
        [&](const std::vector<KeyFrameId>& keyframes) -> std::optional<Sim3> {
          for (const KeyFrameId k : keyframes) {
            const auto it = correction.keyframes.find(k);
            if (it != correction.keyframes.end()) return it->second;
          }
          return std::nullopt;
        });
    {
      // The planes follow their points' adjusted positions exactly (a point
      // fused into another, as a merge's seam does, by the one it became),
      // and planes that are one now (a merge's two floors) become one.
      auto lock = slam->map().readLock();
      const Map& map = slam->map();
      report.planes_removed =
          planes_
              .refit(map_id,
                     [&](MapPointId id) -> std::optional<Eigen::Vector3d> {
                       const MapPointId live = map.livePoint(id);
                       const MapPoint* p = map.point(live);
                       if (!p) {
                         ++report.plane_points_gone;
                         return std::nullopt;
                       }
                       ++(live == id ? report.plane_points_live : report.plane_points_fused);
                       return p->p_w;
                     })
              .removed.size();
    }
    const double reach2 = config_.vo_map_margin * config_.vo_map_margin;
    const std::vector<ObjectId> objects = vos_->transformObjects(
        [&](const VirtualObject& vo) -> std::optional<Sim3> {
          if (vo.map != map_id) return std::nullopt;
          const Sim3* S = nearestCorrection(moved, vo.position, reach2);
          return S ? std::optional<Sim3>(*S) : std::nullopt;
        },
        "map");
    report.objects = objects.size();
    for (const VirtualObject& vo : vos_->objects(objects)) {
      grid_.attachObject(vo, vos_->config().cell_size, vos_->config().attach_margin);
    }
    std::lock_guard<std::mutex> lock(mutex_);
    ++generation_;
  }
  // Keyframe-cell links from the new poses, with the modules going on
  // meanwhile (ray casting hundreds of keyframes takes a while).
  {
    auto structure = structureLock();
    if (epoch() != correction.epoch) return report;  // a map was loaded meanwhile
    recast(map_id, correction, centres_before, &report.keyframes_recast, &report.keyframe_cells);
  }
  try {
    updateVoBounds();
  } catch (const Error&) {
  }
  report.milliseconds = msSince(start);
  std::lock_guard<std::mutex> events(events_mutex_);
  for (GraphListener* l : listeners_) l->onMapCorrected(report);
  return report;
}

void GlobalGraph::recast(MapId map_id, const MapCorrection& correction,
                         const std::unordered_map<KeyFrameId, Eigen::Vector3d>& centres_before,
                         size_t* keyframes, size_t* cells_linked) {
  const std::shared_ptr<SlamSystem> slam = map(map_id);
  if (!slam) return;
  std::vector<Plane> planes_of_map;
  for (Plane& p : planes_.planes()) {
    if (p.map == map_id) planes_of_map.push_back(std::move(p));
  }
  const GridPlanes planes(planes_of_map, config_.grid.boundary_margin);
  std::vector<std::pair<CameraPtr, std::unique_ptr<GridCaster>>> casters;
  std::vector<CellKey> cells;
  const double min_move = 0.25 * config_.grid.cell_size;
  for (const auto& [id, S] : correction.keyframes) {
    const auto before = centres_before.find(id);
    if (before == centres_before.end() || !grid_.hasKeyFrame(id)) continue;
    SE3 T_w_c;
    CameraPtr camera;
    {
      auto lock = slam->map().readLock();
      const KeyFrame* kf = slam->map().keyframe(id);
      if (!kf) continue;
      T_w_c = kf->T_w_c();
      camera = kf->camera;
    }
    if (!camera) continue;
    const double turn = Eigen::AngleAxisd(S.R).angle() * 10.0;  // ~ cell shift at 10 m
    if ((T_w_c.translation() - before->second).norm() < min_move && turn < min_move) continue;
    GridCaster* caster = nullptr;
    for (auto& [c, g] : casters) {
      if (c == camera) caster = g.get();
    }
    if (!caster) {
      casters.emplace_back(camera, std::make_unique<GridCaster>(config_.grid, *camera));
      caster = casters.back().second.get();
    }
    caster->visibleCells(T_w_c, planes, &cells);
    *cells_linked += cells.size();
    ++*keyframes;
    grid_.setKeyFrameCells(id, cells);
  }
}

void GlobalGraph::applyMerge(const MergeEvent& merge) {
  // No upload is tracked while this runs (the atlas holds its session lock):
  // the merged map's planes and objects move into the kept map's coordinates
  // before the merging upload, or any later one, is answered.
  const auto start = std::chrono::steady_clock::now();
  PendingMerge pending;
  pending.report.merge = merge;
  const std::shared_ptr<SlamSystem> into = map(merge.into);
  if (into) {
    auto lock = into->map().readLock();
    for (const auto& [id, S] : merge.correction.keyframes) {
      if (const KeyFrame* kf = into->map().keyframe(id)) {
        pending.centres_before.emplace(id, S.inverse() * kf->center());
      }
    }
  }
  {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    pending.report.planes = planes_.moveMap(merge.from, merge.into, merge.S);
    try {
      const std::vector<ObjectId> objects = vos_->transformObjects(
          [&](const VirtualObject& vo) -> std::optional<Sim3> {
            return vo.map == merge.from ? std::optional<Sim3>(merge.S) : std::nullopt;
          },
          "map", merge.into);
      pending.report.objects = objects.size();
      for (const VirtualObject& vo : vos_->objects(objects)) {
        grid_.attachObject(vo, vos_->config().cell_size, vos_->config().attach_margin);
      }
    } catch (const Error&) {
      // The database refused: the objects stay in the merged map's id (kept,
      // listed as orphans by the next load) rather than half-moved.
    }
    std::lock_guard<std::mutex> lock(mutex_);
    ++generation_;
  }
  pending.report.structure_ms = msSince(start);
  std::lock_guard<std::mutex> lock(mutex_);
  merged_.push_back(std::move(pending));
}

void GlobalGraph::finishMerges() {
  std::vector<PendingMerge> merged;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (merged_.empty()) return;
    merged.swap(merged_);
  }
  for (PendingMerge& m : merged) {
    const auto start = std::chrono::steady_clock::now();
    {
      auto structure = structureLock();
      recast(m.report.merge.into, m.report.merge.correction, m.centres_before,
             &m.report.keyframes_recast, &m.report.keyframe_cells);
    }
    m.report.recast_ms = msSince(start);
    try {
      updateVoBounds();
    } catch (const Error&) {
    }
    std::lock_guard<std::mutex> events(events_mutex_);
    for (GraphListener* l : listeners_) l->onMapsMerged(m.report);
  }
}

void GlobalGraph::updateVoBounds() {
  std::optional<Bounds> all;
  for (const MapId id : mapIds()) {
    const std::shared_ptr<SlamSystem> slam = map(id);
    if (!slam) continue;
    const std::optional<Bounds> b = keyframeBounds(slam->map());
    if (!b) continue;
    if (!all) {
      all = b;
    } else {
      all->min = all->min.cwiseMin(b->min);
      all->max = all->max.cwiseMax(b->max);
    }
  }
  if (!all) return;
  const Eigen::Vector3d margin = Eigen::Vector3d::Constant(config_.vo_map_margin);
  // The configured bounds are the limit; the maps' extent narrows them.
  vos_->setMapBounds((all->min - margin).cwiseMax(config_.vo.map_min),
                     (all->max + margin).cwiseMin(config_.vo.map_max));
}

MapCounts GlobalGraph::save(const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  const std::string where = "map file '" + path + "'";
  const std::shared_ptr<Atlas> atlas = this->atlas();
  if (!atlas || atlas->mapIds().empty()) {
    throw Error(where + ": nothing to save, no device has connected yet");
  }
  MapCounts counts;
  MapFileWriter writer;
  {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    // The largest map first: it is the "slam" section an older build reads.
    std::vector<MapId> ids = atlas->mapIds();
    const MapId largest = largestMap();
    std::stable_partition(ids.begin(), ids.end(), [&](MapId id) { return id == largest; });
    std::vector<std::pair<MapId, std::vector<uint8_t>>> maps;
    for (const MapId id : ids) {
      const std::shared_ptr<SlamSystem> slam = atlas->map(id);
      if (!slam) continue;
      auto lock = slam->map().readLock();
      maps.emplace_back(id, encodeSlamMap(slam->map(), slam->camera()));
      counts.keyframes += static_cast<uint32_t>(slam->map().numKeyFrames());
      counts.map_points += static_cast<uint32_t>(slam->map().numPoints());
    }
    counts.maps = static_cast<uint32_t>(maps.size());
    addAtlasSections(&writer, std::move(maps));
    StructureState state;
    state.planes = planes_.save();
    state.next_plane_id = planes_.nextId();
    state.grid = grid_.save();
    state.vos = vos_->snapshot();
    counts.planes = static_cast<uint32_t>(state.planes.size());
    counts.objects = static_cast<uint32_t>(state.vos.objects.size());
    addStructureSections(&writer, state);
  }
  writer.write(path);  // names the path in its errors
  std::error_code ec;
  counts.bytes = static_cast<size_t>(std::filesystem::file_size(path, ec));
  counts.milliseconds = msSince(start);
  return counts;
}

MapCounts GlobalGraph::load(const std::string& path, size_t max_bytes, VoLoad vos) {
  const auto start = std::chrono::steady_clock::now();
  const MapFileReader file = MapFileReader::open(path, max_bytes);
  // Decode everything before anything changes.
  std::shared_ptr<Atlas> atlas = this->atlas();
  const std::vector<std::pair<MapId, std::string>> sections = atlasSections(file);
  std::vector<MapId> ids;
  for (const auto& s : sections) ids.push_back(s.first);
  const PinholeCamera camera =
      atlas ? atlas->camera(DeviceId()) : decodeSlamCamera(file.reader(kSlamSection));
  const ScaleInfo scale = ScaleInfo::fromConfig(config_.slam.orb);
  std::vector<std::pair<MapId, std::unique_ptr<Map>>> maps;
  MapCounts counts;
  for (const auto& [id, section] : sections) {
    try {
      maps.emplace_back(id, decodeSlamMap(file.reader(section), scale));
    } catch (const Error& e) {
      throw Error("map file '" + path + "': map " + std::to_string(id.value) + ": " + e.what());
    }
    counts.keyframes += static_cast<uint32_t>(maps.back().second->numKeyFrames());
    counts.map_points += static_cast<uint32_t>(maps.back().second->numPoints());
  }
  counts.maps = static_cast<uint32_t>(maps.size());
  StructureState state = readStructureSections(file);
  counts.planes = static_cast<uint32_t>(state.planes.size());
  counts.objects = static_cast<uint32_t>(state.vos.objects.size());
  counts.bytes = file.fileSize();
  if (!atlas) atlas = atlasFor(camera);
  try {
    // No upload is tracked while the atlas installs; the structure is frozen
    // (in that order, as in a merge).
    atlas->install(std::move(maps), [&] {
      std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
      // The VO store first: a database failure changes nothing.
      if (vos == VoLoad::kMergeNewer) {
        const VoStore::MergeCounts merged = vos_->mergeNewer(state.vos);
        counts.objects_from_file = merged.from_snapshot;
        counts.objects_kept = merged.kept;
      } else {
        vos_->replaceAll(state.vos);
      }
      planes_.load(state.planes, state.next_plane_id);
      grid_.load(state.grid);
      grid_.attachObjects(vos_->allObjects(), vos_->config().cell_size,
                          vos_->config().attach_margin);
      std::lock_guard<std::mutex> lock(mutex_);
      ++generation_;
    });
  } catch (const Error& e) {
    throw Error("map file '" + path + "': " + e.what());
  }
  // After the load (a merge keeps the database's objects too).
  for (const VirtualObject& vo : vos_->allObjects()) {
    if (!vo.deleted && std::find(ids.begin(), ids.end(), vo.map) == ids.end()) {
      counts.orphan_objects.push_back(vo.id);
    }
  }
  try {
    updateVoBounds();
  } catch (const Error&) {
    // The configured bounds stay (the map's keyframes lie inside them anyway).
  }
  counts.milliseconds = msSince(start);
  return counts;
}

void GlobalGraph::addListener(GraphListener* listener) {
  std::lock_guard<std::mutex> events(events_mutex_);
  listeners_.push_back(listener);
  if (const std::shared_ptr<Atlas> atlas = this->atlas()) {
    for (const MapId id : atlas->mapIds()) {
      if (const std::shared_ptr<SlamSystem> slam = atlas->map(id)) listener->onMapCreated(id, slam);
    }
  }
  for (const DeviceInfo& d : devices_.devices()) listener->onDeviceAdded(d);
}

void GlobalGraph::removeListener(GraphListener* listener) {
  std::lock_guard<std::mutex> events(events_mutex_);
  listeners_.erase(std::remove(listeners_.begin(), listeners_.end(), listener), listeners_.end());
}

}  // namespace ecar
