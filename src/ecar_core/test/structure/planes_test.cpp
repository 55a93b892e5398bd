#include "ecar_core/structure/plane_map.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// A rectangle on a plane: origin + a * [0, 1] + b * [0, 1] (a, b orthogonal).
struct Patch {
  Eigen::Vector3d origin, a, b;
  int count = 0;
};

/// Builds points with consecutive ids from `first_id`, Gaussian noise of sigma
/// along the patch normal, and `outliers` points uniform in [lo, hi].
struct Cloud {
  std::vector<PlanePoint> points;
  std::map<uint32_t, int> patch_of;  ///< point id -> patch index (-1 outlier)
};

Cloud makeCloud(const std::vector<Patch>& patches, int outliers, const Eigen::Vector3d& lo,
                const Eigen::Vector3d& hi, double sigma, uint32_t first_id, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g(0.0, sigma);
  Cloud c;
  uint32_t id = first_id;
  for (size_t k = 0; k < patches.size(); ++k) {
    const Patch& p = patches[k];
    const Eigen::Vector3d n = p.a.cross(p.b).normalized();
    for (int i = 0; i < p.count; ++i) {
      c.points.push_back({MapPointId(id), p.origin + u(rng) * p.a + u(rng) * p.b + g(rng) * n});
      c.patch_of[id++] = static_cast<int>(k);
    }
  }
  for (int i = 0; i < outliers; ++i) {
    const Eigen::Vector3d r(u(rng), u(rng), u(rng));
    c.points.push_back({MapPointId(id), lo + (hi - lo).cwiseProduct(r)});
    c.patch_of[id++] = -1;
  }
  return c;
}

/// Patches of a corridor along x (width 2.4 m in y, height 2.7 m in z) between x0 and x1.
std::vector<Patch> corridor(double x0, double x1, int per_patch) {
  const double L = x1 - x0;
  const Eigen::Vector3d o(x0, 0, 0);
  return {
      {o, Eigen::Vector3d(L, 0, 0), Eigen::Vector3d(0, 2.4, 0), per_patch},  // floor
      {o + Eigen::Vector3d(0, 0, 2.7), Eigen::Vector3d(L, 0, 0),
       Eigen::Vector3d(0, 2.4, 0),  // ceiling
       per_patch},
      {o, Eigen::Vector3d(L, 0, 0), Eigen::Vector3d(0, 0, 2.7), per_patch},  // wall y = 0
      {o + Eigen::Vector3d(0, 2.4, 0), Eigen::Vector3d(L, 0, 0), Eigen::Vector3d(0, 0, 2.7),
       per_patch},  // wall y = 2.4
  };
}

double polygonArea(const std::vector<Eigen::Vector3d>& poly, const Eigen::Vector3d& n) {
  double twice = 0.0;
  for (size_t i = 0; i < poly.size(); ++i) {
    twice += poly[i].cross(poly[(i + 1) % poly.size()]).dot(n);
  }
  return 0.5 * twice;  // positive when counter-clockwise about n
}

double angleBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0));
}

const PlaneObservation* findObservation(const std::vector<PlaneObservation>& obs,
                                        const Eigen::Vector3d& normal) {
  for (const auto& o : obs) {
    if (angleBetween(o.normal, normal) < 3.0 * kDeg) return &o;
  }
  return nullptr;
}

/// Fraction of the observation's inliers that were generated on `patch`.
double purity(const PlaneObservation& obs, const Cloud& cloud, int patch) {
  int good = 0;
  for (const auto& p : obs.inliers) good += cloud.patch_of.at(p.id.value) == patch;
  return static_cast<double>(good) / static_cast<double>(obs.inliers.size());
}

PlaneKeyFrameInput inputOf(uint32_t keyframe, const Cloud& cloud, const Eigen::Vector3d& center,
                           const Eigen::Vector3d& up) {
  PlaneKeyFrameInput in;
  in.keyframe = KeyFrameId(keyframe);
  in.points = cloud.points;
  in.camera_center_w = center;
  in.up_w = up;
  return in;
}

/// Checks the four corridor planes of a segmentation in a map rotated by R_m (map = R_m world +
/// t_m).
void expectCorridor(const std::vector<PlaneObservation>& obs, const Cloud& cloud,
                    const Eigen::Matrix3d& R_m, const Eigen::Vector3d& t_m, double length) {
  ASSERT_EQ(obs.size(), 4u);
  struct Expected {
    Eigen::Vector3d n;
    Eigen::Vector3d on;  ///< a point on the plane (world)
    PlaneLabel label;
    int patch;
    double area;
  };
  const std::vector<Expected> expected = {
      {Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, 0), PlaneLabel::kFloor, 0, length * 2.4},
      {-Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, 2.7), PlaneLabel::kCeiling, 1,
       length * 2.4},
      {Eigen::Vector3d::UnitY(), Eigen::Vector3d(0, 0, 0), PlaneLabel::kWall, 2, length * 2.7},
      {-Eigen::Vector3d::UnitY(), Eigen::Vector3d(0, 2.4, 0), PlaneLabel::kWall, 3, length * 2.7},
  };
  for (const auto& e : expected) {
    const Eigen::Vector3d n_m = R_m * e.n;
    const PlaneObservation* o = findObservation(obs, n_m);
    ASSERT_NE(o, nullptr) << "no plane with normal " << n_m.transpose();
    EXPECT_EQ(o->label, e.label) << toString(o->label);
    EXPECT_LT(angleBetween(o->normal, n_m), 1.0 * kDeg);
    // Offset: the plane passes through the mapped point.
    EXPECT_NEAR(o->normal.dot(R_m * e.on + t_m) + o->offset, 0.0, 0.01);
    EXPECT_GE(o->inliers.size(), 270u);  // of 300 generated, 1 cm noise, 4 cm threshold
    // Outliers inside the 4 cm slab and the neighbouring surfaces' points along
    // the corners lie on the plane too: a few percent.
    EXPECT_GE(purity(*o, cloud, e.patch), 0.92);
    EXPECT_LT(o->rms, 0.015);
    // The hull is counter-clockwise about the normal and covers the patch.
    EXPECT_NEAR(polygonArea(o->boundary, o->normal), e.area, 0.12 * e.area);
    for (const auto& v : o->boundary) EXPECT_NEAR(o->normal.dot(v) + o->offset, 0.0, 1e-9);
  }
}

