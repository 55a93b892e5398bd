#include "ecar_core/server/grid_connection.h"

#include <algorithm>
#include <chrono>
#include <set>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/slam/map_queries.h"
#include "ecar_core/structure/grid_cells.h"

namespace ecar {
GridConnection::GridConnection(GlobalGraph* graph, const GridConnectionConfig& config)
    : graph_(graph),
      config_(config),
      limiter_(config.max_interaction_rate, config.interaction_burst) {
  if (!graph_) throw Error("GridConnection: no global graph");
}

std::shared_ptr<const GridCaster> GridConnection::caster(const CameraPtr& camera) {
  if (!camera) return nullptr;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [c, grid] : casters_) {
    if (c == camera) return grid;
  }
  casters_.emplace_back(camera, std::make_shared<const GridCaster>(graph_->config().grid, *camera));
  return casters_.back().second;
}

std::shared_ptr<const GridPlanes> GridConnection::gridPlanes(MapId map) {
  const uint64_t revision = graph_->planes().revision();
  const uint64_t generation = graph_->generation();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = grid_planes_.find(map);
    if (it != grid_planes_.end() && revision == it->second.revision &&
        generation == it->second.generation) {
      return it->second.planes;
    }
  }
  std::vector<Plane> planes = graph_->planes().planes();
  planes.erase(
      std::remove_if(planes.begin(), planes.end(), [&](const Plane& p) { return p.map != map; }),
      planes.end());
  auto snapshot = std::make_shared<const GridPlanes>(planes, graph_->config().grid.boundary_margin);
  std::lock_guard<std::mutex> lock(mutex_);
  // Snapshots of maps merged away or replaced go with the next change.
  for (auto it = grid_planes_.begin(); it != grid_planes_.end();) {
    it = it->second.generation != generation ? grid_planes_.erase(it) : std::next(it);
  }
  grid_planes_[map] = {snapshot, revision, generation};
  return snapshot;
}

size_t GridConnection::linkKeyFrame(const KeyFramePlanes& keyframe) {
  if (!keyframe.done()) return 0;
  MapId map;
  const std::shared_ptr<SlamSystem> slam = graph_->mapOfKeyFrame(keyframe.keyframe, &map);
  if (!slam) return 0;
  // The keyframe's own camera; its device's when it was culled meanwhile.
  CameraPtr camera = keyframeCamera(slam->map(), keyframe.keyframe);
  if (!camera) camera = graph_->camera(graph_->devices().name(keyframe.device));
  const std::shared_ptr<const GridCaster> grid = caster(camera);
  if (!grid) return 0;
  auto structure = graph_->structureLock();
  if (graph_->epoch() != keyframe.map_epoch) return 0;  // from a replaced map
  std::vector<CellKey> cells;
  grid->visibleCells(keyframe.T_w_c, *gridPlanes(map), &cells);
  const size_t n = cells.size();
  graph_->grid().setKeyFrameCells(keyframe.keyframe, std::move(cells));
  return n;
}

