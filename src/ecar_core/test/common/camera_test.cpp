#include "ecar_core/common/camera.h"

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

// EuRoC V1_01 cam0 (mav0/cam0/sensor.yaml): strong barrel distortion.
PinholeCamera eurocCamera() {
  CameraParams p;
  p.width = 752;
  p.height = 480;
  p.fx = 458.654;
  p.fy = 457.296;
  p.cx = 367.215;
  p.cy = 248.375;
  p.dist = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0};
  p.fps = 20;
  return PinholeCamera(p);
}

// Every pixel centre on a 4-pixel grid, plus the last row and column.
std::vector<Eigen::Vector2d> imageGrid(const PinholeCamera& cam) {
  std::vector<Eigen::Vector2d> pts;
  std::vector<int> us, vs;
  for (int u = 0; u < cam.width(); u += 4) us.push_back(u);
  for (int v = 0; v < cam.height(); v += 4) vs.push_back(v);
  us.push_back(cam.width() - 1);
  vs.push_back(cam.height() - 1);
  for (int v : vs) {
    for (int u : us) pts.emplace_back(u, v);
  }
  return pts;
}

class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "ecar_camera_test_XXXXXX").string();
    path_ = mkdtemp(pattern.data());
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (fs::path(path_) / name).string(); }

 private:
  std::string path_;
};

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

TEST(PinholeCameraTest, EurocUnprojectProjectRoundTripOverWholeImage) {
  const PinholeCamera cam = eurocCamera();
  ASSERT_TRUE(cam.hasDistortion());
  double worst = 0.0;
  for (const Eigen::Vector2d& uv : imageGrid(cam)) {
    const Eigen::Vector3d ray = cam.unproject(uv);
    EXPECT_DOUBLE_EQ(ray.z(), 1.0);
    const auto back = cam.project(2.5 * ray);  // any depth along the ray
    ASSERT_TRUE(back.has_value());
    worst = std::max(worst, (*back - uv).norm());
  }
  EXPECT_LT(worst, 1e-6) << "worst round-trip error in pixels";
}

TEST(PinholeCameraTest, ProjectMatchesOpenCv) {
  const PinholeCamera cam = eurocCamera();
  cv::Mat K, D;
  cv::Mat(cv::Matx33d(cam.params().fx, 0, cam.params().cx, 0, cam.params().fy, cam.params().cy, 0,
                      0, 1))
      .copyTo(K);
  cv::Mat(cv::Matx<double, 1, 5>(cam.params().dist.data())).copyTo(D);
  std::vector<cv::Point3d> points;
  for (double x = -1.0; x <= 1.0; x += 0.125) {
    for (double y = -0.6; y <= 0.6; y += 0.125) points.emplace_back(x, y, 1.3);
  }
  std::vector<cv::Point2d> expected;
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, expected);
  for (size_t i = 0; i < points.size(); ++i) {
    const auto uv = cam.project({points[i].x, points[i].y, points[i].z});
    ASSERT_TRUE(uv.has_value());
    EXPECT_NEAR(uv->x(), expected[i].x, 1e-9);
    EXPECT_NEAR(uv->y(), expected[i].y, 1e-9);
  }
}

TEST(PinholeCameraTest, ProjectRejectsPointsBehindTheCamera) {
  const PinholeCamera cam = eurocCamera();
  EXPECT_FALSE(cam.project({0.1, 0.2, 0.0}).has_value());
  EXPECT_FALSE(cam.project({0.1, 0.2, -1.0}).has_value());
}

