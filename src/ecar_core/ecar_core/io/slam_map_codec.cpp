#include "ecar_core/io/slam_map_codec.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <unordered_map>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

/// Layout of the "slam" section's contents (independent of the container's).
/// Version 1 had one camera for the whole map; it is still read.
constexpr uint32_t kSlamSectionVersion = 2;
constexpr uint32_t kMaxCameras = 1024;
constexpr size_t kCameraBytes = 4 + 4 + 9 * 8;
constexpr size_t kDescriptorRecordBytes = 32;
constexpr size_t kKeypointBytes = 6 * 4;  // x, y, size, angle, response, octave
constexpr size_t kObservationBytes = 8;   // keyframe id, keypoint index

}  // namespace

// ---------------------------------------------------------------- the SLAM map
//
// Layout of the "slam" section (version kSlamSectionVersion):
//   u32 version; u32 camera count (the first is the SLAM system's default),
//   each camera: i32 width, i32 height, f64 fx, fy, cx, cy, f64 x5
//   distortion; u32 pyramid levels, f32 scale per level;
//   u32 epoch, u32 next keyframe id, u32 next point id, u8 metric (1: in
//   metres from odometry);
//   u32 keyframe count, each: u32 id, u32 device, u32 frame index,
//     f64 timestamp, se3 T_c_w, u32 camera index, u8 flags (1 bad, 2 gravity,
//     4 odometry),
//     [vec3 gravity_c], [se3 T_o_c], u32 N, N x (f32 x, y, size, angle,
//     response, i32 octave), u8 descriptors present, [N x 32 bytes],
//     N x u32 point id (0: none);
//   u32 point count, each: u32 id, vec3 p_w, vec3 normal, f32 min and max
//     distance, u32 reference and first keyframe, i32 visible, i32 found,
//     u32 version, u8 flags (1 bad, 2 descriptor), [32 bytes descriptor],
//     u32 M, M x (u32 keyframe id, i32 keypoint index).

