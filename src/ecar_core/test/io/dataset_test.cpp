#include "ecar_core/io/dataset.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/io/dataset_writer.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

const std::string kDataDir = ECAR_REPO_ROOT "/../shared/data";
const std::string kCameraDir = ECAR_REPO_ROOT "/config/cameras";

#define SKIP_WITHOUT_REAL_DATA()                                                          \
  if (!fs::is_directory(kDataDir)) {                                                      \
    GTEST_SKIP() << "real test data not found at " << kDataDir << ": skipping this test"; \
  }

class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "ecar_dataset_test_XXXXXX").string();
    path_ = mkdtemp(pattern.data());
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const std::string& path() const { return path_; }
  std::string file(const std::string& name) const { return (fs::path(path_) / name).string(); }

 private:
  std::string path_;
};

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
}

// Replaces line `number` (1-based) of a text file.
void replaceLine(const std::string& path, int number, const std::string& replacement) {
  std::istringstream in(readText(path));
  std::string out, line;
  for (int n = 1; std::getline(in, line); ++n) out += (n == number ? replacement : line) + "\n";
  writeText(path, out);
}

// The message of the ecar::Error `f` throws; fails the test when it throws
// nothing (any other exception escapes and fails the test too).
template <typename F>
std::string errorOf(F f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected an ecar::Error";
  return "";
}

#define EXPECT_CONTAINS(text, part) \
  EXPECT_NE(std::string(text).find(part), std::string::npos) << "'" << (text) << "'"

// ---------------------------------------------------------------------------
// Real data (../shared/data)

TEST(DatasetRealDataTest, Kitti07) {
  SKIP_WITHOUT_REAL_DATA();
  const Dataset ds = Dataset::open(kDataDir + "/kitti07_0-159");
  EXPECT_EQ(ds.format(), DatasetFormat::kKitti);
  ASSERT_EQ(ds.size(), 160u);
  const CameraParams& p = ds.camera().params();
  EXPECT_EQ(p.width, 1226);
  EXPECT_EQ(p.height, 370);
  EXPECT_DOUBLE_EQ(p.fx, 707.0912);
  EXPECT_DOUBLE_EQ(p.fy, 707.0912);
  EXPECT_DOUBLE_EQ(p.cx, 601.8873);
  EXPECT_DOUBLE_EQ(p.cy, 183.1104);
  EXPECT_FALSE(ds.camera().hasDistortion());

  // The shipped camera file agrees with calib.txt.
  const PinholeCamera shipped = PinholeCamera::loadYaml(kCameraDir + "/kitti07.yaml");
  EXPECT_EQ(shipped.width(), p.width);
  EXPECT_EQ(shipped.height(), p.height);
  EXPECT_DOUBLE_EQ(shipped.params().fx, p.fx);
  EXPECT_DOUBLE_EQ(shipped.params().cx, p.cx);
  EXPECT_DOUBLE_EQ(shipped.params().cy, p.cy);

  ASSERT_TRUE(ds.hasGroundTruth());
  for (size_t i = 0; i < ds.size(); ++i) {
    ASSERT_TRUE(ds.frame(i).T_w_c_gt.has_value()) << "frame " << i;
    EXPECT_TRUE(fs::path(ds.frame(i).image_path).is_absolute());
    if (i > 0) {
      EXPECT_GT(ds.frame(i).timestamp, ds.frame(i - 1).timestamp);
    }
  }
  const Trajectory gt = ds.groundTruth();
  ASSERT_EQ(gt.size(), 160u);
  EXPECT_LT(gt.front().T_w_c.translation().norm(), 1e-9);
  double length = 0.0;
  for (size_t i = 1; i < gt.size(); ++i) {
    length += (gt[i].T_w_c.translation() - gt[i - 1].T_w_c.translation()).norm();
  }
  EXPECT_NEAR(length, 90.6, 1.0) << "README: about 90.6 m of driving";

  const cv::Mat first = ds.loadImage(0);
  EXPECT_EQ(first.cols, 1226);
  EXPECT_EQ(first.rows, 370);
  EXPECT_EQ(first.type(), CV_8UC1);
  EXPECT_EQ(ds.loadImage(159).size(), first.size());
  EXPECT_THROW(ds.frame(160), Error);
  EXPECT_THROW(ds.loadImage(160), Error);
  EXPECT_TRUE(ds.imu().empty());
}

