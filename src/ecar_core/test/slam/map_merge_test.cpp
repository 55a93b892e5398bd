// Merging maps: a map of the corridor and the same map as another device's
// SLAM would have made it (another coordinate system and scale, other ids) are
// merged through the similarity between them; every pair of duplicate points
// becomes one, and the covisibility graph is welded across the seam.
#include "ecar_core/slam/map_merge.h"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/place_verification.h"
#include "ecar_core/slam/pose_graph.h"
#include "ecar_core/slam/seam_refit.h"
#include "ecar_core/slam/slam_system.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

// The SLAM's map of the first 30 uploads of the corridor's device_0.
std::unique_ptr<SlamSystem> corridorMap() {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto motion = generateMotion(scene, scene.device("device_0"), scene.camera.fps);
  auto slam = std::make_unique<SlamSystem>(renderer.camera());
  RenderOptions opt;
  RenderOutput r;
  for (size_t i = 0; i < motion.size() && i < 120; i += 4) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &r);
    slam->track(DeviceId(1), r.image, motion[i].timestamp, static_cast<uint32_t>(i),
                motion[i].gravity_c, motion[i].T_o_c);
  }
  return slam;
}

// `map` as seen from another frame: ids moved up by `offset`, positions through T
// (the other map's world = T * this world).
std::unique_ptr<Map> copyOf(const Map& map, uint32_t offset, const Sim3& T) {
  auto copy = std::make_unique<Map>(map.scale());
  const Sim3 T_inverse = T.inverse();
  for (const KeyFrameId id : map.keyframeIds()) {
    KeyFrame kf = *map.keyframe(id);
    kf.id = KeyFrameId(id.value + offset);
    kf.T_c_w = metricPose(similarityOf(kf.T_c_w) * T_inverse);
    kf.covisibility.clear();
    for (MapPointId& p : kf.points) {
      if (p.valid()) p = MapPointId(p.value + offset);
    }
    copy->insertKeyFrame(std::move(kf));
  }
  for (const MapPointId id : map.pointIds()) {
    MapPoint p = *map.point(id);
    p.id = MapPointId(id.value + offset);
    p.p_w = T * p.p_w;
    p.reference = KeyFrameId(p.reference.value + offset);
    p.first_keyframe = KeyFrameId(p.first_keyframe.value + offset);
    std::map<KeyFrameId, int> observations;
    for (const auto& [k, idx] : p.observations) observations[KeyFrameId(k.value + offset)] = idx;
    p.observations = std::move(observations);
    copy->insertPoint(std::move(p));
  }
  copy->setCounters(KeyFrameId(map.nextKeyFrameId().value + offset),
                    MapPointId(map.nextPointId().value + offset), 1);
  for (const KeyFrameId id : copy->keyframeIds()) copy->updateCovisibility(id);
  return copy;
}

