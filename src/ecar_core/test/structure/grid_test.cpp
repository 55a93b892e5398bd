#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_map.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

PinholeCamera camera640() {
  CameraParams p;
  p.width = 640;
  p.height = 480;
  p.fx = 525.0;
  p.fy = 525.0;
  p.cx = 319.5;
  p.cy = 239.5;
  return PinholeCamera(p);
}

/// A rectangular plane with the given corners (ordered by planeHull).
Plane rectangle(uint32_t id, const Eigen::Vector3d& normal, double offset,
                const std::vector<Eigen::Vector3d>& corners) {
  Plane p;
  p.id = PlaneId(id);
  p.normal = normal;
  p.offset = offset;
  p.boundary = planeHull(corners, normal, offset);
  p.version = 1;
  return p;
}

/// Floor z = h over x in [x0, x1], y in [y0, y1].
Plane floorPlane(uint32_t id, double x0, double x1, double y0, double y1, double h = 0.0) {
  return rectangle(id, Eigen::Vector3d::UnitZ(), -h,
                   {{x0, y0, h}, {x1, y0, h}, {x1, y1, h}, {x0, y1, h}});
}

/// The paper's ray for the world-to-camera pose [R | t]: l_w = R^T K^-1 (u, v, 1)^T - R^T t,
/// intersected with the floor z = h from the centre -R^T t. Empty when it misses.
std::optional<Eigen::Vector3d> analyticFloorHit(const SE3& T_w_c, const Eigen::Matrix3d& K,
                                                const Eigen::Vector2d& uv, double h = 0.0) {
  const SE3 T_c_w = T_w_c.inverse();
  const Eigen::Matrix3d R = T_c_w.linear();
  const Eigen::Vector3d t = T_c_w.translation();
  const Eigen::Vector3d l_w =
      R.transpose() * K.inverse() * Eigen::Vector3d(uv.x(), uv.y(), 1.0) - R.transpose() * t;
  const Eigen::Vector3d c = -R.transpose() * t;
  const Eigen::Vector3d dir = l_w - c;
  if (dir.z() >= 0.0) return std::nullopt;
  return c + ((h - c.z()) / dir.z()) * dir;
}

CellKey analyticCell(const Eigen::Vector3d& p, double cell) {
  return {static_cast<int32_t>(std::floor(p.x() / cell)),
          static_cast<int32_t>(std::floor(p.y() / cell)),
          static_cast<int32_t>(std::floor(p.z() / cell))};
}

TEST(GridTest, WindowSamplingCount) {
  const PinholeCamera cam = camera640();
  GridConfig c;
  GridCaster g5(c, cam);
  EXPECT_EQ(g5.numSamples(), 128u * 96u);
  EXPECT_EQ(g5.samplePixels().front(), Eigen::Vector2d(2, 2));
  EXPECT_EQ(g5.samplePixels().back(), Eigen::Vector2d(637, 477));
  c.window = 4;
  GridCaster g4(c, cam);
  EXPECT_EQ(g4.numSamples(), 160u * 120u);
  EXPECT_EQ(g4.samplePixels().front(), Eigen::Vector2d(1, 1));
  c.window = 7;  // 640 = 91 * 7 + 3: columns 3, 10, ..., 633
  GridCaster g7(c, cam);
  EXPECT_EQ(g7.numSamples(), 91u * 69u);
}