TEST(PlanesTest, CorridorFloorWallsCeilingWithNoiseAndOutliers) {
  const Cloud cloud = makeCloud(corridor(0.0, 6.0, 300), 120, Eigen::Vector3d(0, 0, 0),
                                Eigen::Vector3d(6, 2.4, 2.7), 0.01, 1, 7);
  PlaneSegmenter segmenter{PlaneConfig()};
  const auto obs =
      segmenter.segment(inputOf(1, cloud, Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d::UnitZ()));
  expectCorridor(obs, cloud, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), 6.0);
}

TEST(PlanesTest, TiltedMapUsesGravityNotZ) {
  // The SLAM map is rotated (up is not z): map = R_m * world + t_m.
  const Eigen::Matrix3d R_m =
      (Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 0.5).normalized())).toRotationMatrix();
  const Eigen::Vector3d t_m(3.0, -2.0, 1.0);
  Cloud cloud = makeCloud(corridor(0.0, 6.0, 300), 120, Eigen::Vector3d(0, 0, 0),
                          Eigen::Vector3d(6, 2.4, 2.7), 0.01, 1, 11);
  for (auto& p : cloud.points) p.p_w = R_m * p.p_w + t_m;
  // A camera in the map looking along the corridor; its accelerometer measures
  // the specific force (up, 9.81 m/s^2) in its own frame.
  SE3 T_w_c = lookAt(Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d(5, 1.2, 1.0));
  SE3 T_map_world = SE3::Identity();
  T_map_world.linear() = R_m;
  T_map_world.translation() = t_m;
  const SE3 T_map_c = T_map_world * T_w_c;
  const Eigen::Vector3d f_c = T_w_c.linear().transpose() * Eigen::Vector3d(0, 0, 9.81);
  const Eigen::Vector3d up_map = upFromGravity(T_map_c, f_c);
  EXPECT_LT(angleBetween(up_map, R_m * Eigen::Vector3d::UnitZ()), 1e-9);

  PlaneSegmenter segmenter{PlaneConfig()};
  const auto obs = segmenter.segment(inputOf(1, cloud, T_map_c.translation(), up_map));
  expectCorridor(obs, cloud, R_m, t_m, 6.0);

  // Assuming z-up in this map would mislabel: no plane is horizontal in map z.
  const auto wrong =
      segmenter.segment(inputOf(1, cloud, T_map_c.translation(), Eigen::Vector3d::UnitZ()));
  int floors = 0;
  for (const auto& o : wrong) floors += o.label == PlaneLabel::kFloor;
  EXPECT_EQ(floors, 0);
}

TEST(PlanesTest, RoomWithRampLabelsEverySurface) {
  // A 5 x 4 x 2.7 m room and a ramp tilted 35 degrees.
  const double W = 5.0, D = 4.0, H = 2.7;
  std::vector<Patch> patches = {
      {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(W, 0, 0), Eigen::Vector3d(0, D, 0), 300},
      {Eigen::Vector3d(0, 0, H), Eigen::Vector3d(W, 0, 0), Eigen::Vector3d(0, D, 0), 300},
      {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(W, 0, 0), Eigen::Vector3d(0, 0, H), 250},
      {Eigen::Vector3d(0, D, 0), Eigen::Vector3d(W, 0, 0), Eigen::Vector3d(0, 0, H), 250},
      {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, D, 0), Eigen::Vector3d(0, 0, H), 250},
      {Eigen::Vector3d(W, 0, 0), Eigen::Vector3d(0, D, 0), Eigen::Vector3d(0, 0, H), 250},
      {Eigen::Vector3d(2, 1.5, 0.3),
       Eigen::Vector3d(1.2 * std::cos(35 * kDeg), 0, 1.2 * std::sin(35 * kDeg)),
       Eigen::Vector3d(0, 1.0, 0), 120},
  };
  const Cloud cloud =
      makeCloud(patches, 150, Eigen::Vector3d::Zero(), Eigen::Vector3d(W, D, H), 0.01, 1, 3);
  PlaneSegmenter segmenter{PlaneConfig()};
  const auto obs = segmenter.segment(
      inputOf(9, cloud, Eigen::Vector3d(2.5, 2.0, 1.6), Eigen::Vector3d::UnitZ()));
  std::map<PlaneLabel, int> labels;
  for (const auto& o : obs) ++labels[o.label];
  EXPECT_EQ(obs.size(), 7u);
  EXPECT_EQ(labels[PlaneLabel::kFloor], 1);
  EXPECT_EQ(labels[PlaneLabel::kCeiling], 1);
  EXPECT_EQ(labels[PlaneLabel::kWall], 4);
  EXPECT_EQ(labels[PlaneLabel::kOther], 1);
  const PlaneObservation* ramp =
      findObservation(obs, Eigen::Vector3d(-std::sin(35 * kDeg), 0, std::cos(35 * kDeg)));
  ASSERT_NE(ramp, nullptr);
  EXPECT_EQ(ramp->label, PlaneLabel::kOther);
  EXPECT_GE(purity(*ramp, cloud, 6), 0.95);
  // Every wall's normal points into the room (towards the camera).
  for (const auto& o : obs) {
    EXPECT_GT(o.normal.dot(Eigen::Vector3d(2.5, 2.0, 1.6)) + o.offset, 0.0);
  }
}

