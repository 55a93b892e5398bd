// The device side: its keyframe queue, and tracking every frame of a rendered
// corridor walk against the local graphs of a real SLAM run on the uploads
// (every 4th frame, JPEG quality 70), delivered late as a round trip would.
#include "ecar_core/device/device_tracker.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <map>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/slam_system.h"
#include "ecar_core/sync/local_graph_composer.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

DeviceKeyFrame keyframeOf(std::initializer_list<uint32_t> ids) {
  DeviceKeyFrame kf;
  for (uint32_t id : ids) {
    kf.point_ids.push_back(MapPointId(id));
    kf.keypoints.emplace_back(10.0f, 10.0f, 31.0f, 0.0f, 0.0f, 0);
  }
  kf.descriptors = cv::Mat::zeros(static_cast<int>(ids.size()), 32, CV_8U);
  kf.valid.assign(ids.size(), 1);
  return kf;
}

std::vector<GraphPosition> positionsOf(std::initializer_list<uint32_t> ids) {
  std::vector<GraphPosition> out;
  for (uint32_t id : ids) out.push_back({MapPointId(id), Eigen::Vector3f(id, 0.0f, 1.0f)});
  return out;
}

TEST(DeviceKeyFrameQueueTest, CountsObservationsAndEvictsTheOldest) {
  DeviceKeyFrameQueue queue(2);
  auto r = queue.insert(keyframeOf({1, 2, 3}), positionsOf({1, 2, 3}));
  EXPECT_TRUE(r.missing.empty());
  EXPECT_EQ(r.new_positions, 3);
  EXPECT_EQ(queue.size(), 1u);
  EXPECT_EQ(queue.numPoints(), 3u);
  // Points 2 and 3 are held already: only 4 needs a position.
  r = queue.insert(keyframeOf({2, 3, 4}), positionsOf({4}));
  EXPECT_TRUE(r.missing.empty());
  EXPECT_EQ(queue.observations(MapPointId(1)), 1);
  EXPECT_EQ(queue.observations(MapPointId(2)), 2);
  EXPECT_EQ(queue.observations(MapPointId(4)), 1);
  // A third keyframe evicts the first: point 1 reaches zero and is deleted,
  // point 3 (shared by the evicted and the new keyframe) keeps its position.
  r = queue.insert(keyframeOf({3, 5}), positionsOf({5}));
  EXPECT_EQ(r.evicted_keyframes, 1);
  EXPECT_EQ(r.deleted_points, 1);
  EXPECT_TRUE(r.missing.empty());
  EXPECT_EQ(queue.size(), 2u);
  EXPECT_EQ(queue.observations(MapPointId(1)), 0);
  EXPECT_EQ(queue.position(MapPointId(1)), nullptr);
  EXPECT_EQ(queue.observations(MapPointId(2)), 1);
  EXPECT_EQ(queue.observations(MapPointId(3)), 2);
  ASSERT_NE(queue.position(MapPointId(3)), nullptr);
  EXPECT_DOUBLE_EQ(queue.position(MapPointId(3))->x(), 3.0);
  EXPECT_EQ(queue.numPoints(), 4u);  // 2, 3, 4, 5
  EXPECT_EQ(queue.keyframes().front().point_ids.front(), MapPointId(2));
}

TEST(DeviceKeyFrameQueueTest, UpdatesPositionsAndReportsMissingOnes) {
  DeviceKeyFrameQueue queue(10);
  queue.insert(keyframeOf({1, 2}), positionsOf({1, 2}));
  // A newer position replaces the held one; a position of a point no
  // keyframe holds is not kept.
  auto r = queue.insert(keyframeOf({1}), {{MapPointId(1), Eigen::Vector3f(7, 8, 9)},
                                          {MapPointId(9), Eigen::Vector3f(1, 1, 1)}});
  EXPECT_EQ(r.new_positions, 1);
  EXPECT_DOUBLE_EQ(queue.position(MapPointId(1))->z(), 9.0);
  EXPECT_EQ(queue.position(MapPointId(9)), nullptr);
  EXPECT_EQ(queue.observations(MapPointId(9)), 0);
  // A graph naming points whose positions never arrived (a missed graph).
  r = queue.insert(keyframeOf({2, 5, 6}), positionsOf({6}));
  ASSERT_EQ(r.missing.size(), 1u);
  EXPECT_EQ(r.missing[0], MapPointId(5));
  EXPECT_EQ(queue.observations(MapPointId(5)), 1);  // held, without a position
  EXPECT_EQ(queue.position(MapPointId(5)), nullptr);
  // The position arrives later (the server resent everything after a reset).
  r = queue.insert(keyframeOf({5}), positionsOf({5}));
  EXPECT_TRUE(r.missing.empty());
  EXPECT_NE(queue.position(MapPointId(5)), nullptr);
}

