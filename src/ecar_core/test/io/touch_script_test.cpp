// Touch scripts in scene files: both item kinds parse, bad items give errors
// naming the file, device and key, and scriptTouches projects world points to
// the analytic pixels of known poses.
#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/scene.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

// 64x48, fx = fy = 50, principal point at the centre, no distortion.
const char* kHead =
    "name: touch_test\n"
    "camera: {width: 64, height: 48, fx: 50, fy: 50, cx: 31.5, cy: 23.5}\n"
    "spaces:\n  - {min: [-1, -3, 0], max: [10, 3, 3]}\n"
    "devices:\n"
    "  - name: dev\n"
    "    trajectory: {type: walk, waypoints: [[0, 0], [5, 0]]}\n";

class TouchScriptTest : public ::testing::Test {
 protected:
  void TearDown() override {
    if (!path_.empty()) fs::remove(path_);
  }
  // Loads kHead + "    touches:\n" + items.
  Scene load(const std::string& items) {
    path_ = (fs::temp_directory_path() / "ecar_touch_script_test.yaml").string();
    std::ofstream(path_) << kHead << "    touches:\n" << items;
    return loadScene(path_);
  }
  std::string errorOf(const std::string& items) {
    try {
      load(items);
    } catch (const Error& e) {
      return e.what();
    }
    ADD_FAILURE() << "no error for:\n" << items;
    return "";
  }
  std::string path_;
};

TEST_F(TouchScriptTest, ParsesEventsAndStrokes) {
  const Scene scene = load(
      "      - {frame: 2, phase: begin, pixel: [10, 20], color: [0, 255, 7], width: 0.05}\n"
      "      - {frame: 4, phase: move, at: [2, 1.5, 0]}\n"
      "      - {frame: 5, phase: end, pixel: [12.5, 22], width: 0.04}\n"
      "      - stroke: {start_frame: 8, end_frame: 12, from_pixel: [10, 10], to_pixel: [50, 30]}\n"
      "      - stroke: {start_frame: 14, end_frame: 16, from: [3, 1, 0], to: [3.5, 1, 0],\n"
      "                 color: [1, 2, 3], width: 0.01}\n");
  const auto& t = scene.devices.at(0).touches;
  ASSERT_EQ(t.size(), 5u);
  EXPECT_FALSE(t[0].stroke);
  EXPECT_EQ(t[0].start_frame, 2);
  EXPECT_EQ(t[0].end_frame, 2);
  EXPECT_EQ(t[0].phase, TouchPhase::kBegin);
  EXPECT_FALSE(t[0].in_world);
  EXPECT_EQ(t[0].from_uv, Eigen::Vector2d(10, 20));
  EXPECT_EQ(t[0].to_uv, Eigen::Vector2d(10, 20));
  EXPECT_EQ(t[0].r, 0);
  EXPECT_EQ(t[0].g, 255);
  EXPECT_EQ(t[0].b, 7);
  EXPECT_DOUBLE_EQ(t[0].width, 0.05);
  EXPECT_EQ(t[1].phase, TouchPhase::kMove);
  EXPECT_TRUE(t[1].in_world);
  EXPECT_EQ(t[1].from_w, Eigen::Vector3d(2, 1.5, 0));
  // A move or end without colour and width takes its begin's.
  EXPECT_EQ(t[1].g, 255);
  EXPECT_EQ(t[1].b, 7);
  EXPECT_DOUBLE_EQ(t[1].width, 0.05);
  EXPECT_EQ(t[2].phase, TouchPhase::kEnd);
  EXPECT_EQ(t[2].b, 7);
  EXPECT_DOUBLE_EQ(t[2].width, 0.04);  // its own
  // Defaults.
  EXPECT_EQ(t[3].r, 255);
  EXPECT_EQ(t[3].g, 64);
  EXPECT_EQ(t[3].b, 32);
  EXPECT_DOUBLE_EQ(t[3].width, 0.03);
  EXPECT_TRUE(t[3].stroke);
  EXPECT_EQ(t[3].start_frame, 8);
  EXPECT_EQ(t[3].end_frame, 12);
  EXPECT_FALSE(t[3].in_world);
  EXPECT_EQ(t[3].to_uv, Eigen::Vector2d(50, 30));
  EXPECT_TRUE(t[4].stroke);
  EXPECT_TRUE(t[4].in_world);
  EXPECT_EQ(t[4].from_w, Eigen::Vector3d(3, 1, 0));
  EXPECT_EQ(t[4].to_w, Eigen::Vector3d(3.5, 1, 0));
  EXPECT_EQ(t[4].b, 3);
  EXPECT_DOUBLE_EQ(t[4].width, 0.01);
}

