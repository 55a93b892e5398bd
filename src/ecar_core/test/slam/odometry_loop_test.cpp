// Loops closed through a device's odometry (LoopClosingConfig::by_odometry):
// a device lost briefly relocalises in an older part of a metric map, and its
// odometry across the gap disagrees with where it relocalised. The tracker
// reports the loop; the closer drops it when the two places share points and
// otherwise moves the map around the last tracked place to agree.
#include <algorithm>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/loop_closer.h"
#include "ecar_core/slam/slam_system.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";
constexpr size_t kUploads = 50;  // every 4th frame of the corridor's device_0: 6.5 m

class OdometryLoopTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new Scene(loadScene(kScenes + "/corridor.yaml"));
    renderer_ = new Renderer(*scene_);
    motion_ = new std::vector<MotionSample>(
        generateMotion(*scene_, scene_->device("device_0"), scene_->camera.fps));
    slam_ = new SlamSystem(renderer_->camera());
    for (size_t u = 0; u < kUploads; ++u) last_ = track(4 * u, (*motion_)[4 * u].T_o_c);
  }
  static void TearDownTestSuite() {
    delete slam_;
    delete motion_;
    delete renderer_;
    delete scene_;
  }

  static TrackResult track(size_t frame, const std::optional<SE3>& T_o_c, double timestamp = -1.0,
                           bool blank = false) {
    RenderOptions opt;
    opt.noise_sigma = static_cast<float>(scene_->noise_sigma);
    opt.noise_seed = static_cast<uint32_t>(frame);
    RenderOutput r;
    renderer_->render((*motion_)[frame].T_w_c, opt, &r);
    if (blank) r.image.setTo(128);
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", r.image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
    const MotionSample& m = (*motion_)[frame];
    return slam_->track(DeviceId(1), cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE),
                        timestamp >= 0.0 ? timestamp : m.timestamp, static_cast<uint32_t>(frame),
                        m.gravity_c, T_o_c);
  }

  static Scene* scene_;
  static Renderer* renderer_;
  static std::vector<MotionSample>* motion_;
  static SlamSystem* slam_;
  static TrackResult last_;
};

Scene* OdometryLoopTest::scene_ = nullptr;
Renderer* OdometryLoopTest::renderer_ = nullptr;
std::vector<MotionSample>* OdometryLoopTest::motion_ = nullptr;
SlamSystem* OdometryLoopTest::slam_ = nullptr;
TrackResult OdometryLoopTest::last_;

// A made-up odometry loop: the device's odometry puts it 10 cm below where
// it relocalised (at `after`, lost after `before`).
OdometryLoop tenCentimetresUp(KeyFrameId before, KeyFrameId after) {
  OdometryLoop loop;
  loop.device = DeviceId(1);
  loop.before = before;
  loop.after = after;
  loop.G.translation() = Eigen::Vector3d(0.0, 0.0, 0.1);
  loop.drift_m = 0.1;
  loop.inliers = 80;
  return loop;
}

TEST_F(OdometryLoopTest, ARelocalisationTheOdometryContradictsIsReportedAsALoop) {
  ASSERT_EQ(last_.state, TrackingState::kOk);
  ASSERT_TRUE(slam_->map().metric());
  const size_t last_frame = 4 * (kUploads - 1);
  const double t_last = (*motion_)[last_frame].timestamp;
  // Lost for one upload (a covered camera), then the device is shown a place
  // 10 uploads back (1.3 m) while its odometry says it stepped there 0.2 m to
  // the side: as if the map between the two places had drifted by that much.
  const TrackResult lost = track(last_frame, (*motion_)[last_frame].T_o_c, t_last + 0.13, true);
  ASSERT_EQ(lost.state, TrackingState::kLost);
  const size_t back = last_frame - 40;
  const SE3& T_w_last = (*motion_)[last_frame].T_w_c;
  SE3 T_w_back_shifted = (*motion_)[back].T_w_c;
  T_w_back_shifted.translation() += Eigen::Vector3d(0.0, 0.2, 0.0);
  const SE3 T_o_now = (*motion_)[last_frame].T_o_c * T_w_last.inverse() * T_w_back_shifted;
  const size_t closures_before = slam_->loopCloser().closures().size();
  const TrackResult r = track(back, T_o_now, t_last + 0.27);
  ASSERT_EQ(r.state, TrackingState::kOk) << r.message;
  EXPECT_TRUE(r.relocalised);
  ASSERT_TRUE(r.odometry_loop.has_value()) << "the odometry's 0.2 m was not reported";
  EXPECT_NEAR(r.odometry_loop->drift_m, 0.2, 0.03);
  EXPECT_NEAR(r.odometry_loop->gap_s, 0.27, 1e-9);
  EXPECT_GE(r.odometry_loop->inliers, 50);
  EXPECT_NE(r.odometry_loop->before, r.odometry_loop->after);
  EXPECT_NEAR(r.odometry_loop->G.translation().norm(), 0.2, 0.05);
  // The two places share points: the closer drops it (no loop, no move).
  EXPECT_EQ(slam_->loopCloser().closures().size(), closures_before);

  // Consistent odometry gives no loop; a gap longer than odometry_max_gap neither.
  const TrackResult lost_again = track(back, T_o_now, t_last + 0.40, true);
  ASSERT_EQ(lost_again.state, TrackingState::kLost);
  const TrackResult consistent =
      track(back + 4, T_o_now * (*motion_)[back].T_w_c.inverse() * (*motion_)[back + 4].T_w_c,
            t_last + 0.53);
  ASSERT_EQ(consistent.state, TrackingState::kOk);
  EXPECT_FALSE(consistent.odometry_loop.has_value());
}

