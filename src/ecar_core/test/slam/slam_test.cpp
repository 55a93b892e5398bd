// The whole SLAM on short rendered sequences: initialisation, tracking,
// mapping, several devices in one map, and bad images; and on a real one.
#include "ecar_core/slam/slam_system.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/io/dataset.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";
const std::string kRealData = ECAR_REPO_ROOT "/../shared/data";

struct Upload {
  cv::Mat image;
  MotionSample motion;
  uint32_t frame = 0;
};

// Every `every`th frame of a device, rendered and JPEG-compressed at quality 70.
std::vector<Upload> renderUploads(const Scene& scene, const Renderer& renderer,
                                  const std::string& device, int every, int max_uploads,
                                  size_t first = 0) {
  const DeviceSpec& spec = scene.device(device);
  const auto motion = generateMotion(scene, spec, scene.cameraOf(spec).fps);
  std::vector<Upload> out;
  RenderOptions opt;
  opt.noise_sigma = static_cast<float>(scene.noise_sigma);
  RenderOutput r;
  for (size_t i = first; i < motion.size() && static_cast<int>(out.size()) < max_uploads;
       i += every) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &r);
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", r.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
    out.push_back({cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE), motion[i], static_cast<uint32_t>(i)});
  }
  return out;
}

// ATE of tracked uploads after one Sim(3) (or SE(3)) alignment.
double ate(const std::vector<Eigen::Vector3d>& est, const std::vector<Eigen::Vector3d>& gt,
           bool scale) {
  const Sim3 S = umeyama(est, gt, scale);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((S * est[i] - gt[i]).norm());
  return computeStats(e).rmse;
}

TEST(SlamTest, HalfCircleIsTrackedAccurately) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "half_circle", 4, 60);
  SlamSystem slam(renderer.camera());
  std::vector<Eigen::Vector3d> est, gt;
  int tracked = 0, init = -1;
  for (size_t i = 0; i < uploads.size(); ++i) {
    const auto r = slam.track(DeviceId(1), uploads[i].image, uploads[i].motion.timestamp,
                              uploads[i].frame, uploads[i].motion.gravity_c);
    if (r.initialised) init = static_cast<int>(i);
    if (r.state == TrackingState::kOk) {
      ++tracked;
      est.push_back(r.T_w_c.translation());
      gt.push_back(uploads[i].motion.T_w_c.translation());
      EXPECT_GT(r.tracked.size(), 50u) << "upload " << i;
    }
  }
  ASSERT_GE(init, 0) << "never initialised";
  EXPECT_LE(init, 10);  // the device stands still for 0.5 s, then speeds up
  const int after = static_cast<int>(uploads.size()) - init;
  EXPECT_GE(tracked, 0.95 * after) << tracked << " of " << after;
  ASSERT_GE(est.size(), 10u);
  EXPECT_LT(ate(est, gt, true), 0.015);
  EXPECT_GE(slam.map().numKeyFrames(), 3u);
}

// The atlas tracks one upload in several maps with the features extracted
// once: a map given them tracks exactly as one that extracts its own.
TEST(SlamTest, FeaturesExtractedOnceTrackAsExtractedAgain) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "half_circle", 4, 30);
  SlamConfig config;
  config.synchronous_mapping = true;
  SlamSystem extracting(renderer.camera(), config), given(renderer.camera(), config);
  int tracked = 0;
  for (size_t i = 0; i < uploads.size(); ++i) {
    const Upload& u = uploads[i];
    ImageFeatures features;
    const auto a = extracting.track(DeviceId(1), u.image, u.motion.timestamp, u.frame,
                                    u.motion.gravity_c, std::nullopt, &features);
    ASSERT_TRUE(features.extracted) << "upload " << i;
    ASSERT_EQ(features.keypoints.size(), static_cast<size_t>(features.descriptors.rows));
    // (Given features, the image is only checked for its size.)
    const auto b = given.track(DeviceId(1), u.image, u.motion.timestamp, u.frame,
                               u.motion.gravity_c, std::nullopt, &features);
    ASSERT_EQ(a.state, b.state) << "upload " << i;
    ASSERT_EQ(a.tracked.size(), b.tracked.size()) << "upload " << i;
    if (a.state == TrackingState::kOk) {
      ++tracked;
      EXPECT_LT((a.T_w_c.translation() - b.T_w_c.translation()).norm(), 1e-9) << "upload " << i;
    }
  }
  EXPECT_GE(tracked, 15);
}

