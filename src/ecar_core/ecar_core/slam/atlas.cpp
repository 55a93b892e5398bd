#include "ecar_core/slam/atlas.h"

#include <algorithm>
#include <chrono>
#include <map>

#include "ecar_core/common/error.h"

namespace ecar {

bool Atlas::initialised(const SlamSystem& slam) {
  auto lock = slam.map().readLock();
  return slam.map().initialized();
}

void AtlasConfig::validate() const {
  const auto fail = [](const std::string& key, const std::string& why) {
    throw Error("atlas." + key + ": " + why);
  };
  if (new_map_after_lost < 0) fail("new_map_after_lost", "must be >= 0");
  if (merge_candidates < 1) fail("merge_candidates", "must be >= 1");
  if (relocalise_every < 0) fail("relocalise_every", "must be >= 0");
  if (relocalise_min_inliers < 3) fail("relocalise_min_inliers", "must be >= 3");
  if (id_range < 1000) fail("id_range", "must be >= 1000");
}

Atlas::Atlas(const PinholeCamera& camera, const SlamConfig& config, const AtlasConfig& atlas)
    : camera_(camera),
      config_(config),
      atlas_((atlas.validate(), atlas)),
      epoch_(std::max<uint32_t>(1, config.first_epoch)) {}

void Atlas::setCallbacks(AtlasCallbacks callbacks) {
  std::lock_guard<std::mutex> lock(mutex_);
  callbacks_ = std::move(callbacks);
}

MapId Atlas::addMap() {
  MapId id;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    id = newMap();
  }
  announce();
  return id;
}

PinholeCamera Atlas::camera(DeviceId device) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = cameras_.find(device);
  return it == cameras_.end() ? camera_ : it->second;
}

void Atlas::announce() {
  std::lock_guard<std::mutex> order(announce_mutex_);
  std::vector<Entry> created;
  std::vector<MapId> removed;
  AtlasCallbacks callbacks;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    created.swap(created_);
    removed.swap(removed_);
    callbacks = callbacks_;
  }
  for (const Entry& e : created) {
    if (callbacks.created) callbacks.created(e.id, e.slam);
  }
  for (const MapId id : removed) {
    if (callbacks.removed) callbacks.removed(id);
  }
}

void Atlas::dropMap(MapId id) {
  const auto it =
      std::find_if(maps_.begin(), maps_.end(), [&](const Entry& e) { return e.id == id; });
  if (it == maps_.end()) return;
  maps_.erase(it);
  removed_.push_back(id);
}

void Atlas::removeDevice(DeviceId device) {
  std::vector<std::shared_ptr<SlamSystem>> maps;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    devices_.erase(device);
    for (const Entry& e : maps_) maps.push_back(e.slam);
  }
  for (const auto& s : maps) s->removeDevice(device);
}

bool Atlas::hasKeyFramesOf(DeviceId device) const {
  std::vector<std::shared_ptr<SlamSystem>> maps;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const Entry& e : maps_) maps.push_back(e.slam);
  }
  // The maps' locks are not taken under mutex_ (a merge takes them the other
  // way round).
  for (const auto& s : maps) {
    if (s->hasKeyFramesOf(device)) return true;
  }
  return false;
}

void Atlas::forgetDevice(DeviceId device) {
  std::lock_guard<std::mutex> lock(mutex_);
  devices_.erase(device);
  cameras_.erase(device);
  for (const Entry& e : maps_) e.slam->forgetDevice(device);
}

uint32_t Atlas::epoch() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return epoch_;
}

MapId Atlas::mapOfKeyFrame(KeyFrameId keyframe) const {
  if (!keyframe.valid()) return MapId();
  std::lock_guard<std::mutex> lock(mutex_);
  MapId id((keyframe.value - 1) / atlas_.id_range + 1);
  for (auto it = merged_into_.find(id); it != merged_into_.end(); it = merged_into_.find(id)) {
    id = it->second.first;
  }
  return slamOf(id) ? id : MapId();
}