TEST(PlanesTest, SegmentationIsDeterministic) {
  const Cloud cloud = makeCloud(corridor(0.0, 4.0, 200), 80, Eigen::Vector3d(0, 0, 0),
                                Eigen::Vector3d(4, 2.4, 2.7), 0.01, 1, 5);
  PlaneSegmenter segmenter{PlaneConfig()};
  const auto in = inputOf(4, cloud, Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d::UnitZ());
  const auto a = segmenter.segment(in);
  const auto b = segmenter.segment(in);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].normal, b[i].normal);
    EXPECT_EQ(a[i].offset, b[i].offset);
    ASSERT_EQ(a[i].inliers.size(), b[i].inliers.size());
  }
}

TEST(PlanesTest, FarCoplanarStraysAreNotPartOfThePlane) {
  // A 3 x 3 m floor and 30 points on the same plane 10 m away: the boundary
  // stays on the floor patch.
  const Cloud cloud = makeCloud(
      {{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(3, 0, 0), Eigen::Vector3d(0, 3, 0), 300},
       {Eigen::Vector3d(13, 0, 0), Eigen::Vector3d(3, 0, 0), Eigen::Vector3d(0, 3, 0), 30}},
      0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.005, 1, 2);
  PlaneSegmenter segmenter{PlaneConfig()};
  const auto obs = segmenter.segment(
      inputOf(1, cloud, Eigen::Vector3d(1.5, 1.5, 1.5), Eigen::Vector3d::UnitZ()));
  ASSERT_EQ(obs.size(), 1u);
  EXPECT_EQ(obs[0].inliers.size(), 300u);
  for (const auto& v : obs[0].boundary) EXPECT_LT(v.x(), 3.01);
}

TEST(PlanesTest, TheDepthNoiseAboveAFloorIsNoSecondFloor) {
  // A 4 x 4 m floor (1.5 cm noise) and, over the whole of it, the tail that
  // monocular depth noise puts on the cameras' side: 250 points 4-14 cm up.
  Cloud cloud = makeCloud(
      {{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(4, 0, 0), Eigen::Vector3d(0, 4, 0), 1500}}, 250,
      Eigen::Vector3d(0, 0, 0.04), Eigen::Vector3d(4, 4, 0.14), 0.015, 1, 3);
  const auto in = inputOf(1, cloud, Eigen::Vector3d(2, 2, 1.5), Eigen::Vector3d::UnitZ());
  PlaneConfig config;
  const auto obs = PlaneSegmenter(config).segment(in);
  ASSERT_EQ(obs.size(), 1u);
  EXPECT_EQ(obs[0].label, PlaneLabel::kFloor);
  EXPECT_NEAR(obs[0].offset, 0.0, 0.005);
  // Without the rule the tail is a second floor a few cm above the first.
  config.min_separation = 1e-3;
  const auto ghost = PlaneSegmenter(config).segment(in);
  ASSERT_EQ(ghost.size(), 2u);
  EXPECT_EQ(ghost[1].label, PlaneLabel::kFloor);
  EXPECT_GT(-ghost[1].offset, 0.05);
}

TEST(PlanesTest, AStepAboveTheFloorIsItsOwnPlane) {
  // The same floor with a 1.5 x 1.5 m platform 20 cm up, above min_separation.
  const Cloud cloud = makeCloud(
      {{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(4, 0, 0), Eigen::Vector3d(0, 4, 0), 1500},
       {Eigen::Vector3d(1, 1, 0.2), Eigen::Vector3d(1.5, 0, 0), Eigen::Vector3d(0, 1.5, 0), 300}},
      0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.01, 1, 4);
  const auto obs = PlaneSegmenter{PlaneConfig()}.segment(
      inputOf(1, cloud, Eigen::Vector3d(2, 2, 1.5), Eigen::Vector3d::UnitZ()));
  ASSERT_EQ(obs.size(), 2u);
  EXPECT_NEAR(obs[0].offset, 0.0, 0.005);
  EXPECT_NEAR(obs[1].offset, -0.2, 0.005);
  EXPECT_GE(purity(obs[1], cloud, 1), 0.95);
}

// ---------------------------------------------------------------- PlaneMap

/// A floor patch x in [x0, x1], y in [0, 2.4] at height z, ids from first_id.
Cloud floorCloud(double x0, double x1, double z, int count, uint32_t first_id, uint32_t seed) {
  return makeCloud({{Eigen::Vector3d(x0, 0, z), Eigen::Vector3d(x1 - x0, 0, 0),
                     Eigen::Vector3d(0, 2.4, 0), count}},
                   0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.01, first_id, seed);
}