TEST(GridTest, EachPixelCellIsTheAnalyticRayPlaneIntersection) {
  const PinholeCamera cam = camera640();
  GridConfig config;
  config.max_distance = 200.0;  // every hit this close lies inside the 1 km floor
  const GridCaster grid(config, cam);
  // The floor at z = -1.234: no hit lies on a z cell border.
  const double floor_z = -1.234;
  const GridPlanes planes({floorPlane(1, -500, 500, -500, 500, floor_z)}, config.boundary_margin);
  for (const SE3& T_w_c : {lookAt(Eigen::Vector3d(1.0, 2.0, 1.5), Eigen::Vector3d(4.0, 2.5, 0.0)),
                           lookAt(Eigen::Vector3d(-3.2, 0.7, 2.1), Eigen::Vector3d(-3.0, 1.0, 0.0),
                                  Eigen::Vector3d(1, 1, 0))}) {
    std::vector<SampleHit> hits;
    grid.castSamples(T_w_c, planes, &hits);
    std::set<CellKey> expected;
    size_t expected_hits = 0;
    size_t h = 0;
    for (size_t k = 0; k < grid.numSamples(); ++k) {
      const auto p = analyticFloorHit(T_w_c, cam.K(), grid.samplePixels()[k], floor_z);
      if (!p || (*p - T_w_c.translation()).norm() > config.max_distance) continue;
      ++expected_hits;
      expected.insert(analyticCell(*p, 0.1));
      // Hits are in sample order: find this sample's.
      while (h < hits.size() && hits[h].sample < static_cast<int>(k)) ++h;
      ASSERT_LT(h, hits.size());
      ASSERT_EQ(hits[h].sample, static_cast<int>(k));
      EXPECT_EQ(hits[h].plane, PlaneId(1));
      EXPECT_LT((hits[h].p_w - *p).norm(), 1e-9 * std::max(1.0, p->norm()))
          << k << " " << hits[h].p_w.transpose() << " vs " << p->transpose();
      const CellKey a = analyticCell(*p, 0.1);
      // A hit exactly on a cell border may round either way.
      if (std::abs(p->x() / 0.1 - std::round(p->x() / 0.1)) > 1e-9 &&
          std::abs(p->y() / 0.1 - std::round(p->y() / 0.1)) > 1e-9) {
        EXPECT_EQ(hits[h].cell, a) << "sample " << k;
      }
      EXPECT_EQ(hits[h].cell, cellOf(hits[h].p_w, 0.1));
    }
    EXPECT_EQ(hits.size(), expected_hits);
    EXPECT_GT(expected_hits, 1000u);

    // visibleCells: exactly the analytic cells of the sampled rays.
    std::vector<CellKey> cells;
    grid.visibleCells(T_w_c, planes, &cells);
    std::set<CellKey> got(cells.begin(), cells.end());
    EXPECT_EQ(got.size(), cells.size());
    EXPECT_TRUE(std::is_sorted(cells.begin(), cells.end()));
    EXPECT_EQ(got, expected);
  }
}

TEST(GridTest, CameraLookingDownSeesExactlyTheFootprintCells) {
  // Straight down from 2 m: the sampled rays hit a 2.44 x 1.83 m rectangle.
  const PinholeCamera cam = camera640();
  GridConfig config;
  const GridCaster grid(config, cam);
  const GridPlanes planes({floorPlane(1, -10, 10, -10, 10, 0.05)}, 0.0);
  const SE3 T_w_c = lookAt(Eigen::Vector3d(0.33, 0.27, 2.0), Eigen::Vector3d(0.33, 0.27, 0.0),
                           Eigen::Vector3d::UnitX());
  std::vector<CellKey> cells;
  grid.visibleCells(T_w_c, planes, &cells);
  std::set<CellKey> expected;
  for (const auto& uv : grid.samplePixels()) {
    expected.insert(analyticCell(*analyticFloorHit(T_w_c, cam.K(), uv, 0.05), 0.1));
  }
  EXPECT_EQ(std::set<CellKey>(cells.begin(), cells.end()), expected);
  // At 2 m a 5 px step is 1.9 cm: every cell of the footprint's interior is hit.
  for (int x = -5; x <= 11; ++x) {
    for (int y = -9; y <= 13; ++y) {
      EXPECT_TRUE(std::binary_search(cells.begin(), cells.end(), CellKey{x, y, 0}))
          << x << " " << y;
    }
  }
  for (const CellKey& c : cells) EXPECT_EQ(c.z, 0);
}