TEST(DatasetRealDataTest, EurocV101) {
  SKIP_WITHOUT_REAL_DATA();
  const Dataset ds = Dataset::open(kDataDir + "/euroc_v1_01_cam0_0-94");
  EXPECT_EQ(ds.format(), DatasetFormat::kEuroc);
  ASSERT_EQ(ds.size(), 95u);
  const CameraParams& p = ds.camera().params();
  EXPECT_EQ(p.width, 752);
  EXPECT_EQ(p.height, 480);
  EXPECT_DOUBLE_EQ(p.fx, 458.654);
  EXPECT_DOUBLE_EQ(p.fy, 457.296);
  EXPECT_DOUBLE_EQ(p.cx, 367.215);
  EXPECT_DOUBLE_EQ(p.cy, 248.375);
  EXPECT_DOUBLE_EQ(p.dist[0], -0.28340811);
  EXPECT_DOUBLE_EQ(p.dist[3], 1.76187114e-05);
  EXPECT_DOUBLE_EQ(p.fps, 20.0);
  EXPECT_FALSE(ds.hasGroundTruth());
  EXPECT_TRUE(ds.groundTruth().empty());
  EXPECT_NEAR(ds.frame(1).timestamp - ds.frame(0).timestamp, 0.05, 1e-3);

  // 200 Hz IMU. Unlike its README says, the excerpt starts at the first image
  // (not 1 s before it); it does end 1 s after the last image.
  ASSERT_EQ(ds.imu().size(), 1141u);
  EXPECT_NEAR(ds.imu()[1].timestamp - ds.imu()[0].timestamp, 0.005, 1e-6);
  EXPECT_LE(ds.imu().front().timestamp, ds.frame(0).timestamp);
  EXPECT_NEAR(ds.imu().back().timestamp - ds.frame(94).timestamp, 1.0, 0.01);

  for (size_t i = 0; i < ds.size(); ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    const auto& g = ds.frame(i).gravity_c;
    ASSERT_TRUE(g.has_value());
    // The drone moves gently: the mean over 50 ms is close to gravity.
    EXPECT_NEAR(g->norm(), 9.81, 0.6);
    // The camera looks forward and somewhat down: "up" is mostly image-up
    // (-y) and a little towards the camera (-z), hardly sideways.
    const Eigen::Vector3d up = g->normalized();
    EXPECT_LT(up.y(), -0.8);
    EXPECT_LT(up.z(), 0.0);
    EXPECT_LT(std::abs(up.x()), 0.3);
  }

  const cv::Mat image = ds.loadImage(0);
  EXPECT_EQ(image.cols, 752);
  EXPECT_EQ(image.rows, 480);
  EXPECT_EQ(image.type(), CV_8UC1);
  EXPECT_EQ(ds.loadImage(94).size(), image.size());

  const PinholeCamera shipped = PinholeCamera::loadYaml(kCameraDir + "/euroc_cam0.yaml");
  for (int k = 0; k < 5; ++k) EXPECT_DOUBLE_EQ(shipped.params().dist[k], p.dist[k]);
}

TEST(DatasetRealDataTest, TumFr3OfficeSparse) {
  SKIP_WITHOUT_REAL_DATA();
  const Dataset ds = Dataset::open(kDataDir + "/tum_fr3_office_sparse17");
  EXPECT_EQ(ds.format(), DatasetFormat::kTum);
  ASSERT_EQ(ds.size(), 17u);
  // Intrinsics inferred from "fr3" in the folder name.
  const CameraParams& p = ds.camera().params();
  EXPECT_EQ(p.width, 640);
  EXPECT_EQ(p.height, 480);
  EXPECT_DOUBLE_EQ(p.fx, 535.4);
  EXPECT_DOUBLE_EQ(p.fy, 539.2);
  EXPECT_DOUBLE_EQ(p.cx, 320.1);
  EXPECT_DOUBLE_EQ(p.cy, 247.6);
  EXPECT_FALSE(ds.camera().hasDistortion());

  // The motion-capture poses start 67 ms after the first image: every frame
  // but the first has one within 20 ms.
  EXPECT_FALSE(ds.frame(0).T_w_c_gt.has_value());
  for (size_t i = 1; i < ds.size(); ++i) EXPECT_TRUE(ds.frame(i).T_w_c_gt.has_value()) << i;
  EXPECT_EQ(ds.groundTruth().size(), 16u);

  const cv::Mat image = ds.loadImage(0);
  EXPECT_EQ(image.cols, 640);
  EXPECT_EQ(image.rows, 480);
  EXPECT_EQ(image.type(), CV_8UC3);
  EXPECT_EQ(ds.loadImage(16, cv::IMREAD_GRAYSCALE).type(), CV_8UC1);

  // The shipped camera file gives the same intrinsics as an override.
  const Dataset overridden = Dataset::open(kDataDir + "/tum_fr3_office_sparse17",
                                           DatasetFormat::kTum, kCameraDir + "/tum_fr3.yaml");
  EXPECT_DOUBLE_EQ(overridden.camera().params().fy, 539.2);
  EXPECT_DOUBLE_EQ(overridden.camera().params().cx, 320.1);
  EXPECT_EQ(overridden.groundTruth().size(), 16u);
}