std::vector<uint8_t> encodeSlamMap(const Map& map, const PinholeCamera& default_camera) {
  ByteWriter out;
  const std::vector<KeyFrameId> keyframes = map.keyframeIds();
  const std::vector<MapPointId> points = map.pointIds();
  // At least the bytes written below (a map of 100 keyframes is about 15 MB:
  // grown by doubling it would be copied and held twice over).
  size_t bound = 4096;
  for (const KeyFrameId id : keyframes) {
    const KeyFrame& kf = *map.keyframe(id);
    bound +=
        512 + kf.features.keypoints.size() * (24 + kDescriptorRecordBytes) + kf.points.size() * 4;
  }
  for (const MapPointId id : points) bound += 160 + map.point(id)->observations.size() * 8;
  out.reserve(bound);
  out.u32(kSlamSectionVersion);
  // The default camera first, then the keyframes' distinct cameras (keyframes
  // of one device share one object).
  std::vector<CameraPtr> cameras = {std::make_shared<const PinholeCamera>(default_camera)};
  std::unordered_map<const PinholeCamera*, uint32_t> camera_index;
  for (const KeyFrameId id : keyframes) {
    const CameraPtr& camera = map.keyframe(id)->camera;
    if (!camera)
      throw Error("encodeSlamMap: keyframe " + std::to_string(id.value) + " has no camera");
    if (camera_index.count(camera.get())) continue;
    uint32_t index = static_cast<uint32_t>(cameras.size());
    for (uint32_t i = 0; i < cameras.size(); ++i) {
      if (cameras[i]->difference(*camera).empty()) index = i;
    }
    camera_index[camera.get()] = index;
    if (index == cameras.size()) cameras.push_back(camera);
  }
  out.u32(static_cast<uint32_t>(cameras.size()));
  for (const CameraPtr& camera : cameras) {
    const CameraParams& c = camera->params();
    out.i32(c.width);
    out.i32(c.height);
    for (const double v : {c.fx, c.fy, c.cx, c.cy}) out.f64(v);
    for (const double v : c.dist) out.f64(v);
  }
  const ScaleInfo& scale = map.scale();
  out.u32(static_cast<uint32_t>(scale.levels()));
  for (const float s : scale.scale) out.f32(s);
  out.u32(map.epoch());
  out.u32(map.nextKeyFrameId().value);
  out.u32(map.nextPointId().value);
  out.u8(map.metric() ? 1 : 0);

  out.u32(static_cast<uint32_t>(keyframes.size()));
  for (const KeyFrameId id : keyframes) {
    const KeyFrame& kf = *map.keyframe(id);
    const Frame& f = kf.features;
    out.u32(kf.id.value);
    out.u32(kf.device.value);
    out.u32(kf.frame_index);
    out.f64(kf.timestamp);
    out.se3(kf.T_c_w);
    out.u32(camera_index.at(kf.camera.get()));
    out.u8(static_cast<uint8_t>((kf.bad ? 1 : 0) | (f.gravity_c ? 2 : 0) | (f.T_o_c ? 4 : 0)));
    if (f.gravity_c) out.vec3(*f.gravity_c);
    if (f.T_o_c) out.se3(*f.T_o_c);
    const bool has_descriptors = !f.descriptors.empty();
    if (has_descriptors && (f.descriptors.rows != static_cast<int>(f.keypoints.size()) ||
                            f.descriptors.cols != static_cast<int>(kDescriptorRecordBytes) ||
                            f.descriptors.type() != CV_8U)) {
      throw Error("encodeSlamMap: keyframe " + std::to_string(id.value) +
                  " has descriptors unlike its keypoints (not N x 32 CV_8U)");
    }
    out.u32(static_cast<uint32_t>(f.keypoints.size()));
    for (const cv::KeyPoint& k : f.keypoints) {
      out.f32(k.pt.x);
      out.f32(k.pt.y);
      out.f32(k.size);
      out.f32(k.angle);
      out.f32(k.response);
      out.i32(k.octave);
    }
    // Descriptors: one 32-byte row per keypoint (none when the matrix is empty).
    out.u8(has_descriptors ? 1 : 0);
    for (int r = 0; has_descriptors && r < f.descriptors.rows; ++r) {
      out.bytes(f.descriptors.ptr<uint8_t>(r), kDescriptorRecordBytes);
    }
    for (const MapPointId pid : kf.points) out.u32(pid.value);
  }

  out.u32(static_cast<uint32_t>(points.size()));
  for (const MapPointId id : points) {
    const MapPoint& p = *map.point(id);
    out.u32(p.id.value);
    out.vec3(p.p_w);
    out.vec3(p.normal);
    out.f32(p.min_distance);
    out.f32(p.max_distance);
    out.u32(p.reference.value);
    out.u32(p.first_keyframe.value);
    out.i32(p.visible);
    out.i32(p.found);
    out.u32(p.version);
    const bool has_descriptor = !p.descriptor.empty();
    if (has_descriptor && (p.descriptor.total() != kDescriptorRecordBytes ||
                           p.descriptor.type() != CV_8U || !p.descriptor.isContinuous())) {
      throw Error("encodeSlamMap: point " + std::to_string(id.value) +
                  " has a descriptor other than 1 x 32 CV_8U");
    }
    out.u8(static_cast<uint8_t>((p.bad ? 1 : 0) | (has_descriptor ? 2 : 0)));
    if (has_descriptor) out.bytes(p.descriptor.ptr<uint8_t>(0), kDescriptorRecordBytes);
    out.u32(static_cast<uint32_t>(p.observations.size()));
    for (const auto& [kid, idx] : p.observations) {
      out.u32(kid.value);
      out.i32(idx);
    }
  }
  return out.release();
}