PlaneMapUpdate addKeyFrame(PlaneMap* map, const PlaneSegmenter& segmenter, uint32_t keyframe,
                           const Cloud& cloud, const Eigen::Vector3d& center,
                           const std::vector<MapPointId>& gone = {}) {
  auto in = inputOf(keyframe, cloud, center, Eigen::Vector3d::UnitZ());
  in.gone = gone;
  return map->integrate(in, segmenter.segment(in));
}

TEST(PlaneMapTest, SamePlaneFromTwoKeyFramesMerges) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const Cloud first = floorCloud(0.0, 4.0, 0.0, 300, 1, 1);
  const auto u1 = addKeyFrame(&map, segmenter, 1, first, Eigen::Vector3d(1, 1.2, 1.5));
  ASSERT_EQ(u1.created.size(), 1u);
  const PlaneId floor = u1.created[0];
  const Plane p1 = *map.plane(floor);
  EXPECT_EQ(p1.version, 1u);
  EXPECT_EQ(p1.label, PlaneLabel::kFloor);
  EXPECT_EQ(p1.num_points, 300u);
  EXPECT_LT(angleBetween(p1.normal, Eigen::Vector3d::UnitZ()), 1 * kDeg);

  // The second keyframe sees x in [3, 7]: the overlap and new points (new ids),
  // plus the old points of x in [3, 4] (covisible: same ids, same positions).
  Cloud second = floorCloud(4.0, 7.0, 0.0, 240, 1000, 2);
  for (const auto& p : first.points) {
    if (p.p_w.x() >= 3.0) {
      second.points.push_back(p);
      second.patch_of[p.id.value] = 0;
    }
  }
  const auto u2 = addKeyFrame(&map, segmenter, 2, second, Eigen::Vector3d(5, 1.2, 1.5));
  EXPECT_TRUE(u2.created.empty());
  EXPECT_TRUE(u2.removed.empty());
  ASSERT_EQ(u2.updated, std::vector<PlaneId>{floor});
  EXPECT_EQ(u2.keyframe_planes, std::vector<PlaneId>{floor});
  ASSERT_EQ(map.size(), 1u);
  const Plane p2 = *map.plane(floor);
  EXPECT_EQ(p2.version, 2u);
  EXPECT_EQ(p2.num_points, 540u);
  EXPECT_GT(p2.num_points, p1.num_points);
  EXPECT_EQ(map.pointsOfPlane(floor).size(), 540u);
  EXPECT_EQ(map.keyframesOfPlane(floor), (std::vector<KeyFrameId>{KeyFrameId(1), KeyFrameId(2)}));
  EXPECT_EQ(map.planesOfKeyFrame(KeyFrameId(1)), std::vector<PlaneId>{floor});
  EXPECT_EQ(map.planeOfPoint(MapPointId(1000)), floor);
  EXPECT_NEAR(p2.offset, 0.0, 0.005);
  // The boundary now spans both views (area close to 7 x 2.4).
  EXPECT_NEAR(polygonArea(p2.boundary, p2.normal), 7.0 * 2.4, 0.1 * 7.0 * 2.4);
}

TEST(PlaneMapTest, ParallelPlaneIsNotMerged) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const auto u1 = addKeyFrame(&map, segmenter, 1, floorCloud(0.0, 4.0, 0.0, 300, 1, 1),
                              Eigen::Vector3d(1, 1.2, 1.5));
  ASSERT_EQ(u1.created.size(), 1u);
  // A platform 0.3 m above the floor, over the same extent.
  const auto u2 = addKeyFrame(&map, segmenter, 2, floorCloud(0.5, 3.5, 0.3, 250, 1000, 2),
                              Eigen::Vector3d(1, 1.2, 1.5));
  ASSERT_EQ(u2.created.size(), 1u);
  EXPECT_NE(u2.created[0], u1.created[0]);
  EXPECT_TRUE(u2.updated.empty());
  EXPECT_EQ(map.size(), 2u);
  EXPECT_EQ(map.plane(u1.created[0])->version, 1u);
  EXPECT_NEAR(map.plane(u2.created[0])->offset, -0.3, 0.005);
  EXPECT_EQ(map.plane(u2.created[0])->label, PlaneLabel::kFloor);
}

/// `cloud` with its points moved by `shift` (bundle adjustment moved them).
Cloud moved(Cloud cloud, const Eigen::Vector3d& shift) {
  for (auto& p : cloud.points) p.p_w += shift;
  return cloud;
}

/// `a` and `b` in one input (a keyframe seeing both).
Cloud both(const Cloud& a, const Cloud& b) {
  Cloud c = a;
  c.points.insert(c.points.end(), b.points.begin(), b.points.end());
  c.patch_of.insert(b.patch_of.begin(), b.patch_of.end());
  return c;
}

/// A floor seen by keyframe 1 and a floor patch `height` up found alone by
/// keyframe 2 (too far to join the floor).
struct FloorAndPatch {
  PlaneMap map{PlaneConfig()};
  PlaneSegmenter segmenter{PlaneConfig()};
  Cloud floor, patch;
  PlaneId floor_id, patch_id;