TEST(DatasetRealDataTest, TumFolderWithoutCameraNameNeedsACameraFile) {
  SKIP_WITHOUT_REAL_DATA();
  TempDir tmp;
  const std::string dir = tmp.file("office");  // no fr1/fr2/fr3 in the name
  fs::create_directory(dir);
  fs::copy_file(kDataDir + "/tum_fr3_office_sparse17/rgb.txt", dir + "/rgb.txt");
  fs::create_directory_symlink(kDataDir + "/tum_fr3_office_sparse17/rgb", dir + "/rgb");
  const std::string msg = errorOf([&] { Dataset::open(dir); });
  EXPECT_CONTAINS(msg, dir);
  EXPECT_CONTAINS(msg, "camera file");
  const Dataset ds = Dataset::open(dir, DatasetFormat::kAuto, kCameraDir + "/tum_fr3.yaml");
  EXPECT_EQ(ds.format(), DatasetFormat::kTum);
  EXPECT_EQ(ds.size(), 17u);
  EXPECT_FALSE(ds.hasGroundTruth());
}

// ---------------------------------------------------------------------------
// Writer -> reader round trip

struct SyntheticFrame {
  double timestamp;
  cv::Mat image;
  SE3 T_w_c;
  std::optional<Eigen::Vector3d> gravity_c;
  std::optional<SE3> T_o_c;
};

PinholeCamera smallCamera() {
  CameraParams p;
  p.width = 64;
  p.height = 48;
  p.fx = p.fy = 50.0;
  p.cx = 31.5;
  p.cy = 23.5;
  p.dist = {-0.1, 0.01, 0.001, -0.002, 0.0};
  p.fps = 30.0;
  return PinholeCamera(p);
}

std::vector<SyntheticFrame> syntheticFrames(const PinholeCamera& cam, int count) {
  cv::RNG rng(7);
  std::vector<SyntheticFrame> frames;
  for (int i = 0; i < count; ++i) {
    SyntheticFrame f;
    f.timestamp = 1000.0 + i / 30.0;
    f.image = cv::Mat(cam.height(), cam.width(), CV_8UC3);
    rng.fill(f.image, cv::RNG::UNIFORM, 0, 256);
    Vector6d xi;
    for (int k = 0; k < 6; ++k) xi[k] = rng.uniform(-1.0, 1.0);
    f.T_w_c = expSE3(xi);
    if (i % 2 == 0) f.gravity_c = Eigen::Vector3d(0.1 * i, -9.8, 0.3);
    if (i != 2) f.T_o_c = expSE3(0.5 * xi);
    frames.push_back(f);
  }
  return frames;
}

// Writes a sim dataset of `count` frames and 3 IMU samples per frame.
std::string writeSim(const TempDir& tmp, const std::vector<SyntheticFrame>& frames,
                     const PinholeCamera& cam, std::vector<ImuSample>* imu = nullptr) {
  const std::string dir = tmp.file("sim");
  DatasetWriter writer(dir, cam);
  for (const SyntheticFrame& f : frames) {
    for (int k = 0; k < 3; ++k) {
      ImuSample s;
      s.timestamp = f.timestamp + k * 0.01;
      s.acc_c = Eigen::Vector3d(0.01 * k, -9.81, 0.5) + f.T_w_c.translation();
      s.gyro_c = Eigen::Vector3d(0.1, -0.2, 0.3 * k);
      writer.addImu(s);
      if (imu) imu->push_back(s);
    }
    writer.addFrame(f.timestamp, f.image, f.T_w_c, f.gravity_c, f.T_o_c);
  }
  writer.finish();
  return dir;
}

void expectPoseNear(const SE3& a, const SE3& b, double tol) {
  EXPECT_LT((a.matrix() - b.matrix()).cwiseAbs().maxCoeff(), tol);
}

TEST(DatasetWriterTest, RoundTripThroughTheReader) {
  TempDir tmp;
  const PinholeCamera cam = smallCamera();
  const auto frames = syntheticFrames(cam, 5);
  std::vector<ImuSample> imu;
  const std::string dir = writeSim(tmp, frames, cam, &imu);

  const Dataset ds = Dataset::open(dir);
  EXPECT_EQ(ds.format(), DatasetFormat::kSim);
  ASSERT_EQ(ds.size(), frames.size());
  EXPECT_EQ(ds.camera().width(), cam.width());
  EXPECT_NEAR(ds.camera().params().fx, cam.params().fx, 1e-12);
  for (int k = 0; k < 5; ++k) {
    EXPECT_NEAR(ds.camera().params().dist[k], cam.params().dist[k], 1e-12);
  }
  EXPECT_DOUBLE_EQ(ds.camera().params().fps, 30.0);

  for (size_t i = 0; i < frames.size(); ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    const DatasetFrame& f = ds.frame(i);
    EXPECT_NEAR(f.timestamp, frames[i].timestamp, 1e-6);
    ASSERT_TRUE(f.T_w_c_gt.has_value());
    expectPoseNear(*f.T_w_c_gt, frames[i].T_w_c, 1e-12);
    ASSERT_EQ(f.gravity_c.has_value(), frames[i].gravity_c.has_value());
    if (f.gravity_c) {
      EXPECT_EQ(*f.gravity_c, *frames[i].gravity_c);
    }
    ASSERT_EQ(f.T_o_c_odom.has_value(), frames[i].T_o_c.has_value());
    if (f.T_o_c_odom) {
      expectPoseNear(*f.T_o_c_odom, *frames[i].T_o_c, 1e-12);
    }
    const cv::Mat image = ds.loadImage(i);
    ASSERT_EQ(image.size(), frames[i].image.size());
    EXPECT_EQ(cv::norm(image, frames[i].image, cv::NORM_INF), 0.0);
  }
  EXPECT_EQ(ds.groundTruth().size(), frames.size());

  ASSERT_EQ(ds.imu().size(), imu.size());
  for (size_t i = 0; i < imu.size(); ++i) {
    EXPECT_NEAR(ds.imu()[i].timestamp, imu[i].timestamp, 1e-9);
    EXPECT_EQ(ds.imu()[i].acc_c, imu[i].acc_c);
    EXPECT_EQ(ds.imu()[i].gyro_c, imu[i].gyro_c);
  }
}