namespace {

uint32_t readVersion(ByteReader* in) {
  const uint32_t version = in->u32("slam version");
  if (version != 1 && version != kSlamSectionVersion) {
    in->fail("slam version", "version " + std::to_string(version) +
                                 ", this build reads versions 1 to " +
                                 std::to_string(kSlamSectionVersion));
  }
  return version;
}

CameraPtr readCamera(ByteReader* in) {
  CameraParams c;
  c.width = in->i32("camera.width");
  c.height = in->i32("camera.height");
  c.fx = in->f64("camera.fx");
  c.fy = in->f64("camera.fy");
  c.cx = in->f64("camera.cx");
  c.cy = in->f64("camera.cy");
  for (double& d : c.dist) d = in->f64("camera.distortion");
  try {
    return std::make_shared<const PinholeCamera>(c);
  } catch (const Error& e) {
    in->fail("camera", e.what());
  }
}

// The cameras of the map's keyframes (version 1: the one camera).
std::vector<CameraPtr> readCameras(ByteReader* in, uint32_t version) {
  if (version == 1) return {readCamera(in)};
  const uint32_t n = in->count("camera count", kCameraBytes);
  if (n == 0 || n > kMaxCameras) {
    in->fail("camera count",
             std::to_string(n) + " cameras (1 to " + std::to_string(kMaxCameras) + " expected)");
  }
  std::vector<CameraPtr> cameras;
  for (uint32_t i = 0; i < n; ++i) {
    in->setScope("camera " + std::to_string(i));
    cameras.push_back(readCamera(in));
  }
  in->setScope("");
  return cameras;
}

// Reads the pyramid the map was made with and checks it against this
// system's: keypoint octaves and distance ranges mean nothing with another.
void checkScale(ByteReader* in, const ScaleInfo& scale) {
  const uint32_t levels = in->u32("pyramid.levels");
  if (levels != static_cast<uint32_t>(scale.levels())) {
    in->fail("pyramid.levels", "the map was made with " + std::to_string(levels) +
                                   " ORB levels, this system has " +
                                   std::to_string(scale.levels()));
  }
  for (uint32_t l = 0; l < levels; ++l) {
    const float s = in->f32("pyramid.scale");
    if (std::fabs(s - scale.scale[l]) > 1e-5f * scale.scale[l]) {
      in->fail("pyramid.scale", "level " + std::to_string(l) + " scale " + std::to_string(s) +
                                    ", this system has " + std::to_string(scale.scale[l]));
    }
  }
}

}  // namespace