TEST(PinholeCameraTest, UndistortPointsInvertsDistortionAndMatchesOpenCv) {
  const PinholeCamera cam = eurocCamera();
  const std::vector<Eigen::Vector2d> distorted = imageGrid(cam);
  std::vector<Eigen::Vector2d> ideal;
  cam.undistortPoints(distorted, &ideal);
  ASSERT_EQ(ideal.size(), distorted.size());

  // Re-distorting the ideal pixels gives the original pixels back.
  const auto& p = cam.params();
  double worst = 0.0;
  for (size_t i = 0; i < ideal.size(); ++i) {
    const Eigen::Vector2d xn((ideal[i].x() - p.cx) / p.fx, (ideal[i].y() - p.cy) / p.fy);
    const Eigen::Vector2d xd = cam.distort(xn);
    const Eigen::Vector2d uv(p.fx * xd.x() + p.cx, p.fy * xd.y() + p.cy);
    worst = std::max(worst, (uv - distorted[i]).norm());
  }
  EXPECT_LT(worst, 1e-6);

  // OpenCV's iterative undistortion (run to convergence) agrees.
  const cv::Matx33d K(p.fx, 0, p.cx, 0, p.fy, p.cy, 0, 0, 1);
  const cv::Matx<double, 1, 5> D(p.dist.data());
  std::vector<cv::Point2d> in, out;
  for (const auto& uv : distorted) in.emplace_back(uv.x(), uv.y());
  cv::undistortPoints(
      in, out, K, D, cv::noArray(), K,
      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-14));
  double worst_cv = 0.0;
  for (size_t i = 0; i < out.size(); ++i) {
    worst_cv = std::max(worst_cv, (Eigen::Vector2d(out[i].x, out[i].y) - ideal[i]).norm());
  }
  EXPECT_LT(worst_cv, 1e-3) << "largest difference to cv::undistortPoints in pixels";

  // Without distortion undistortPoint is the identity.
  const PinholeCamera ideal_cam(CameraParams{});
  EXPECT_FALSE(ideal_cam.hasDistortion());
  EXPECT_EQ(ideal_cam.undistortPoint({12.25, 300.5}), Eigen::Vector2d(12.25, 300.5));
}

TEST(PinholeCameraTest, RejectsInvalidParameters) {
  CameraParams p;
  p.width = 0;
  EXPECT_THROW(PinholeCamera{p}, Error);
  p = CameraParams{};
  p.fx = -1;
  EXPECT_THROW(PinholeCamera{p}, Error);
  p = CameraParams{};
  p.dist[0] = std::nan("");
  EXPECT_THROW(PinholeCamera{p}, Error);
  // Sizes a hostile camera_info could make the server allocate for.
  p = CameraParams{};
  p.width = kMaxCameraSide + 1;
  EXPECT_THROW(PinholeCamera{p}, Error);
  // A distortion that folds the image within its border cannot be inverted.
  p = CameraParams{};
  p.dist = {-3.0, 0.0, 0.0, 0.0, 0.0};
  try {
    PinholeCamera{p};
    ADD_FAILURE() << "a folding distortion was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("folds the image"), std::string::npos) << e.what();
  }
}

// The undistorted image box holds every undistorted pixel (keypoint grids and
// projection checks rely on it); without distortion it is the image.
TEST(PinholeCameraTest, UndistortedBoundsHoldEveryPixel) {
  const PinholeCamera euroc = eurocCamera();
  for (int v = 0; v < euroc.height(); v += 7) {
    for (int u = 0; u < euroc.width(); u += 7) {
      const Eigen::Vector2d x = euroc.undistortPoint(Eigen::Vector2d(u, v));
      ASSERT_GE(x.x(), euroc.minU());
      ASSERT_GE(x.y(), euroc.minV());
      ASSERT_LT(x.x(), euroc.maxU());
      ASSERT_LT(x.y(), euroc.maxV());
    }
  }
  EXPECT_LT(euroc.minU(), -10.0);  // barrel distortion: the corners move out
  EXPECT_GT(euroc.maxU(), euroc.width() + 10.0);
  const PinholeCamera ideal{CameraParams{}};
  EXPECT_EQ(ideal.minU(), 0.0);
  EXPECT_EQ(ideal.maxU(), 640.0);
  EXPECT_EQ(ideal.maxV(), 480.0);
  EXPECT_EQ(ideal.difference(ideal), "");
  CameraParams other;
  other.fx = 530.0;
  EXPECT_NE(PinholeCamera(other).difference(ideal).find("fx 530"), std::string::npos);
  EXPECT_EQ(PinholeCamera(other).difference(ideal, 0.01), "");
}