TEST(DatasetWriterTest, RejectsBadInput) {
  TempDir tmp;
  const PinholeCamera cam = smallCamera();
  DatasetWriter writer(tmp.file("w"), cam);
  const cv::Mat image(cam.height(), cam.width(), CV_8UC1, cv::Scalar(0));
  writer.addFrame(1.0, image, SE3::Identity());
  EXPECT_THROW(writer.addFrame(1.0, image, SE3::Identity()), Error);  // same stamp
  EXPECT_THROW(writer.addFrame(2.0, cv::Mat(10, 10, CV_8UC1), SE3::Identity()), Error);
  EXPECT_THROW(writer.addFrame(2.0, cv::Mat(), SE3::Identity()), Error);
  SE3 bad = SE3::Identity();
  bad.translation().x() = std::nan("");
  EXPECT_THROW(writer.addFrame(2.0, image, bad), Error);
  EXPECT_EQ(writer.frameCount(), 1u);
  writer.finish();
  EXPECT_THROW(writer.addFrame(3.0, image, SE3::Identity()), Error);

  // A folder that cannot be created: a regular file is in the way.
  writeText(tmp.file("file"), "x");
  EXPECT_THROW(DatasetWriter(tmp.file("file/sub"), cam), Error);
}

TEST(DatasetWriterTest, DestructorFinishes) {
  TempDir tmp;
  const PinholeCamera cam = smallCamera();
  {
    DatasetWriter writer(tmp.file("d"), cam);
    writer.addFrame(0.5, cv::Mat(cam.height(), cam.width(), CV_8UC1, cv::Scalar(9)),
                    SE3::Identity());
  }
  const Dataset ds = Dataset::open(tmp.file("d"));
  EXPECT_EQ(ds.format(), DatasetFormat::kSim);
  EXPECT_EQ(ds.size(), 1u);
  EXPECT_TRUE(ds.imu().empty());
  EXPECT_FALSE(ds.frame(0).gravity_c.has_value());
  EXPECT_EQ(ds.loadImage(0).type(), CV_8UC1);
}

// ---------------------------------------------------------------------------
// Other layouts, built synthetically

void writePng(const std::string& path, int width, int height) {
  ASSERT_TRUE(cv::imwrite(path, cv::Mat(height, width, CV_8UC1, cv::Scalar(128))));
}

TEST(DatasetFormatsTest, KittiWithTimesAndPoses) {
  TempDir tmp;
  const std::string dir = tmp.file("kitti");
  fs::create_directories(dir + "/image_0");
  for (int i = 0; i < 3; ++i) writePng(dir + "/image_0/00000" + std::to_string(i) + ".png", 40, 20);
  writeText(dir + "/calib.txt",
            "P0: 100 0 20 0 0 110 10 0 0 0 1 0\nP1: 100 0 20 -50 0 110 10 0 0 0 1 0\n");
  writeText(dir + "/times.txt", "0.000000e+00\n1.0e-01\n2.0e-01\n");
  writeText(dir + "/poses.txt",
            "1 0 0 0 0 1 0 0 0 0 1 0\n"
            "1 0 0 0.1 0 1 0 0 0 0 1 1.5\n"
            "0 -1 0 0 1 0 0 0 0 0 1 3\n");
  const Dataset ds = Dataset::open(dir);
  EXPECT_EQ(ds.format(), DatasetFormat::kKitti);
  ASSERT_EQ(ds.size(), 3u);
  EXPECT_EQ(ds.camera().width(), 40);
  EXPECT_EQ(ds.camera().height(), 20);
  EXPECT_DOUBLE_EQ(ds.camera().params().fy, 110.0);
  EXPECT_DOUBLE_EQ(ds.frame(2).timestamp, 0.2);
  ASSERT_TRUE(ds.frame(1).T_w_c_gt.has_value());
  EXPECT_EQ(ds.frame(1).T_w_c_gt->translation(), Eigen::Vector3d(0.1, 0, 1.5));
  EXPECT_NEAR(ds.frame(2).T_w_c_gt->linear()(1, 0), 1.0, 1e-12);

  // A pose count that does not match the frames names poses.txt.
  writeText(dir + "/poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir); }), "poses.txt");
  // No P0 line.
  writeText(dir + "/poses.txt", "");
  fs::remove(dir + "/poses.txt");
  writeText(dir + "/calib.txt", "P1: 100 0 20 -50 0 110 10 0 0 0 1 0\n");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir); }), "calib.txt");
}