  PlaneMapUpdate see(uint32_t keyframe, const Cloud& cloud,
                     const std::vector<MapPointId>& gone = {}) {
    return addKeyFrame(&map, segmenter, keyframe, cloud, Eigen::Vector3d(1, 1.2, 1.5), gone);
  }
};

std::unique_ptr<FloorAndPatch> floorAndPatch(double height) {
  auto r = std::make_unique<FloorAndPatch>();
  r->floor = floorCloud(0.0, 4.0, 0.0, 300, 1, 1);
  r->patch = floorCloud(1.0, 3.0, height, 80, 1000, 2);
  r->floor_id = r->see(1, r->floor).created.at(0);
  r->patch_id = r->see(2, r->patch).created.at(0);
  EXPECT_EQ(r->map.size(), 2u);
  return r;
}

TEST(PlaneMapTest, APlaneWhosePointsMovedFollowsThemUnseen) {
  const auto r = floorAndPatch(0.3);
  const PlaneId b = r->patch_id;
  const uint32_t version = r->map.plane(b)->version;
  // Keyframe 3 sees the floor again and 30 of the platform's points, 5 cm
  // lower: too few for an observation, the platform is not seen.
  Cloud some = r->patch;
  some.points.resize(30);
  const auto u = r->see(3, both(r->floor, moved(some, Eigen::Vector3d(0, 0, -0.05))));
  EXPECT_TRUE(u.removed.empty());
  EXPECT_NE(std::find(u.updated.begin(), u.updated.end(), b), u.updated.end());
  EXPECT_EQ(r->map.planesOfKeyFrame(KeyFrameId(3)), std::vector<PlaneId>{r->floor_id});
  // Least squares: through the centroid of its points, 30 of them 5 cm lower.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : r->patch.points) centroid += p.p_w;
  centroid = centroid / 80.0 - Eigen::Vector3d(0, 0, 0.05 * 30 / 80);
  EXPECT_NEAR(r->map.plane(b)->signedDistance(centroid), 0.0, 1e-6);
  EXPECT_LT(angleBetween(r->map.plane(b)->normal, Eigen::Vector3d::UnitZ()), 3 * kDeg);
  EXPECT_EQ(r->map.plane(b)->num_points, 80u);
  EXPECT_GT(r->map.plane(b)->version, version);
  EXPECT_NEAR(r->map.plane(r->floor_id)->offset, 0.0, 0.005);
  // Points moved by less than distance_threshold / 4 leave it as it is.
  const uint32_t now = r->map.plane(b)->version;
  r->see(4, both(r->floor, moved(some, Eigen::Vector3d(0, 0, -0.055))));
  EXPECT_EQ(r->map.plane(b)->version, now);
}

TEST(PlaneMapTest, APlaneWhosePointsMovedOntoTheFloorBecomesTheFloor) {
  // A "second floor" 10 cm up (bad depth from one keyframe) whose points
  // bundle adjustment moved down onto the floor: one floor.
  const auto r = floorAndPatch(0.1);
  const auto u = r->see(3, both(r->floor, moved(r->patch, Eigen::Vector3d(0, 0, -0.1))));
  EXPECT_EQ(u.removed, std::vector<PlaneId>{r->patch_id});
  ASSERT_EQ(r->map.size(), 1u);
  EXPECT_EQ(r->map.plane(r->floor_id)->num_points, 380u);
  EXPECT_EQ(r->map.planeOfPoint(MapPointId(1000)), r->floor_id);
  EXPECT_NEAR(r->map.plane(r->floor_id)->offset, 0.0, 0.005);
}

TEST(PlaneMapTest, APlaneWhosePointsAllMovedAwayGoes) {
  // 30 cm down: too far to stay on their plane, which is left with none.
  const auto r = floorAndPatch(0.3);
  const auto u = r->see(3, both(r->floor, moved(r->patch, Eigen::Vector3d(0, 0, -0.3))));
  EXPECT_EQ(u.removed, std::vector<PlaneId>{r->patch_id});
  EXPECT_FALSE(r->map.contains(r->patch_id));
  EXPECT_FALSE(r->map.planeOfPoint(MapPointId(1000)).has_value());
  EXPECT_TRUE(r->map.planesOfKeyFrame(KeyFrameId(2)).empty());
  EXPECT_EQ(r->map.size(), 1u);
}

TEST(PlaneMapTest, APlaneWhoseNoisePointsWereCulledGoes) {
  // The room scene's E8 "second floor" 13.5 cm up: fitted to noise points over
  // the floor that the SLAM map culled since, and to a few good points at the
  // walls' foot. Culled points leave it; with fewer than min_inliers left it
  // goes, unseen by the keyframe that reports them.
  const auto r = floorAndPatch(0.135);
  std::vector<MapPointId> culled;
  for (uint32_t id = 1000; id < 1060; ++id) culled.push_back(MapPointId(id));
  culled.push_back(MapPointId(1));    // one floor point, too
  culled.push_back(MapPointId(777));  // no plane's: ignored
  Cloud seen = r->floor;              // the keyframe sees the floor without it
  ASSERT_EQ(seen.points.front().id, MapPointId(1));
  seen.points.erase(seen.points.begin());
  const auto u = r->see(3, seen, culled);
  EXPECT_EQ(u.removed, std::vector<PlaneId>{r->patch_id});
  EXPECT_FALSE(r->map.contains(r->patch_id));
  EXPECT_FALSE(r->map.planeOfPoint(MapPointId(1070)).has_value());
  EXPECT_TRUE(r->map.planesOfKeyFrame(KeyFrameId(2)).empty());
  ASSERT_EQ(r->map.size(), 1u);
  EXPECT_FALSE(r->map.planeOfPoint(MapPointId(1)).has_value());
  EXPECT_EQ(r->map.plane(r->floor_id)->num_points, 299u);
  EXPECT_TRUE(r->map.pointsOfMap(r->map.plane(r->floor_id)->map).size() == 299u);
}