void Atlas::install(std::vector<std::pair<MapId, std::unique_ptr<Map>>> maps,
                    const std::function<void()>& first) {
  for (size_t i = 0; i < maps.size(); ++i) {
    if (!maps[i].first.valid()) throw Error("atlas: map id 0");
    if (!maps[i].second)
      throw Error("atlas: map " + std::to_string(maps[i].first.value) + " is missing");
    for (size_t j = 0; j < i; ++j) {
      if (maps[j].first == maps[i].first) {
        throw Error("atlas: map " + std::to_string(maps[i].first.value) + " given twice");
      }
    }
  }
  std::vector<std::shared_ptr<SlamSystem>> old;
  {
    std::unique_lock<std::shared_mutex> session(session_mutex_);  // no track() runs
    uint32_t before = 0;
    {
      // The epoch moves on first: whatever was aligned before is stale from
      // now on, also while `first` replaces what hangs on the maps.
      std::lock_guard<std::mutex> lock(mutex_);
      before = epoch_;
      uint32_t epoch = epoch_;
      for (const Entry& e : maps_) {
        auto ml = e.slam->map().readLock();
        epoch = std::max(epoch, e.slam->map().epoch());
      }
      for (const auto& m : maps) epoch = std::max(epoch, m.second->epoch());
      epoch_ = epoch + 1;
    }
    try {
      if (first) first();
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      epoch_ = before;
      throw;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    for (const Entry& e : maps_) {
      old.push_back(e.slam);
      removed_.push_back(e.id);
    }
    maps_.clear();
    devices_.clear();
    merged_into_.clear();
    next_map_ = 1;
    for (auto& [id, map] : maps) {
      newMap(id);
      const std::shared_ptr<SlamSystem> slam = maps_.back().slam;
      slam->installMap(std::move(map));
      auto wl = slam->map().writeLock();
      slam->map().setCounters(slam->map().nextKeyFrameId(), slam->map().nextPointId(), epoch_);
    }
  }
  for (const auto& s : old) {
    s->mapper().stopThread();
    s->loopCloser().stopThread();
  }
  announce();
}

Atlas::~Atlas() { finish(); }

void Atlas::finish() {
  std::vector<std::shared_ptr<SlamSystem>> maps;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const Entry& e : maps_) maps.push_back(e.slam);
  }
  for (const auto& s : maps) {
    s->mapper().stopThread();
    s->mapper().processPending();
    s->loopCloser().stopThread();
    s->loopCloser().processPending();
  }
}

void Atlas::setCamera(DeviceId device, const PinholeCamera& camera, double tolerance) {
  std::lock_guard<std::mutex> lock(mutex_);
  cameras_.insert_or_assign(device, camera);
  camera_tolerance_ = tolerance;
  for (const Entry& e : maps_) e.slam->setCamera(device, camera, tolerance);
}

std::shared_ptr<SlamSystem> Atlas::slamOf(MapId id) const {
  for (const Entry& e : maps_) {
    if (e.id == id) return e.slam;
  }
  return nullptr;
}

Atlas::Entry* Atlas::entryOf(MapId id) {
  for (Entry& e : maps_) {
    if (e.id == id) return &e;
  }
  return nullptr;
}

MapId Atlas::newMap(MapId id) {
  if (!id.valid()) id = MapId(next_map_);
  next_map_ = std::max(next_map_, id.value + 1);
  SlamConfig config = config_;
  config.first_epoch = epoch_;
  auto slam = std::make_shared<SlamSystem>(camera_, config);
  {
    // Disjoint id ranges: a merge moves keyframes and points as they are.
    const uint32_t base = (id.value - 1) * atlas_.id_range + 1;
    auto lock = slam->map().writeLock();
    slam->map().setCounters(KeyFrameId(base), MapPointId(base), epoch_);
  }
  for (const auto& [device, camera] : cameras_) {
    slam->setCamera(device, camera, camera_tolerance_);
  }
  maps_.push_back({id, slam, 0, MapId()});
  created_.push_back({id, std::move(slam), 0, MapId()});
  return id;
}