TEST(DeviceKeyFrameQueueTest, ClearDropsEverything) {
  DeviceKeyFrameQueue queue(3);
  queue.insert(keyframeOf({1, 2}), positionsOf({1, 2}));
  queue.insert(keyframeOf({3}), positionsOf({3}));
  queue.clear();
  EXPECT_TRUE(queue.empty());
  EXPECT_EQ(queue.numPoints(), 0u);
  EXPECT_EQ(queue.position(MapPointId(1)), nullptr);
  // After an epoch change the old ids are unknown: the next graph needs positions.
  const auto r = queue.insert(keyframeOf({1}), {});
  EXPECT_EQ(r.missing.size(), 1u);
}

TEST(DeviceKeyFrameQueueTest, InvalidCapacityThrows) {
  EXPECT_THROW(DeviceKeyFrameQueue(0), Error);
  DeviceTrackerConfig config;
  config.keyframe_queue = 0;
  try {
    config.validate();
    FAIL() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("keyframe_queue"), std::string::npos);
  }
}

TEST(DeviceTrackerTest, NothingToTrackBeforeTheFirstGraph) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  RenderOutput out;
  renderer.render(generateMotion(scene, scene.device("device_0"), scene.camera.fps, 1)[0].T_w_c,
                  RenderOptions(), &out);
  DeviceTracker tracker(renderer.camera());
  EXPECT_EQ(tracker.track(out.image, 0.0, 0).state, TrackingState::kNotInitialised);
  EXPECT_EQ(tracker.track(cv::Mat(10, 10, CV_8U), 0.0, 1).state, TrackingState::kNotInitialised);
}

// ---- the corridor run, shared by the accuracy tests

/// Wire quantisation of a graph's keypoints (ecar_msgs/TrackedPoint: 1/8 px,
/// 256 angle steps) and positions (float32).
void quantise(LocalGraph* g) {
  for (GraphPoint& p : g->points) {
    p.u = std::round(p.u * 8.0f) / 8.0f;
    p.v = std::round(p.v * 8.0f) / 8.0f;
    p.angle =
        static_cast<float>(static_cast<int>(std::lround(p.angle / 1.40625f)) % 256) * 1.40625f;
  }
}

struct FrameRecord {
  uint32_t frame = 0;
  SE3 T_w_c_gt;
  bool uploaded = false;
  bool server_ok = false;
  SE3 T_w_c_server;
  bool graph_seen = false;  ///< the device had received a local graph before this frame
  TrackingState state[2] = {TrackingState::kNotInitialised, TrackingState::kNotInitialised};
  SE3 T_w_c_device[2];
  double ms[2] = {0.0, 0.0};
};

struct CorridorRun {
  std::vector<FrameRecord> frames;
  int missing_positions = 0;  ///< ecar mode: named points without a position
  size_t max_keyframes = 0;
};