// A hand-held shake (5 cm, 4 degrees, 1 Hz) has little parallax between any
// two views: initialisation must find the pair of recent views with the
// largest baseline, not wait for the first view to be renewed.
TEST(SlamTest, HandHeldShakeInitialisesFromItsBestPairOfViews) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "shake", 4, 36);
  SlamSystem slam(renderer.camera());
  std::vector<Eigen::Vector3d> est, gt;
  int init = -1;
  for (size_t i = 0; i < uploads.size(); ++i) {
    const auto r = slam.track(DeviceId(1), uploads[i].image, uploads[i].motion.timestamp,
                              uploads[i].frame, uploads[i].motion.gravity_c);
    if (r.initialised) init = static_cast<int>(i);
    if (r.state == TrackingState::kOk) {
      est.push_back(r.T_w_c.translation());
      gt.push_back(uploads[i].motion.T_w_c.translation());
    } else {
      EXPECT_LT(init, 0) << "lost at upload " << i;
    }
  }
  ASSERT_GE(init, 0) << "never initialised";
  EXPECT_LE(init, 26);  // the first pair 10 cm apart comes at upload 18-22
  ASSERT_GE(est.size(), 8u);
  EXPECT_LT(ate(est, gt, true), 0.01);
}

// Real street: the car drives ~1 m per frame with most points far away. The
// two-view step must accept the forward motion early, and tracking follow it.
TEST(SlamRealDataTest, Kitti07InitialisesAndTracks) {
  const std::string dir = kRealData + "/kitti07_0-159";
  if (!std::filesystem::is_directory(dir)) {
    GTEST_SKIP() << "real test data not found at " << dir << ": skipping this test";
  }
  const Dataset data = Dataset::open(dir);
  SlamSystem slam(data.camera());
  std::vector<Eigen::Vector3d> est, gt;
  int tracked = 0, init = -1;
  const size_t n = std::min<size_t>(40, data.size());
  for (size_t i = 0; i < n; ++i) {
    const DatasetFrame& f = data.frame(i);
    const auto r = slam.track(DeviceId(1), data.loadImage(i, cv::IMREAD_GRAYSCALE), f.timestamp,
                              static_cast<uint32_t>(i));
    if (r.initialised) init = static_cast<int>(i);
    if (r.state != TrackingState::kOk) continue;
    ++tracked;
    ASSERT_TRUE(f.T_w_c_gt.has_value());
    est.push_back(r.T_w_c.translation());
    gt.push_back(f.T_w_c_gt->translation());
  }
  ASSERT_GE(init, 0) << "never initialised";
  EXPECT_LE(init, 20);
  EXPECT_GE(tracked, 0.95 * (static_cast<int>(n) - init)) << tracked << " tracked";
  ASSERT_GE(est.size(), 10u);
  EXPECT_LT(ate(est, gt, true), 0.5);  // over ~35 m of driving
}

TEST(SlamTest, OdometryGivesAMetricMap) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "device_0", 4, 40);
  SlamSystem slam(renderer.camera());
  std::vector<Eigen::Vector3d> est, gt;
  for (const auto& u : uploads) {
    const auto r = slam.track(DeviceId(1), u.image, u.motion.timestamp, u.frame, u.motion.gravity_c,
                              u.motion.T_o_c);
    if (r.state == TrackingState::kOk) {
      est.push_back(r.T_w_c.translation());
      gt.push_back(u.motion.T_w_c.translation());
    }
  }
  ASSERT_GE(est.size(), 25u);
  const Sim3 S = umeyama(est, gt, true);
  // Metric within the odometry's scale error (1%) plus the two-view estimate.
  EXPECT_NEAR(S.scale, 1.0, 0.05);
  // Gravity-aligned: the map's z axis is up.
  EXPECT_GT((S.R * Eigen::Vector3d::UnitZ()).z(), 0.99);
}

