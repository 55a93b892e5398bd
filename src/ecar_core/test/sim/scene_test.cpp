// Scene files: every shipped scene loads; malformed ones give an error naming
// the file and the key.
#include "ecar_core/sim/scene.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/motion.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;
const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

TEST(SceneTest, EveryShippedSceneLoadsAndItsDevicesStayInside) {
  int count = 0;
  for (const auto& entry : fs::directory_iterator(kScenes)) {
    if (entry.path().extension() != ".yaml") continue;
    SCOPED_TRACE(entry.path().string());
    const Scene scene = loadScene(entry.path().string());
    EXPECT_FALSE(scene.spaces.empty());
    EXPECT_FALSE(scene.devices.empty());
    for (const auto& d : scene.devices) {
      // generateMotion throws when a path leaves the free space.
      EXPECT_NO_THROW(generateMotion(scene, d, scene.camera.fps)) << d.name;
    }
    ++count;
  }
  EXPECT_GE(count, 2);
}

TEST(SceneTest, CorridorAndRoomHaveTheRequiredShape) {
  const Scene corridor = loadScene(kScenes + "/corridor.yaml");
  ASSERT_EQ(corridor.spaces.size(), 1u);
  const Eigen::Vector3d size = corridor.spaces[0].max - corridor.spaces[0].min;
  EXPECT_DOUBLE_EQ(size.x(), 30.0);
  EXPECT_DOUBLE_EQ(size.y(), 2.4);
  EXPECT_DOUBLE_EQ(size.z(), 2.7);
  EXPECT_GE(corridor.devices.size(), 2u);
  // One device sees through its own camera; the others through the scene's.
  const DeviceSpec& phone = corridor.device("phone_800");
  ASSERT_TRUE(phone.camera.has_value());
  EXPECT_EQ(corridor.cameraOf(phone).width, 800);
  EXPECT_NE(corridor.cameraOf(phone).dist[0], 0.0);
  EXPECT_EQ(corridor.cameraOf(corridor.device("device_0")).width, 640);
  const Scene room = loadScene(kScenes + "/room.yaml");
  const Eigen::Vector3d rs = room.spaces[0].max - room.spaces[0].min;
  EXPECT_DOUBLE_EQ(rs.x(), 6.0);
  EXPECT_DOUBLE_EQ(rs.y(), 5.0);
  EXPECT_DOUBLE_EQ(rs.z(), 2.7);
  bool has_half_circle = false, has_shake = false;
  for (const auto& d : room.devices) {
    has_half_circle |= d.trajectory.type == TrajectoryType::kHalfCircle;
    has_shake |= d.trajectory.type == TrajectoryType::kShake;
  }
  EXPECT_TRUE(has_half_circle);
  EXPECT_TRUE(has_shake);
  EXPECT_THROW(room.device("nobody"), Error);
}

class BadSceneTest : public ::testing::Test {
 protected:
  std::string write(const std::string& text) {
    path_ = (fs::temp_directory_path() / "ecar_bad_scene.yaml").string();
    std::ofstream(path_) << text;
    return path_;
  }
  void TearDown() override { fs::remove(path_); }

  // Loads the text and returns the error message (fails when none is thrown).
  std::string errorOf(const std::string& text) {
    try {
      loadScene(write(text));
    } catch (const Error& e) {
      return e.what();
    }
    ADD_FAILURE() << "no error for:\n" << text;
    return "";
  }
  std::string path_;
};

const char* kCamera = "camera: {width: 64, height: 48, fx: 50, fy: 50, cx: 31.5, cy: 23.5}\n";
const char* kSpace = "spaces:\n  - {min: [0, 0, 0], max: [4, 3, 2.5]}\n";

TEST_F(BadSceneTest, MissingFileAndInvalidYaml) {
  try {
    loadScene("/nonexistent/scene.yaml");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/scene.yaml"), std::string::npos);
  }
  const std::string msg = errorOf("name: x\ncamera: [unclosed\n");
  EXPECT_NE(msg.find("not valid YAML"), std::string::npos) << msg;
  EXPECT_NE(msg.find(path_), std::string::npos) << msg;
}

