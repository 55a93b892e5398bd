#include "ecar_core/slam/slam_system.h"

#include "ecar_core/common/error.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"

namespace ecar {

SlamSystem::SlamSystem(const PinholeCamera& camera, const SlamConfig& config)
    : camera_(std::make_shared<const PinholeCamera>(camera)),
      config_(config),
      map_(ScaleInfo::fromConfig(config.orb)),
      index_(config.place),
      keypoint_index_(config.keypoints),
      mapper_(&map_, &index_, config, &keypoint_index_),
      loops_(&map_, &index_, config) {
  if (config_.first_epoch < 1) throw Error("SlamConfig: first_epoch must be >= 1");
  map_.setCounters(map_.nextKeyFrameId(), map_.nextPointId(), config_.first_epoch);
  mapper_.setLoopCloser(&loops_);
  if (!config_.synchronous_mapping) {
    loops_.startThread();
    mapper_.startThread();
  }
}

SlamSystem::~SlamSystem() {
  mapper_.stopThread();
  loops_.stopThread();
}

std::shared_ptr<Tracker> SlamSystem::sharedTracker(DeviceId device) {
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  auto& t = trackers_[device];
  if (!t) {
    const auto c = cameras_.find(device);
    t = std::make_shared<Tracker>(device, &map_, &index_, &mapper_,
                                  c != cameras_.end() ? c->second : camera_, config_,
                                  &keypoint_index_);
  }
  return t;
}

Tracker& SlamSystem::tracker(DeviceId device) { return *sharedTracker(device); }

void SlamSystem::setCamera(DeviceId device, const PinholeCamera& camera, double tolerance) {
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  auto it = cameras_.find(device);
  if (it != cameras_.end() && it->second->difference(camera, tolerance).empty()) return;
  // One shared camera object per distinct camera: keyframes of devices with
  // the same camera share it, and the map file stores it once.
  CameraPtr shared;
  if (camera_->difference(camera, tolerance).empty()) shared = camera_;
  for (const auto& kv : cameras_) {
    if (!shared && kv.second->difference(camera, tolerance).empty()) shared = kv.second;
  }
  if (!shared) shared = std::make_shared<const PinholeCamera>(camera);
  cameras_[device] = shared;
  trackers_.erase(device);  // the next track() starts with the new camera
}

CameraPtr SlamSystem::camera(DeviceId device) const {
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  const auto it = cameras_.find(device);
  return it != cameras_.end() ? it->second : camera_;
}

void SlamSystem::removeDevice(DeviceId device) {
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  trackers_.erase(device);
}

bool SlamSystem::hasKeyFramesOf(DeviceId device) const {
  auto lock = map_.readLock();
  for (const KeyFrameId id : map_.keyframeIds()) {
    const KeyFrame* kf = map_.keyframe(id);
    if (kf && kf->device == device) return true;
  }
  return false;
}

void SlamSystem::forgetDevice(DeviceId device) {
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  trackers_.erase(device);
  cameras_.erase(device);
}

TrackResult SlamSystem::track(DeviceId device, const cv::Mat& image, double timestamp,
                              uint32_t frame_index, const std::optional<Eigen::Vector3d>& gravity_c,
                              const std::optional<SE3>& T_o_c, ImageFeatures* features) {
  std::shared_lock<std::shared_mutex> session(session_mutex_);
  // A shared reference: setCamera() may replace the device's tracker meanwhile.
  const std::shared_ptr<Tracker> tracker = sharedTracker(device);
  TrackResult result = tracker->track(image, timestamp, frame_index, gravity_c, T_o_c, features);
  if (result.odometry_loop) loops_.closeByOdometry(*result.odometry_loop);
  auto lock = map_.readLock();
  result.map_epoch = map_.epoch();  // installMap() cannot run while `session` is held
  return result;
}

void SlamSystem::saveMap(const std::string& path) const {
  MapFileWriter writer;
  writeMapSection(&writer);
  writer.write(path);
}

void SlamSystem::loadMap(const std::string& path) {
  installMap(readMapSection(MapFileReader::open(path)));
}

void SlamSystem::writeMapSection(MapFileWriter* writer) const {
  std::vector<uint8_t> bytes;
  {
    auto lock = map_.readLock();
    bytes = encodeSlamMap(map_, *camera_);
  }
  writer->addSection(kSlamSection, std::move(bytes));
}

std::unique_ptr<Map> SlamSystem::readMapSection(const MapFileReader& reader) const {
  return decodeSlamMap(reader.reader(kSlamSection), map_.scale());
}

void SlamSystem::installMap(std::unique_ptr<Map> map) {
  if (!map) throw Error("SlamSystem::installMap: no map");
  std::unique_lock<std::shared_mutex> session(session_mutex_);  // no track() runs
  mapper_.reset();
  loops_.reset();
  {
    auto lock = map_.writeLock();
    map_.replaceWith(std::move(*map));
  }
  reindex();
  std::lock_guard<std::mutex> lock(trackers_mutex_);
  for (auto& kv : trackers_) kv.second->reset();
}

void SlamSystem::reindex() {
  index_.clear();
  keypoint_index_.clear();
  std::vector<KeyFrameId> ids;
  {
    auto lock = map_.readLock();
    ids = map_.keyframeIds();
  }
  indexKeyFrames(ids);
}

void SlamSystem::indexKeyFrames(const std::vector<KeyFrameId>& ids) {
  std::vector<std::pair<KeyFrameId, cv::Mat>> descriptors;
  std::vector<std::vector<int>> point_rows;
  {
    auto lock = map_.readLock();
    for (const KeyFrameId id : ids) {
      const KeyFrame* kf = map_.keyframe(id);
      if (!kf || kf->features.descriptors.empty()) continue;
      std::vector<int> rows;
      for (size_t i = 0; i < kf->points.size(); ++i) {
        if (map_.point(kf->points[i])) rows.push_back(static_cast<int>(i));
      }
      descriptors.emplace_back(id, kf->features.descriptors);
      point_rows.push_back(std::move(rows));
    }
  }
  for (size_t k = 0; k < descriptors.size(); ++k) {
    index_.add(descriptors[k].first, descriptors[k].second);
    keypoint_index_.add(descriptors[k].first, descriptors[k].second, point_rows[k]);
  }
}

}  // namespace ecar