std::unique_ptr<Map> decodeSlamMap(ByteReader in, const ScaleInfo& scale) {
  const uint32_t version = readVersion(&in);
  const std::vector<CameraPtr> cameras = readCameras(&in, version);
  checkScale(&in, scale);
  const uint32_t epoch = in.u32("epoch");
  const KeyFrameId next_keyframe(in.u32("next keyframe id"));
  const MapPointId next_point(in.u32("next point id"));
  bool metric = false;
  if (version >= 2) {
    const uint8_t m = in.u8("metric");
    if (m > 1) in.fail("metric", "not 0 or 1");
    metric = m == 1;
  }

  auto map = std::make_unique<Map>(scale);
  const uint32_t num_keyframes =
      in.count("keyframe count", 4 + 4 + 4 + 8 + 96 + (version == 1 ? 0 : 4) + 1 + 4 + 1);
  for (uint32_t k = 0; k < num_keyframes; ++k) {
    in.setScope("keyframe #" + std::to_string(k));
    KeyFrame kf;
    kf.id = KeyFrameId(in.u32("id"));
    if (!kf.id.valid() || !(kf.id < next_keyframe) || map->keyframe(kf.id)) {
      in.fail("id", "keyframe id " + std::to_string(kf.id.value) +
                        " is 0, duplicate or not below the next id " +
                        std::to_string(next_keyframe.value));
    }
    in.setScope("keyframe " + std::to_string(kf.id.value));
    kf.device = DeviceId(in.u32("device"));
    kf.frame_index = in.u32("frame index");
    kf.timestamp = in.f64("timestamp");
    kf.T_c_w = in.se3("T_c_w");
    const uint32_t camera = version == 1 ? 0 : in.u32("camera index");
    if (camera >= cameras.size()) {
      in.fail("camera index", std::to_string(camera) + " is not below the camera count " +
                                  std::to_string(cameras.size()));
    }
    kf.camera = cameras[camera];
    Frame& f = kf.features;
    f.frame_index = kf.frame_index;
    f.timestamp = kf.timestamp;
    const uint8_t flags = in.u8("flags");
    if (flags & ~7u) in.fail("flags", "unknown flags " + std::to_string(flags));
    kf.bad = (flags & 1) != 0;
    if (flags & 2) {
      f.gravity_c = in.vec3("gravity");
      if (!f.gravity_c->allFinite()) in.fail("gravity", "non-finite");
    }
    if (flags & 4) f.T_o_c = in.se3("odometry T_o_c");
    const uint32_t n = in.count("keypoint count", kKeypointBytes + 4);
    f.keypoints.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      cv::KeyPoint& kp = f.keypoints[i];
      kp.pt.x = in.f32("keypoint.x");
      kp.pt.y = in.f32("keypoint.y");
      kp.size = in.f32("keypoint.size");
      kp.angle = in.f32("keypoint.angle");
      kp.response = in.f32("keypoint.response");
      kp.octave = in.i32("keypoint.octave");
      if (!std::isfinite(kp.pt.x) || !std::isfinite(kp.pt.y) || !std::isfinite(kp.angle) ||
          !std::isfinite(kp.size) || kp.octave < 0 || kp.octave >= scale.levels()) {
        in.fail("keypoint", "keypoint " + std::to_string(i) +
                                " has a non-finite value or an octave outside the pyramid");
      }
    }
    const uint8_t has_descriptors = in.u8("descriptors present");
    if (has_descriptors > 1) in.fail("descriptors present", "not 0 or 1");
    if (has_descriptors) {
      if (n * kDescriptorRecordBytes > in.remaining()) {
        in.fail("descriptors", "truncated (" + std::to_string(n) + " rows of 32 bytes)");
      }
      f.descriptors.create(static_cast<int>(n), static_cast<int>(kDescriptorRecordBytes), CV_8U);
      for (uint32_t i = 0; i < n; ++i) {
        in.bytes(f.descriptors.ptr<uint8_t>(static_cast<int>(i)), kDescriptorRecordBytes,
                 "descriptors");
      }
    }
    kf.points.resize(n);
    for (uint32_t i = 0; i < n; ++i) kf.points[i] = MapPointId(in.u32("point id"));
    f.finalize(*kf.camera);
    map->insertKeyFrame(std::move(kf));
  }

  in.setScope("");
  const uint32_t num_points = in.count("point count", 4 + 48 + 8 + 8 + 12 + 1 + 4);
  for (uint32_t k = 0; k < num_points; ++k) {
    in.setScope("point #" + std::to_string(k));
    MapPoint p;
    p.id = MapPointId(in.u32("id"));
    if (!p.id.valid() || !(p.id < next_point) || map->point(p.id)) {
      in.fail("id", "point id " + std::to_string(p.id.value) +
                        " is 0, duplicate or not below the next id " +
                        std::to_string(next_point.value));
    }
    in.setScope("point " + std::to_string(p.id.value));
    p.p_w = in.vec3("p_w");
    p.normal = in.vec3("normal");
    if (!p.p_w.allFinite() || !p.normal.allFinite())
      in.fail("p_w", "non-finite position or normal");
    p.min_distance = in.f32("min distance");
    p.max_distance = in.f32("max distance");
    p.reference = KeyFrameId(in.u32("reference keyframe"));
    p.first_keyframe = KeyFrameId(in.u32("first keyframe"));
    p.visible = in.i32("visible");
    p.found = in.i32("found");
    p.version = in.u32("version");
    const uint8_t flags = in.u8("flags");
    if (flags & ~3u) in.fail("flags", "unknown flags " + std::to_string(flags));
    p.bad = (flags & 1) != 0;
    if (flags & 2) {
      p.descriptor.create(1, static_cast<int>(kDescriptorRecordBytes), CV_8U);
      in.bytes(p.descriptor.ptr<uint8_t>(0), kDescriptorRecordBytes, "descriptor");
    }
    const uint32_t num_obs = in.count("observation count", kObservationBytes);
    for (uint32_t o = 0; o < num_obs; ++o) {
      const KeyFrameId kid(in.u32("observation keyframe"));
      const int32_t idx = in.i32("observation keypoint");
      const KeyFrame* kf = map->keyframe(kid);
      if (!kf) {
        in.fail("observation keyframe",
                "keyframe " + std::to_string(kid.value) + " is not in the map");
      }
      if (idx < 0 || idx >= static_cast<int32_t>(kf->points.size()) || kf->points[idx] != p.id) {
        in.fail("observation keypoint", "keypoint " + std::to_string(idx) + " of keyframe " +
                                            std::to_string(kid.value) +
                                            " does not hold this point");
      }
      if (!p.observations.emplace(kid, idx).second) {
        in.fail("observation keyframe", "keyframe " + std::to_string(kid.value) + " twice");
      }
    }
    map->insertPoint(std::move(p));
  }
  in.setScope("");
  in.expectEnd();
  map->setCounters(next_keyframe, next_point, epoch);
  map->setMetric(metric);
  for (const KeyFrameId id : map->keyframeIds()) map->updateCovisibility(id);
  const std::string problem = map->checkConsistency();
  if (!problem.empty()) in.fail("map", "inconsistent map: " + problem);
  return map;
}