constexpr char kEurocSensorYaml[] = R"(%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [40, 20]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
)";

TEST(DatasetFormatsTest, EurocMavLayoutWithGroundTruth) {
  TempDir tmp;
  const std::string mav = tmp.file("seq/mav0");
  fs::create_directories(mav + "/cam0/data");
  fs::create_directories(mav + "/imu0");
  fs::create_directories(mav + "/state_groundtruth_estimate0");
  writeText(mav + "/cam0/sensor.yaml", kEurocSensorYaml);
  writePng(mav + "/cam0/data/1000000000.png", 40, 20);
  writePng(mav + "/cam0/data/1050000000.png", 40, 20);
  writeText(mav + "/cam0/data.csv",
            "#timestamp [ns],filename\r\n1000000000,1000000000.png\r\n"
            "1050000000,1050000000.png\r\n");
  // Body at rest, x axis up: the accelerometer reads +g along x.
  std::string imu = "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n";
  for (int64_t ns = 950000000; ns <= 1100000000; ns += 5000000) {
    imu += std::to_string(ns) + ",0.01,0.02,0.03,9.81,0,0\n";
  }
  writeText(mav + "/imu0/data.csv", imu);
  // Body moves along world x at 1 m/s; ground truth every 10 ms.
  std::string gt = "#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z,v_x,v_y,v_z\n";
  for (int64_t ns = 995000000; ns <= 1045000000; ns += 10000000) {
    gt += std::to_string(ns) + "," + std::to_string((ns - 1000000000) * 1e-9) +
          ",2,3,1,0,0,0,1,0,0\n";
  }
  writeText(mav + "/state_groundtruth_estimate0/data.csv", gt);

  const Dataset ds = Dataset::open(tmp.file("seq"));
  EXPECT_EQ(ds.format(), DatasetFormat::kEuroc);
  ASSERT_EQ(ds.size(), 2u);
  EXPECT_DOUBLE_EQ(ds.frame(1).timestamp, 1.05);
  EXPECT_EQ(ds.camera().width(), 40);

  Eigen::Matrix4d M;
  M << 0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975, 0.999557249008,
      0.0149672133247, 0.025715529948, -0.064676986768, -0.0257744366974, 0.00375618835797,
      0.999660727178, 0.00981073058949, 0, 0, 0, 1;
  const Eigen::Matrix3d R_b_c = M.topLeftCorner<3, 3>();
  // gravity_c = R_BS^T * a_b; the camera's -y (image up) is the body's +x.
  ASSERT_TRUE(ds.frame(0).gravity_c.has_value());
  EXPECT_LT((*ds.frame(0).gravity_c - R_b_c.transpose() * Eigen::Vector3d(9.81, 0, 0)).norm(),
            1e-3);
  EXPECT_LT(ds.frame(0).gravity_c->normalized().y(), -0.99);
  ASSERT_EQ(ds.imu().size(), 31u);
  EXPECT_LT((ds.imu()[0].gyro_c - R_b_c.transpose() * Eigen::Vector3d(0.01, 0.02, 0.03)).norm(),
            1e-3);

  // Frame 0 lies between two ground-truth samples: interpolated; frame 1 is
  // after the last one: no pose.
  ASSERT_TRUE(ds.frame(0).T_w_c_gt.has_value());
  EXPECT_FALSE(ds.frame(1).T_w_c_gt.has_value());
  SE3 T_w_b = SE3::Identity();
  T_w_b.translation() = Eigen::Vector3d(0.0, 2, 3);
  SE3 T_b_c = SE3::Identity();
  T_b_c.linear() = R_b_c;
  T_b_c.translation() = M.topRightCorner<3, 1>();
  expectPoseNear(*ds.frame(0).T_w_c_gt, T_w_b * T_b_c, 1e-6);
}

TEST(DatasetFormatsTest, EurocSensorYamlErrorsNameFileAndKey) {
  TempDir tmp;
  fs::create_directories(tmp.file("e/cam0/data"));
  writePng(tmp.file("e/cam0/data/1.png"), 40, 20);
  writeText(tmp.file("e/cam0/data.csv"), "1,1.png\n");
  std::string yaml = kEurocSensorYaml;
  yaml.replace(yaml.find("intrinsics"), 10, "intrinsicz");
  writeText(tmp.file("e/cam0/sensor.yaml"), yaml);
  const std::string msg = errorOf([&] { Dataset::open(tmp.file("e")); });
  EXPECT_CONTAINS(msg, "sensor.yaml");
  EXPECT_CONTAINS(msg, "'intrinsics'");
}

