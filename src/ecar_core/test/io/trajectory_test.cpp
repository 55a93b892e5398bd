#include "ecar_core/io/trajectory.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

// A fresh directory under the system temp dir, removed with its contents.
class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "ecar_trajectory_test_XXXXXX").string();
    if (mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  fs::path path_;
};

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

Trajectory randomTrajectory(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Trajectory traj;
  double t = 1341847980.79;  // a TUM-like stamp: needs all 17 significant digits
  for (size_t k = 0; k < n; ++k) {
    t += 0.033 + 0.001 * u(rng);
    Vector6d xi;
    xi << 3 * u(rng), 3 * u(rng), 3 * u(rng), 100 * u(rng), 100 * u(rng), 1e-7 * u(rng);
    StampedPose pose;
    pose.timestamp = t;
    pose.T_w_c = expSE3(xi);
    traj.push_back(pose);
  }
  return traj;
}

TEST(TrajectoryTest, WriteReadRoundTripIsExact) {
  TempDir dir;
  const std::string path = dir.file("traj.txt");
  const Trajectory traj = randomTrajectory(100, 7);
  writeTum(path, traj, "a comment\nover two lines");
  const Trajectory back = readTum(path);
  ASSERT_EQ(back.size(), traj.size());
  for (size_t k = 0; k < traj.size(); ++k) {
    EXPECT_EQ(back[k].timestamp, traj[k].timestamp) << k;  // shortest round-trip text
    EXPECT_EQ(back[k].T_w_c.translation(), traj[k].T_w_c.translation()) << k;
    EXPECT_TRUE(back[k].T_w_c.linear().isApprox(traj[k].T_w_c.linear(), 1e-14)) << k;
  }
  std::ifstream in(path);
  std::string first;
  std::getline(in, first);
  EXPECT_EQ(first, "# a comment");
}

TEST(TrajectoryTest, ReadSkipsCommentsBlankLinesAndCarriageReturns) {
  TempDir dir;
  const std::string path = dir.file("tum.txt");
  writeText(path,
            "# ground truth trajectory\r\n"
            "\r\n"
            "   \t\n"
            "  # indented comment\n"
            "1.5 1 2 3 0 0 0 1\r\n"
            "2.5\t-1 -2 -3 0 0 0.7071067811865476 0.7071067811865476\n"
            "3.5 +1e-3 2E2 .5 0 0 0 2");  // no final newline; '+', exponents, non-unit quaternion
  const Trajectory traj = readTum(path);
  ASSERT_EQ(traj.size(), 3u);
  EXPECT_EQ(traj[0].timestamp, 1.5);
  EXPECT_TRUE(traj[0].T_w_c.isApprox(makeSE3(Eigen::Quaterniond::Identity(), {1, 2, 3})));
  EXPECT_TRUE((traj[1].T_w_c.linear() * Eigen::Vector3d::UnitX())
                  .isApprox(Eigen::Vector3d::UnitY(), 1e-12));
  EXPECT_TRUE(traj[2].T_w_c.translation().isApprox(Eigen::Vector3d(1e-3, 200, 0.5)));
  EXPECT_TRUE(traj[2].T_w_c.linear().isIdentity());
}

