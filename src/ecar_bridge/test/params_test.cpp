// Reading parameters: typed reads, defaults kept, errors naming the key,
// nested namespaces, unknown keys, and YAML files as rosparam loads them.
#include "ecar_bridge/params.h"

#include <cstdio>
#include <fstream>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar_bridge {
namespace {

XmlRpc::XmlRpcValue sample() {
  const std::string path = testing::TempDir() + "/params_test.yaml";
  std::ofstream(path) << "every: 8\nratio: 2\nname: dev\nquoted: \"12\"\nflag: true\n"
                         "bounds: [1, -2.5, 3]\ntracking:\n  radius: 4.5\n  typo: 1\nextra: x\n";
  return paramsFromYaml(path);
}

TEST(ParamReaderTest, ReadsTypedValuesAndKeepsDefaults) {
  ParamReader r(sample(), "~");
  int every = 4, missing = 7;
  double ratio = 0.0;
  std::string name, quoted;
  bool flag = false;
  Eigen::Vector3d bounds = Eigen::Vector3d::Zero();
  r.read("every", &every);
  r.read("missing", &missing);
  r.read("ratio", &ratio);  // an integer where a double is read
  r.read("name", &name);
  r.read("quoted", &quoted);
  r.read("flag", &flag);
  r.read("bounds", &bounds);
  EXPECT_EQ(every, 8);
  EXPECT_EQ(missing, 7);
  EXPECT_DOUBLE_EQ(ratio, 2.0);
  EXPECT_EQ(name, "dev");
  EXPECT_EQ(quoted, "12");
  EXPECT_TRUE(flag);
  EXPECT_EQ(bounds, Eigen::Vector3d(1, -2.5, 3));
  double radius = 0.0;
  r.child("tracking").read("radius", &radius);
  EXPECT_DOUBLE_EQ(radius, 4.5);
  EXPECT_EQ(r.unknown(), (std::vector<std::string>{"extra", "tracking/typo"}));
}

TEST(ParamReaderTest, WrongTypesNameTheParameter) {
  ParamReader r(sample(), "/edge_server/");
  int i = 0;
  try {
    r.read("name", &i);
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_EQ(std::string(e.what()), "/edge_server/name: expected an integer");
  }
  double d = 0.0;
  EXPECT_THROW(r.read("flag", &d), ecar::Error);
  Eigen::Vector3d v;
  EXPECT_THROW(r.read("name", &v), ecar::Error);
  EXPECT_THROW(r.child("every"), ecar::Error);
  try {
    double x = 0.0;
    ParamReader& t = r.child("tracking");
    t.read("radius", &x);
    std::string s;
    t.read("radius", &s);
    FAIL() << "no error";
  } catch (const ecar::Error& e) {
    EXPECT_EQ(std::string(e.what()), "/edge_server/tracking/radius: expected a string");
  }
  EXPECT_THROW(paramsFromYaml("/nonexistent/params.yaml"), ecar::Error);
}

}  // namespace
}  // namespace ecar_bridge