// ---------------------------------------------------------------------------
// Bad input: every case throws an ecar::Error naming the file (and line).

class DatasetBadInputTest : public ::testing::Test {
 protected:
  void SetUp() override {
    cam_ = smallCamera();
    dir_ = writeSim(tmp_, syntheticFrames(cam_, 4), cam_);
    rgb_txt_ = dir_ + "/rgb.txt";
  }
  // rgb.txt and groundtruth.txt start with 3 comment lines: frame i is on line 4 + i.
  static int lineOf(int frame) { return 4 + frame; }
  std::string imageOf(int frame) const {
    std::istringstream in(readText(rgb_txt_));
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      if (n == lineOf(frame)) return dir_ + "/" + line.substr(line.find(' ') + 1);
    }
    return "";
  }

  TempDir tmp_;
  PinholeCamera cam_;
  std::string dir_;
  std::string rgb_txt_;
};

TEST_F(DatasetBadInputTest, MissingFolder) {
  const std::string missing = tmp_.file("no_such_folder");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(missing); }), missing);
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(missing, DatasetFormat::kTum); }), missing);
}

TEST_F(DatasetBadInputTest, UnknownFormatName) {
  EXPECT_EQ(parseDatasetFormat("euroc"), DatasetFormat::kEuroc);
  EXPECT_EQ(parseDatasetFormat(toString(DatasetFormat::kSim)), DatasetFormat::kSim);
  EXPECT_CONTAINS(errorOf([] { parseDatasetFormat("rosbag"); }), "rosbag");
}

TEST_F(DatasetBadInputTest, MissingRgbTxt) {
  fs::remove(rgb_txt_);
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), "rgb.txt");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_, DatasetFormat::kSim); }), rgb_txt_);
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_, DatasetFormat::kTum); }), rgb_txt_);
}

TEST_F(DatasetBadInputTest, MissingListFilesOfOtherFormats) {
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_, DatasetFormat::kKitti); }), "calib.txt");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_, DatasetFormat::kEuroc); }), "data.csv");
}

TEST_F(DatasetBadInputTest, ListedImageMissing) {
  const std::string image = imageOf(2);
  fs::remove(image);
  const std::string msg = errorOf([&] { Dataset::open(dir_); });
  EXPECT_CONTAINS(msg, rgb_txt_ + ":" + std::to_string(lineOf(2)));
  EXPECT_CONTAINS(msg, image);
}

TEST_F(DatasetBadInputTest, MalformedRgbTxtLine) {
  const std::string at = rgb_txt_ + ":" + std::to_string(lineOf(1));
  replaceLine(rgb_txt_, lineOf(1), "1000.033333");  // filename missing
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), at);
  replaceLine(rgb_txt_, lineOf(1), "one rgb/1000.033333.png");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), at);
  replaceLine(rgb_txt_, lineOf(1), "nan rgb/1000.033333.png");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), at);
  replaceLine(rgb_txt_, lineOf(1), "999.0 rgb/1000.033333.png");  // goes back in time
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), at);
}

TEST_F(DatasetBadInputTest, MalformedGroundTruthLine) {
  const std::string gt = dir_ + "/groundtruth.txt";
  replaceLine(gt, lineOf(3), "1000.100000 0 0 0 0 0 zero 1");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), gt + ":" + std::to_string(lineOf(3)));
  replaceLine(gt, lineOf(3), "1000.100000 0 0 inf 0 0 0 1");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), gt + ":" + std::to_string(lineOf(3)));
  // A sim frame without its pose names the file and the frame's rgb.txt line.
  replaceLine(gt, lineOf(3), "# removed");
  const std::string msg = errorOf([&] { Dataset::open(dir_); });
  EXPECT_CONTAINS(msg, gt);
  EXPECT_CONTAINS(msg, rgb_txt_ + ":" + std::to_string(lineOf(3)));
}

TEST_F(DatasetBadInputTest, MalformedImuAndGravityLines) {
  replaceLine(dir_ + "/imu.txt", 5, "1000.01 1 2 3 4 5");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), dir_ + "/imu.txt:5");
  writeText(dir_ + "/imu.txt", "");
  replaceLine(dir_ + "/gravity.txt", 3, "1000.000000 0 -9.8");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), dir_ + "/gravity.txt:3");
  replaceLine(dir_ + "/gravity.txt", 3, "5.000000 0 -9.8 0");  // matches no frame
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), dir_ + "/gravity.txt:3");
}

TEST_F(DatasetBadInputTest, EmptyDataset) {
  writeText(rgb_txt_, "# timestamp filename\n\n");
  const std::string msg = errorOf([&] { Dataset::open(dir_); });
  EXPECT_CONTAINS(msg, dir_);
  EXPECT_CONTAINS(msg, "empty");
}