TEST(GridTest, DistanceThresholdDropsFarHits) {
  const PinholeCamera cam = camera640();
  GridConfig config;
  config.max_distance = 5.0;
  const GridCaster grid(config, cam);
  const GridPlanes planes({floorPlane(1, -100, 100, -100, 100)}, 0.1);
  const SE3 T_w_c = lookAt(Eigen::Vector3d(0, 0, 1.5), Eigen::Vector3d(10, 0, 0.5));
  std::vector<SampleHit> hits;
  grid.castSamples(T_w_c, planes, &hits);
  size_t expected = 0;
  for (const auto& uv : grid.samplePixels()) {
    const auto p = analyticFloorHit(T_w_c, cam.K(), uv);
    if (p && (*p - T_w_c.translation()).norm() <= 5.0) ++expected;
  }
  EXPECT_EQ(hits.size(), expected);
  EXPECT_GT(expected, 100u);
  for (const auto& h : hits) EXPECT_LE(h.distance, 5.0 + 1e-9);
  config.max_distance = 50.0;
  const GridCaster far(config, cam);
  std::vector<SampleHit> far_hits;
  far.castSamples(T_w_c, planes, &far_hits);
  EXPECT_GT(far_hits.size(), hits.size());
}

TEST(GridTest, BoundaryWithMargin) {
  const Plane floor = floorPlane(1, 0, 3, 0, 3);
  const Eigen::Vector3d down(0, 0, -1);
  const GridPlanes with_margin({floor}, 0.1);
  const GridPlanes no_margin({floor}, 0.0);
  EXPECT_TRUE(with_margin.intersect(Eigen::Vector3d(1.5, 1.5, 1), down, 10.0).has_value());
  EXPECT_TRUE(with_margin.intersect(Eigen::Vector3d(3.05, 1.5, 1), down, 10.0).has_value());
  EXPECT_FALSE(no_margin.intersect(Eigen::Vector3d(3.05, 1.5, 1), down, 10.0).has_value());
  EXPECT_FALSE(with_margin.intersect(Eigen::Vector3d(3.15, 1.5, 1), down, 10.0).has_value());
  EXPECT_FALSE(with_margin.intersect(Eigen::Vector3d(1.5, -0.15, 1), down, 10.0).has_value());
  // Behind the origin, or farther than the threshold: no hit.
  EXPECT_FALSE(with_margin.intersect(Eigen::Vector3d(1.5, 1.5, 1), -down, 10.0).has_value());
  EXPECT_FALSE(with_margin.intersect(Eigen::Vector3d(1.5, 1.5, 1), down, 0.9).has_value());
  const auto hit = with_margin.intersect(Eigen::Vector3d(1.5, 1.5, 1), 2.0 * down, 10.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->distance, 1.0, 1e-12);
  EXPECT_TRUE(hit->p_w.isApprox(Eigen::Vector3d(1.5, 1.5, 0)));
  // A plane without a boundary is ignored.
  Plane bare = floor;
  bare.boundary.clear();
  EXPECT_EQ(GridPlanes({bare}, 0.1).size(), 0u);
}