PinholeCamera decodeSlamCamera(ByteReader in) {
  const uint32_t version = readVersion(&in);
  return *readCameras(&in, version).front();
}

namespace {
constexpr const char* kAtlasSection = "atlas";
constexpr uint32_t kAtlasSectionVersion = 1;
constexpr uint32_t kMaxMaps = 4096;

std::string slamSectionOf(MapId id, bool first) {
  return first ? std::string(kSlamSection)
               : std::string(kSlamSection) + "." + std::to_string(id.value);
}
}  // namespace

void addAtlasSections(MapFileWriter* writer,
                      std::vector<std::pair<MapId, std::vector<uint8_t>>> maps) {
  ByteWriter atlas;
  atlas.u32(kAtlasSectionVersion);
  atlas.u32(static_cast<uint32_t>(maps.size()));
  for (const auto& m : maps) atlas.u32(m.first.value);
  writer->addSection(kAtlasSection, atlas.release());
  for (size_t i = 0; i < maps.size(); ++i) {
    writer->addSection(slamSectionOf(maps[i].first, i == 0), std::move(maps[i].second));
  }
}

std::vector<std::pair<MapId, std::string>> atlasSections(const MapFileReader& file) {
  std::vector<std::pair<MapId, std::string>> out;
  if (!file.has(kAtlasSection)) {
    out.emplace_back(MapId(1), kSlamSection);
    return out;
  }
  ByteReader in = file.reader(kAtlasSection);
  const uint32_t version = in.u32("version");
  if (version != kAtlasSectionVersion) {
    in.fail("version", "atlas section version " + std::to_string(version) +
                           ", this build reads version " + std::to_string(kAtlasSectionVersion));
  }
  const uint32_t count = in.count("map count", 4);
  if (count < 1 || count > kMaxMaps) {
    in.fail("map count", std::to_string(count) + " maps (1 to " + std::to_string(kMaxMaps) + ")");
  }
  for (uint32_t k = 0; k < count; ++k) {
    const MapId id(in.u32("map id"));
    for (const auto& o : out) {
      if (o.first == id) in.fail("map id", "map " + std::to_string(id.value) + " twice");
    }
    if (!id.valid()) in.fail("map id", "0");
    out.emplace_back(id, slamSectionOf(id, k == 0));
    if (!file.has(out.back().second)) {
      in.fail("map id",
              "map " + std::to_string(id.value) + " has no section '" + out.back().second + "'");
    }
  }
  in.expectEnd();
  return out;
}

}  // namespace ecar
