// Map files: the container (sections, CRC, damage), the SLAM map's round trip,
// relocalisation in the loaded map's coordinate system, bad files leaving the
// map untouched, and the size and time of a 100-keyframe map.
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/slam_system.h"
#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::contains;
using ecar::testing::errorOf;
using ecar::testing::readBytes;
using ecar::testing::TempDir;
using ecar::testing::writeBytes;

namespace fs = std::filesystem;

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

const TempDir& tempDir() {
  static const TempDir dir("ecar_map_io_test");
  return dir;
}

// ------------------------------------------------------------ the container

TEST(MapIoTest, Crc32HasTheStandardCheckValue) {
  const std::string check = "123456789";
  EXPECT_EQ(crc32(check.data(), check.size()), 0xCBF43926u);
  EXPECT_EQ(crc32(nullptr, 0), 0u);
  // Continuing a CRC over a split buffer gives the CRC of the whole.
  const std::string text = "The quick brown fox jumps over the lazy dog";
  EXPECT_EQ(crc32(text.data(), text.size()), 0x414FA339u);
  for (size_t split : {1, 3, 17, 40}) {
    EXPECT_EQ(crc32(text.data() + split, text.size() - split, crc32(text.data(), split)),
              0x414FA339u);
  }
}

TEST(MapIoTest, PrimitivesRoundTripLittleEndian) {
  ByteWriter out;
  out.u8(0xAB);
  out.u16(0x1234);
  out.u32(0xDEADBEEFu);
  out.u64(0x0102030405060708ull);
  out.i32(-7);
  out.f32(-1.5f);
  out.f64(M_PI);
  out.string("planes");
  out.vec3(Eigen::Vector3d(1, -2, 3.25));
  SE3 T = SE3::Identity();
  T.linear() = expSO3(Eigen::Vector3d(0.1, -0.2, 0.3));
  T.translation() = Eigen::Vector3d(4, 5, -6);
  out.se3(T);
  const std::vector<uint8_t> bytes = out.release();
  // Little-endian on every host: the u16 0x1234 is 34 12.
  ASSERT_GE(bytes.size(), 7u);
  EXPECT_EQ(bytes[1], 0x34);
  EXPECT_EQ(bytes[2], 0x12);
  EXPECT_EQ(bytes[3], 0xEF);

  ByteReader in(bytes.data(), bytes.size(), "test data");
  EXPECT_EQ(in.u8("a"), 0xAB);
  EXPECT_EQ(in.u16("b"), 0x1234);
  EXPECT_EQ(in.u32("c"), 0xDEADBEEFu);
  EXPECT_EQ(in.u64("d"), 0x0102030405060708ull);
  EXPECT_EQ(in.i32("e"), -7);
  EXPECT_EQ(in.f32("f"), -1.5f);
  EXPECT_EQ(in.f64("g"), M_PI);
  EXPECT_EQ(in.string("h"), "planes");
  EXPECT_EQ(in.vec3("i"), Eigen::Vector3d(1, -2, 3.25));
  EXPECT_TRUE(in.se3("j").isApprox(T, 0.0));
  in.expectEnd();
  // Past the end: the error names the context, the scope and the field.
  in.setScope("plane 3");
  const std::string e = errorOf([&] { in.u32("normal"); });
  EXPECT_TRUE(contains(e, "test data, plane 3, field 'normal'")) << e;
  EXPECT_TRUE(contains(e, "truncated")) << e;
}

TEST(MapIoTest, ReaderRejectsImpossibleCountsAndRotations) {
  ByteWriter out;
  out.u32(1000000);  // a count far beyond the bytes that follow
  out.u32(0);
  ByteReader in(out.data().data(), out.size(), "test data");
  EXPECT_TRUE(contains(errorOf([&] { in.count("cells", 12); }), "field 'cells'"));
  ByteWriter bad;
  for (int i = 0; i < 12; ++i) bad.f64(2.0);  // not a rotation
  ByteReader bad_in(bad.data().data(), bad.size(), "test data");
  EXPECT_TRUE(contains(errorOf([&] { bad_in.se3("pose"); }), "not orthonormal"));
}

std::vector<uint8_t> smallFile() {
  MapFileWriter writer;
  writer.addSection("slam", {1, 2, 3, 4, 5, 6, 7, 8});
  writer.addSection("planes", std::vector<uint8_t>(100, 0x5A));
  writer.addSection("empty", {});
  return writer.serialize();
}