TEST(PlaneMapTest, APlaneThatLostSomeCulledPointsStaysOnTheRest) {
  const auto r = floorAndPatch(0.3);
  std::vector<MapPointId> culled;
  for (uint32_t id = 1000; id < 1030; ++id) culled.push_back(MapPointId(id));
  const uint32_t version = r->map.plane(r->patch_id)->version;
  const auto u = r->see(3, r->floor, culled);
  EXPECT_TRUE(u.removed.empty());
  ASSERT_TRUE(r->map.contains(r->patch_id));
  EXPECT_EQ(r->map.plane(r->patch_id)->num_points, 50u);
  EXPECT_GT(r->map.plane(r->patch_id)->version, version);
  EXPECT_EQ(r->map.planeOfPoint(MapPointId(1030)), r->patch_id);
  EXPECT_FALSE(r->map.planeOfPoint(MapPointId(1029)).has_value());
  // A culled id of another map's plane is not this map's to drop.
  PlaneMap other{PlaneConfig()};
  PlaneSegmenter segmenter{PlaneConfig()};
  auto in = inputOf(1, r->floor, Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d::UnitZ());
  in.map = MapId(2);
  other.integrate(in, segmenter.segment(in));
  auto next = inputOf(2, Cloud(), Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d::UnitZ());
  next.map = MapId(3);
  next.gone = {MapPointId(5), MapPointId(6)};
  other.integrate(next, {});
  EXPECT_EQ(other.planes().at(0).num_points, 300u);
}

TEST(PlaneMapTest, RefitTakesAdjustedPointsAndFusesPlanesThatBecameOne) {
  // A merged map: the floor of the larger map, and the floor the smaller map
  // had estimated 12 cm high (too far to be merged as one plane); its points'
  // positions after the bundle adjustment lie on the floor; 50 of the floor's
  // points are no longer in the SLAM map (culled): they leave it. And a plane
  // with all but 20 of its points culled: it goes.
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const Cloud low = floorCloud(0.0, 4.0, 0.0, 300, 1, 1);
  const Cloud high = floorCloud(3.0, 7.0, 0.12, 240, 1000, 2);
  const auto a = addKeyFrame(&map, segmenter, 1, low, Eigen::Vector3d(1, 1.2, 1.5));
  const auto b = addKeyFrame(&map, segmenter, 2, high, Eigen::Vector3d(5, 1.2, 1.5));
  const auto c = addKeyFrame(&map, segmenter, 3, floorCloud(0.0, 3.0, 1.0, 200, 5000, 3),
                             Eigen::Vector3d(1, 1.2, 2.5));
  ASSERT_EQ(a.created.size(), 1u);
  ASSERT_EQ(b.created.size(), 1u);
  ASSERT_EQ(c.created.size(), 1u);
  ASSERT_EQ(map.size(), 3u);
  const PlaneId floor = a.created[0], second = b.created[0], culled = c.created[0];
  std::map<uint32_t, Eigen::Vector3d> adjusted;  // 20 of the third plane's points
  for (const auto& p : low.points) {
    if (p.id.value > 50) adjusted[p.id.value] = p.p_w;
  }
  for (uint32_t id = 5000; id < 5020; ++id) adjusted[id] = Eigen::Vector3d(0.5, 0.5, 1.0);
  for (const auto& p : high.points) adjusted[p.id.value] = {p.p_w.x(), p.p_w.y(), 0.0};
  const uint32_t version = map.plane(floor)->version;
  const PlaneMapUpdate u =
      map.refit(map.plane(floor)->map, [&](MapPointId id) -> std::optional<Eigen::Vector3d> {
        const auto it = adjusted.find(id.value);
        return it != adjusted.end() ? std::optional<Eigen::Vector3d>(it->second) : std::nullopt;
      });
  EXPECT_EQ(u.removed, (std::vector<PlaneId>{second, culled}));
  EXPECT_FALSE(map.contains(second));
  EXPECT_FALSE(map.contains(culled));
  EXPECT_TRUE(map.contains(floor));
  EXPECT_EQ(u.updated, std::vector<PlaneId>{floor});
  ASSERT_EQ(map.size(), 1u);
  const Plane p = *map.plane(floor);
  EXPECT_GT(p.version, version);
  EXPECT_EQ(p.num_points, 490u);
  EXPECT_FALSE(map.planeOfPoint(MapPointId(50)).has_value());
  EXPECT_EQ(p.label, PlaneLabel::kFloor);
  EXPECT_NEAR(p.offset, 0.0, 0.005);
  EXPECT_EQ(map.planeOfPoint(MapPointId(1000)), floor);
  EXPECT_FALSE(map.planeOfPoint(MapPointId(5000)).has_value());
  EXPECT_EQ(map.keyframesOfPlane(floor), (std::vector<KeyFrameId>{KeyFrameId(1), KeyFrameId(2)}));
  EXPECT_TRUE(map.planesOfKeyFrame(KeyFrameId(2)) == std::vector<PlaneId>{floor});
  EXPECT_NEAR(polygonArea(p.boundary, p.normal), 7.0 * 2.4, 0.1 * 7.0 * 2.4);
  // Planes of another map are left alone.
  EXPECT_TRUE(map.refit(MapId(77), [](MapPointId) { return std::nullopt; }).removed.empty());
  EXPECT_EQ(map.size(), 1u);
}

