// The atlas on the small ring (config/scenes/ring_small.yaml): two devices start
// at the same time on opposite sides of the ring. Each makes a map of its own
// at once (neither waits for the other's map), and when walker_b reaches the
// ground walker mapped first the two maps merge into one. And a device whose
// camera goes blank for 3 s and sees again somewhere unmapped: a new map at
// once, merged back when it sees its first map's ground again.
#include "ecar_core/slam/atlas.h"

#include <optional>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

TEST(AtlasTest, DevicesStartingApartMakeTheirOwnMapsWhichMerge) {
  const Scene scene = loadScene(kScenes + "/ring_small.yaml");
  const Renderer renderer(scene);
  const std::vector<std::string> names = {"walker", "walker_b"};
  std::vector<std::vector<MotionSample>> motion;
  for (const auto& n : names) {
    motion.push_back(generateMotion(scene, scene.device(n), scene.camera.fps));
  }
  Atlas atlas(renderer.camera(), SlamConfig());
  RenderOptions opt;
  RenderOutput r;
  int first_tracked[2] = {-1, -1};
  size_t most_maps = 0;
  int merged_at = -1;
  int answered_in_a_gone_map = 0;
  // The pose of the upload whose merge moved its own map (answered in the merged map).
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> merging_pose;  // (estimate, truth)
  const size_t uploads = std::max(motion[0].size(), motion[1].size()) / 4;
  for (size_t u = 0; u < uploads; ++u) {
    for (size_t d = 0; d < 2; ++d) {
      const size_t i = 4 * u;
      if (i >= motion[d].size()) continue;
      opt.noise_seed = static_cast<uint32_t>(i + 100000 * d);
      renderer.render(motion[d][i].T_w_c, opt, &r);
      std::vector<uint8_t> jpeg;
      cv::imencode(".jpg", r.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
      MapId map;
      const TrackResult t = atlas.track(DeviceId(d + 1), cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE),
                                        motion[d][i].timestamp, static_cast<uint32_t>(i),
                                        motion[d][i].gravity_c, motion[d][i].T_o_c, &map);
      if (t.state == TrackingState::kOk && first_tracked[d] < 0)
        first_tracked[d] = static_cast<int>(u);
      most_maps = std::max(most_maps, atlas.mapIds().size());
      EXPECT_EQ(t.map, map);
      if (map.valid() && !atlas.map(map)) ++answered_in_a_gone_map;
      if (merged_at < 0 && !atlas.merges().empty()) {
        merged_at = static_cast<int>(u);
        if (t.state == TrackingState::kOk && atlas.merges().front().device == DeviceId(d + 1)) {
          merging_pose.emplace(t.T_w_c.translation(), motion[d][i].T_w_c.translation());
        }
      }
    }
  }
  atlas.finish();
  EXPECT_EQ(answered_in_a_gone_map, 0) << "uploads answered in a map merged away";
  // Both tracked as soon as they move (0.5 s standing: about 4 uploads), each in its own map.
  EXPECT_GE(most_maps, 2u);
  EXPECT_GE(first_tracked[0], 0);
  EXPECT_LE(first_tracked[0], 12);
  EXPECT_GE(first_tracked[1], 0);
  EXPECT_LE(first_tracked[1], 12) << "the second device waited for the first one's map";
  ASSERT_GE(merged_at, 0) << "the maps never merged";
  ASSERT_EQ(atlas.mapIds().size(), 1u);
  EXPECT_EQ(atlas.mapOf(DeviceId(1)), atlas.mapOf(DeviceId(2)));
  const MergeEvent m = atlas.merges().front();
  EXPECT_GE(m.inliers, 20);

  // One transform fits both devices' keyframes in the merged map.
  const std::shared_ptr<SlamSystem> slam = atlas.map(atlas.mapIds().front());
  std::vector<Eigen::Vector3d> est, gt;
  int per_device[3] = {0, 0, 0};
  {
    auto lock = slam->map().readLock();
    EXPECT_EQ(slam->map().checkConsistency(), "");
    for (const KeyFrameId id : slam->map().keyframeIds()) {
      const KeyFrame* kf = slam->map().keyframe(id);
      const size_t d = kf->device.value - 1;
      est.push_back(kf->center());
      gt.push_back(motion[d][kf->frame_index].T_w_c.translation());
      ++per_device[kf->device.value];
    }
  }
  EXPECT_GE(per_device[1], 10);
  EXPECT_GE(per_device[2], 10);
  const Sim3 S = umeyama(est, gt, true);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((S * est[i] - gt[i]).norm());
  const double ate = computeStats(e).rmse;
  std::printf(
      "maps %zu at most; first tracked uploads %d and %d; merged at upload %d (%d inliers, "
      "%.0f ms); keyframe ATE after the merge %.4f m\n",
      most_maps, first_tracked[0], first_tracked[1], merged_at, m.inliers, m.ms, ate);
  EXPECT_LT(ate, 0.08);
  // The merging upload was answered where it is in the merged map.
  ASSERT_TRUE(merging_pose.has_value());
  EXPECT_LT((S * merging_pose->first - merging_pose->second).norm(), 0.15)
      << merging_pose->first.transpose();
}