TEST(MapIoTest, SectionsRoundTripThroughAFile) {
  const std::string path = tempDir().file("small.ecarmap");
  MapFileWriter writer;
  writer.addSection("slam", {1, 2, 3, 4, 5, 6, 7, 8});
  writer.addSection("planes", std::vector<uint8_t>(100, 0x5A));
  writer.addSection("empty", {});
  writer.write(path);
  // No temporary file is left beside it.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(fs::path(path).parent_path())) {
    files += entry.path().filename().string().rfind("small.ecarmap", 0) == 0 ? 1 : 0;
  }
  EXPECT_EQ(files, 1);
  EXPECT_EQ(readBytes(path), smallFile());

  const MapFileReader file = MapFileReader::open(path);
  EXPECT_EQ(file.version(), kMapFileVersion);
  EXPECT_EQ(file.sectionNames(), (std::vector<std::string>{"slam", "planes", "empty"}));
  EXPECT_EQ(file.section("slam"), (std::vector<uint8_t>{1, 2, 3, 4, 5, 6, 7, 8}));
  EXPECT_EQ(file.section("planes"), std::vector<uint8_t>(100, 0x5A));
  EXPECT_TRUE(file.section("empty").empty());
  EXPECT_FALSE(file.has("vos"));
  const std::string e = errorOf([&] { file.reader("vos"); });
  EXPECT_TRUE(contains(e, path) && contains(e, "no section 'vos'")) << e;
  // A section reader keeps the bytes alive after the file object is gone.
  ByteReader planes = MapFileReader::open(path).reader("planes");
  EXPECT_EQ(planes.u8("first"), 0x5A);

  EXPECT_TRUE(contains(errorOf([&] { writer.addSection("slam", {}); }), "duplicate"));
  EXPECT_TRUE(contains(errorOf([&] { writer.addSection("bad name", {}); }), "invalid"));
  EXPECT_TRUE(contains(errorOf([] { MapFileReader::open("/nonexistent/dir/map.ecarmap"); }),
                       "cannot open"));
}

TEST(MapIoTest, DamagedContainersAreRejectedWithTheReason) {
  const std::vector<uint8_t> good = smallFile();
  const auto parse = [](const std::vector<uint8_t>& bytes) {
    return errorOf([&] { MapFileReader::parse(bytes, "damaged.ecarmap"); });
  };
  // Truncated anywhere: in the magic, the header, the table, a section.
  for (size_t size : {size_t(0), size_t(5), size_t(10), size_t(20), size_t(60), good.size() - 1}) {
    const std::string e = parse(std::vector<uint8_t>(good.begin(), good.begin() + size));
    EXPECT_TRUE(contains(e, "damaged.ecarmap")) << e;
    EXPECT_TRUE(contains(e, "truncated") || contains(e, "bad magic")) << size << ": " << e;
  }
  // Foreign file.
  const std::string png = "\x89PNG\r\n\x1a\n and more bytes of an image";
  EXPECT_TRUE(contains(parse(std::vector<uint8_t>(png.begin(), png.end())), "not an eCAR map"));
  // Another version of the format.
  std::vector<uint8_t> v2 = good;
  v2[8] = 2;
  EXPECT_TRUE(contains(parse(v2), "format version 2, this build reads version 1")) << parse(v2);
  // A flipped bit in the header (a section's length).
  std::vector<uint8_t> header = good;
  header[30] ^= 0x10;
  EXPECT_TRUE(contains(parse(header), "header")) << parse(header);
  // Bytes appended after the last section.
  std::vector<uint8_t> longer = good;
  longer.push_back(0);
  EXPECT_TRUE(contains(parse(longer), "after the last section"));
  // A flipped byte in a section: that section fails its CRC, the others read.
  std::vector<uint8_t> flipped = good;
  flipped[flipped.size() - 50] ^= 0x01;  // inside "planes"
  const MapFileReader file = MapFileReader::parse(flipped, "flipped.ecarmap");
  const std::string e = errorOf([&] { file.reader("planes"); });
  EXPECT_TRUE(contains(e, "'flipped.ecarmap', section 'planes': CRC mismatch")) << e;
  EXPECT_EQ(file.section("slam").size(), 8u);
}

// ------------------------------------------------------------ loading support

KeyFrame keyFrameWith(uint32_t id, int keypoints) {
  KeyFrame kf;
  kf.camera = std::make_shared<const PinholeCamera>(CameraParams());
  kf.id = KeyFrameId(id);
  kf.features.keypoints.resize(keypoints);
  kf.points.resize(keypoints);
  return kf;
}

