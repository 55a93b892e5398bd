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

std::shared_ptr<SlamSystem> GlobalGraph::slamLocked(const PinholeCamera& camera, bool* created) {
  *created = false;
  if (slam_) return slam_;
  SlamConfig c = config_.slam;
  c.synchronous_mapping = false;
  slam_ = std::make_shared<SlamSystem>(camera, c);
  // What hangs on the map moves with every loop correction.
  slam_->loopCloser().setCorrectedCallback([this](const MapCorrection& correction) {
    try {
      applyMapCorrection(correction);
    } catch (const Error&) {
      // A VO database write failed: the objects stay where they were (still
      // stored), the planes moved; the next correction or change retries.
    }
  });
  *created = true;
  return slam_;
}

DeviceConnectResult GlobalGraph::connect(const std::string& name, const PinholeCamera& camera,
                                         const std::string& sync_mode, uint32_t keyframe_queue,
                                         double now) {
  DeviceConnectResult result;
  result.message = DeviceRegistry::refusal(name, sync_mode);
  if (!result.message.empty()) return result;
  std::lock_guard<std::mutex> events(events_mutex_);
  std::shared_ptr<SlamSystem> created, slam;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    bool is_new = false;
    slam = slamLocked(camera, &is_new);
    if (is_new) created = slam;
  }
  result = devices_.connect(name, sync_mode, keyframe_queue, now);
  // Each device tracks with its own camera; its keyframes carry it.
  if (result.accepted) slam->setCamera(result.device.id, camera, config_.camera_tolerance);
  if (created) {
    for (GraphListener* l : listeners_) l->onSlamCreated(created);
  }
  if (result.accepted && !result.reconnected) {
    for (GraphListener* l : listeners_) l->onDeviceAdded(result.device);
  }
  return result;
}

bool GlobalGraph::disconnect(const std::string& name) {
  std::lock_guard<std::mutex> events(events_mutex_);
  const std::optional<DeviceInfo> removed = devices_.disconnect(name);
  if (removed) {
    for (GraphListener* l : listeners_) l->onDeviceRemoved(*removed);
  }
  return removed.has_value();
}

std::vector<std::string> GlobalGraph::removeSilent(double now) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::vector<std::string> names;
  for (const DeviceInfo& d : devices_.removeSilent(now)) {
    names.push_back(d.name);
    for (GraphListener* l : listeners_) l->onDeviceRemoved(d);
  }
  return names;
}

std::shared_ptr<SlamSystem> GlobalGraph::slam() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return slam_;
}

std::shared_ptr<SlamSystem> GlobalGraph::slamFor(const PinholeCamera& camera) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::shared_ptr<SlamSystem> slam;
  bool created = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    slam = slamLocked(camera, &created);
  }
  if (created) {
    for (GraphListener* l : listeners_) l->onSlamCreated(slam);
  }
  return slam;
}

CameraPtr GlobalGraph::camera(const std::string& device) const {
  const std::shared_ptr<SlamSystem> slam = this->slam();
  if (!slam) return nullptr;
  const std::optional<DeviceInfo> info = devices_.device(device);
  return slam->camera(info ? info->id : DeviceId());
}

