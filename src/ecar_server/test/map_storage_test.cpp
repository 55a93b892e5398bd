// saveServerMap / loadServerMap on ServerContexts without ROS: a server's
// planes, grid links and VOs (and its empty SLAM map's camera and counters)
// come back in a fresh server, which creates its SLAM system from the file;
// bad files and paths fail naming the path with nothing changed; keyframe
// inputs copied before a load are dropped.
#include "ecar_server/map_storage.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "../../ecar_core/test/test_support.h"
#include "ecar_core/common/error.h"
#include "structure_fixtures.h"

namespace ecar_server {
namespace {

using ecar_server::testing::camera640;
using ecar_server::testing::floorKeyFrame;
using ecar_server::testing::lookingAlongX;

using ecar::testing::contains;
using ecar::testing::TempDir;

namespace fs = std::filesystem;

ServerConfig configWith(const std::string& database) {
  ServerConfig c;
  c.vo.database_path = database;
  return c;
}

ecar::VirtualObject lineAt(double x) {
  ecar::VirtualObject vo;
  vo.start = Eigen::Vector3d(x, 0.2, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, 0.2, 0.0);
  vo.width = 0.05f;
  vo.owner = "device_0";
  return vo;
}

// A server with a floor plane, its keyframe's cells and two objects (one moved).
void fill(ServerContext* ctx) {
  ctx->slamFor(camera640());
  Structure& s = ctx->structure();
  const ecar::SE3 T_w_c = lookingAlongX(0.0);
  const auto grid = s.gridConnection(camera640());
  ASSERT_EQ(s.integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(1), T_w_c), T_w_c, *grid)
                .update.created.size(),
            1u);
  const ecar::VoOutcome a = s.vos().registerObject(lineAt(2.0));
  ASSERT_TRUE(a.accepted) << a.reason;
  ASSERT_TRUE(s.vos().manipulate(a.id, 1, lineAt(2.5), "device_1").accepted);
  ASSERT_TRUE(s.vos().registerObject(lineAt(4.0)).accepted);
}

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const ecar::Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no ecar::Error thrown";
  return {};
}

TEST(MapStorageTest, AFreshServerResumesTheSavedMap) {
  const TempDir dir;
  ServerContext first(configWith(dir.file("first.sqlite")), 100);
  fill(&first);
  const MapCounts saved = saveServerMap(first, dir.file("map.ecarmap"));
  EXPECT_EQ(saved.planes, 1u);
  EXPECT_EQ(saved.objects, 2u);
  EXPECT_EQ(saved.keyframes, 0u);
  EXPECT_GT(saved.bytes, 0u);

  ServerContext second(configWith(dir.file("second.sqlite")), 5000);
  ASSERT_FALSE(second.slam());
  const uint32_t epoch = second.mapEpoch();
  const uint64_t generation = second.structure().generation();
  const MapCounts loaded = loadServerMap(second, dir.file("map.ecarmap"), 10.0);
  EXPECT_EQ(loaded.planes, 1u);
  EXPECT_EQ(loaded.objects, 2u);
  ASSERT_TRUE(second.slam());  // created with the file's camera
  EXPECT_EQ(second.slam()->camera().params().fx, 525.0);
  EXPECT_NE(second.mapEpoch(), epoch);
  EXPECT_EQ(second.structure().generation(), generation + 1);

  const auto planes1 = first.structure().planes().planes();
  const auto planes2 = second.structure().planes().planes();
  ASSERT_EQ(planes2.size(), 1u);
  EXPECT_EQ(planes2[0].id, planes1[0].id);
  EXPECT_EQ(planes2[0].version, planes1[0].version);
  EXPECT_EQ(planes2[0].normal, planes1[0].normal);
  EXPECT_EQ(planes2[0].boundary, planes1[0].boundary);
  EXPECT_EQ(second.structure().planes().nextId(), first.structure().planes().nextId());
  EXPECT_EQ(second.structure().grid().save(), first.structure().grid().save());
  const auto vos1 = first.structure().vos().allObjects();
  const auto vos2 = second.structure().vos().allObjects();
  ASSERT_EQ(vos2.size(), 2u);
  for (size_t i = 0; i < vos1.size(); ++i) {
    EXPECT_EQ(vos2[i].id, vos1[i].id);
    EXPECT_EQ(vos2[i].version, vos1[i].version);
    EXPECT_EQ(vos2[i].position, vos1[i].position);
  }
  // The planes are cast again (the GridPlanes snapshot was rebuilt).
  EXPECT_EQ(second.structure().gridPlanes()->size(), 1u);
  // Graphs of uploads received before the load finished are not sent.
  EXPECT_TRUE(second.mapStale(9.0));
  EXPECT_FALSE(second.mapStale(11.0));
  // A keyframe copied before the load is dropped; one copied after is integrated.
  const ecar::SE3 T_w_c = lookingAlongX(1.0);
  const auto grid = second.structure().gridConnection(camera640());
  EXPECT_TRUE(
      second.structure()
          .integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(2), T_w_c), T_w_c, *grid, generation)
          .stale);
  EXPECT_EQ(second.structure().grid().numKeyFrames(), 1u);
  EXPECT_FALSE(second.structure()
                   .integrateKeyFrame(floorKeyFrame(ecar::KeyFrameId(2), T_w_c), T_w_c, *grid,
                                      second.structure().generation())
                   .stale);
  EXPECT_EQ(second.structure().grid().numKeyFrames(), 2u);
}