TEST(MapLoadingTest, InsertKeepsIdsAndCountersMoveOn) {
  Map map(ScaleInfo::fromConfig(OrbConfig()));
  auto lock = map.writeLock();
  map.insertKeyFrame(keyFrameWith(7, 3));
  map.insertKeyFrame(keyFrameWith(9, 3));
  MapPoint p;
  p.id = MapPointId(40);
  p.observations = {{KeyFrameId(7), 1}, {KeyFrameId(9), 2}};
  map.mutableKeyFrame(KeyFrameId(7))->points[1] = p.id;
  map.mutableKeyFrame(KeyFrameId(9))->points[2] = p.id;
  map.insertPoint(p);
  EXPECT_EQ(map.checkConsistency(), "");
  EXPECT_TRUE(contains(errorOf([&] { map.insertKeyFrame(keyFrameWith(7, 3)); }), "present"));
  EXPECT_TRUE(contains(errorOf([&] { map.insertKeyFrame(keyFrameWith(0, 3)); }), "invalid"));
  KeyFrame uneven = keyFrameWith(11, 3);
  uneven.points.resize(2);
  EXPECT_TRUE(contains(errorOf([&] { map.insertKeyFrame(uneven); }), "point slots"));
  EXPECT_TRUE(contains(errorOf([&] { map.insertPoint(p); }), "present"));
  // Counters must stay above every id, or ids would be reused.
  EXPECT_TRUE(
      contains(errorOf([&] { map.setCounters(KeyFrameId(9), MapPointId(41), 3); }), "keyframe 9"));
  EXPECT_TRUE(
      contains(errorOf([&] { map.setCounters(KeyFrameId(10), MapPointId(40), 3); }), "point 40"));
  map.setCounters(KeyFrameId(10), MapPointId(41), 3);
  EXPECT_EQ(map.epoch(), 3u);
  EXPECT_EQ(map.addKeyFrame(keyFrameWith(0, 1)), KeyFrameId(10));
  EXPECT_EQ(map.addPoint(Eigen::Vector3d::Zero(), KeyFrameId(10)), MapPointId(41));

  // Replacing a map takes the contents and counters and moves the epoch past both.
  Map live(ScaleInfo::fromConfig(OrbConfig()));
  auto live_lock = live.writeLock();
  live.addKeyFrame(keyFrameWith(0, 1));
  live.clear();
  live.clear();  // epoch 3
  live.replaceWith(std::move(map));
  EXPECT_EQ(live.epoch(), 4u);
  EXPECT_EQ(live.numKeyFrames(), 3u);
  EXPECT_EQ(live.numPoints(), 2u);
  EXPECT_EQ(live.nextKeyFrameId(), KeyFrameId(11));
  EXPECT_EQ(map.numKeyFrames(), 0u);
}

TEST(MapLoadingTest, IndexesClearCompletely) {
  cv::Mat descriptors(200, 32, CV_8U);
  cv::randu(descriptors, 0, 256);
  std::vector<int> rows(200);
  for (int i = 0; i < 200; ++i) rows[i] = i;
  PlaceIndex place;
  KeypointIndex keypoints;
  place.add(KeyFrameId(1), descriptors);
  keypoints.add(KeyFrameId(1), descriptors, rows);
  place.clear();
  keypoints.clear();
  EXPECT_EQ(place.size(), 0u);
  EXPECT_TRUE(place.query(descriptors).empty());
  EXPECT_EQ(keypoints.size(), 0u);
  EXPECT_EQ(keypoints.entries(), 0u);
  EXPECT_TRUE(keypoints.query(descriptors, 10, 1).empty());
  // And work as new afterwards.
  place.add(KeyFrameId(2), descriptors);
  keypoints.add(KeyFrameId(2), descriptors, rows);
  ASSERT_FALSE(place.query(descriptors).empty());
  EXPECT_EQ(place.query(descriptors).front().keyframe, KeyFrameId(2));
  EXPECT_EQ(keypoints.query(descriptors, 0, 1).size(), 200u);
}

// ------------------------------------------------------------ the SLAM map

struct Upload {
  cv::Mat image;
  MotionSample motion;
  uint32_t frame = 0;
};

// A device walking the corridor with odometry (a metric, gravity-aligned map),
// every 4th frame rendered and JPEG-compressed as the device uploads it; the
// SLAM run over it once for every test below.
struct Session {
  std::unique_ptr<Scene> scene;
  std::unique_ptr<Renderer> renderer;
  std::vector<Upload> uploads;
  std::vector<TrackResult> results;
  std::unique_ptr<SlamSystem> slam;
  std::string path;  ///< its map, saved
  double save_ms = 0.0;
};

const Session& session() {
  static const std::unique_ptr<Session> s = [] {
    auto s = std::make_unique<Session>();
    s->scene = std::make_unique<Scene>(loadScene(kScenes + "/corridor.yaml"));
    s->renderer = std::make_unique<Renderer>(*s->scene);
    const auto motion = generateMotion(*s->scene, s->scene->device("device_0"), 30.0);
    RenderOptions opt;
    opt.noise_sigma = static_cast<float>(s->scene->noise_sigma);
    RenderOutput r;
    for (size_t i = 0; i < motion.size() && s->uploads.size() < 36; i += 4) {
      opt.noise_seed = static_cast<uint32_t>(i);
      s->renderer->render(motion[i].T_w_c, opt, &r);
      std::vector<uint8_t> jpeg;
      cv::imencode(".jpg", r.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
      s->uploads.push_back(
          {cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE), motion[i], static_cast<uint32_t>(i)});
    }
    s->slam = std::make_unique<SlamSystem>(s->renderer->camera());
    for (const Upload& u : s->uploads) {
      s->results.push_back(s->slam->track(DeviceId(1), u.image, u.motion.timestamp, u.frame,
                                          u.motion.gravity_c, u.motion.T_o_c));
    }
    s->path = tempDir().file("corridor.ecarmap");
    const auto t0 = std::chrono::steady_clock::now();
    s->slam->saveMap(s->path);
    s->save_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    return s;
  }();
  return *s;
}