/// Renders `num_frames` of the corridor walk; uploads every 4th frame (JPEG
/// 70, gravity, odometry) to a SlamSystem; delivers each local graph `delay`
/// frames later to two device trackers (ecar mode: index 0, edgeslam: 1),
/// which track every frame on the uncompressed image.
CorridorRun runCorridor(int num_frames, int delay) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto motion = generateMotion(scene, scene.device("device_0"), scene.camera.fps, num_frames);
  SlamSystem slam(renderer.camera());
  DeviceTracker ecar_device(renderer.camera()), edgeslam_device(renderer.camera());
  // The server's side: the composer with exact positions (every moved point resent).
  LocalGraphComposerConfig composer_config;
  composer_config.position_tolerance = 0.0;
  const LocalGraphComposer composer(composer_config);
  DeviceSyncState ecar_state(ecar_device.config().keyframe_queue), edgeslam_state;
  const ComposerLookups lookups;

  struct Pending {
    int deliver_at;
    cv::Mat image;  ///< the device's own uncompressed image of the uploaded frame
    LocalGraph ecar;
    LocalGraph full;
  };
  std::deque<Pending> in_flight;
  CorridorRun run;
  RenderOptions opt;
  opt.noise_sigma = static_cast<float>(scene.noise_sigma);
  opt.depth = opt.labels = false;
  RenderOutput out;
  bool graph_seen = false;
  for (int i = 0; i < static_cast<int>(motion.size()); ++i) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &out);
    FrameRecord rec;
    rec.frame = static_cast<uint32_t>(i);
    rec.T_w_c_gt = motion[i].T_w_c;
    // Graphs whose round trip has ended arrive before this frame is tracked.
    while (!in_flight.empty() && in_flight.front().deliver_at <= i) {
      Pending& p = in_flight.front();
      const GraphUpdate u = ecar_device.addLocalGraph(p.image, p.ecar);
      run.missing_positions += static_cast<int>(u.queue.missing.size());
      edgeslam_device.replaceLocalMap(p.full);
      graph_seen = true;
      in_flight.pop_front();
    }
    rec.graph_seen = graph_seen;
    if (i % 4 == 0) {
      rec.uploaded = true;
      std::vector<uint8_t> jpeg;
      cv::imencode(".jpg", out.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
      const TrackResult r =
          slam.track(DeviceId(1), cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE), motion[i].timestamp,
                     rec.frame, motion[i].gravity_c, motion[i].T_o_c);
      if (r.state == TrackingState::kOk) {
        rec.server_ok = true;
        rec.T_w_c_server = r.T_w_c;
        Pending p;
        p.deliver_at = i + delay;
        p.image = out.image.clone();
        ComposerInput in;
        in.device = "device_0";
        in.frame_index = rec.frame;
        in.map_epoch = r.map_epoch;
        in.frame = &r;
        in.mode = SyncMode::kEcar;
        p.ecar = composer.compose(slam.map(), in, lookups, &ecar_state).value();
        quantise(&p.ecar);
        in.mode = SyncMode::kEdgeSlam;
        p.full = composer.compose(slam.map(), in, lookups, &edgeslam_state).value();
        in_flight.push_back(std::move(p));
      }
    }
    DeviceTracker* devices[2] = {&ecar_device, &edgeslam_device};
    for (int d = 0; d < 2; ++d) {
      const DeviceTrackResult& t = devices[d]->track(out.image, motion[i].timestamp, rec.frame);
      rec.state[d] = t.state;
      rec.T_w_c_device[d] = t.T_w_c;
      rec.ms[d] = t.total_ms;
    }
    run.max_keyframes = std::max(run.max_keyframes, ecar_device.numKeyFrames());
    run.frames.push_back(rec);
  }
  return run;
}

const CorridorRun& corridorRun() {
  static const CorridorRun run = runCorridor(150, 2);
  return run;
}

/// ATE after one Sim(3) alignment (the map is metric only within the odometry's scale error).
double ate(const std::vector<Eigen::Vector3d>& est, const std::vector<Eigen::Vector3d>& gt) {
  if (est.size() < 3) return 0.0;
  const Sim3 S = umeyama(est, gt, true);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((S * est[i] - gt[i]).norm());
  return computeStats(e).rmse;
}

struct Accuracy {
  int after_graph = 0, tracked = 0;
  double rmse_vs_server = 0.0, max_rot_deg_vs_server = 0.0, ate_vs_gt = 0.0, server_ate = 0.0;
  int compared = 0;
  double median_ms = 0.0, p95_ms = 0.0;
};

Accuracy accuracyOf(const CorridorRun& run, int d) {
  Accuracy a;
  std::vector<double> err, ms;
  std::vector<Eigen::Vector3d> est, gt, server, server_gt;
  for (const FrameRecord& f : run.frames) {
    if (f.server_ok) {
      server.push_back(f.T_w_c_server.translation());
      server_gt.push_back(f.T_w_c_gt.translation());
    }
    if (!f.graph_seen) continue;
    ++a.after_graph;
    ms.push_back(f.ms[d]);
    if (f.state[d] != TrackingState::kOk) continue;
    ++a.tracked;
    est.push_back(f.T_w_c_device[d].translation());
    gt.push_back(f.T_w_c_gt.translation());
    if (!f.server_ok) continue;
    err.push_back((f.T_w_c_device[d].translation() - f.T_w_c_server.translation()).norm());
    a.max_rot_deg_vs_server =
        std::max(a.max_rot_deg_vs_server,
                 rotationAngle(f.T_w_c_device[d].linear().transpose() * f.T_w_c_server.linear()) *
                     180.0 / M_PI);
  }
  a.compared = static_cast<int>(err.size());
  if (!err.empty()) a.rmse_vs_server = computeStats(err).rmse;
  a.ate_vs_gt = ate(est, gt);
  a.server_ate = ate(server, server_gt);
  std::sort(ms.begin(), ms.end());
  if (!ms.empty()) {
    a.median_ms = ms[ms.size() / 2];
    a.p95_ms = ms[std::min(ms.size() - 1, ms.size() * 95 / 100)];
  }
  std::printf(
      "[device %s] frames after the first graph %d, tracked %d; vs server on %d uploads: RMSE "
      "%.2f mm, max rotation %.3f deg; ATE vs ground truth %.1f mm (server %.1f mm); tracking "
      "%.1f ms median, %.1f ms p95\n",
      d == 0 ? "ecar" : "edgeslam", a.after_graph, a.tracked, a.compared, 1000.0 * a.rmse_vs_server,
      a.max_rot_deg_vs_server, 1000.0 * a.ate_vs_gt, 1000.0 * a.server_ate, a.median_ms, a.p95_ms);
  return a;
}