TEST(GridTest, NearestPlaneOccludes) {
  // Floor z = 0 for x in [-1, 20]; a wall x = 5 facing the camera, y in [-3, 3], z in [0, 3].
  const Plane floor = floorPlane(1, -1, 20, -3, 3);
  const Plane wall =
      rectangle(2, -Eigen::Vector3d::UnitX(), 5.0, {{5, -3, 0}, {5, 3, 0}, {5, 3, 3}, {5, -3, 3}});
  GridConfig config;
  const GridCaster grid(config, camera640());
  const GridPlanes planes({floor, wall}, 0.0);
  const SE3 T_w_c = lookAt(Eigen::Vector3d(0, 0, 1.5), Eigen::Vector3d(5, 0, 1.0));
  std::vector<SampleHit> hits;
  grid.castSamples(T_w_c, planes, &hits);
  int on_wall = 0, on_floor = 0;
  for (const auto& h : hits) {
    if (h.plane == PlaneId(2)) {
      ++on_wall;
      EXPECT_NEAR(h.p_w.x(), 5.0, 1e-9);
    } else {
      ++on_floor;
      EXPECT_LE(h.p_w.x(), 5.0 + 1e-9);  // the floor behind the wall is hidden
    }
  }
  EXPECT_GT(on_wall, 1000);
  EXPECT_GT(on_floor, 1000);
  EXPECT_TRUE(grid.isVisible(T_w_c, planes, Eigen::Vector3d(3, 0, 0)));
  EXPECT_TRUE(grid.isVisible(T_w_c, planes, Eigen::Vector3d(5, 0.5, 1.0)));  // on the wall
  EXPECT_FALSE(grid.isVisible(T_w_c, planes, Eigen::Vector3d(8, 0, 0)));     // behind it
  EXPECT_FALSE(grid.isVisible(T_w_c, planes, Eigen::Vector3d(-3, 0, 0)));    // behind the camera
  EXPECT_FALSE(grid.isVisible(T_w_c, planes, Eigen::Vector3d(3, 10, 0)));    // outside the image
}

TEST(GridTest, CorridorVisibleCellsAreFast) {
  // 30 m corridor: floor, ceiling, two walls, two end walls.
  std::vector<Plane> planes = {
      floorPlane(1, 0, 30, 0, 2.4),
      rectangle(2, -Eigen::Vector3d::UnitZ(), 2.7,
                {{0, 0, 2.7}, {30, 0, 2.7}, {30, 2.4, 2.7}, {0, 2.4, 2.7}}),
      rectangle(3, Eigen::Vector3d::UnitY(), 0.0,
                {{0, 0, 0}, {30, 0, 0}, {30, 0, 2.7}, {0, 0, 2.7}}),
      rectangle(4, -Eigen::Vector3d::UnitY(), 2.4,
                {{0, 2.4, 0}, {30, 2.4, 0}, {30, 2.4, 2.7}, {0, 2.4, 2.7}}),
      rectangle(5, Eigen::Vector3d::UnitX(), 0.0,
                {{0, 0, 0}, {0, 2.4, 0}, {0, 2.4, 2.7}, {0, 0, 2.7}}),
      rectangle(6, -Eigen::Vector3d::UnitX(), 30.0,
                {{30, 0, 0}, {30, 2.4, 0}, {30, 2.4, 2.7}, {30, 0, 2.7}}),
  };
  GridConfig config;
  const GridCaster grid(config, camera640());
  const GridPlanes prepared(planes, config.boundary_margin);
  const SE3 T_w_c = lookAt(Eigen::Vector3d(1, 1.2, 1.5), Eigen::Vector3d(30, 1.2, 1.2));
  std::vector<CellKey> cells;
  grid.visibleCells(T_w_c, prepared, &cells);
  // Every sampled ray hits a surface of the closed corridor.
  std::vector<SampleHit> hits;
  grid.castSamples(T_w_c, prepared, &hits);
  EXPECT_EQ(hits.size(), grid.numSamples());
  EXPECT_GT(cells.size(), 1000u);
  // The far end wall is seen.
  EXPECT_TRUE(std::any_of(hits.begin(), hits.end(),
                          [](const SampleHit& h) { return h.plane == PlaneId(6); }));
  // A VO on the floor 25 m away, 3 mm below the plane: visible (the floor it lies
  // on does not hide it at the grazing angle); the same spot seen from behind the
  // far end wall is not.
  EXPECT_TRUE(grid.isVisible(T_w_c, prepared, Eigen::Vector3d(26.0, 1.2, -0.003)));
  EXPECT_TRUE(grid.isVisible(T_w_c, prepared, Eigen::Vector3d(29.0, 0.0, 1.0)));  // on a wall
  const SE3 outside = lookAt(Eigen::Vector3d(35, 1.2, 1.5), Eigen::Vector3d(20, 1.2, 0.0));
  EXPECT_FALSE(grid.isVisible(outside, prepared, Eigen::Vector3d(26.0, 1.2, 0.0)));
  EXPECT_TRUE(
      grid.isVisible(outside, GridPlanes({planes[0]}, 0.1), Eigen::Vector3d(26.0, 1.2, 0.0)));
  const size_t before = cells.size();
  const int runs = 50;
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < runs; ++i) grid.visibleCells(T_w_c, prepared, &cells);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() /
      runs;
  // Recorded, not asserted: a timed test fails on a loaded machine or under the sanitizers
  // (25 ms there); ecar_bench_grid measures the figure.
  RecordProperty("visible_cells_ms", std::to_string(ms));
  EXPECT_EQ(cells.size(), before);  // every run gives the same cells
}

