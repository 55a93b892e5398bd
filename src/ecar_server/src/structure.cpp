#include "ecar_server/structure.h"

#include <algorithm>
#include <chrono>
#include <set>

#include "ecar_core/common/error.h"

namespace ecar_server {
namespace {

double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace

Structure::Structure(const ServerConfig& config)
    : config_(config),
      segmenter_(config.planes),
      planes_(config.planes),
      grid_planes_(std::make_shared<const ecar::GridPlanes>()) {
  config_.grid.validate();
}

ecar::VoStore& Structure::vos() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!vos_) {
    if (!vos_error_.empty()) throw ecar::Error(vos_error_);
    ecar::VoStoreConfig c = config_.vo;
    c.cell_size = config_.grid.cell_size;
    try {
      vos_ = std::make_unique<ecar::VoStore>(c);
    } catch (const ecar::Error& e) {
      vos_error_ = e.what();
      throw;
    }
  }
  return *vos_;
}

std::shared_ptr<const ecar::GridCaster> Structure::gridConnection(
    const ecar::PinholeCamera& camera) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!caster_) caster_ = std::make_shared<const ecar::GridCaster>(config_.grid, camera);
  return caster_;
}

std::shared_ptr<const ecar::GridPlanes> Structure::gridPlanes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return grid_planes_;
}

KeyFrameStructure Structure::integrateKeyFrame(const ecar::PlaneKeyFrameInput& input,
                                               const ecar::SE3& T_w_c,
                                               const ecar::GridCaster& grid,
                                               std::optional<uint64_t> generation) {
  KeyFrameStructure out;
  std::shared_lock<std::shared_mutex> replace(replace_mutex_);
  if (generation && *generation != generation_.load()) {
    out.stale = true;
    return out;
  }
  auto start = std::chrono::steady_clock::now();
  const std::vector<ecar::PlaneObservation> observations = segmenter_.segment(input);
  out.observations = observations.size();
  out.segment_ms = msSince(start);
  start = std::chrono::steady_clock::now();
  out.update = planes_.integrate(input, observations);
  const uint64_t revision = planes_.revision();
  bool rebuild = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    rebuild = revision != grid_planes_revision_;
  }
  if (rebuild) {
    auto snapshot =
        std::make_shared<const ecar::GridPlanes>(planes_.planes(), config_.grid.boundary_margin);
    std::lock_guard<std::mutex> lock(mutex_);
    grid_planes_ = std::move(snapshot);
    grid_planes_revision_ = revision;
  }
  out.integrate_ms = msSince(start);
  start = std::chrono::steady_clock::now();
  std::vector<ecar::CellKey> cells;
  grid.visibleCells(T_w_c, *gridPlanes(), &cells);
  out.cells = cells.size();
  grid_.setKeyFrameCells(input.keyframe, std::move(cells));
  out.grid_ms = msSince(start);
  return out;
}

void Structure::eraseKeyFrame(ecar::KeyFrameId id) {
  std::shared_lock<std::shared_mutex> replace(replace_mutex_);
  planes_.eraseKeyFrame(id);
  grid_.eraseKeyFrame(id);
}

VisibleStructure Structure::visible(const ecar::SE3& T_w_c,
                                    const std::vector<ecar::KeyFrameId>& local_keyframes,
                                    const ecar::GridCaster& grid) {
  const auto start = std::chrono::steady_clock::now();
  VisibleStructure out;
  std::shared_lock<std::shared_mutex> replace(replace_mutex_);
  const std::shared_ptr<const ecar::GridPlanes> grid_planes = gridPlanes();
  thread_local std::vector<ecar::SampleHit> hits;
  grid.castSamples(T_w_c, *grid_planes, &hits);
  std::set<ecar::PlaneId> plane_ids;
  out.cells.reserve(hits.size());
  for (const auto& h : hits) {
    plane_ids.insert(h.plane);
    out.cells.push_back(h.cell);
  }
  std::sort(out.cells.begin(), out.cells.end());
  out.cells.erase(std::unique(out.cells.begin(), out.cells.end()), out.cells.end());
  if (config_.graph_keyframe_planes) {
    for (const auto& kf : local_keyframes) {
      for (const auto& id : planes_.planesOfKeyFrame(kf)) plane_ids.insert(id);
    }
  }
  out.planes = planes_.planes(std::vector<ecar::PlaneId>(plane_ids.begin(), plane_ids.end()));

  ecar::VoStore* store_ptr = nullptr;
  try {
    store_ptr = &vos();
  } catch (const ecar::Error& e) {
    out.error = e.what();
    out.milliseconds = msSince(start);
    return out;
  }
  ecar::VoStore& store = *store_ptr;
  if (store.attachMode() == ecar::VoAttachMode::kKeyFrame) {
    out.objects = store.objectsOfKeyFrames(local_keyframes);
  } else {
    // Cells with radius 1 (a floor along a cell border), then the exact
    // per-point test for the rest: the sampled rays miss most far floor cells.
    std::map<ecar::ObjectId, ecar::VirtualObject> found;
    for (auto& vo : store.allObjects()) {
      if (vo.deleted) continue;
      bool seen = false;
      for (const auto& cell : store.cellsOf(vo.id)) {
        if (ecar::containsCell(out.cells, cell, 1)) {
          seen = true;
          break;
        }
      }
      if (!seen) {
        seen = grid.isVisible(T_w_c, *grid_planes, vo.position) ||
               grid.isVisible(T_w_c, *grid_planes, vo.start) ||
               grid.isVisible(T_w_c, *grid_planes, vo.end);
      }
      if (seen) found.emplace(vo.id, std::move(vo));
    }
    out.objects.reserve(found.size());
    for (auto& kv : found) out.objects.push_back(std::move(kv.second));
  }
  out.milliseconds = msSince(start);
  return out;
}

std::unique_lock<std::shared_mutex> Structure::lockForReplace() {
  return std::unique_lock<std::shared_mutex>(replace_mutex_);
}

ecar::StructureState Structure::save() {
  ecar::StructureState state;
  state.planes = planes_.save();
  state.next_plane_id = planes_.nextId();
  state.grid = grid_.save();
  state.vos = vos().snapshot();
  return state;
}

void Structure::replace(const ecar::StructureState& state,
                        const std::function<void()>& install_slam) {
  vos().replaceAll(state.vos);
  if (install_slam) install_slam();
  planes_.load(state.planes, state.next_plane_id);
  grid_.load(state.grid);
  auto snapshot =
      std::make_shared<const ecar::GridPlanes>(planes_.planes(), config_.grid.boundary_margin);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    grid_planes_ = std::move(snapshot);
    grid_planes_revision_ = planes_.revision();
    device_cells_.clear();
  }
  ++generation_;
}

void Structure::setDeviceCells(const std::string& device, std::vector<ecar::CellKey> cells) {
  std::lock_guard<std::mutex> lock(mutex_);
  device_cells_[device] = std::move(cells);
}

std::map<std::string, std::vector<ecar::CellKey>> Structure::deviceCells() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return device_cells_;
}

void Structure::eraseDevice(const std::string& device) {
  std::lock_guard<std::mutex> lock(mutex_);
  device_cells_.erase(device);
}

}  // namespace ecar_server