void expectSameKeyPoints(const std::vector<cv::KeyPoint>& a, const std::vector<cv::KeyPoint>& b,
                         KeyFrameId id) {
  ASSERT_EQ(a.size(), b.size()) << "keyframe " << id;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].pt, b[i].pt) << "keyframe " << id << " keypoint " << i;
    ASSERT_EQ(a[i].angle, b[i].angle);
    ASSERT_EQ(a[i].octave, b[i].octave);
    ASSERT_EQ(a[i].size, b[i].size);
    ASSERT_EQ(a[i].response, b[i].response);
  }
}

bool sameMat(const cv::Mat& a, const cv::Mat& b) {
  if (a.empty() || b.empty()) return a.empty() && b.empty();
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0;
}

// Every saved field of both maps is equal (the caller holds both read locks).
void expectSameMap(const Map& a, const Map& b) {
  ASSERT_EQ(a.keyframeIds(), b.keyframeIds());
  ASSERT_EQ(a.pointIds(), b.pointIds());
  EXPECT_EQ(a.nextKeyFrameId(), b.nextKeyFrameId());
  EXPECT_EQ(a.nextPointId(), b.nextPointId());
  for (const KeyFrameId id : a.keyframeIds()) {
    const KeyFrame& x = *a.keyframe(id);
    const KeyFrame& y = *b.keyframe(id);
    EXPECT_EQ(x.device, y.device);
    EXPECT_EQ(x.frame_index, y.frame_index);
    EXPECT_EQ(x.timestamp, y.timestamp);
    EXPECT_TRUE(x.T_c_w.isApprox(y.T_c_w, 0.0)) << "keyframe " << id;
    expectSameKeyPoints(x.features.keypoints, y.features.keypoints, id);
    EXPECT_TRUE(sameMat(x.features.descriptors, y.features.descriptors)) << "keyframe " << id;
    EXPECT_TRUE(x.features.undistorted == y.features.undistorted) << "keyframe " << id;
    EXPECT_TRUE(x.features.gravity_c == y.features.gravity_c) << "keyframe " << id;
    ASSERT_EQ(x.features.T_o_c.has_value(), y.features.T_o_c.has_value());
    if (x.features.T_o_c) {
      EXPECT_TRUE(x.features.T_o_c->isApprox(*y.features.T_o_c, 0.0));
    }
    EXPECT_TRUE(x.points == y.points) << "keyframe " << id;
    EXPECT_EQ(x.camera->difference(*y.camera, 0.0), "") << "keyframe " << id;
    EXPECT_EQ(x.features.width, y.features.width);
    // The grid was rebuilt: it finds the same keypoints.
    std::vector<int> near_x, near_y;
    x.features.grid.query(320, 240, 60, -1, -1, &near_x);
    y.features.grid.query(320, 240, 60, -1, -1, &near_y);
    EXPECT_EQ(near_x, near_y);
  }
  for (const MapPointId id : a.pointIds()) {
    const MapPoint& p = *a.point(id);
    const MapPoint& q = *b.point(id);
    EXPECT_TRUE(p.p_w == q.p_w) << "point " << id;
    EXPECT_EQ(p.observations, q.observations) << "point " << id;
    EXPECT_TRUE(sameMat(p.descriptor, q.descriptor)) << "point " << id;
    EXPECT_TRUE(p.normal == q.normal) << "point " << id;
    EXPECT_EQ(p.min_distance, q.min_distance);
    EXPECT_EQ(p.max_distance, q.max_distance);
    EXPECT_EQ(p.reference, q.reference);
    EXPECT_EQ(p.first_keyframe, q.first_keyframe);
    EXPECT_EQ(p.visible, q.visible);
    EXPECT_EQ(p.found, q.found);
    EXPECT_EQ(p.version, q.version);
  }
}

