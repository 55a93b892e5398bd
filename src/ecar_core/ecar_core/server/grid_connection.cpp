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
    : graph_(graph), config_(config) {
  if (!graph_) throw Error("GridConnection: no global graph");
  grid_planes_ = std::make_shared<const GridPlanes>();
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

std::shared_ptr<const GridPlanes> GridConnection::gridPlanes() {
  const uint64_t revision = graph_->planes().revision();
  const uint64_t generation = graph_->generation();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (revision == grid_planes_revision_ && generation == grid_planes_generation_) {
      return grid_planes_;
    }
  }
  auto snapshot = std::make_shared<const GridPlanes>(graph_->planes().planes(),
                                                     graph_->config().grid.boundary_margin);
  std::lock_guard<std::mutex> lock(mutex_);
  grid_planes_ = std::move(snapshot);
  grid_planes_revision_ = revision;
  grid_planes_generation_ = generation;
  return grid_planes_;
}

size_t GridConnection::linkKeyFrame(const KeyFramePlanes& keyframe) {
  if (!keyframe.done()) return 0;
  const std::shared_ptr<SlamSystem> slam = graph_->slam();
  if (!slam) return 0;
  // The keyframe's own camera; its device's when it was culled meanwhile.
  CameraPtr camera = keyframeCamera(slam->map(), keyframe.keyframe);
  if (!camera) camera = slam->camera(keyframe.device);
  const std::shared_ptr<const GridCaster> grid = caster(camera);
  if (!grid) return 0;
  auto structure = graph_->structureLock();
  if (graph_->epoch() != keyframe.map_epoch) return 0;  // from a replaced map
  std::vector<CellKey> cells;
  grid->visibleCells(keyframe.T_w_c, *gridPlanes(), &cells);
  const size_t n = cells.size();
  graph_->grid().setKeyFrameCells(keyframe.keyframe, std::move(cells));
  return n;
}

VoOutcome GridConnection::apply(const VoRequest& r) {
  std::lock_guard<std::mutex> serial(apply_mutex_);
  auto structure = graph_->structureLock();
  VoStore& store = graph_->vos();
  VoOutcome outcome;
  switch (r.type) {
    case VoRequestType::kRegister: {
      VirtualObject vo = r.object;
      vo.owner = r.device;
      KeyFrameId keyframe;
      const std::shared_ptr<SlamSystem> slam = graph_->slam();
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
  const std::shared_ptr<const GridPlanes> planes = gridPlanes();
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
    } else {
      // Cells with radius 1 (a floor along a cell border), then the exact
      // per-point test for the rest: the sampled rays miss most far floor cells.
      const GridMap& links = graph_->grid();
      store.forEachLive([&](const VirtualObject& vo) {
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
  return out;
}

}  // namespace ecar