TEST_F(TouchScriptTest, ErrorsNameFileDeviceItemAndKey) {
  const std::string begin = "      - {frame: 1, phase: begin, pixel: [1, 1]}\n";
  const std::string end = "      - {frame: 9, phase: end, pixel: [1, 1]}\n";
  struct Case {
    std::string items, expected;
  } cases[] = {
      {"      - {frame: 1, phase: begin, pixel: [1, 1], colour: [1, 2, 3]}\n" + end,
       "devices[0].touches[0]: unknown key 'colour'"},
      {"      - stroke: {start_frame: 1, end_frame: 3, from: [0, 0, 0], to: [1, 0, 0], "
       "size: 2}\n",
       "devices[0].touches[0].stroke: unknown key 'size'"},
      {"      - {stroke: {start_frame: 1, end_frame: 3, from: [0, 0, 0], to: [1, 0, 0]}, "
       "frame: 1}\n",
       "devices[0].touches[0]: unknown key 'frame'"},
      {"      - {frame: 1, phase: down, pixel: [1, 1]}\n",
       "touches[0]: key 'phase' must be begin, move or end (got 'down')"},
      {"      - {frame: 1, phase: begin, pixel: [1, 1], at: [0, 0, 0]}\n" + end,
       "touches[0]: needs exactly one of 'pixel' and 'at'"},
      {"      - {frame: 1, phase: begin}\n" + end, "needs exactly one of 'pixel' and 'at'"},
      {"      - {frame: -1, phase: begin, pixel: [1, 1]}\n" + end,
       "touches[0]: key 'frame' must be a frame number >= 0"},
      {"      - {frame: 1.5, phase: begin, pixel: [1, 1]}\n" + end,
       "touches[0]: key 'frame' has an invalid value"},
      {"      - {frame: 1, phase: begin, pixel: [64, 1]}\n" + end,
       "touches[0]: key 'pixel' is outside the 64x48 image"},
      {"      - {frame: 1, phase: begin, at: [.nan, 0, 0]}\n" + end,
       "touches[0]: key 'at' has a non-finite coordinate"},
      {"      - {frame: 1, phase: begin, pixel: [1, 1], color: [0, 256, 0]}\n" + end,
       "touches[0]: key 'color' must hold integers 0-255"},
      {"      - {frame: 1, phase: begin, pixel: [1, 1], color: [0, 0]}\n" + end,
       "touches[0]: key 'color' must be [r, g, b]"},
      {"      - {frame: 1, phase: begin, pixel: [1, 1], width: 0}\n" + end,
       "touches[0]: key 'width' must be positive"},
      {begin + "      - {frame: 1, phase: end, pixel: [1, 1]}\n",
       "touches[1]: frame 1 must be after the previous item's (1)"},
      {"      - {frame: 1, phase: move, pixel: [1, 1]}\n",
       "touches[0]: 'move' without a 'begin' before"},
      {begin + "      - {frame: 2, phase: begin, pixel: [1, 1]}\n",
       "touches[1]: 'begin' inside the stroke begun at devices[0].touches[0]"},
      {begin, "devices[0]: touches[0]: the stroke begun here has no 'end'"},
      {begin +
           "      - stroke: {start_frame: 3, end_frame: 5, from_pixel: [1, 1], "
           "to_pixel: [2, 2]}\n" +
           end,
       "touches[1]: a stroke cannot start inside the stroke begun at devices[0].touches[0]"},
      {"      - stroke: {start_frame: 3, end_frame: 3, from_pixel: [1, 1], to_pixel: [2, 2]}\n",
       "touches[0].stroke: 'end_frame' must be after 'start_frame'"},
      {"      - stroke: {start_frame: 3, end_frame: 5, from: [1, 1, 0], to_pixel: [2, 2]}\n",
       "needs either 'from' and 'to' or 'from_pixel' and 'to_pixel'"},
      {"      - stroke: {start_frame: 3, end_frame: 5, from: [1, 1, 0]}\n",
       "touches[0].stroke: missing key 'to'"},
      {"      - stroke: {start_frame: 1, end_frame: 5, from_pixel: [1, 1], to_pixel: [2, 2]}\n"
       "      - stroke: {start_frame: 5, end_frame: 7, from_pixel: [1, 1], to_pixel: [2, 2]}\n",
       "touches[1]: frame 5 must be after the previous item's (5)"},
  };
  for (const auto& c : cases) {
    const std::string msg = errorOf(c.items);
    EXPECT_NE(msg.find(c.expected), std::string::npos)
        << "expected: " << c.expected << "\ngot: " << msg;
    EXPECT_EQ(msg.rfind(path_, 0), 0u) << "message must start with the file: " << msg;
  }
  EXPECT_NE(errorOf("      - {}\n").find("missing key 'frame'"), std::string::npos);
  EXPECT_NE(errorOf("      {frame: 1}\n").find("key 'touches' must be a list"), std::string::npos);
}