TEST_F(DatasetBadInputTest, CorruptPngOnLoadImage) {
  const Dataset ds = Dataset::open(dir_);
  const std::string image = imageOf(1);
  writeText(image, "this is not a PNG file \x01\x02\x03");
  const std::string msg = errorOf([&] { ds.loadImage(1); });
  EXPECT_CONTAINS(msg, image);
  EXPECT_CONTAINS(msg, rgb_txt_ + ":" + std::to_string(lineOf(1)));
  // A truncated PNG (valid signature, then garbage) too.
  writeText(image, std::string("\x89PNG\r\n\x1a\n", 8) + "garbage garbage garbage");
  EXPECT_CONTAINS(errorOf([&] { ds.loadImage(1); }), image);
  // An empty file, and a file deleted after open().
  writeText(image, "");
  EXPECT_CONTAINS(errorOf([&] { ds.loadImage(1); }), image);
  fs::remove(image);
  EXPECT_CONTAINS(errorOf([&] { ds.loadImage(1); }), image);
  // The other frames still load.
  EXPECT_EQ(ds.loadImage(0).cols, cam_.width());
}

TEST_F(DatasetBadInputTest, ImageOfTheWrongSize) {
  const Dataset ds = Dataset::open(dir_);
  const std::string image = imageOf(3);
  writePng(image, cam_.width() + 1, cam_.height());
  const std::string msg = errorOf([&] { ds.loadImage(3); });
  EXPECT_CONTAINS(msg, image);
  EXPECT_CONTAINS(msg, rgb_txt_ + ":" + std::to_string(lineOf(3)));
  EXPECT_CONTAINS(msg, std::to_string(cam_.width() + 1) + "x" + std::to_string(cam_.height()));
}

TEST_F(DatasetBadInputTest, BadCameraFile) {
  writeText(dir_ + "/camera.yaml", "width: 64\nheight: 48\nfx: 50\n");
  const std::string msg = errorOf([&] { Dataset::open(dir_); });
  EXPECT_CONTAINS(msg, dir_ + "/camera.yaml");
  EXPECT_CONTAINS(msg, "'fy'");
  const std::string missing = tmp_.file("nope.yaml");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_, DatasetFormat::kSim, missing); }), missing);
}

// ---------------------------------------------------------------------------
// touches.txt

TouchEvent touchOn(const std::vector<SyntheticFrame>& frames, size_t frame, TouchPhase phase,
                   double u, double v) {
  TouchEvent e;
  e.frame = frame;
  e.timestamp = frames[frame].timestamp;
  e.phase = phase;
  e.uv = Eigen::Vector2d(u, v);
  return e;
}

TEST(DatasetTouchesTest, WriterAndReaderRoundTrip) {
  TempDir tmp;
  const PinholeCamera cam = smallCamera();
  const auto frames = syntheticFrames(cam, 5);
  const std::string dir = tmp.file("sim");
  std::vector<TouchEvent> touches = {
      touchOn(frames, 0, TouchPhase::kBegin, 1.0 / 3.0, 47.25),
      touchOn(frames, 1, TouchPhase::kMove, 2.5, 40.0),
      touchOn(frames, 2, TouchPhase::kEnd, 63.49, -0.5),
      touchOn(frames, 2, TouchPhase::kBegin, 10, 10),  // two events on one frame
      touchOn(frames, 4, TouchPhase::kEnd, 11, 12),
  };
  touches[1].r = 0;
  touches[1].g = 128;
  touches[1].b = 255;
  touches[1].width = 0.1 / 3.0;
  {
    DatasetWriter writer(dir, cam);
    for (size_t i = 0; i < frames.size(); ++i) {
      writer.addFrame(frames[i].timestamp, frames[i].image, frames[i].T_w_c);
      for (const TouchEvent& e : touches) {
        if (e.frame == i) writer.addTouch(e);
      }
    }
    EXPECT_EQ(writer.touchCount(), touches.size());
    writer.finish();
  }
  const std::string text = readText(dir + "/touches.txt");
  EXPECT_EQ(text.rfind("# scripted touches", 0), 0u) << text;
  EXPECT_CONTAINS(text, "# timestamp frame_index u v phase r g b width\n");
  EXPECT_CONTAINS(text, "1000.033333 1 2.5 40 move 0 128 255 ");

  const Dataset ds = Dataset::open(dir);
  ASSERT_EQ(ds.touches().size(), touches.size());
  for (size_t k = 0; k < touches.size(); ++k) {
    SCOPED_TRACE("touch " + std::to_string(k));
    const TouchEvent& got = ds.touches()[k];
    const TouchEvent& want = touches[k];
    EXPECT_EQ(got.frame, want.frame);
    EXPECT_DOUBLE_EQ(got.timestamp, ds.frame(want.frame).timestamp);
    EXPECT_EQ(got.uv, want.uv);  // 17 significant digits: exact
    EXPECT_EQ(got.phase, want.phase);
    EXPECT_EQ(got.r, want.r);
    EXPECT_EQ(got.g, want.g);
    EXPECT_EQ(got.b, want.b);
    EXPECT_EQ(got.width, want.width);
  }

  // A later run without touches in the same folder leaves none behind.
  writeSim(tmp, frames, cam);
  EXPECT_FALSE(fs::exists(dir + "/touches.txt"));
  EXPECT_TRUE(Dataset::open(dir).touches().empty());
}