// Found by the scene fuzz target (its input is test/fuzz/corpus/scene/regression-list-as-key.yaml):
// a key that is a list, or a value of another shape than its key takes, made yaml-cpp throw
// past the reader (std::terminate in make_dataset).
TEST_F(BadSceneTest, ValuesOfTheWrongShapeAreErrorsNotCrashes) {
  std::string msg = errorOf(std::string("name: x\n") + kCamera + "? [a, b]\n: 1\n");
  EXPECT_NE(msg.find("a key that is not a name"), std::string::npos) << msg;
  msg = errorOf(std::string("name: [x, y]\n") + kCamera);
  EXPECT_NE(msg.find(path_), std::string::npos) << msg;
  const std::string fuzzed = ECAR_REPO_ROOT "/test/fuzz/corpus/scene/regression-list-as-key.yaml";
  EXPECT_THROW(loadScene(fuzzed), Error);
}

TEST_F(BadSceneTest, ErrorsNameTheKey) {
  const std::string base = std::string("name: x\n") + kCamera + kSpace;
  struct Case {
    std::string text, expected;
  } cases[] = {
      {std::string(kCamera) + kSpace, "missing key 'name'"},
      {std::string("name: x\n") + kSpace, "missing key 'camera'"},
      {std::string("name: x\n") + kCamera, "missing key 'spaces'"},
      {"name: x\ncamera: {width: 64, height: 48, fx: -5, fy: 50, cx: 1, cy: 1}\n" +
           std::string(kSpace),
       "camera: key 'fx' must be positive"},
      {"name: x\ncamera: {width: 64, height: 48, fy: 50, cx: 1, cy: 1}\n" + std::string(kSpace),
       "missing key 'fx'"},
      {std::string("name: x\n") + kCamera + "spaces:\n  - {min: [0, 0, 0], max: [4, 3]}\n",
       "spaces[0]: key 'max' must be [x, y, z]"},
      {std::string("name: x\n") + kCamera + "spaces:\n  - {min: [0, 0, 0], max: [4, -3, 2]}\n",
       "spaces[0]: 'max' must exceed 'min'"},
      {std::string("name: x\n") + kCamera + "spaces:\n  - {min: [0, 0, a], max: [4, 3, 2]}\n",
       "key 'min' has an invalid value"},
      {base + "colour: red\n", "unknown key 'colour'"},
      {base + "texture: {texel_size: 0}\n", "texture: key 'texel_size' must be positive"},
      {base + "devices:\n  - name: d\n    trajectory: {type: fly}\n",
       "devices[0].trajectory: key 'type' must be walk, half_circle or shake"},
      {base + "devices:\n  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1]]}\n",
       "devices[0].trajectory: key 'waypoints' must list at least two"},
      {base + "devices:\n  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]], "
              "sped: 3}\n",
       "devices[0].trajectory: unknown key 'sped'"},
      {base + "devices:\n  - name: d\n    trajectory: {type: shake, target: [1, 1, 1]}\n",
       "devices[0].trajectory: missing key 'position'"},
      {base + "devices:\n  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]], "
              "blank: [2, 0]}\n",
       "devices[0].trajectory: key 'blank' must be [start_s, duration_s]"},
      {base + "devices:\n  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]], "
              "blank: [2]}\n",
       "devices[0].trajectory: key 'blank' must be [start_s, duration_s]"},
      {base + "devices:\n  - name: a-b\n    trajectory: {type: walk, waypoints: [[1, 1], [2, "
              "1]]}\n",
       "must be a ROS name"},
      {base + "devices:\n  - name: d\n    camera: {width: 64, height: 48, fx: 50, fy: 50}\n"
              "    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]]}\n",
       "devices[0].camera: missing key 'cx'"},
      {base + "devices:\n  - name: d\n    camera: {width: 64, height: 48, fx: 50, fy: 50, cx: 1, "
              "cy: 1, distortion: [0, 0, 0]}\n    trajectory: {type: walk, waypoints: [[1, 1], [2, "
              "1]]}\n",
       "devices[0].camera: key 'distortion' must be"},
      {base + "devices:\n  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]]}\n"
              "  - name: d\n    trajectory: {type: walk, waypoints: [[1, 1], [2, 1]]}\n",
       "duplicate device name 'd'"},
  };
  for (const auto& c : cases) {
    const std::string msg = errorOf(c.text);
    EXPECT_NE(msg.find(c.expected), std::string::npos) << "got: " << msg;
    EXPECT_EQ(msg.rfind(path_, 0), 0u) << "message must start with the file: " << msg;
  }
}

TEST_F(BadSceneTest, DeviceLeavingTheSpaceIsReported) {
  const Scene scene = loadScene(write(std::string("name: x\n") + kCamera + kSpace +
                                      "devices:\n  - name: runaway\n    trajectory: {type: walk, "
                                      "waypoints: [[1, 1], [9, 1]]}\n"));
  try {
    generateMotion(scene, scene.devices[0], 30.0);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'runaway' leaves the free space"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace ecar