// The initialising upload is answered from the adjusted two-view map (the
// devices track on the points of that answer until their next graph): a
// second adjustment of the pair moves its newer keyframe by less than 0.2
// mm (measured: not at all), where the raw reconstruction moved 1.1 mm.
TEST(SlamTest, TheInitialisingUploadIsAnsweredFromTheAdjustedMap) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "device_0", 4, 20);
  SlamConfig config;
  config.synchronous_mapping = false;  // the mapper's own work does not run in track()
  SlamSystem slam(renderer.camera(), config);
  std::optional<TrackResult> init;
  for (const auto& u : uploads) {
    TrackResult r = slam.track(DeviceId(1), u.image, u.motion.timestamp, u.frame,
                               u.motion.gravity_c, u.motion.T_o_c);
    if (r.initialised) {
      init = std::move(r);
      break;
    }
  }
  ASSERT_TRUE(init) << "never initialised";
  ASSERT_TRUE(init->new_keyframe);
  const KeyFrameId kf = *init->new_keyframe;
  SE3 T_c_w;
  {
    auto lock = slam.map().readLock();
    ASSERT_EQ(slam.map().numKeyFrames(), 2u);
    T_c_w = slam.map().keyframe(kf)->T_c_w;
  }
  EXPECT_LT((init->T_w_c.translation() - T_c_w.inverse().translation()).norm(), 1e-9)
      << "the answer is not the keyframe's pose";
  slam.mapper().adjustNow(kf);
  auto lock = slam.map().readLock();
  const SE3 T_c_w_again = slam.map().keyframe(kf)->T_c_w;
  EXPECT_LT((T_c_w_again.inverse().translation() - T_c_w.inverse().translation()).norm(), 2e-4)
      << "the two-view map was answered before its adjustment";
}

TEST(SlamTest, TwoDevicesEndInOneMap) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto a = renderUploads(scene, renderer, "device_0", 4, 35);
  const auto b = renderUploads(scene, renderer, "device_2", 4, 35);
  SlamSystem slam(renderer.camera());
  std::vector<Eigen::Vector3d> est, gt;
  int tracked_b = 0, joined_b = -1;
  for (size_t i = 0; i < std::max(a.size(), b.size()); ++i) {
    for (int d = 0; d < 2; ++d) {
      const auto& ups = d == 0 ? a : b;
      if (i >= ups.size()) continue;
      const auto r = slam.track(DeviceId(d + 1), ups[i].image, ups[i].motion.timestamp,
                                ups[i].frame, ups[i].motion.gravity_c);
      if (r.state != TrackingState::kOk) continue;
      if (d == 1) {
        ++tracked_b;
        if (joined_b < 0) joined_b = static_cast<int>(i);
      }
      est.push_back(r.T_w_c.translation());
      gt.push_back(ups[i].motion.T_w_c.translation());
    }
  }
  EXPECT_GE(joined_b, 0) << "the second device never joined the map";
  EXPECT_GE(tracked_b, 0.8 * static_cast<int>(b.size()));
  ASSERT_GE(est.size(), 20u);
  // Both devices' poses fit the ground truth with a single transform.
  EXPECT_LT(ate(est, gt, true), 0.05);
  // Keyframes from both devices are in the map.
  auto lock = slam.map().readLock();
  bool has[3] = {false, false, false};
  for (const auto& id : slam.map().keyframeIds()) has[slam.map().keyframe(id)->device.value] = true;
  EXPECT_TRUE(has[1]);
  EXPECT_TRUE(has[2]);
}