// Camera i at (0.1 i, 0, 1.5) looking along world +x (x_c = -y_w, y_c = -z_w).
Trajectory lookingAlongX(int count) {
  Trajectory frames;
  for (int i = 0; i < count; ++i) {
    StampedPose p;
    p.timestamp = 10.0 + i / 30.0;
    p.T_w_c.linear() << 0, 0, 1, -1, 0, 0, 0, -1, 0;
    p.T_w_c.translation() = Eigen::Vector3d(0.1 * i, 0, 1.5);
    frames.push_back(p);
  }
  return frames;
}

// The analytic pixel of world point p_w from camera i of lookingAlongX.
Eigen::Vector2d analyticPixel(const Eigen::Vector3d& p_w, int i) {
  const double depth = p_w.x() - 0.1 * i;
  return {31.5 + 50.0 * (-p_w.y()) / depth, 23.5 + 50.0 * (1.5 - p_w.z()) / depth};
}

TEST_F(TouchScriptTest, WorldPointsProjectToTheAnalyticPixel) {
  const Scene scene = load(
      "      - {frame: 0, phase: begin, at: [3, 0.5, 0.5], color: [1, 2, 3], width: 0.02}\n"
      "      - {frame: 1, phase: end, at: [3, 0.5, 0.5]}\n"
      "      - stroke: {start_frame: 2, end_frame: 6, from: [3, 0.5, 0.5], to: [3, -0.5, 0.5]}\n"
      "      - stroke: {start_frame: 8, end_frame: 12, from_pixel: [10, 10], to_pixel: [50, "
      "30]}\n");
  const Trajectory frames = lookingAlongX(20);
  const auto events = scriptTouches(scene, scene.devices[0], frames, frames.size());
  ASSERT_EQ(events.size(), 2u + 5u + 5u);

  EXPECT_EQ(events[0].frame, 0u);
  EXPECT_EQ(events[0].phase, TouchPhase::kBegin);
  EXPECT_DOUBLE_EQ(events[0].timestamp, frames[0].timestamp);
  EXPECT_LT((events[0].uv - analyticPixel({3, 0.5, 0.5}, 0)).norm(), 1e-9);
  EXPECT_NEAR(events[0].uv.x(), 31.5 - 25.0 / 3.0, 1e-9);
  EXPECT_NEAR(events[0].uv.y(), 23.5 + 50.0 / 3.0, 1e-9);
  EXPECT_EQ(events[0].r, 1);
  EXPECT_EQ(events[0].b, 3);
  EXPECT_DOUBLE_EQ(events[0].width, 0.02);
  // The same world point from the next pose (0.1 m closer) is another pixel.
  EXPECT_EQ(events[1].phase, TouchPhase::kEnd);
  EXPECT_LT((events[1].uv - analyticPixel({3, 0.5, 0.5}, 1)).norm(), 1e-9);

  // World stroke: interpolated in the world, projected with each frame's pose.
  const TouchPhase phases[] = {TouchPhase::kBegin, TouchPhase::kMove, TouchPhase::kMove,
                               TouchPhase::kMove, TouchPhase::kEnd};
  for (int k = 0; k < 5; ++k) {
    const TouchEvent& e = events[2 + k];
    const int f = 2 + k;
    EXPECT_EQ(e.frame, static_cast<size_t>(f));
    EXPECT_EQ(e.phase, phases[k]);
    EXPECT_DOUBLE_EQ(e.timestamp, frames[f].timestamp);
    const Eigen::Vector3d p_w(3, 0.5 - 0.25 * k, 0.5);
    EXPECT_LT((e.uv - analyticPixel(p_w, f)).norm(), 1e-9) << "frame " << f;
    EXPECT_EQ(e.r, 255);  // default colour and width
    EXPECT_EQ(e.g, 64);
    EXPECT_DOUBLE_EQ(e.width, 0.03);
  }
  // Pixel stroke: interpolated in the image.
  for (int k = 0; k < 5; ++k) {
    const TouchEvent& e = events[7 + k];
    EXPECT_EQ(e.frame, static_cast<size_t>(8 + k));
    EXPECT_EQ(e.phase, phases[k]);
    EXPECT_LT((e.uv - Eigen::Vector2d(10 + 10 * k, 10 + 5 * k)).norm(), 1e-12);
  }
}