TEST(CameraYamlTest, EveryShippedCameraFileLoads) {
  const fs::path dir = fs::path(ECAR_REPO_ROOT) / "config" / "cameras";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".yaml") continue;
    SCOPED_TRACE(entry.path().string());
    PinholeCamera cam;
    ASSERT_NO_THROW(cam = PinholeCamera::loadYaml(entry.path().string()));
    EXPECT_GT(cam.params().fps, 0.0);
    names.push_back(entry.path().filename().string());
  }
  for (const char* expected :
       {"kitti07.yaml", "euroc_cam0.yaml", "tum_fr3.yaml", "sim_640x480.yaml"}) {
    EXPECT_NE(std::find(names.begin(), names.end(), expected), names.end()) << expected;
  }

  const PinholeCamera euroc = PinholeCamera::loadYaml((dir / "euroc_cam0.yaml").string());
  EXPECT_EQ(euroc.width(), 752);
  EXPECT_EQ(euroc.height(), 480);
  EXPECT_DOUBLE_EQ(euroc.params().dist[0], -0.28340811);
  const PinholeCamera sim = PinholeCamera::loadYaml((dir / "sim_640x480.yaml").string());
  EXPECT_DOUBLE_EQ(sim.params().fx, 525.0);
  EXPECT_DOUBLE_EQ(sim.params().cy, 239.5);
  EXPECT_FALSE(sim.hasDistortion());
  EXPECT_DOUBLE_EQ(sim.params().fps, 30.0);
}

TEST(CameraYamlTest, SaveLoadRoundTrip) {
  TempDir tmp;
  const PinholeCamera cam = eurocCamera();
  cam.saveYaml(tmp.file("cam.yaml"));
  const PinholeCamera back = PinholeCamera::loadYaml(tmp.file("cam.yaml"));
  EXPECT_EQ(back.width(), cam.width());
  EXPECT_EQ(back.height(), cam.height());
  EXPECT_NEAR(back.params().fx, cam.params().fx, 1e-9);
  EXPECT_NEAR(back.params().cy, cam.params().cy, 1e-9);
  for (int k = 0; k < 5; ++k) EXPECT_NEAR(back.params().dist[k], cam.params().dist[k], 1e-12);
  EXPECT_DOUBLE_EQ(back.params().fps, 20.0);
}

// The message of the ecar::Error thrown by loadYaml(path), or "" when none is.
std::string loadError(const std::string& path) {
  try {
    PinholeCamera::loadYaml(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(CameraYamlTest, ErrorsNameTheFileAndTheKey) {
  TempDir tmp;
  const std::string missing_fy = tmp.file("missing_fy.yaml");
  writeText(missing_fy, "width: 640\nheight: 480\nfx: 500\ncx: 320\ncy: 240\n");
  std::string msg = loadError(missing_fy);
  EXPECT_NE(msg.find(missing_fy), std::string::npos) << msg;
  EXPECT_NE(msg.find("'fy'"), std::string::npos) << msg;

  const std::string bad_value = tmp.file("bad_value.yaml");
  writeText(bad_value, "width: 640\nheight: 480\nfx: five\nfy: 500\ncx: 320\ncy: 240\n");
  msg = loadError(bad_value);
  EXPECT_NE(msg.find(bad_value), std::string::npos) << msg;
  EXPECT_NE(msg.find("'fx'"), std::string::npos) << msg;

  const std::string bad_distortion = tmp.file("bad_distortion.yaml");
  writeText(bad_distortion,
            "width: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\ndistortion: [1, 2]\n");
  msg = loadError(bad_distortion);
  EXPECT_NE(msg.find(bad_distortion), std::string::npos) << msg;
  EXPECT_NE(msg.find("'distortion'"), std::string::npos) << msg;

  const std::string absent = tmp.file("does_not_exist.yaml");
  msg = loadError(absent);
  EXPECT_NE(msg.find(absent), std::string::npos) << msg;
}

}  // namespace
}  // namespace ecar