TEST(DeviceTrackerTest, EcarGraphsTrackEveryFrameWithinHalfACentimetreOfTheServer) {
  const CorridorRun& run = corridorRun();
  const Accuracy a = accuracyOf(run, 0);
  ASSERT_GT(a.after_graph, 60) << "the server never initialised early enough";
  EXPECT_GE(a.tracked, 0.98 * a.after_graph);
  ASSERT_GE(a.compared, 15);
  EXPECT_LE(a.rmse_vs_server, 0.005);
  EXPECT_LT(a.max_rot_deg_vs_server, 0.5);
  EXPECT_LT(a.ate_vs_gt, 0.03);
  EXPECT_LT(a.ate_vs_gt, a.server_ate + 0.005);
  // The server's mirror and the device agree: no graph named an unknown point.
  EXPECT_EQ(run.missing_positions, 0);
  EXPECT_EQ(run.max_keyframes, 10u);
}

TEST(DeviceTrackerTest, EdgeslamLocalMapsTrack) {
  const Accuracy a = accuracyOf(corridorRun(), 1);
  ASSERT_GT(a.after_graph, 60);
  EXPECT_GE(a.tracked, 0.98 * a.after_graph);
  ASSERT_GE(a.compared, 15);
  EXPECT_LE(a.rmse_vs_server, 0.005);
  EXPECT_LT(a.ate_vs_gt, 0.03);
}

TEST(DeviceTrackerTest, ClearForgetsTheMap) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto motion = generateMotion(scene, scene.device("device_0"), scene.camera.fps, 1);
  RenderOutput out;
  renderer.render(motion[0].T_w_c, RenderOptions(), &out);
  DeviceTracker tracker(renderer.camera());
  // A graph built from the exact geometry: keypoints detected on the image,
  // positions from the depth map.
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps;
  orb.detectAndCompute(out.image, &kps, nullptr);
  LocalGraph g;
  g.status = GraphStatus::kOk;
  g.T_w_c = motion[0].T_w_c;
  for (size_t i = 0; i < kps.size(); ++i) {
    const float z = out.depth.at<float>(cvRound(kps[i].pt.y), cvRound(kps[i].pt.x));
    if (z <= 0.0f) continue;
    const Eigen::Vector3d ray =
        renderer.camera().unproject(Eigen::Vector2d(kps[i].pt.x, kps[i].pt.y));
    const MapPointId id(static_cast<uint32_t>(i + 1));
    g.points.push_back({id, kps[i].pt.x, kps[i].pt.y, kps[i].angle, kps[i].octave});
    g.positions.push_back({id, (motion[0].T_w_c * (ray * z)).cast<float>()});
  }
  const GraphUpdate u = tracker.addLocalGraph(out.image, g);
  EXPECT_TRUE(u.queue.missing.empty());
  EXPECT_GT(u.points, 300);
  const DeviceTrackResult& r = tracker.track(out.image, 0.0, 1);
  ASSERT_EQ(r.state, TrackingState::kOk);
  EXPECT_LT((r.T_w_c.translation() - motion[0].T_w_c.translation()).norm(), 0.005);
  tracker.clear();
  EXPECT_EQ(tracker.numPoints(), 0u);
  EXPECT_EQ(tracker.numKeyFrames(), 0u);
  EXPECT_EQ(tracker.track(out.image, 0.0, 2).state, TrackingState::kNotInitialised);
}

}  // namespace
}  // namespace ecar