TEST(MapIoSlamTest, MapRoundTripsExactly) {
  const Session& s = session();
  const MapFileReader file = MapFileReader::open(s.path);
  EXPECT_EQ(file.sectionNames(), std::vector<std::string>{"slam"});
  SlamSystem loaded(s.renderer->camera());
  uint32_t saved_epoch;
  {
    auto lock = s.slam->map().readLock();
    saved_epoch = s.slam->map().epoch();
    ASSERT_GE(s.slam->map().numKeyFrames(), 8u);
  }
  loaded.loadMap(s.path);
  auto lock_a = s.slam->map().readLock();
  auto lock_b = loaded.map().readLock();
  expectSameMap(s.slam->map(), loaded.map());
  EXPECT_EQ(loaded.map().checkConsistency(), "");
  EXPECT_GT(loaded.map().epoch(), saved_epoch);
  // Covisibility rebuilt: every keyframe has a neighbour, as in the original.
  for (const KeyFrameId id : loaded.map().keyframeIds()) {
    EXPECT_EQ(loaded.map().keyframe(id)->covisibility.empty(),
              s.slam->map().keyframe(id)->covisibility.empty())
        << "keyframe " << id;
  }
  std::printf("corridor map: %zu keyframes, %zu points, %zu bytes, saved in %.1f ms\n",
              loaded.map().numKeyFrames(), loaded.map().numPoints(), file.fileSize(), s.save_ms);
}

// Keyframes of devices with different cameras: each keyframe comes back with
// its own camera (one shared object per saved camera) and its keypoints
// undistorted with it; a camera index past the list is refused by name.
TEST(MapIoSlamTest, EachKeyFrameKeepsItsCamera) {
  const Session& s = session();
  const ScaleInfo scale = s.slam->map().scale();
  const MapFileReader file = MapFileReader::open(s.path);
  std::unique_ptr<Map> map = decodeSlamMap(file.reader(kSlamSection), scale);
  CameraParams phone;
  phone.width = 800;
  phone.height = 600;
  phone.fx = phone.fy = 600.0;
  phone.cx = 399.5;
  phone.cy = 299.5;
  phone.dist = {-0.12, 0.05, 0.001, -0.0008, 0.0};
  const CameraPtr other = std::make_shared<const PinholeCamera>(phone);
  const std::vector<KeyFrameId> ids = map->keyframeIds();
  ASSERT_GE(ids.size(), 4u);
  for (size_t k = 1; k < ids.size(); k += 2) {
    KeyFrame* kf = map->mutableKeyFrame(ids[k]);
    kf->camera = other;
    kf->features.finalize(*other);
  }
  const std::vector<uint8_t> bytes = encodeSlamMap(*map, s.renderer->camera());
  const std::unique_ptr<Map> back =
      decodeSlamMap(ByteReader(bytes.data(), bytes.size(), "slam"), scale);
  expectSameMap(*map, *back);
  // Two cameras, each one object shared by its keyframes.
  EXPECT_EQ(back->keyframe(ids[1])->camera, back->keyframe(ids[3])->camera);
  EXPECT_EQ(back->keyframe(ids[0])->camera, back->keyframe(ids[2])->camera);
  EXPECT_NE(back->keyframe(ids[0])->camera, back->keyframe(ids[1])->camera);
  EXPECT_EQ(back->keyframe(ids[1])->features.min_u, other->minU());
  EXPECT_LT(other->minU(), -1.0);  // barrel distortion: the undistorted image is larger
  EXPECT_EQ(decodeSlamCamera(ByteReader(bytes.data(), bytes.size(), "slam"))
                .difference(s.renderer->camera(), 0.0),
            "");

  // The first keyframe's camera index (after version, camera count, the two
  // cameras, pyramid, epoch, counters and metric flag, keyframe count, id, device, frame,
  // timestamp and pose) set past the list.
  std::vector<uint8_t> bad = bytes;
  const size_t index_at = 4 + 4 + 2 * 80 + 4 + 4 * scale.levels() + 12 + 1 + 4 + 12 + 8 + 96;
  bad[index_at] = 9;
  const std::string e =
      errorOf([&] { decodeSlamMap(ByteReader(bad.data(), bad.size(), "slam"), scale); });
  EXPECT_TRUE(contains(e, "field 'camera index'") && contains(e, "9 is not below")) << e;
}