TEST_F(TouchScriptTest, PointsBehindOrOutsideAndFramesPastTheEndAreErrors) {
  const Trajectory frames = lookingAlongX(20);
  auto errorOfScript = [&](const std::string& items, size_t total) {
    const Scene scene = load(items);
    try {
      scriptTouches(scene, scene.devices[0], frames, total);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    ADD_FAILURE() << "no error for:\n" << items;
    return std::string();
  };
  std::string msg = errorOfScript(
      "      - stroke: {start_frame: 2, end_frame: 6, from: [3, 0, 1], to: [-3, 0, 1]}\n", 20);
  EXPECT_EQ(msg.rfind(path_ + ": device 'dev': touches[0]: frame 4: world point", 0), 0u) << msg;
  EXPECT_NE(msg.find("is behind the camera"), std::string::npos) << msg;
  msg = errorOfScript(
      "      - {frame: 3, phase: begin, at: [3, 5, 1]}\n"
      "      - {frame: 4, phase: end, at: [3, 0, 1]}\n",
      20);
  EXPECT_NE(msg.find("device 'dev': touches[0]: frame 3: world point"), std::string::npos) << msg;
  EXPECT_NE(msg.find("outside the 64x48 image"), std::string::npos) << msg;
  msg = errorOfScript(
      "      - stroke: {start_frame: 2, end_frame: 30, from_pixel: [1, 1], to_pixel: [2, 2]}\n",
      20);
  EXPECT_NE(msg.find("touches[0]: frame 30 is past the device's last frame (19)"),
            std::string::npos)
      << msg;
}

TEST_F(TouchScriptTest, APrefixOfTheTrajectoryEndsTheStrokeItCuts) {
  const Scene scene = load(
      "      - stroke: {start_frame: 2, end_frame: 6, from_pixel: [10, 10], to_pixel: [50, 30]}\n"
      "      - {frame: 8, phase: begin, pixel: [5, 5]}\n"
      "      - {frame: 12, phase: end, pixel: [6, 6]}\n");
  const Trajectory all = lookingAlongX(20);
  auto prefix = [&](size_t n) {
    return scriptTouches(scene, scene.devices[0], Trajectory(all.begin(), all.begin() + n), 20);
  };
  // Cut inside the stroke: its MOVE on the last frame becomes END.
  auto e = prefix(5);
  ASSERT_EQ(e.size(), 3u);
  EXPECT_EQ(e[2].frame, 4u);
  EXPECT_EQ(e[2].phase, TouchPhase::kEnd);
  EXPECT_LT((e[2].uv - Eigen::Vector2d(30, 20)).norm(), 1e-12);
  // Cut after a BEGIN event: END on the last frame at the BEGIN's pixel.
  e = prefix(10);
  ASSERT_EQ(e.size(), 7u);
  EXPECT_EQ(e[5].phase, TouchPhase::kBegin);
  EXPECT_EQ(e[6].frame, 9u);
  EXPECT_DOUBLE_EQ(e[6].timestamp, all[9].timestamp);
  EXPECT_EQ(e[6].phase, TouchPhase::kEnd);
  EXPECT_EQ(e[6].uv, Eigen::Vector2d(5, 5));
  // A BEGIN on the last frame is dropped; a stroke begun there has no length.
  e = prefix(9);
  ASSERT_EQ(e.size(), 5u);
  EXPECT_EQ(e.back().phase, TouchPhase::kEnd);
  EXPECT_EQ(e.back().frame, 6u);
  // The whole trajectory: the script as written.
  e = prefix(20);
  ASSERT_EQ(e.size(), 7u);
  EXPECT_EQ(e.back().frame, 12u);
  EXPECT_EQ(e.back().uv, Eigen::Vector2d(6, 6));
}

TEST(ShippedTouchScriptsTest, EveryShippedDeviceScriptProjectsIntoItsImages) {
  for (const auto& entry : fs::directory_iterator(ECAR_REPO_ROOT "/config/scenes")) {
    if (entry.path().extension() != ".yaml") continue;
    const Scene scene = loadScene(entry.path().string());
    for (const DeviceSpec& d : scene.devices) {
      if (d.touches.empty()) continue;
      SCOPED_TRACE(entry.path().string() + " " + d.name);
      const auto motion = generateMotion(scene, d, scene.camera.fps);
      Trajectory frames;
      for (const MotionSample& m : motion) frames.push_back({m.timestamp, m.T_w_c});
      const auto events = scriptTouches(scene, d, frames, frames.size());
      const auto bad = firstIllFormedTouch(events, [](const TouchEvent& e) { return e.phase; });
      EXPECT_FALSE(bad.has_value());
    }
  }
}

}  // namespace
}  // namespace ecar