uint32_t GlobalGraph::epoch() const {
  const std::shared_ptr<SlamSystem> slam = this->slam();
  return slam ? mapEpoch(slam->map()) : config_.slam.first_epoch;
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

MapCorrectionReport GlobalGraph::applyMapCorrection(const MapCorrection& correction) {
  const auto start = std::chrono::steady_clock::now();
  MapCorrectionReport report;
  const std::shared_ptr<SlamSystem> slam = this->slam();
  if (!slam || correction.empty()) return report;
  // Where the moved keyframes were before (VOs take the correction of the
  // nearest), and their new poses and cameras (their grid links are re-cast).
  struct Moved {
    KeyFrameId id;
    Eigen::Vector3d centre_before;
    Sim3 S;
    SE3 T_w_c;
    CameraPtr camera;
  };
  std::vector<Moved> moved;
  {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    {
      auto lock = slam->map().readLock();
      if (slam->map().epoch() != correction.epoch) return report;  // a replaced map
      for (const auto& [id, S] : correction.keyframes) {
        const KeyFrame* kf = slam->map().keyframe(id);
        if (kf) moved.push_back({id, S.inverse() * kf->center(), S, kf->T_w_c(), kf->camera});
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
    const double reach2 = config_.vo_map_margin * config_.vo_map_margin;
    const std::vector<ObjectId> objects = vos_->transformObjects(
        [&](const VirtualObject& vo) -> std::optional<Sim3> {
          const Moved* nearest = nullptr;
          double best = reach2;
          for (const Moved& m : moved) {
            const double d2 = (m.centre_before - vo.position).squaredNorm();
            if (d2 < best) {
              best = d2;
              nearest = &m;
            }
          }
          if (!nearest) return std::nullopt;
          return nearest->S;
        },
        "map");
    report.objects = objects.size();
    for (const VirtualObject& vo : vos_->objects(objects)) {
      grid_.attachObject(vo, vos_->config().cell_size, vos_->config().attach_margin);
    }
    std::lock_guard<std::mutex> lock(mutex_);
    ++generation_;
  }
  // Keyframe-cell links from the new poses, for keyframes that moved by more
  // than a fraction of a cell (a global BA moves most by millimetres). Under
  // the shared structure lock: modules go on meanwhile (ray casting hundreds
  // of keyframes takes a while).
  {
    auto structure = structureLock();
    if (epoch() != correction.epoch) return report;  // a map was loaded meanwhile
    const GridPlanes planes(planes_.planes(), config_.grid.boundary_margin);
    std::vector<std::pair<CameraPtr, std::unique_ptr<GridCaster>>> casters;
    std::vector<CellKey> cells;
    const double min_move = 0.25 * config_.grid.cell_size;
    for (const Moved& m : moved) {
      if (!m.camera || !grid_.hasKeyFrame(m.id)) continue;
      const Eigen::Vector3d centre = m.T_w_c.translation();
      const double turn = Eigen::AngleAxisd(m.S.R).angle() * 10.0;  // ~ cell shift at 10 m
      if ((centre - m.centre_before).norm() < min_move && turn < min_move) continue;
      GridCaster* caster = nullptr;
      for (auto& [c, g] : casters) {
        if (c == m.camera) caster = g.get();
      }
      if (!caster) {
        casters.emplace_back(m.camera, std::make_unique<GridCaster>(config_.grid, *m.camera));
        caster = casters.back().second.get();
      }
      caster->visibleCells(m.T_w_c, planes, &cells);
      report.keyframe_cells += cells.size();
      ++report.keyframes_recast;
      grid_.setKeyFrameCells(m.id, cells);
    }
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

void GlobalGraph::updateVoBounds() {
  const std::shared_ptr<SlamSystem> slam = this->slam();
  if (!slam) return;
  const std::optional<Bounds> b = keyframeBounds(slam->map());
  if (!b) return;
  const Eigen::Vector3d margin = Eigen::Vector3d::Constant(config_.vo_map_margin);
  // The configured bounds are the limit; the map's extent narrows them.
  vos_->setMapBounds((b->min - margin).cwiseMax(config_.vo.map_min),
                     (b->max + margin).cwiseMin(config_.vo.map_max));
}

MapCounts GlobalGraph::save(const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  const std::string where = "map file '" + path + "'";
  const std::shared_ptr<SlamSystem> slam = this->slam();
  if (!slam) throw Error(where + ": nothing to save, no device has connected yet");
  MapCounts counts;
  MapFileWriter writer;
  {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    std::vector<uint8_t> slam_bytes;
    {
      auto lock = slam->map().readLock();
      slam_bytes = encodeSlamMap(slam->map(), slam->camera());
      counts.keyframes = static_cast<uint32_t>(slam->map().numKeyFrames());
      counts.map_points = static_cast<uint32_t>(slam->map().numPoints());
    }
    writer.addSection(kSlamSection, std::move(slam_bytes));
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

MapCounts GlobalGraph::load(const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  const MapFileReader file = MapFileReader::open(path);
  // Decode everything before anything changes.
  std::shared_ptr<SlamSystem> slam = this->slam();
  const PinholeCamera camera = slam ? slam->camera() : decodeSlamCamera(file.reader(kSlamSection));
  const ScaleInfo scale = slam ? slam->map().scale() : ScaleInfo::fromConfig(config_.slam.orb);
  std::unique_ptr<Map> map = decodeSlamMap(file.reader(kSlamSection), scale);
  const StructureState state = readStructureSections(file);
  MapCounts counts;
  counts.keyframes = static_cast<uint32_t>(map->numKeyFrames());
  counts.map_points = static_cast<uint32_t>(map->numPoints());
  counts.planes = static_cast<uint32_t>(state.planes.size());
  counts.objects = static_cast<uint32_t>(state.vos.objects.size());
  counts.bytes = file.fileSize();
  try {
    std::unique_lock<std::shared_mutex> frozen(structure_mutex_);
    // The VO store first: a database failure changes nothing.
    vos_->replaceAll(state.vos);
    if (!slam) slam = slamFor(camera);
    slam->installMap(std::move(map));
    planes_.load(state.planes, state.next_plane_id);
    grid_.load(state.grid);
    grid_.attachObjects(vos_->allObjects(), vos_->config().cell_size, vos_->config().attach_margin);
    std::lock_guard<std::mutex> lock(mutex_);
    ++generation_;
  } catch (const Error& e) {
    throw Error("map file '" + path + "': " + e.what());
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
  const std::shared_ptr<SlamSystem> slam = this->slam();
  if (slam) listener->onSlamCreated(slam);
  for (const DeviceInfo& d : devices_.devices()) listener->onDeviceAdded(d);
}

void GlobalGraph::removeListener(GraphListener* listener) {
  std::lock_guard<std::mutex> events(events_mutex_);
  listeners_.erase(std::remove(listeners_.begin(), listeners_.end(), listener), listeners_.end());
}

}  // namespace ecar