// The pose the original run gave an upload, and the one a device joining the
// loaded map gets for the same image, are the same up to mapping noise: the
// session resumes in the same coordinate system. The mapper runs on its own
// thread here, restarted by the load, and maps the new keyframes.
TEST(MapIoSlamTest, LoadedMapRelocalisesInTheSameCoordinateSystem) {
  const Session& s = session();
  SlamConfig config;
  config.synchronous_mapping = false;
  SlamSystem loaded(s.renderer->camera(), config);
  loaded.loadMap(s.path);
  KeyFrameId next_keyframe_before;
  {
    auto lock = loaded.map().readLock();
    next_keyframe_before = loaded.map().nextKeyFrameId();
  }
  int relocalised = 0, tracked = 0;
  double max_dt = 0.0, max_dr = 0.0;
  for (size_t i = 12; i < s.uploads.size(); ++i) {
    const Upload& u = s.uploads[i];
    const TrackResult r =
        loaded.track(DeviceId(5), u.image, u.motion.timestamp, u.frame, u.motion.gravity_c);
    if (i == 12) {
      EXPECT_TRUE(r.relocalised) << r.message;
    }
    if (r.state != TrackingState::kOk || s.results[i].state != TrackingState::kOk) continue;
    ++tracked;
    relocalised += r.relocalised ? 1 : 0;
    const SE3& original = s.results[i].T_w_c;
    const double dt = (r.T_w_c.translation() - original.translation()).norm();
    const double dr = Eigen::AngleAxisd(r.T_w_c.linear().transpose() * original.linear()).angle();
    max_dt = std::max(max_dt, dt);
    max_dr = std::max(max_dr, dr * 180.0 / M_PI);
    EXPECT_LT(dt, 0.03) << "upload " << i;
    EXPECT_LT(dr * 180.0 / M_PI, 1.0) << "upload " << i;
  }
  std::printf(
      "after loading: %d uploads tracked, poses within %.1f mm and %.2f deg of the original run\n",
      tracked, max_dt * 1e3, max_dr);
  EXPECT_EQ(tracked, static_cast<int>(s.uploads.size()) - 12);
  EXPECT_EQ(relocalised, 1);
  loaded.mapper().stopThread();
  auto lock = loaded.map().readLock();
  EXPECT_EQ(loaded.map().checkConsistency(), "");
  // The new device's keyframes went through the restarted mapper (its BA ran).
  EXPECT_GT(loaded.map().nextKeyFrameId().value, next_keyframe_before.value);
  EXPECT_FALSE(loaded.mapper().baTimes().empty());
}

// Every kind of bad file gives an error naming the problem, and the map, its
// epoch and the device's tracking state stay as they were.
TEST(MapIoSlamTest, BadFilesLeaveTheMapUntouched) {
  const Session& s = session();
  SlamSystem slam(s.renderer->camera());
  slam.loadMap(s.path);
  const Upload& u = s.uploads[20];
  ASSERT_EQ(slam.track(DeviceId(1), u.image, u.motion.timestamp, u.frame, u.motion.gravity_c).state,
            TrackingState::kOk);
  const auto snapshot = [&] {
    auto lock = slam.map().readLock();
    const KeyFrame* kf = slam.map().keyframe(slam.map().keyframeIds().back());
    return std::make_tuple(slam.map().numKeyFrames(), slam.map().numPoints(), slam.map().epoch(),
                           kf->T_c_w.translation(), slam.map().checkConsistency());
  };
  const auto before = snapshot();

  const std::vector<uint8_t> good = readBytes(s.path);
  const MapFileReader good_file = MapFileReader::parse(good, "good");
  const size_t slam_start = good.size() - good_file.section("slam").size();
  struct Case {
    std::string name;
    std::vector<uint8_t> bytes;
    std::vector<std::string> expected;  ///< parts of the error text
  };
  std::vector<Case> cases;
  cases.push_back({"truncated header", {good.begin(), good.begin() + 14}, {"truncated"}});
  cases.push_back({"truncated slam",
                   {good.begin(), good.begin() + good.size() / 2},
                   {"section 'slam'", "truncated"}});
  cases.push_back({"last byte missing", {good.begin(), good.end() - 1}, {"truncated"}});
  std::vector<uint8_t> flipped = good;
  flipped[slam_start + (good.size() - slam_start) / 3] ^= 0x40;
  cases.push_back({"flipped byte", flipped, {"section 'slam'", "CRC mismatch"}});
  std::vector<uint8_t> magic = good;
  magic[0] = 'X';
  cases.push_back({"wrong magic", magic, {"not an eCAR map file"}});
  std::vector<uint8_t> version = good;
  version[8] = 7;
  cases.push_back({"wrong version", version, {"format version 7"}});
  {
    // Well-formed container (CRCs right) around a slam section cut in half.
    std::vector<uint8_t> half = good_file.section("slam");
    half.resize(half.size() / 2);
    MapFileWriter w;
    w.addSection("slam", half);
    cases.push_back({"malformed slam", w.serialize(), {"section 'slam'", "keyframe", "field '"}});
  }
  {
    // An observation pointing at a keypoint that does not hold the point.
    std::vector<uint8_t> bytes = good_file.section("slam");
    const size_t tail = bytes.size() - 4;  // the last point's last observation's keypoint
    bytes[tail] ^= 0x01;
    MapFileWriter w;
    w.addSection("slam", bytes);
    cases.push_back(
        {"inconsistent slam", w.serialize(), {"field 'observation keypoint'", "does not hold"}});
  }
  {
    MapFileWriter w;
    w.addSection("planes", {1, 2, 3});
    cases.push_back({"no slam section", w.serialize(), {"no section 'slam'"}});
  }
  for (const Case& c : cases) {
    const std::string path = tempDir().file(c.name + ".ecarmap");
    writeBytes(path, c.bytes);
    const std::string e = errorOf([&] { slam.loadMap(path); });
    EXPECT_TRUE(contains(e, path)) << c.name << ": " << e;
    for (const std::string& part : c.expected) {
      EXPECT_TRUE(contains(e, part)) << c.name << ": " << e;
    }
    EXPECT_EQ(snapshot(), before) << c.name;
    EXPECT_EQ(slam.tracker(DeviceId(1)).state(), TrackingState::kOk) << c.name;
  }
  EXPECT_TRUE(
      contains(errorOf([&] { slam.loadMap(tempDir().file("missing.ecarmap")); }), "cannot open"));
  // A system with another default camera loads the file: the keyframes keep
  // the camera they were made with (frames are undistorted with it).
  CameraParams other = s.renderer->camera().params();
  other.fx = 500.0;
  SlamSystem other_camera{PinholeCamera(other)};
  other_camera.loadMap(s.path);
  {
    auto lock = other_camera.map().readLock();
    ASSERT_GT(other_camera.map().numKeyFrames(), 0u);
    for (const KeyFrameId id : other_camera.map().keyframeIds()) {
      EXPECT_EQ(other_camera.map().keyframe(id)->camera->params().fx,
                s.renderer->camera().params().fx);
    }
  }
  EXPECT_EQ(snapshot(), before);

  // A good load still works after all that, and resets the tracker: the next
  // image relocalises in the new epoch.
  slam.loadMap(s.path);
  EXPECT_EQ(slam.tracker(DeviceId(1)).state(), TrackingState::kNotInitialised);
  {
    auto lock = slam.map().readLock();
    EXPECT_EQ(slam.map().epoch(), std::get<2>(before) + 1);
  }
  const Upload& v = s.uploads[22];
  const TrackResult r =
      slam.track(DeviceId(1), v.image, v.motion.timestamp, v.frame, v.motion.gravity_c);
  EXPECT_EQ(r.state, TrackingState::kOk) << r.message;
  EXPECT_TRUE(r.relocalised);
}