TEST(DatasetTouchesTest, WriterRejectsBadTouches) {
  TempDir tmp;
  const PinholeCamera cam = smallCamera();
  const auto frames = syntheticFrames(cam, 3);
  DatasetWriter writer(tmp.file("w"), cam);
  writer.addFrame(frames[0].timestamp, frames[0].image, frames[0].T_w_c);
  EXPECT_THROW(writer.addTouch(touchOn(frames, 1, TouchPhase::kBegin, 1, 1)), Error);  // no frame
  EXPECT_THROW(writer.addTouch(touchOn(frames, 0, TouchPhase::kMove, 1, 1)), Error);   // no begin
  TouchEvent e = touchOn(frames, 0, TouchPhase::kBegin, 1, 1);
  e.timestamp += 0.01;
  EXPECT_THROW(writer.addTouch(e), Error);                                              // stamp
  EXPECT_THROW(writer.addTouch(touchOn(frames, 0, TouchPhase::kBegin, 64, 1)), Error);  // outside
  e = touchOn(frames, 0, TouchPhase::kBegin, 1, 1);
  e.width = 0;
  EXPECT_THROW(writer.addTouch(e), Error);
  EXPECT_EQ(writer.touchCount(), 0u);
  writer.addTouch(touchOn(frames, 0, TouchPhase::kBegin, 1, 1));
  EXPECT_THROW(writer.addTouch(touchOn(frames, 0, TouchPhase::kBegin, 1, 1)), Error);  // open
  writer.addFrame(frames[1].timestamp, frames[1].image, frames[1].T_w_c);
  writer.addTouch(touchOn(frames, 1, TouchPhase::kMove, 2, 2));
  EXPECT_THROW(writer.addTouch(touchOn(frames, 0, TouchPhase::kEnd, 1, 1)), Error);  // back
  EXPECT_EQ(writer.touchCount(), 2u);
  EXPECT_CONTAINS(errorOf([&] { writer.finish(); }), "the last stroke has no end");
}

TEST_F(DatasetBadInputTest, MalformedTouchesLineNamesFileAndLine) {
  const std::string file = dir_ + "/touches.txt";
  // Frame stamps: 1000 + i / 30 (4 frames).
  const std::string header = "# touches\n";
  const std::string begin = "1000.000000 0 10 10 begin 255 64 32 0.03\n";
  const std::string end = "1000.100000 3 12 12 end 255 64 32 0.03\n";
  writeText(file, header + begin + "1000.033333 1 11 11 move 1 2 3 0.5\n" + end);
  ASSERT_EQ(Dataset::open(dir_).touches().size(), 3u);
  EXPECT_EQ(Dataset::open(dir_).touches()[1].phase, TouchPhase::kMove);
  struct Case {
    std::string line, expected;
  } cases[] = {
      {"1000.033333 1 11 11 move 1 2 3", "expected 9 fields"},
      {"1000.033333 4 11 11 move 1 2 3 0.5", "frame_index '4' is not an integer in [0, 3]"},
      {"1000.033333 -1 11 11 move 1 2 3 0.5", "frame_index '-1'"},
      {"1000.033333 1.0 11 11 move 1 2 3 0.5", "frame_index '1.0'"},
      {"1000.066667 1 11 11 move 1 2 3 0.5", "is not the stamp of frame 1"},
      {"1000.033333 1 11 nan move 1 2 3 0.5", "v 'nan' is not"},
      {"1000.033333 1 11 48 move 1 2 3 0.5", "outside the 64x48 image"},
      {"1000.033333 1 11 11 drag 1 2 3 0.5", "phase 'drag' is not begin, move or end"},
      {"1000.033333 1 11 11 move 1 256 3 0.5", "g '256' is not an integer in [0, 255]"},
      {"1000.033333 1 11 11 move 1 2 3 0", "width 0 must be > 0"},
      {"1000.033333 1 11 11 begin 1 2 3 0.5", "phase 'begin' inside a stroke"},
  };
  for (const auto& c : cases) {
    writeText(file, header + begin + c.line + "\n" + end);
    const std::string msg = errorOf([&] { Dataset::open(dir_); });
    EXPECT_CONTAINS(msg, file + ":3: ");
    EXPECT_CONTAINS(msg, c.expected);
  }
  // Order and whole strokes.
  writeText(file, header + end + begin);
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), file + ":3: frame_index 0 is before");
  writeText(file, header + "1000.033333 1 11 11 move 1 2 3 0.5\n");
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }),
                  file + ":2: phase 'move' without a 'begin' before");
  writeText(file, header + begin);
  EXPECT_CONTAINS(errorOf([&] { Dataset::open(dir_); }), file + ": the last stroke has no 'end'");
}

}  // namespace
}  // namespace ecar