TrackResult Atlas::track(DeviceId device, const cv::Mat& image, double timestamp,
                         uint32_t frame_index, const std::optional<Eigen::Vector3d>& gravity_c,
                         const std::optional<SE3>& T_o_c, MapId* map) {
  *map = MapId();
  TrackResult result;
  std::optional<std::pair<MapId, KeyFrameId>> new_keyframe;
  std::optional<MergeCandidate> found;
  {
    std::shared_lock<std::shared_mutex> session(session_mutex_);
    MapId current_id, fresh_id;
    std::shared_ptr<SlamSystem> current, fresh;
    std::vector<std::pair<MapId, std::shared_ptr<SlamSystem>>> others;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      Device& d = devices_[device];
      if (!d.current.valid() && !d.fresh.valid()) {
        // The first device makes the first map; later ones start their own at
        // once while they try to relocalise into the others.
        if (maps_.empty()) {
          d.current = newMap();
        } else if (!atlas_.several_maps) {
          d.current = maps_.front().id;
        } else {
          d.fresh = newMap();
        }
      } else if (atlas_.several_maps && d.current.valid() && !d.fresh.valid() &&
                 atlas_.new_map_after_lost > 0 && d.lost >= atlas_.new_map_after_lost) {
        d.fresh = newMap();  // lost for long: somewhere new
      }
      current_id = d.current;
      fresh_id = d.fresh;
      current = slamOf(current_id);
      fresh = slamOf(fresh_id);
      for (const Entry& e : maps_) {
        if (e.id != current_id && e.id != fresh_id) others.emplace_back(e.id, e.slam);
      }
    }
    announce();  // a map made for this device gets its callbacks before use
    // The upload's ORB features, extracted by the first map that tracks it and
    // reused by the others (every map's trackers share the extractor settings
    // and the device's camera). Kept per thread: no allocation per upload.
    thread_local ImageFeatures features;
    features.extracted = false;
    const auto track_in = [&](SlamSystem& s) {
      return s.track(device, image, timestamp, frame_index, gravity_c, T_o_c, &features);
    };
    // Settles the device in `id` and drops its fresh map if nothing was made in it.
    const auto settle = [&](MapId id, const TrackResult& r) {
      std::lock_guard<std::mutex> lock(mutex_);
      Device& d = devices_[device];
      if (d.fresh.valid() && d.fresh != id) {
        const std::shared_ptr<SlamSystem> f = slamOf(d.fresh);
        if (f && !initialised(*f)) dropMap(d.fresh);
      }
      d.fresh = MapId();
      d.current = id;
      d.lost = 0;
      *map = id;
      result.map = id;
      if (r.new_keyframe) new_keyframe.emplace(id, *r.new_keyframe);
    };
    bool done = false;
    if (current) {
      result = track_in(*current);
      if (result.state == TrackingState::kOk) {
        settle(current_id, result);
        done = true;
        if (atlas_.merge && atlas_.relocalise_every > 0) {
          MapId last;
          bool probe = false;
          {
            std::lock_guard<std::mutex> lock(mutex_);
            if (Entry* e = entryOf(current_id)) {
              probe = ++e->tracked % atlas_.relocalise_every == 0;
              last = e->probed;
            }
          }
          // One other map per probe, in turn: the initialised one with the
          // next id after the last probed (wrapping round to the lowest).
          const std::pair<MapId, std::shared_ptr<SlamSystem>>* target = nullptr;
          const auto after_last = [&](MapId id) {
            return std::make_pair(id.value <= last.value, id.value);  // smaller: sooner
          };
          if (probe) {
            for (const auto& o : others) {
              if (!initialised(*o.second)) continue;
              if (!target || after_last(o.first) < after_last(target->first)) target = &o;
            }
          }
          if (target) {
            {
              std::lock_guard<std::mutex> lock(mutex_);
              if (Entry* e = entryOf(current_id)) e->probed = target->first;
            }
            found = relocalisedOverlap(current_id, *current, result, target->first, *target->second,
                                       track_in(*target->second), device);
          }
        }
      } else if (initialised(*current)) {
        // Lost in a map it tracked in (a map still initialising is not a
        // place to leave: it made a new map for nothing, dropped at once).
        std::lock_guard<std::mutex> lock(mutex_);
        ++devices_[device].lost;
      }
    }
    if (!done && fresh) {
      for (const auto& [id, s] : others) {
        if (!initialised(*s)) continue;
        const TrackResult r = track_in(*s);
        if (r.state == TrackingState::kOk) {
          result = r;
          settle(id, r);
          done = true;
          break;
        }
      }
      if (!done) {
        const TrackResult r = track_in(*fresh);
        if (r.state == TrackingState::kOk) {
          result = r;
          settle(fresh_id, r);
        } else if (!current) {
          result = r;
        } else if (!r.message.empty()) {
          // Lost in its map: say how its new map is doing as well.
          result.message += "; new map " + std::to_string(fresh_id.value) + ": " + r.message;
        }
      }
    }
  }
  if (found) {
    std::shared_ptr<SlamSystem> merged;
    std::vector<KeyFrameId> moved;
    {
      std::unique_lock<std::shared_mutex> session(session_mutex_);
      merged = doMerge(*found, std::chrono::steady_clock::now(), &moved);
    }
    adjustMerged(merged, moved);
  } else if (new_keyframe && atlas_.merge) {
    tryMerge(new_keyframe->first, new_keyframe->second, device);
  }
  // Its map merged into another in this call: the upload is answered in the
  // merged map (else the pipeline would find its map gone and not answer).
  if (toLiveMap(&result)) *map = result.map;
  announce();
  return result;
}

bool Atlas::toLiveMap(TrackResult* r) const {
  if (!r->map.valid()) return false;
  const auto [live, S] = finalFrameOf(r->map);
  if (live == r->map || !map(live)) return false;
  r->T_w_c = S.transformPose(r->T_w_c);
  for (TrackedPoint& t : r->tracked) t.p_w = S * t.p_w;
  r->map = live;  // the atlas's maps share one epoch
  return true;
}

std::vector<MapId> Atlas::mapIds() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<MapId> ids;
  for (const Entry& e : maps_) ids.push_back(e.id);
  return ids;
}

std::shared_ptr<SlamSystem> Atlas::map(MapId id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return slamOf(id);
}

MapId Atlas::mapOf(DeviceId device) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(device);
  return it == devices_.end() ? MapId() : it->second.current;
}

std::vector<MergeEvent> Atlas::merges() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return merges_;
}

std::pair<MapId, Sim3> Atlas::finalFrameOf(MapId id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  Sim3 S;
  for (auto it = merged_into_.find(id); it != merged_into_.end(); it = merged_into_.find(id)) {
    S = it->second.second * S;
    id = it->second.first;
  }
  return {id, S};
}

std::vector<LoopClosure> Atlas::loopClosures() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<LoopClosure> out = closed_loops_;
  for (const Entry& e : maps_) {
    for (const LoopClosure& l : e.slam->loopCloser().closures()) out.push_back(l);
  }
  return out;
}

}  // namespace ecar