// Saving and loading while a device tracks on its own thread and the mapper
// runs on its own: the tracker waits for a load, then relocalises; every
// saved snapshot is a consistent map.
TEST(MapIoSlamTest, SaveAndLoadWhileADeviceTracks) {
  const Session& s = session();
  SlamConfig config;
  config.synchronous_mapping = false;
  SlamSystem slam(s.renderer->camera(), config);
  slam.loadMap(s.path);
  uint32_t epoch;
  {
    auto lock = slam.map().readLock();
    epoch = slam.map().epoch();
  }
  std::atomic<bool> done{false};
  std::atomic<int> tracked{0};
  std::thread device([&] {
    for (size_t i = 0; !done; i = (i + 1) % s.uploads.size()) {
      const Upload& u = s.uploads[i];
      const auto r =
          slam.track(DeviceId(3), u.image, u.motion.timestamp, u.frame, u.motion.gravity_c);
      tracked += r.state == TrackingState::kOk ? 1 : 0;
    }
  });
  std::vector<std::string> snapshots;
  for (int k = 0; k < 3; ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(150));
    snapshots.push_back(tempDir().file("snapshot_" + std::to_string(k) + ".ecarmap"));
    slam.saveMap(snapshots.back());
    slam.loadMap(s.path);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(150));
  done = true;
  device.join();
  slam.mapper().stopThread();
  EXPECT_GT(tracked, 3);
  {
    auto lock = slam.map().readLock();
    EXPECT_EQ(slam.map().checkConsistency(), "");
    EXPECT_EQ(slam.map().epoch(), epoch + 3);
  }
  for (const std::string& path : snapshots) {
    SlamSystem loaded(s.renderer->camera());
    loaded.loadMap(path);  // decoding checks the consistency
    auto lock = loaded.map().readLock();
    EXPECT_GE(loaded.map().numKeyFrames(), 8u);
  }
}

// A map saved before initialisation loads as an empty map in a new epoch.
TEST(MapIoSlamTest, EmptyMapRoundTrips) {
  const Session& s = session();
  SlamSystem empty(s.renderer->camera());
  const std::string path = tempDir().file("empty.ecarmap");
  empty.saveMap(path);
  SlamSystem loaded(s.renderer->camera());
  loaded.loadMap(s.path);
  loaded.loadMap(path);
  auto lock = loaded.map().readLock();
  EXPECT_EQ(loaded.map().numKeyFrames(), 0u);
  EXPECT_EQ(loaded.map().numPoints(), 0u);
  EXPECT_FALSE(loaded.map().initialized());
  EXPECT_EQ(loaded.map().epoch(), 3u);
  EXPECT_EQ(loaded.map().nextKeyFrameId(), KeyFrameId(1));
}

