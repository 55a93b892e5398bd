// Loop closing on a rendered ring corridor (config/scenes/ring_small.yaml):
// a device walks once around and on past its start; the SLAM recognises the
// start, verifies it, corrects the map and keeps tracking.
#include <algorithm>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/slam_system.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

struct RingRun {
  std::vector<LoopClosure> closures;
  double keyframe_ate = 0.0;  ///< Sim(3), the map's keyframes at the end
  int tracked_after_closure = 0, uploads_after_closure = 0;
  std::string consistency;
};

// Every 4th frame of the walk, JPEG 70, with gravity and odometry.
RingRun runRing(bool loops) {
  const Scene scene = loadScene(kScenes + "/ring_small.yaml");
  const Renderer renderer(scene);
  const auto motion = generateMotion(scene, scene.device("walker"), scene.camera.fps);
  SlamConfig config;
  config.loops.enabled = loops;
  SlamSystem slam(renderer.camera(), config);
  RenderOptions opt;
  opt.noise_sigma = static_cast<float>(scene.noise_sigma);
  RenderOutput r;
  RingRun run;
  std::vector<double> closed_at;  // timestamps of the uploads that closed a loop
  for (size_t i = 0; i < motion.size(); i += 4) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &r);
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", r.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
    const size_t closures_before = slam.loopCloser().closures().size();
    const TrackResult t =
        slam.track(DeviceId(1), cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE), motion[i].timestamp,
                   static_cast<uint32_t>(i), motion[i].gravity_c, motion[i].T_o_c);
    if (slam.loopCloser().closures().size() > closures_before) closed_at.push_back(i);
    if (!closed_at.empty() && i > closed_at.front()) {
      ++run.uploads_after_closure;
      run.tracked_after_closure += t.state == TrackingState::kOk ? 1 : 0;
    }
  }
  run.closures = slam.loopCloser().closures();
  std::vector<Eigen::Vector3d> est, gt;
  auto lock = slam.map().readLock();
  for (const KeyFrameId id : slam.map().keyframeIds()) {
    const KeyFrame* kf = slam.map().keyframe(id);
    est.push_back(kf->center());
    gt.push_back(motion[kf->frame_index].T_w_c.translation());
  }
  const Sim3 S = umeyama(est, gt, true);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((S * est[i] - gt[i]).norm());
  run.keyframe_ate = computeStats(e).rmse;
  run.consistency = slam.map().checkConsistency();
  return run;
}

TEST(LoopClosingTest, ARingWalkedOnceIsClosedAndTheMapStraightened) {
  const RingRun open = runRing(false);
  const RingRun closed = runRing(true);
  EXPECT_TRUE(open.closures.empty());
  ASSERT_GE(closed.closures.size(), 1u) << "the loop was not closed";
  const LoopClosure& first = closed.closures.front();
  EXPECT_LT(first.match.value, 10u) << "closed with the start of the walk";
  EXPECT_GE(first.inliers, 40);
  EXPECT_GT(first.points_fused, 20u);
  EXPECT_GT(first.keyframes_moved, 50u);
  std::printf(
      "loop: keyframe %u with %u, %d inliers, moved %.3f m, %.1f ms (+%.1f ms global BA); "
      "keyframe ATE %.4f m without closing, %.4f m with\n",
      first.query.value, first.match.value, first.inliers, first.drift_m,
      first.detect_ms + first.correct_ms, first.global_ba_ms, open.keyframe_ate,
      closed.keyframe_ate);
  EXPECT_LT(closed.keyframe_ate, 0.025);
  EXPECT_LT(closed.keyframe_ate, 0.6 * open.keyframe_ate);
  // Tracking goes on across the correction.
  EXPECT_GE(closed.tracked_after_closure, closed.uploads_after_closure - 1);
  EXPECT_EQ(closed.consistency, "");
}

}  // namespace
}  // namespace ecar