TEST_F(OdometryLoopTest, TheClosedLoopMovesThePlaceLeftBehindAndKeepsTheOther) {
  // A made-up 10 cm loop across this short walk (its keyframes a few
  // covisibility links apart: 10 cm is more than real drift across them),
  // so the closer allows any disagreement per link, and moves only the 2 best
  // neighbours with the place left behind (the real corridor's two legs share
  // none); without the global BA, which would move the made-up correction
  // back to what the images say.
  SlamConfig config;
  config.loops.odometry_max_drift_per_link = 1.0;
  config.loops.covisible_excluded = 2;
  config.loops.global_ba = false;
  PlaceIndex unused(config.place);
  std::vector<KeyFrameId> ids;
  {
    auto lock = slam_->map().readLock();
    ids = slam_->map().keyframeIds();
  }
  std::sort(ids.begin(), ids.end());
  ASSERT_GE(ids.size(), 10u);
  const KeyFrameId before = ids.back(), after = ids[2], middle = ids[ids.size() / 2];
  Eigen::Vector3d c_before, c_after, c_middle;
  {
    auto lock = slam_->map().readLock();
    c_before = slam_->map().keyframe(before)->center();
    c_after = slam_->map().keyframe(after)->center();
    c_middle = slam_->map().keyframe(middle)->center();
  }
  LoopCloser closer(&slam_->map(), &unused, config);
  const OdometryLoop loop = tenCentimetresUp(before, after);
  closer.closeByOdometry(loop);
  const std::vector<LoopClosure> closures = closer.closures();
  ASSERT_EQ(closures.size(), 1u);
  EXPECT_TRUE(closures[0].by_odometry);
  EXPECT_EQ(closures[0].query, before);
  EXPECT_EQ(closures[0].match, after);
  EXPECT_GT(closures[0].keyframes_moved, 3u);
  auto lock = slam_->map().readLock();
  const Eigen::Vector3d moved = slam_->map().keyframe(before)->center() - c_before;
  // This short walk's keyframes share many points all along (strong
  // covisibility edges), so the pose graph spreads the 10 cm over it: the
  // place left behind moves up most, the middle less, the match not at all.
  const double middle_z = slam_->map().keyframe(middle)->center().z() - c_middle.z();
  std::printf("moved up: the place left behind %.3f m, the middle %.3f m\n", moved.z(), middle_z);
  EXPECT_GT(moved.z(), 0.02) << "the place left behind moves with the correction";
  EXPECT_LT(moved.z(), 0.11);
  EXPECT_LT(moved.head<2>().norm(), 0.02);
  EXPECT_GT(middle_z, 0.0);
  EXPECT_LT(middle_z, moved.z());
  EXPECT_LT((slam_->map().keyframe(after)->center() - c_after).norm(), 1e-6);
  EXPECT_EQ(slam_->map().checkConsistency(), "");
}

// Keyframes two covisibility links apart (no point in common, but both share
// points with a third) are held together by the map: the odometry's 10 cm
// disagreement there is a wrong relocalisation, and the closer drops it
// (LoopClosingConfig::odometry_min_hops 3). Allowed two links, it still drops
// it at 4 cm per link (8 cm across two), and closes it at 6 cm per link.
TEST_F(OdometryLoopTest, AGapBetweenKeyframesTwoLinksApartIsNoLoop) {
  std::vector<KeyFrameId> ids;
  KeyFrameId before, after;
  {
    auto lock = slam_->map().readLock();
    ids = slam_->map().keyframeIds();
    std::sort(ids.begin(), ids.end());
    before = ids.back();
    for (const KeyFrameId id : ids) {
      if (slam_->map().covisibilityHops(before, id, 3) == 2) after = id;
    }
  }
  ASSERT_TRUE(after.valid()) << "no keyframe two links from the last";
  const OdometryLoop loop = tenCentimetresUp(before, after);
  SlamConfig config;
  config.loops.global_ba = false;
  PlaceIndex unused(config.place);
  ASSERT_EQ(config.loops.odometry_min_hops, 3);
  ASSERT_DOUBLE_EQ(config.loops.odometry_max_drift_per_link, 0.04);
  const auto closures = [&](const SlamConfig& c) {
    LoopCloser closer(&slam_->map(), &unused, c);
    closer.closeByOdometry(loop);
    return closer.closures();
  };
  EXPECT_TRUE(closures(config).empty());
  config.loops.odometry_min_hops = 2;
  EXPECT_TRUE(closures(config).empty());
  config.loops.odometry_max_drift_per_link = 0.06;
  const std::vector<LoopClosure> closed = closures(config);
  ASSERT_EQ(closed.size(), 1u);
  EXPECT_EQ(closed[0].match, after);
  EXPECT_EQ(closed[0].links, 2);
  EXPECT_DOUBLE_EQ(closed[0].odometry_disagreement_m, 0.1);
}

}  // namespace
}  // namespace ecar