TEST(AtlasTest, ADeviceBlindFor3sStartsANewMapAndIsMergedBack) {
  const Scene scene = loadScene(kScenes + "/ring_small.yaml");
  const Renderer renderer(scene);
  const std::vector<MotionSample> motion =
      generateMotion(scene, scene.device("blind"), scene.camera.fps);
  AtlasConfig config;
  config.background_merge_ba = true;  // queued on the loop closer (run at once: synchronous)
  Atlas atlas(renderer.camera(), SlamConfig(), config);
  RenderOptions opt;
  RenderOutput r;
  int lost_at = -1, textured_at = -1, tracked_again = -1, merged_at = -1;
  MapId before, after;
  for (size_t u = 0; 4 * u < motion.size(); ++u) {
    const size_t i = 4 * u;
    opt.noise_seed = static_cast<uint32_t>(i);
    opt.blank = motion[i].blank;
    renderer.render(motion[i].T_w_c, opt, &r);
    MapId map;
    const TrackResult t =
        atlas.track(DeviceId(1), r.image, motion[i].timestamp, static_cast<uint32_t>(i),
                    motion[i].gravity_c, motion[i].T_o_c, &map);
    const bool ok = t.state == TrackingState::kOk;
    if (lost_at < 0 && motion[i].blank) {
      lost_at = static_cast<int>(u);
      before = atlas.mapOf(DeviceId(1));
      EXPECT_FALSE(ok) << "tracked a blank image at upload " << u;
    }
    if (lost_at >= 0 && textured_at < 0 && !motion[i].blank) textured_at = static_cast<int>(u);
    if (textured_at >= 0 && tracked_again < 0 && ok) {
      tracked_again = static_cast<int>(u);
      after = map;
    }
    if (merged_at < 0 && !atlas.merges().empty()) merged_at = static_cast<int>(u);
  }
  atlas.finish();
  ASSERT_GE(lost_at, 0) << "the scene's device never goes blank";
  ASSERT_GE(tracked_again, 0) << "never tracked again after the blank";
  std::printf(
      "blank from upload %d, textured again at %d, tracked again at %d (map %u, was %u); "
      "merged back at upload %d\n",
      lost_at, textured_at, tracked_again, after.value, before.value, merged_at);
  // Unmapped ground: a new map, within 5 uploads of seeing texture again.
  EXPECT_LE(tracked_again - textured_at, 5);
  EXPECT_NE(after, before) << "relocalised in its first map: the scene's new place was mapped";
  // The next map id: no map was made (and dropped) while the first one initialised.
  EXPECT_EQ(after.value, before.value + 1);
  // The walk ends in the south corridor it mapped first, looking the same way.
  ASSERT_GT(merged_at, tracked_again) << "the maps never merged";
  EXPECT_EQ(atlas.mapIds().size(), 1u);
  const MergeEvent m = atlas.merges().front();
  EXPECT_TRUE((m.into == before && m.from == after) || (m.into == after && m.from == before));
  EXPECT_EQ(atlas.map(atlas.mapIds().front())->loopCloser().requestedBundleAdjustmentsMs().size(),
            1u);
  const std::shared_ptr<SlamSystem> slam = atlas.map(atlas.mapIds().front());
  std::vector<Eigen::Vector3d> est, gt;
  {
    auto lock = slam->map().readLock();
    EXPECT_EQ(slam->map().checkConsistency(), "");
    for (const KeyFrameId id : slam->map().keyframeIds()) {
      const KeyFrame* kf = slam->map().keyframe(id);
      est.push_back(kf->center());
      gt.push_back(motion[kf->frame_index].T_w_c.translation());
    }
  }
  const Sim3 S = umeyama(est, gt, true);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((S * est[i] - gt[i]).norm());
  const double ate = computeStats(e).rmse;
  std::printf("keyframe ATE of the merged map %.4f m (%zu keyframes)\n", ate, est.size());
  EXPECT_LT(ate, 0.08);
}

}  // namespace
}  // namespace ecar