// Sections of other components, and of later versions, are skipped.
TEST(MapIoSlamTest, UnknownSectionsAreIgnored) {
  const Session& s = session();
  MapFileWriter writer;
  writer.addSection("planes", std::vector<uint8_t>(64, 1));
  s.slam->writeMapSection(&writer);
  writer.addSection("grid", std::vector<uint8_t>(1000, 2));
  writer.addSection("vos_v9_future", {9, 9, 9});
  const std::string path = tempDir().file("extra_sections.ecarmap");
  writer.write(path);
  SlamSystem loaded(s.renderer->camera());
  loaded.loadMap(path);
  auto lock_a = s.slam->map().readLock();
  auto lock_b = loaded.map().readLock();
  expectSameMap(s.slam->map(), loaded.map());
}

// A map of about 100 keyframes (the corridor map, repeated along x as far-off
// copies): file size and the times to save and to load it.
TEST(MapIoSlamTest, HundredKeyframeMapSizeAndTimes) {
  const Session& s = session();
  const SlamSystem& source = *s.slam;
  auto big = std::make_unique<Map>(source.map().scale());
  int copies = 0;
  {
    auto lock = source.map().readLock();
    const Map& m = source.map();
    const uint32_t kf_stride = m.nextKeyFrameId().value, point_stride = m.nextPointId().value;
    copies = static_cast<int>((100 + m.numKeyFrames() - 1) / m.numKeyFrames());
    for (int c = 0; c < copies; ++c) {
      const Eigen::Vector3d shift(40.0 * c, 0, 0);
      const auto kf_id = [&](KeyFrameId id) { return KeyFrameId(id.value + c * kf_stride); };
      const auto point_id = [&](MapPointId id) {
        return id.valid() ? MapPointId(id.value + c * point_stride) : id;
      };
      for (const KeyFrameId id : m.keyframeIds()) {
        KeyFrame kf = *m.keyframe(id);
        kf.id = kf_id(id);
        kf.T_c_w = kf.T_c_w * Eigen::Translation3d(-shift);
        kf.covisibility.clear();
        for (auto& pid : kf.points) pid = point_id(pid);
        big->insertKeyFrame(std::move(kf));
      }
      for (const MapPointId id : m.pointIds()) {
        MapPoint p = *m.point(id);
        p.id = point_id(id);
        p.p_w += shift;
        p.reference = kf_id(p.reference);
        p.first_keyframe = kf_id(p.first_keyframe);
        std::map<KeyFrameId, int> observations;
        for (const auto& [k, idx] : p.observations) observations[kf_id(k)] = idx;
        p.observations = std::move(observations);
        big->insertPoint(std::move(p));
      }
    }
    big->setCounters(KeyFrameId(copies * kf_stride), MapPointId(copies * point_stride), 1);
  }
  for (const KeyFrameId id : big->keyframeIds()) big->updateCovisibility(id);
  ASSERT_EQ(big->checkConsistency(), "");
  const size_t keyframes = big->numKeyFrames(), points = big->numPoints();
  ASSERT_GE(keyframes, 100u);

  using Clock = std::chrono::steady_clock;
  const auto ms = [](Clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  };
  SlamSystem slam(s.renderer->camera());
  auto t0 = Clock::now();
  slam.installMap(std::move(big));
  const double install_ms = ms(t0);
  const std::string path = tempDir().file("hundred.ecarmap");
  t0 = Clock::now();
  slam.saveMap(path);
  const double save_ms = ms(t0);
  const size_t bytes = fs::file_size(path);
  SlamSystem loaded(s.renderer->camera());
  t0 = Clock::now();
  const MapFileReader file = MapFileReader::open(path);
  const double read_ms = ms(t0);
  t0 = Clock::now();
  std::unique_ptr<Map> decoded = loaded.readMapSection(file);
  const double decode_ms = ms(t0);
  t0 = Clock::now();
  loaded.installMap(std::move(decoded));
  const double load_install_ms = ms(t0);
  std::printf(
      "%zu keyframes, %zu points: file %.2f MB (%.1f kB per keyframe); save %.1f ms; load %.1f ms "
      "(read + header %.1f, CRC + decode + rebuild %.1f, install + indexes %.1f); install of the "
      "built map %.1f ms\n",
      keyframes, points, bytes / 1e6, bytes / 1e3 / keyframes, save_ms,
      read_ms + decode_ms + load_install_ms, read_ms, decode_ms, load_install_ms, install_ms);
  auto lock = loaded.map().readLock();
  EXPECT_EQ(loaded.map().numKeyFrames(), keyframes);
  EXPECT_EQ(loaded.map().numPoints(), points);
  EXPECT_EQ(loaded.map().checkConsistency(), "");
  auto lock_a = slam.map().readLock();
  expectSameMap(slam.map(), loaded.map());
  // Fast enough for a service call.
  EXPECT_LT(save_ms, 2000.0);
  EXPECT_LT(read_ms + decode_ms + load_install_ms, 3000.0);
}

}  // namespace
}  // namespace ecar