TEST(GridMapTest, KeyFrameCellLinks) {
  GridMap map;
  map.setKeyFrameCells(KeyFrameId(1), {{0, 0, 0}, {1, 0, 0}, {0, 0, 0}});
  map.setKeyFrameCells(KeyFrameId(2), {{1, 0, 0}, {2, 0, 0}});
  EXPECT_EQ(map.numKeyFrames(), 2u);
  EXPECT_EQ(map.numCells(), 3u);
  EXPECT_EQ(map.cellsOfKeyFrame(KeyFrameId(1)), (std::vector<CellKey>{{0, 0, 0}, {1, 0, 0}}));
  EXPECT_EQ(map.keyframesOfCell({1, 0, 0}),
            (std::vector<KeyFrameId>{KeyFrameId(1), KeyFrameId(2)}));
  // Replacing a keyframe's cells unlinks the old ones.
  map.setKeyFrameCells(KeyFrameId(1), {{5, 5, 5}});
  EXPECT_TRUE(map.keyframesOfCell({0, 0, 0}).empty());
  EXPECT_EQ(map.keyframesOfCell({1, 0, 0}), std::vector<KeyFrameId>{KeyFrameId(2)});
  const auto saved = map.save();
  GridMap loaded;
  loaded.load(saved);
  EXPECT_EQ(loaded.cellsOfKeyFrame(KeyFrameId(1)), map.cellsOfKeyFrame(KeyFrameId(1)));
  EXPECT_EQ(loaded.keyframesOfCell({2, 0, 0}), std::vector<KeyFrameId>{KeyFrameId(2)});
  map.eraseKeyFrame(KeyFrameId(2));
  EXPECT_EQ(map.numKeyFrames(), 1u);
  EXPECT_EQ(map.numCells(), 1u);
  auto bad = saved;
  bad.push_back(saved[0]);
  EXPECT_THROW(loaded.load(bad), Error);
}

TEST(GridTest, ConfigValidationAndCells) {
  GridConfig c;
  c.window = 0;
  try {
    c.validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("grid.window"), std::string::npos);
  }
  c = GridConfig();
  c.cell_size = -0.1;
  EXPECT_THROW(GridCaster(c, camera640()), Error);
  EXPECT_EQ(cellOf(Eigen::Vector3d(0.05, -0.05, 1.23), 0.1), (CellKey{0, -1, 12}));
  EXPECT_TRUE(cellCenter({0, -1, 12}, 0.1).isApprox(Eigen::Vector3d(0.05, -0.05, 1.25)));
  const std::vector<CellKey> sorted = {{0, 0, -1}, {3, 4, 5}};
  EXPECT_TRUE(containsCell(sorted, {3, 4, 5}));
  EXPECT_FALSE(containsCell(sorted, {0, 0, 0}));
  EXPECT_TRUE(containsCell(sorted, {0, 0, 0}, 1));
  EXPECT_FALSE(containsCell(sorted, {0, 0, 1}, 1));
  Plane bad = floorPlane(1, 0, 1, 0, 1);
  bad.normal *= 2.0;
  EXPECT_THROW(GridPlanes({bad}, 0.1), Error);
}

}  // namespace
}  // namespace ecar