TEST(MapMergeTest, TwoMapsOfOnePlaceBecomeOne) {
  const std::unique_ptr<SlamSystem> slam = corridorMap();
  Map& a = slam->map();
  auto lock_a = a.writeLock();
  ASSERT_GE(a.numKeyFrames(), 5u);
  ASSERT_EQ(a.checkConsistency(), "");
  const size_t keyframes = a.numKeyFrames(), points = a.numPoints();
  Sim3 T;  // the other map's frame: turned, shifted, 1.7 times larger
  T.scale = 1.7;
  T.R = expSO3(Eigen::Vector3d(0.2, -0.1, 1.3));
  T.t = Eigen::Vector3d(4.0, -2.0, 0.5);
  const uint32_t offset = 100000;
  std::unique_ptr<Map> b = copyOf(a, offset, T);
  ASSERT_EQ(b->checkConsistency(), "");
  // Every point is seen in both maps (place recognition would find a subset).
  std::vector<std::pair<MapPointId, MapPointId>> duplicates;
  for (const MapPointId id : a.pointIds()) {
    duplicates.emplace_back(MapPointId(id.value + offset), id);
  }
  const MergeResult r = mergeMaps(&a, b.get(), T.inverse(), duplicates);
  EXPECT_EQ(r.keyframes_moved, keyframes);
  EXPECT_EQ(r.points_moved, points);
  EXPECT_EQ(r.points_fused, points);
  EXPECT_EQ(b->numKeyFrames(), 0u);
  EXPECT_EQ(a.numKeyFrames(), 2 * keyframes);
  EXPECT_EQ(a.numPoints(), points);  // one point per physical point
  EXPECT_EQ(a.checkConsistency(), "");
  EXPECT_GT(a.nextKeyFrameId().value, offset);
  for (const KeyFrameId id : slam->map().keyframeIds()) {
    if (id.value >= offset) continue;
    const KeyFrame* original = a.keyframe(id);
    const KeyFrame* moved = a.keyframe(KeyFrameId(id.value + offset));
    ASSERT_NE(moved, nullptr);
    // The moved keyframe is where its twin is, and the seam is welded: the
    // twins share every point.
    EXPECT_LT((moved->center() - original->center()).norm(), 1e-9) << id;
    EXPECT_LT(logSO3(moved->T_c_w.linear().transpose() * original->T_c_w.linear()).norm(), 1e-9);
    const auto link = moved->covisibility.find(id);
    ASSERT_NE(link, moved->covisibility.end()) << "keyframe " << id << " not welded";
    EXPECT_GE(link->second, original->numTrackedPoints() / 2);
    EXPECT_EQ(r.correction.of(moved->id).scale, T.inverse().scale);
  }
  EXPECT_FALSE(r.seam.empty());
  EXPECT_TRUE(r.correction.of(KeyFrameId(1)).R.isIdentity());  // the kept map did not move

  // Maps sharing an id are refused before anything moves.
  std::unique_ptr<Map> clash = copyOf(a, 0, T);
  auto lock_clash = clash->writeLock();
  try {
    mergeMaps(&a, clash.get(), T.inverse(), {});
    ADD_FAILURE() << "merged maps sharing ids";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("in both maps"), std::string::npos) << e.what();
  }
  EXPECT_EQ(clash->numKeyFrames(), 2 * keyframes);
}

// A merge through a slightly wrong similarity (what one view's few dozen
// matches give), then the seam refit: the reprojections across the seam bring
// the moved map back onto its twin.
struct PerturbedMerge {
  std::unique_ptr<SlamSystem> slam = corridorMap();
  std::unique_ptr<Map> b;
  MergeResult r;
  Sim3 S, S_true;  ///< the merge's similarity (refined by refit()), the true one
  static constexpr uint32_t kOffset = 100000;

  // P: the error of the merge's similarity (applied after the true one).
  explicit PerturbedMerge(const Sim3& P, size_t duplicates_wanted = 40) {
    Map& a = slam->map();
    auto lock = a.writeLock();
    Sim3 T;
    T.scale = 1.7;
    T.R = expSO3(Eigen::Vector3d(0.2, -0.1, 1.3));
    T.t = Eigen::Vector3d(4.0, -2.0, 0.5);
    b = copyOf(a, kOffset, T);
    // Place recognition's few dozen matches: every 5th point.
    std::vector<std::pair<MapPointId, MapPointId>> duplicates;
    const std::vector<MapPointId> ids = a.pointIds();
    for (size_t i = 0; i < ids.size() && duplicates.size() < duplicates_wanted; i += 5) {
      duplicates.emplace_back(MapPointId(ids[i].value + kOffset), ids[i]);
    }
    S_true = T.inverse();
    S = P * S_true;
    r = mergeMaps(&a, b.get(), S, duplicates);
  }

  SeamRefit refit(bool fix_scale) {
    Map& a = slam->map();
    auto lock = a.writeLock();
    return refitMerge(&a, &r, &S, fix_scale);
  }

  // Largest distance (m) and angle (deg) between a moved keyframe and its twin.
  std::pair<double, double> twinError() {
    Map& a = slam->map();
    auto lock = a.readLock();
    double distance = 0.0, angle = 0.0;
    for (const KeyFrameId id : a.keyframeIds()) {
      if (id.value >= kOffset) continue;
      const KeyFrame* original = a.keyframe(id);
      const KeyFrame* moved = a.keyframe(KeyFrameId(id.value + kOffset));
      if (!moved) continue;
      distance = std::max(distance, (moved->center() - original->center()).norm());
      angle = std::max(angle,
                       rotationAngle(moved->T_c_w.linear().transpose() * original->T_c_w.linear()) *
                           180.0 / M_PI);
    }
    return {distance, angle};
  }
};

Sim3 perturbation(double deg, const Eigen::Vector3d& t, double scale) {
  Sim3 P;
  P.R = expSO3(Eigen::Vector3d(0.3, 0.2, 0.9).normalized() * deg * M_PI / 180.0);
  P.t = t;
  P.scale = scale;
  return P;
}