TEST(TrajectoryTest, ReadMissingFileNamesIt) {
  const std::string path = "/nonexistent/ecar/traj.txt";
  try {
    readTum(path);
    FAIL() << "expected ecar::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

struct MalformedCase {
  const char* name;
  const char* bad_line;
  const char* expected_text;  // also in the message, besides file and line
};

TEST(TrajectoryTest, MalformedLinesNameFileAndLine) {
  const MalformedCase cases[] = {
      {"too_few_fields", "4.0 1 2 3 0 0 1", "got 7"},
      {"too_many_fields", "4.0 1 2 3 0 0 0 1 9", "got 9"},
      {"non_numeric", "4.0 1 two 3 0 0 0 1", "ty"},
      {"trailing_garbage", "4.0 1 2 3x 0 0 0 1", "tz"},
      {"nan", "4.0 1 2 nan 0 0 0 1", "not finite"},
      {"inf", "4.0 1 2 3 0 0 0 inf", "not finite"},
      {"overflow", "1e999 1 2 3 0 0 0 1", "not finite"},
      {"zero_quaternion", "4.0 1 2 3 0 0 0 0", "quaternion"},
      {"comma_separated", "4.0,1,2,3,0,0,0,1", "got 1"},
  };
  TempDir dir;
  for (const MalformedCase& c : cases) {
    const std::string path = dir.file(std::string(c.name) + ".txt");
    // Line 5 is bad: comment, two good lines, blank, bad.
    writeText(path, std::string("# t x y z qx qy qz qw\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n\n") +
                        c.bad_line + "\n3 0 0 0 0 0 0 1\n");
    try {
      readTum(path);
      ADD_FAILURE() << c.name << ": expected ecar::Error";
    } catch (const Error& e) {
      const std::string message = e.what();
      EXPECT_NE(message.find(path + ":5:"), std::string::npos) << c.name << ": " << message;
      EXPECT_NE(message.find(c.expected_text), std::string::npos) << c.name << ": " << message;
    }
  }
}

TEST(TrajectoryTest, WriteToUnwritablePathThrows) {
  EXPECT_THROW(writeTum("/nonexistent/dir/out.txt", randomTrajectory(2, 1)), Error);
}

TEST(TrajectoryTest, WriteRejectsNonFinitePose) {
  TempDir dir;
  Trajectory traj = randomTrajectory(3, 2);
  traj[1].T_w_c.translation().y() = std::nan("");
  EXPECT_THROW(writeTum(dir.file("nan.txt"), traj), Error);
}

TEST(TrajectoryTest, Timestamps) {
  const Trajectory traj = randomTrajectory(5, 3);
  const std::vector<double> stamps = timestamps(traj);
  ASSERT_EQ(stamps.size(), 5u);
  for (size_t k = 0; k < 5; ++k) EXPECT_EQ(stamps[k], traj[k].timestamp);
}

using Matches = std::vector<std::pair<size_t, size_t>>;

TEST(TrajectoryTest, AssociateExactAndWithinTolerance) {
  const std::vector<double> a = {0.0, 1.0, 2.0, 3.0};
  const std::vector<double> b = {0.005, 1.03, 1.99, 5.0};
  EXPECT_EQ(associate(a, b, 0.02), (Matches{{0, 0}, {2, 2}}));
  EXPECT_EQ(associate(a, b, 0.05), (Matches{{0, 0}, {1, 1}, {2, 2}}));
  EXPECT_TRUE(associate(a, {}, 0.02).empty());
  EXPECT_TRUE(associate({}, b, 0.02).empty());
}

TEST(TrajectoryTest, AssociateIsGreedyBySmallestDifference) {
  // b[0] is within max_dt of a[0] (0.04) and a[1] (0.01): a[1] wins it first, which leaves
  // a[0] unmatched; then b[1] (0.04 from a[1], 0.03 from a[2]) goes to a[2].
  const std::vector<double> a = {0.00, 0.05, 0.12};
  const std::vector<double> b = {0.04, 0.09};
  EXPECT_EQ(associate(a, b, 0.05), (Matches{{1, 0}, {2, 1}}));
  // Each index at most once, even with duplicates.
  EXPECT_EQ(associate({1.0, 1.0}, {1.0}, 0.1), (Matches{{0, 0}}));
}

TEST(TrajectoryTest, AssociateHandlesUnsortedInputAndOffset) {
  const std::vector<double> a = {3.0, 1.0, 2.0};
  const std::vector<double> b = {11.0, 13.001, 12.0};
  EXPECT_TRUE(associate(a, b, 0.01).empty());
  EXPECT_EQ(associate(a, b, 0.01, -10.0), (Matches{{0, 1}, {1, 0}, {2, 2}}));
  EXPECT_THROW(associate(a, b, -1.0), Error);
}

TEST(TrajectoryTest, AssociateMatchesBruteForceOnRandomStamps) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::vector<double> a(300), b(200);
  for (double& t : a) t = u(rng);
  for (double& t : b) t = u(rng);
  const double max_dt = 0.03;
  const Matches matches = associate(a, b, max_dt);
  std::vector<int> used_a(a.size(), 0), used_b(b.size(), 0);
  for (const auto& [i, j] : matches) {
    EXPECT_LE(std::abs(a[i] - b[j]), max_dt);
    ++used_a[i];
    ++used_b[j];
  }
  for (int c : used_a) EXPECT_LE(c, 1);
  for (int c : used_b) EXPECT_LE(c, 1);
  // Maximal: no unused pair within max_dt remains.
  for (size_t i = 0; i < a.size(); ++i) {
    for (size_t j = 0; j < b.size(); ++j) {
      if (!used_a[i] && !used_b[j]) {
        EXPECT_GT(std::abs(a[i] - b[j]), max_dt);
      }
    }
  }
  EXPECT_TRUE(std::is_sorted(matches.begin(), matches.end()));
}

}  // namespace
}  // namespace ecar