TEST(PlaneMapTest, DisjointCoplanarPiecesJoinWhenBridged) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const auto a = addKeyFrame(&map, segmenter, 1, floorCloud(0.0, 3.0, 0.0, 250, 1, 1),
                             Eigen::Vector3d(1, 1.2, 1.5));
  const auto b = addKeyFrame(&map, segmenter, 2, floorCloud(6.0, 9.0, 0.0, 250, 1000, 2),
                             Eigen::Vector3d(7, 1.2, 1.5));
  ASSERT_EQ(a.created.size(), 1u);
  ASSERT_EQ(b.created.size(), 1u);  // 3 m apart: not the same piece yet
  EXPECT_EQ(map.size(), 2u);
  const auto c = addKeyFrame(&map, segmenter, 3, floorCloud(2.5, 6.5, 0.0, 300, 2000, 3),
                             Eigen::Vector3d(4.5, 1.2, 1.5));
  EXPECT_EQ(map.size(), 1u);
  EXPECT_EQ(c.removed, std::vector<PlaneId>{b.created[0]});
  EXPECT_EQ(c.updated, std::vector<PlaneId>{a.created[0]});
  const Plane p = *map.plane(a.created[0]);
  EXPECT_EQ(p.num_points, 800u);
  EXPECT_EQ(map.planesOfKeyFrame(KeyFrameId(2)), std::vector<PlaneId>{a.created[0]});
  EXPECT_EQ(map.keyframesOfPlane(a.created[0]).size(), 3u);
  EXPECT_EQ(map.planeOfPoint(MapPointId(1000)), a.created[0]);
}

TEST(PlaneMapTest, CorridorWalkKeepsFourPlanes) {
  // A 30 m corridor seen by keyframes every 2 m, each seeing 6 m ahead.
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const Cloud all = makeCloud(corridor(0.0, 30.0, 1500), 0, Eigen::Vector3d::Zero(),
                              Eigen::Vector3d::Zero(), 0.01, 1, 9);
  for (int k = 0; k < 13; ++k) {
    const double x0 = 2.0 * k;
    Cloud view;
    for (const auto& p : all.points) {
      if (p.p_w.x() >= x0 && p.p_w.x() <= x0 + 6.0) view.points.push_back(p);
    }
    addKeyFrame(&map, segmenter, static_cast<uint32_t>(k + 1), view, Eigen::Vector3d(x0, 1.2, 1.5));
  }
  const auto planes = map.planes();
  ASSERT_EQ(planes.size(), 4u);
  std::map<PlaneLabel, int> labels;
  for (const auto& p : planes) {
    ++labels[p.label];
    EXPECT_GE(p.num_points, 1400u);
    EXPECT_GT(p.version, 1u);
    double lo = 1e9, hi = -1e9;
    for (const auto& v : p.boundary) {
      lo = std::min(lo, v.x());
      hi = std::max(hi, v.x());
    }
    EXPECT_LT(lo, 0.2);
    EXPECT_GT(hi, 29.8);
  }
  EXPECT_EQ(labels[PlaneLabel::kFloor], 1);
  EXPECT_EQ(labels[PlaneLabel::kCeiling], 1);
  EXPECT_EQ(labels[PlaneLabel::kWall], 2);
}

TEST(PlaneMapTest, PointsMovedOffThePlaneLeaveIt) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  Cloud cloud = floorCloud(0.0, 4.0, 0.0, 300, 1, 1);
  const auto u1 = addKeyFrame(&map, segmenter, 1, cloud, Eigen::Vector3d(1, 1.2, 1.5));
  ASSERT_EQ(u1.created.size(), 1u);
  // Bundle adjustment moved 20 points 0.5 m up: the next keyframe brings their new positions.
  for (int i = 0; i < 20; ++i) cloud.points[i].p_w.z() += 0.5;
  const auto u2 = addKeyFrame(&map, segmenter, 2, cloud, Eigen::Vector3d(2, 1.2, 1.5));
  ASSERT_EQ(u2.updated, u1.created);
  const Plane p = *map.plane(u1.created[0]);
  EXPECT_EQ(p.num_points, 280u);
  EXPECT_EQ(p.version, 2u);
  EXPECT_FALSE(map.planeOfPoint(MapPointId(1)).has_value());
  EXPECT_EQ(map.planeOfPoint(MapPointId(21)), u1.created[0]);
  EXPECT_NEAR(p.offset, 0.0, 0.005);
}