// Two phones with different cameras (640x480 pinhole; 800x600 with a wider
// lens and radial-tangential distortion) in one map: each is tracked with its
// own camera, its keyframes carry it, and points are triangulated, fused and
// bundle-adjusted across keyframes of both cameras.
TEST(SlamTest, DevicesWithTheirOwnCamerasShareOneMap) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const PinholeCamera phone(scene.cameraOf(scene.device("phone_800")));
  ASSERT_EQ(phone.width(), 800);
  ASSERT_TRUE(phone.hasDistortion());
  const Renderer phone_renderer(scene, phone);
  const auto a = renderUploads(scene, renderer, "device_0", 4, 40);
  const auto b = renderUploads(scene, phone_renderer, "phone_800", 4, 40);
  SlamSystem slam(renderer.camera());
  slam.setCamera(DeviceId(2), phone);
  std::vector<Eigen::Vector3d> est[2], gt[2], all_est, all_gt;
  for (size_t i = 0; i < std::max(a.size(), b.size()); ++i) {
    for (int d = 0; d < 2; ++d) {
      const auto& ups = d == 0 ? a : b;
      if (i >= ups.size()) continue;
      const auto r = slam.track(DeviceId(d + 1), ups[i].image, ups[i].motion.timestamp,
                                ups[i].frame, ups[i].motion.gravity_c);
      if (r.state != TrackingState::kOk) continue;
      est[d].push_back(r.T_w_c.translation());
      gt[d].push_back(ups[i].motion.T_w_c.translation());
      all_est.push_back(est[d].back());
      all_gt.push_back(gt[d].back());
    }
  }
  ASSERT_GE(est[0].size(), 25u);
  ASSERT_GE(est[1].size(), 25u);
  // One similarity for both devices; each device's error after it.
  const Sim3 S = umeyama(all_est, all_gt, true);
  for (int d = 0; d < 2; ++d) {
    std::vector<double> e;
    for (size_t i = 0; i < est[d].size(); ++i) e.push_back((S * est[d][i] - gt[d][i]).norm());
    EXPECT_LT(computeStats(e).rmse, 0.03) << "device " << d + 1;
  }
  auto lock = slam.map().readLock();
  const Map& map = slam.map();
  int phone_keyframes = 0, shared_points = 0;
  for (const KeyFrameId id : map.keyframeIds()) {
    const KeyFrame* kf = map.keyframe(id);
    EXPECT_EQ(kf->camera->width(), kf->device == DeviceId(2) ? 800 : 640) << "keyframe " << id;
    phone_keyframes += kf->device == DeviceId(2) ? 1 : 0;
  }
  for (const MapPointId id : map.pointIds()) {
    bool seen[2] = {false, false};
    for (const auto& [kid, idx] : map.point(id)->observations) {
      seen[map.keyframe(kid)->device == DeviceId(2) ? 1 : 0] = true;
    }
    shared_points += seen[0] && seen[1] ? 1 : 0;
  }
  EXPECT_GE(phone_keyframes, 3);
  EXPECT_GE(shared_points, 100) << "points seen through both cameras";
  EXPECT_EQ(map.checkConsistency(), "");
}