// What refers to points by id (planes) finds the point each one became: fused
// at the seam, or fused in the merged-in map before the merge.
TEST(MapMergeTest, PointsFusedBeforeAndAtTheMergeAreFollowedInTheMergedMap) {
  const std::unique_ptr<SlamSystem> slam = corridorMap();
  Map& a = slam->map();
  auto lock_a = a.writeLock();
  Sim3 T;
  T.t = Eigen::Vector3d(1.0, 0.0, 0.0);
  const uint32_t offset = 100000;
  std::unique_ptr<Map> b = copyOf(a, offset, T);
  const std::vector<MapPointId> ids = a.pointIds();
  ASSERT_GE(ids.size(), 2u);
  const MapPointId p(ids[0].value + offset), q(ids[1].value + offset);
  b->replacePoint(p, q);  // b's own fusion, before the merge
  std::vector<std::pair<MapPointId, MapPointId>> duplicates;
  for (const MapPointId id : ids) duplicates.emplace_back(MapPointId(id.value + offset), id);
  const MergeResult r = mergeMaps(&a, b.get(), T.inverse(), duplicates);
  EXPECT_EQ(r.points_fused, ids.size() - 1);  // p was gone already
  const MapPointId q_now = a.livePoint(q);
  ASSERT_TRUE(q_now.valid());
  EXPECT_EQ(a.livePoint(p), q_now);
  for (const auto& [theirs, mine] : duplicates) {
    if (theirs == p) continue;
    const MapPointId now = a.livePoint(theirs);
    ASSERT_TRUE(now.valid()) << theirs;
    EXPECT_EQ(a.livePoint(mine), now) << mine;
  }
  EXPECT_FALSE(b->livePoint(p).valid());  // the record left with the points
}

TEST(SeamRefitTest, ReprojectionsAcrossTheSeamCorrectTheMergesSimilarity) {
  PerturbedMerge m(perturbation(1.0, Eigen::Vector3d(0.05, -0.03, 0.02), 1.01));
  const auto [before_m, before_deg] = m.twinError();
  EXPECT_GT(before_deg, 0.9);
  const SeamRefit r = m.refit(false);
  ASSERT_TRUE(r.applied) << r.inliers << " of " << r.observations << " inliers, " << r.rms_before_px
                         << " -> " << r.rms_after_px << " px";
  EXPECT_GE(r.observations, 100);
  // At the true similarity the residuals are the map's own (about 0.9 px).
  EXPECT_LT(r.rms_after_px, 1.2);
  EXPECT_GT(r.rms_before_px, 2.0 * r.rms_after_px);
  const auto [after_m, after_deg] = m.twinError();
  EXPECT_LT(after_m, 0.001) << before_m;  // 9 cm and 1 degree before
  EXPECT_LT(after_deg, 0.01) << before_deg;
  // The merge's similarity and its correction are the true ones now.
  EXPECT_LT(rotationAngle(m.S.R.transpose() * m.S_true.R) * 180.0 / M_PI, 0.01);
  EXPECT_NEAR(m.S.scale / m.S_true.scale, 1.0, 1e-4);
  EXPECT_NEAR(m.r.correction.of(KeyFrameId(PerturbedMerge::kOffset + 1)).scale, m.S.scale, 1e-12);
  std::printf("twins %.4f m, %.3f deg apart; after the refit %.4f m, %.3f deg\n", before_m,
              before_deg, after_m, after_deg);
  EXPECT_EQ(m.slam->map().checkConsistency(), "");
}

TEST(SeamRefitTest, AMetricMergeKeepsItsScale) {
  // Both maps metric: D is a rotation and translation; the scale error stays.
  PerturbedMerge m(perturbation(0.8, Eigen::Vector3d(0.04, 0.0, -0.02), 1.0));
  const SeamRefit r = m.refit(true);
  ASSERT_TRUE(r.applied);
  EXPECT_DOUBLE_EQ(r.D.scale, 1.0);
  EXPECT_LT(m.twinError().second, 0.01);
}