VoOutcome GridConnection::apply(const VoRequest& r) {
  std::lock_guard<std::mutex> serial(apply_mutex_);
  VoOutcome outcome;
  if (!limiter_.allow(r.device, steadySeconds())) {
    outcome.code = VoReject::kRateLimited;
    outcome.id = r.object_id;
    outcome.reason = r.device + " sent more than " +
                     std::to_string(static_cast<int>(config_.max_interaction_rate)) +
                     " interactions a second (vo.max_interaction_rate)";
    return outcome;
  }
  auto structure = graph_->structureLock();
  VoStore& store = graph_->vos();
  // The map the request's coordinates are in: the one the device held when
  // the user acted (the device's current map when not given; rviz: the
  // largest map).
  const std::optional<DeviceInfo> device = graph_->devices().device(r.device);
  const MapId current = device ? graph_->mapOf(device->id) : graph_->largestMap();
  const MapId map = r.object.map.valid() ? r.object.map : current;
  if (r.type != VoRequestType::kDelete && current.valid() && map != current) {
    outcome.code = VoReject::kStaleMap;
    outcome.id = r.object_id;
    outcome.reason = "drawn in map " + std::to_string(map.value) + ", but " + r.device +
                     " is now in map " + std::to_string(current.value) +
                     " (its map merged): draw again";
    if (const std::optional<VirtualObject> vo = store.get(r.object_id))
      outcome.version = vo->version;
    return outcome;
  }
  switch (r.type) {
    case VoRequestType::kRegister: {
      VirtualObject vo = r.object;
      vo.owner = r.device;
      vo.map = map.valid() ? map : graph_->largestMap();
      KeyFrameId keyframe;
      const std::shared_ptr<SlamSystem> slam = graph_->map(vo.map);
      if (store.attachMode() == VoAttachMode::kKeyFrame && slam) {
        // Where the store will put it: a line's centre, an anchor's point.
        const Eigen::Vector3d at =
            vo.kind == VoKind::kLine ? Eigen::Vector3d(0.5 * (vo.start + vo.end)) : vo.position;
        keyframe = nearestKeyFrame(slam->map(), at);
      }
      outcome = store.registerObject(vo, keyframe);
      break;
    }
    case VoRequestType::kManipulate:
      outcome = store.manipulate(r.object_id, r.base_version, r.object, r.device);
      break;
    case VoRequestType::kDelete:
      outcome = store.remove(r.object_id, r.base_version, r.device);
      break;
  }
  if (outcome.accepted) {
    if (const std::optional<VirtualObject> vo = store.get(outcome.id)) {
      graph_->grid().attachObject(*vo, store.config().cell_size, store.config().attach_margin);
    }
  }
  return outcome;
}

VisibleStructure GridConnection::visible(const TrackResult& frame, const std::string& device) {
  const auto start = std::chrono::steady_clock::now();
  const double cpu_start = threadCpuMs();
  VisibleStructure out;
  out.objects_computed = config_.objects;
  if (frame.state != TrackingState::kOk) return out;
  const std::shared_ptr<const GridCaster> grid = caster(graph_->camera(device));
  if (!grid) return out;
  auto structure = graph_->structureLock();
  if (graph_->epoch() != frame.map_epoch) {
    out.stale = true;
    return out;
  }
  const std::shared_ptr<const GridPlanes> planes = gridPlanes(frame.map);
  thread_local std::vector<SampleHit> hits;
  grid->castSamples(frame.T_w_c, *planes, &hits);
  std::set<PlaneId> plane_ids;
  out.cells.reserve(hits.size());
  for (const auto& h : hits) {
    plane_ids.insert(h.plane);
    out.cells.push_back(h.cell);
  }
  std::sort(out.cells.begin(), out.cells.end());
  out.cells.erase(std::unique(out.cells.begin(), out.cells.end()), out.cells.end());
  if (config_.keyframe_planes) {
    for (const auto& kf : frame.local_keyframes) {
      for (const auto& id : graph_->planes().planesOfKeyFrame(kf)) plane_ids.insert(id);
    }
  }
  out.planes = graph_->planes().planes(std::vector<PlaneId>(plane_ids.begin(), plane_ids.end()));
  if (config_.objects) {
    const VoStore& store = graph_->vos();
    if (store.attachMode() == VoAttachMode::kKeyFrame) {
      out.objects = store.objectsOfKeyFrames(frame.local_keyframes);
      out.objects.erase(
          std::remove_if(out.objects.begin(), out.objects.end(),
                         [&](const VirtualObject& vo) { return vo.map != frame.map; }),
          out.objects.end());
    } else {
      // Cells with radius 1 (a floor along a cell border), then the exact
      // per-point test for the rest: the sampled rays miss most far floor cells.
      const GridMap& links = graph_->grid();
      store.forEachLive([&](const VirtualObject& vo) {
        if (vo.map != frame.map) return;  // another map's coordinates
        bool seen = false;
        for (const CellKey& cell : links.cellsOfObject(vo.id)) {
          if (containsCell(out.cells, cell, 1)) {
            seen = true;
            break;
          }
        }
        if (!seen) {
          seen = grid->isVisible(frame.T_w_c, *planes, vo.position) ||
                 grid->isVisible(frame.T_w_c, *planes, vo.start) ||
                 grid->isVisible(frame.T_w_c, *planes, vo.end);
        }
        if (seen) out.objects.push_back(vo);
      });
    }
  }
  out.milliseconds = msSince(start);
  out.cpu_ms = threadCpuMs() - cpu_start;
  return out;
}

}  // namespace ecar