// Trackers of two devices on their own threads and the mapper on its thread,
// against one map, while a reader checks the map's invariants: the server's
// concurrency. (Run under -fsanitize=thread to check for data races too.)
TEST(SlamTest, ConcurrentTrackersAndMapperKeepTheMapConsistent) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto a = renderUploads(scene, renderer, "device_0", 4, 30);
  const auto b = renderUploads(scene, renderer, "device_2", 4, 30);
  SlamConfig config;
  config.synchronous_mapping = false;
  SlamSystem slam(renderer.camera(), config);
  std::atomic<bool> done{false};
  std::vector<std::string> problems;
  std::thread checker([&] {
    while (!done) {
      {
        auto lock = slam.map().readLock();
        const std::string problem = slam.map().checkConsistency();
        if (!problem.empty()) problems.push_back(problem);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  });
  int tracked[2] = {0, 0};
  const auto run = [&](int d) {
    const auto& ups = d == 0 ? a : b;
    for (size_t i = 0; i < ups.size(); ++i) {
      const auto r = slam.track(DeviceId(d + 1), ups[i].image, ups[i].motion.timestamp,
                                ups[i].frame, ups[i].motion.gravity_c);
      tracked[d] += r.state == TrackingState::kOk ? 1 : 0;
      // Paced like uploads (7.5 per second, sped up), so the devices interleave.
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  };
  std::thread first(run, 0), second(run, 1);
  first.join();
  second.join();
  slam.mapper().stopThread();
  done = true;
  checker.join();
  EXPECT_TRUE(problems.empty()) << problems.front();
  auto lock = slam.map().readLock();
  EXPECT_EQ(slam.map().checkConsistency(), "");
  EXPECT_GE(slam.map().numKeyFrames(), 5u);
  // One device created the map; together they tracked most uploads.
  EXPECT_GE(tracked[0] + tracked[1], 30) << tracked[0] << " + " << tracked[1];
}

// device_1 walks the corridor the other way: it sees device_0's map from the
// opposite side (floor and ceiling rotated 180 degrees in the image).
TEST(SlamTest, DeviceWalkingTheOtherWayJoins) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto a = renderUploads(scene, renderer, "device_0", 4, 45);       // x 0.6 -> 7.3
  const auto b = renderUploads(scene, renderer, "device_1", 4, 14, 522);  // x 13.0 -> 11.0
  SlamSystem slam(renderer.camera());
  std::vector<Eigen::Vector3d> est, gt;
  for (const auto& u : a) {
    const auto r =
        slam.track(DeviceId(1), u.image, u.motion.timestamp, u.frame, u.motion.gravity_c);
    if (r.state != TrackingState::kOk) continue;
    est.push_back(r.T_w_c.translation());
    gt.push_back(u.motion.T_w_c.translation());
  }
  const size_t device_0_poses = est.size();
  ASSERT_GE(device_0_poses, 30u);
  int joined = -1, tracked = 0;
  for (size_t i = 0; i < b.size(); ++i) {
    const auto r = slam.track(DeviceId(2), b[i].image, b[i].motion.timestamp, b[i].frame,
                              b[i].motion.gravity_c);
    if (r.state != TrackingState::kOk) continue;
    if (joined < 0) joined = static_cast<int>(i);
    ++tracked;
    est.push_back(r.T_w_c.translation());
    gt.push_back(b[i].motion.T_w_c.translation());
  }
  std::printf("joined at upload %d, tracked %d of %zu\n", joined, tracked, b.size());
  ASSERT_GE(joined, 0) << "the device walking the other way never joined";
  EXPECT_GE(tracked, static_cast<int>(b.size()) - joined - 2);
  // One transform for both devices: the join is not a wrong alignment.
  EXPECT_LT(ate(est, gt, true), 0.05);
}

// A device at rest (the EuRoC clip's vehicle before take-off): no two-view
// attempt is wasted, and the reason says so.
TEST(SlamTest, DeviceAtRestDoesNotInitialise) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "half_circle", 4, 1);
  SlamSystem slam(renderer.camera());
  TrackResult r;
  for (int i = 0; i < 5; ++i) r = slam.track(DeviceId(1), uploads[0].image, 0.1 * i, 4 * i);
  EXPECT_EQ(r.state, TrackingState::kNotInitialised);
  EXPECT_NE(r.message.find("has not moved"), std::string::npos) << r.message;
  auto lock = slam.map().readLock();
  EXPECT_FALSE(slam.map().initialized());
}