TEST(PlaneMapTest, ReadersCopyWhileAWriterIntegrates) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  const Cloud all = makeCloud(corridor(0.0, 20.0, 800), 0, Eigen::Vector3d::Zero(),
                              Eigen::Vector3d::Zero(), 0.01, 1, 4);
  std::vector<PlaneKeyFrameInput> inputs;
  std::vector<std::vector<PlaneObservation>> observations;
  for (int k = 0; k < 8; ++k) {
    Cloud view;
    for (const auto& p : all.points) {
      if (p.p_w.x() >= 2.0 * k && p.p_w.x() <= 2.0 * k + 6.0) view.points.push_back(p);
    }
    inputs.push_back(inputOf(static_cast<uint32_t>(k + 1), view, Eigen::Vector3d(2.0 * k, 1.2, 1.5),
                             Eigen::Vector3d::UnitZ()));
    observations.push_back(segmenter.segment(inputs.back()));
  }
  std::atomic<bool> done{false};
  std::atomic<int> bad{0}, reads{0};
  auto reader = [&]() {
    while (!done.load()) {
      for (const Plane& p : map.planes()) {
        if (std::abs(p.normal.norm() - 1.0) > 1e-9 || p.boundary.size() < 3 ||
            p.num_points < static_cast<uint32_t>(config.min_inliers)) {
          ++bad;
        }
      }
      ++reads;
    }
  };
  std::thread r1(reader), r2(reader);
  // The readers run before the writer starts (on a loaded machine the writer
  // could otherwise finish before either was scheduled, and nothing overlaps).
  while (reads.load() < 2) std::this_thread::yield();
  for (size_t k = 0; k < inputs.size(); ++k) map.integrate(inputs[k], observations[k]);
  done = true;
  r1.join();
  r2.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_GT(reads.load(), 0);
  EXPECT_EQ(map.size(), 4u);
}

TEST(PlaneMapTest, SaveLoadRoundTrip) {
  const PlaneConfig config;
  PlaneSegmenter segmenter(config);
  PlaneMap map(config);
  addKeyFrame(&map, segmenter, 1, floorCloud(0.0, 4.0, 0.0, 300, 1, 1),
              Eigen::Vector3d(1, 1.2, 1.5));
  addKeyFrame(&map, segmenter, 2, floorCloud(0.0, 4.0, 0.3, 300, 1000, 2),
              Eigen::Vector3d(1, 1.2, 1.5));
  const auto records = map.save();
  PlaneMap loaded(config);
  loaded.load(records);
  ASSERT_EQ(loaded.size(), 2u);
  for (const auto& p : map.planes()) {
    const Plane q = *loaded.plane(p.id);
    EXPECT_EQ(q.normal, p.normal);
    EXPECT_EQ(q.offset, p.offset);
    EXPECT_EQ(q.version, p.version);
    EXPECT_EQ(q.num_points, p.num_points);
    EXPECT_EQ(q.boundary.size(), p.boundary.size());
    EXPECT_EQ(loaded.pointsOfPlane(p.id), map.pointsOfPlane(p.id));
    EXPECT_EQ(loaded.keyframesOfPlane(p.id), map.keyframesOfPlane(p.id));
  }
  // New planes continue after the loaded ids.
  const auto u = addKeyFrame(&loaded, segmenter, 3, floorCloud(0.0, 4.0, 1.0, 300, 5000, 3),
                             Eigen::Vector3d(1, 1.2, 2.0));
  ASSERT_EQ(u.created.size(), 1u);
  EXPECT_EQ(u.created[0], PlaneId(3));
  // Bad records are rejected.
  auto bad = records;
  bad[0].plane.normal *= 2.0;
  EXPECT_THROW(loaded.load(bad), Error);
  bad = records;
  bad.push_back(records[0]);
  EXPECT_THROW(loaded.load(bad), Error);
  loaded.eraseKeyFrame(KeyFrameId(3));
  EXPECT_TRUE(loaded.planesOfKeyFrame(KeyFrameId(3)).empty());
}

TEST(PlanesTest, ConfigValidationNamesTheKey) {
  PlaneConfig c;
  c.min_inliers = 2;
  try {
    c.validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("planes.min_inliers"), std::string::npos);
  }
  c = PlaneConfig();
  c.distance_threshold = std::nan("");
  EXPECT_THROW(PlaneSegmenter{c}, Error);
  c = PlaneConfig();
  c.min_separation = 0.0;
  EXPECT_THROW(c.validate(), Error);
  EXPECT_THROW(upFromGravity(SE3::Identity(), Eigen::Vector3d::Zero()), Error);
  PlaneSegmenter segmenter{PlaneConfig()};
  PlaneKeyFrameInput in;
  in.up_w = Eigen::Vector3d::Zero();
  EXPECT_THROW(segmenter.segment(in), Error);
}

TEST(PlanesTest, HullIsCounterClockwiseAboutTheNormal) {
  const std::vector<Eigen::Vector3d> square = {{0, 0, 1},     {1, 1, 1}, {1, 0, 1},
                                               {0.5, 0.5, 1}, {0, 1, 1}, {0.2, 0.7, 1}};
  for (const double sign : {1.0, -1.0}) {
    const Eigen::Vector3d n(0, 0, sign);
    const auto hull = planeHull(square, n, -sign);
    ASSERT_EQ(hull.size(), 4u);
    EXPECT_NEAR(polygonArea(hull, n), 1.0, 1e-12);
  }
  Eigen::Vector3d n;
  double d;
  fitPlane(square, &n, &d);
  EXPECT_NEAR(std::abs(n.z()), 1.0, 1e-12);
  EXPECT_NEAR(n.z() + d, 0.0, 1e-12);
}

}  // namespace
}  // namespace ecar