TEST(MapStorageTest, BadFilesAndPathsFailNamingThePathAndChangeNothing) {
  const TempDir dir;
  ServerContext server(configWith(dir.file("a.sqlite")), 100);
  EXPECT_TRUE(contains(errorOf([&] { saveServerMap(server, dir.file("m.ecarmap")); }),
                       "no device has connected"));
  fill(&server);
  const std::string good = dir.file("good.ecarmap");
  saveServerMap(server, good);
  const std::string unwritable = dir.file("no_such_dir/x.ecarmap");
  EXPECT_TRUE(contains(errorOf([&] { saveServerMap(server, unwritable); }), unwritable));

  // The server now differs from the file: one more object.
  ASSERT_TRUE(server.structure().vos().registerObject(lineAt(5.0)).accepted);
  const uint32_t epoch = server.mapEpoch();
  const uint64_t generation = server.structure().generation();

  std::ifstream in(good, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), {});
  bytes[bytes.size() - 30] ^= 0x5a;  // inside the last section, "vos"
  const std::string corrupt = dir.file("corrupt.ecarmap");
  std::ofstream(corrupt, std::ios::binary).write(bytes.data(), bytes.size());
  std::string error = errorOf([&] { loadServerMap(server, corrupt, 1.0); });
  EXPECT_TRUE(contains(error, corrupt) && contains(error, "section 'vos'")) << error;
  const std::string missing = dir.file("missing.ecarmap");
  error = errorOf([&] { loadServerMap(server, missing, 1.0); });
  EXPECT_TRUE(contains(error, missing)) << error;

  EXPECT_EQ(server.structure().vos().numObjects(), 3u);
  EXPECT_EQ(server.mapEpoch(), epoch);
  EXPECT_EQ(server.structure().generation(), generation);
  EXPECT_FALSE(server.mapStale(0.5));  // failed loads leave the graphs alone

  // A map made with another camera is refused by a server that has one.
  ecar::CameraParams other = camera640().params();
  other.fx = 400.0;
  ServerContext foreign(configWith(dir.file("b.sqlite")), 100);
  foreign.slamFor(ecar::PinholeCamera(other));
  error = errorOf([&] { loadServerMap(foreign, good, 1.0); });
  EXPECT_TRUE(contains(error, "camera.fx")) << error;
  EXPECT_EQ(foreign.structure().vos().numObjects(), 0u);
}

}  // namespace
}  // namespace ecar_server