TEST(SlamTest, BadImagesAreReportedAndSkipped) {
  const Scene scene = loadScene(kScenes + "/room.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "half_circle", 4, 16);
  SlamSystem slam(renderer.camera());
  size_t i = 0;
  for (; i < 10; ++i) {
    slam.track(DeviceId(1), uploads[i].image, uploads[i].motion.timestamp, uploads[i].frame);
  }
  ASSERT_EQ(slam.tracker(DeviceId(1)).state(), TrackingState::kOk);
  size_t keyframes;
  {
    auto lock = slam.map().readLock();
    keyframes = slam.map().numKeyFrames();
  }
  const cv::Mat black = cv::Mat::zeros(480, 640, CV_8UC1);
  const cv::Mat blank(480, 640, CV_8UC1, cv::Scalar(200));
  const cv::Mat small = cv::Mat::zeros(100, 100, CV_8UC1);
  std::vector<uint8_t> jpeg;
  cv::imencode(".jpg", uploads[10].image, jpeg);
  jpeg.resize(jpeg.size() / 3);  // truncated JPEG: decodes partly or not at all
  const cv::Mat truncated = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
  for (const cv::Mat& bad : {black, blank, small, cv::Mat()}) {
    const auto r = slam.track(DeviceId(1), bad, 0.0, 0);
    EXPECT_NE(r.state, TrackingState::kNotInitialised);
    EXPECT_FALSE(r.message.empty());
  }
  // The map is unchanged by the bad images.
  {
    auto lock = slam.map().readLock();
    EXPECT_EQ(slam.map().numKeyFrames(), keyframes);
  }
  // A truncated JPEG decodes partly (or not at all): tracked or reported, no crash.
  const auto rt = slam.track(DeviceId(1), truncated, 0.0, 0);
  EXPECT_TRUE(rt.state == TrackingState::kOk || !rt.message.empty());
  bool recovered = false;
  for (i = 10; i < uploads.size(); ++i) {
    const auto r =
        slam.track(DeviceId(1), uploads[i].image, uploads[i].motion.timestamp, uploads[i].frame);
    recovered |= r.state == TrackingState::kOk;
  }
  EXPECT_TRUE(recovered);
  // A repeated image is tracked (zero motion), not a crash.
  const auto r1 = slam.track(DeviceId(1), uploads.back().image, 100.0, 1000);
  const auto r2 = slam.track(DeviceId(1), uploads.back().image, 100.1, 1001);
  EXPECT_EQ(r2.state, r1.state);
}

// Map distance over odometry distance between a device's consecutive
// keyframes, summed over the map.
double mapOverOdometry(const Map& map) {
  std::vector<const KeyFrame*> kfs;
  for (const KeyFrameId& id : map.keyframeIds()) {
    const KeyFrame* k = map.keyframe(id);
    if (k && k->features.T_o_c) kfs.push_back(k);
  }
  std::sort(kfs.begin(), kfs.end(),
            [](const KeyFrame* a, const KeyFrame* b) { return a->timestamp < b->timestamp; });
  double in_map = 0.0, by_odometry = 0.0;
  for (size_t i = 1; i < kfs.size(); ++i) {
    in_map += (kfs[i]->center() - kfs[i - 1]->center()).norm();
    by_odometry +=
        (kfs[i]->features.T_o_c->translation() - kfs[i - 1]->features.T_o_c->translation()).norm();
  }
  return in_map / by_odometry;
}

// A young metric map is bundle-adjusted whole, so its scale is every
// keyframe's odometry. The map is scaled by 10% about its first keyframe
// (which no image can tell): whole, one adjustment brings it back to metres;
// in windows of ba_keyframes the keyframes fixed around the window keep the
// old scale and hold the window to it (how E8's young map slid by 11-25%).
TEST(SlamTest, AYoungMetricMapTakesItsScaleFromAllItsOdometry) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto uploads = renderUploads(scene, renderer, "device_0", 4, 32);
  std::map<int, double> before, after;
  for (const int whole : {30, 0}) {
    SlamConfig config;
    config.ba_whole_map_keyframes = whole;
    SlamSystem slam(renderer.camera(), config);
    KeyFrameId last;
    for (const auto& u : uploads) {
      const auto r = slam.track(DeviceId(1), u.image, u.motion.timestamp, u.frame,
                                u.motion.gravity_c, u.motion.T_o_c);
      if (r.new_keyframe) last = *r.new_keyframe;
    }
    ASSERT_TRUE(last.valid());
    {
      auto lock = slam.map().writeLock();
      Map& map = slam.map();
      ASSERT_TRUE(map.metric());
      ASSERT_GT(map.numKeyFrames(), static_cast<size_t>(config.ba_keyframes) + 4);
      ASSERT_LE(map.numKeyFrames(), 30u);
      const Eigen::Vector3d c0 = map.keyframe(map.keyframeIds().front())->center();
      for (const KeyFrameId& id : map.keyframeIds()) {
        KeyFrame* k = map.mutableKeyFrame(id);
        const Eigen::Vector3d c = c0 + 1.1 * (k->center() - c0);
        k->T_c_w.translation() = -(k->T_c_w.linear() * c);
      }
      for (const MapPointId& id : map.pointIds()) {
        MapPoint* p = map.mutablePoint(id);
        p->p_w = c0 + 1.1 * (p->p_w - c0);
      }
      before[whole] = mapOverOdometry(map);
    }
    slam.mapper().adjustNow(last);
    auto lock = slam.map().readLock();
    after[whole] = mapOverOdometry(slam.map());
  }
  std::printf("map/odometry scaled %.4f; adjusted whole %.4f, in windows %.4f\n", before[30],
              after[30], after[0]);
  EXPECT_NEAR(before[30], 1.1, 0.03);
  EXPECT_NEAR(after[30], 1.0, 0.02) << "the whole map follows its odometry";
  EXPECT_GT(after[0], 1.06) << "windows keep the scale of the keyframes fixed around them";
}

}  // namespace
}  // namespace ecar