TEST(SeamRefitTest, NotAppliedWithoutASeamOrWhenTheCorrectionIsLarge) {
  {
    // No duplicates: nothing of one side is seen by the other.
    PerturbedMerge m(perturbation(1.0, Eigen::Vector3d::Zero(), 1.0), 0);
    const SeamRefit r = m.refit(false);
    EXPECT_FALSE(r.applied);
    EXPECT_EQ(r.observations, 0);
  }
  {
    // 12 degrees off is not a refinement of a verified similarity.
    PerturbedMerge m(perturbation(12.0, Eigen::Vector3d(0.5, 0.0, 0.0), 1.0));
    const auto before = m.twinError();
    EXPECT_FALSE(m.refit(false).applied);
    EXPECT_DOUBLE_EQ(m.twinError().first, before.first);  // nothing moved
  }
}

// Place verification's quick rejection (LoopClosingConfig::min_candidate_matches):
// a keyframe of one map and its twin in the other map's copy (another frame,
// scale and ids) are the same place. It is verified with the check off and at
// its default with the same similarity and inliers, through the twins' points;
// the check counts the query keyframe's own points matched to the candidate's
// own, so a threshold one above that count rejects the place.
TEST(PlaceVerificationTest, QuickRejectionKeepsTheTruePlaceAndRejectsAboveItsOwnMatches) {
  const std::unique_ptr<SlamSystem> slam = corridorMap();
  const Map& a = slam->map();
  Sim3 T;
  T.scale = 1.7;
  T.R = expSO3(Eigen::Vector3d(0.2, -0.1, 1.3));
  T.t = Eigen::Vector3d(4.0, -2.0, 0.5);
  const uint32_t offset = 100000;
  std::unique_ptr<Map> b;
  KeyFrameId candidate;
  int tracked = 0;
  {
    auto lock = a.readLock();
    b = copyOf(a, offset, T);
    const std::vector<KeyFrameId> ids = a.keyframeIds();
    ASSERT_GE(ids.size(), 5u);
    candidate = ids[ids.size() / 2];
    tracked = a.keyframe(candidate)->numTrackedPoints();
  }
  const KeyFrameId query(candidate.value + offset);
  const Sim3 S_true = T.inverse();  // b's world -> a's world

  LoopClosingConfig off;
  off.min_candidate_matches = 0;
  const LoopClosingConfig standard;
  ASSERT_GT(standard.min_candidate_matches, 0);
  const auto without = verifyPlace(*b, query, a, candidate, {}, off, false, 1);
  const auto with = verifyPlace(*b, query, a, candidate, {}, standard, false, 1);
  ASSERT_TRUE(without.has_value());
  ASSERT_TRUE(with.has_value());
  EXPECT_EQ(with->inliers, without->inliers);
  EXPECT_EQ(with->duplicates, without->duplicates);
  EXPECT_GE(with->inliers, standard.min_inliers);
  EXPECT_LT(rotationAngle(with->S.R.transpose() * S_true.R) * 180.0 / M_PI, 0.5);
  EXPECT_NEAR(with->S.scale / S_true.scale, 1.0, 0.01);
  // Nearly every inlier pair is a point and its own twin.
  size_t twins = 0;
  for (const auto& [q, m] : with->duplicates) twins += q.value == m.value + offset;
  EXPECT_GE(twins, with->duplicates.size() * 9 / 10);

  // The largest threshold that still verifies is the count of own-point
  // matches (accepted iff count >= threshold): find it by bisection.
  LoopClosingConfig c;
  int accepted = standard.min_candidate_matches, rejected = tracked + 1;
  c.min_candidate_matches = rejected;
  EXPECT_FALSE(verifyPlace(*b, query, a, candidate, {}, c, false, 1).has_value());
  while (rejected - accepted > 1) {
    c.min_candidate_matches = (accepted + rejected) / 2;
    if (verifyPlace(*b, query, a, candidate, {}, c, false, 1)) {
      accepted = c.min_candidate_matches;
    } else {
      rejected = c.min_candidate_matches;
    }
  }
  // A true place's keyframes share many points (79 and 131 on the logged runs).
  EXPECT_GE(accepted, 40);
  c.min_candidate_matches = accepted;
  const auto at = verifyPlace(*b, query, a, candidate, {}, c, false, 1);
  ASSERT_TRUE(at.has_value());
  EXPECT_EQ(at->inliers, without->inliers);
  RecordProperty("own_point_matches", accepted);
  std::printf("own-point matches %d of %d tracked; %d inliers\n", accepted, tracked, with->inliers);
}

}  // namespace
}  // namespace ecar
