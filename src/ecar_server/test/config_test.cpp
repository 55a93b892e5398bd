// The server's parameters: config/server.yaml (every key known, and the
// documented values are the defaults), wrong types and values naming the key,
// unknown keys, the configs handed to the core, and the shared global graph.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "ecar_bridge/params.h"
#include "ecar_core/common/error.h"
#include "ecar_server/config.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {
namespace {

const std::string kServerYaml = ECAR_REPO_ROOT "/config/server.yaml";

TEST(ServerConfigTest, ShippedYamlHasOnlyKnownKeysWithTheDefaults) {
  std::vector<std::string> unknown;
  const ServerConfig c =
      parseServerConfig(ecar_bridge::paramsFromYaml(kServerYaml), "/edge_server/", &unknown);
  EXPECT_TRUE(unknown.empty()) << "unknown key in config/server.yaml: " << unknown.front();
  const ServerConfig d;
  EXPECT_EQ(c.sync_mode, d.sync_mode);
  EXPECT_EQ(c.workers, d.workers);
  EXPECT_DOUBLE_EQ(c.position_tolerance, d.position_tolerance);
  EXPECT_DOUBLE_EQ(c.position_tolerance_deg, d.position_tolerance_deg);
  EXPECT_DOUBLE_EQ(c.position_tolerance_depth, d.position_tolerance_depth);
  EXPECT_EQ(c.graph_plane_refresh, d.graph_plane_refresh);
  EXPECT_DOUBLE_EQ(c.plane_resend_offset, d.plane_resend_offset);
  EXPECT_EQ(c.grid.window, d.grid.window);
  EXPECT_EQ(c.vo_share, d.vo_share);
  EXPECT_EQ(c.vo.attach_mode, d.vo.attach_mode);
  EXPECT_EQ(c.background_nice, d.background_nice);
  EXPECT_EQ(c.loop_by_odometry, d.loop_by_odometry);
  EXPECT_DOUBLE_EQ(c.loop_odometry_max_gap, d.loop_odometry_max_gap);
  EXPECT_EQ(c.loop_odometry_min_hops, d.loop_odometry_min_hops);
  EXPECT_DOUBLE_EQ(c.loop_odometry_max_drift_per_link, d.loop_odometry_max_drift_per_link);
  EXPECT_DOUBLE_EQ(c.uplink_capacity, d.uplink_capacity);
  EXPECT_DOUBLE_EQ(c.uplink_utilisation, d.uplink_utilisation);
}

TEST(ServerConfigTest, UnknownKeysAndWrongTypesAreNamed) {
  XmlRpc::XmlRpcValue params = ecar_bridge::paramsFromYaml(kServerYaml);
  params["planes"]["graph_plane_refrsh"] = 3;
  params["workrs"] = 2;
  std::vector<std::string> unknown;
  parseServerConfig(params, "/edge_server/", &unknown);
  EXPECT_EQ(unknown, (std::vector<std::string>{"workrs", "planes/graph_plane_refrsh"}));
  params["vo"]["share"] = 5;
  try {
    parseServerConfig(params, "/edge_server/", nullptr);
    FAIL() << "accepted";
  } catch (const ecar::Error& e) {
    EXPECT_EQ(std::string(e.what()), "/edge_server/vo/share: expected a string");
  }
  params["vo"]["share"] = "sideways";
  try {
    parseServerConfig(params, "/edge_server/", nullptr);
    FAIL() << "accepted";
  } catch (const ecar::Error& e) {
    EXPECT_NE(std::string(e.what()).find("vo.share"), std::string::npos) << e.what();
  }
}

TEST(ServerConfigTest, InvalidValuesNameTheirKey) {
  const auto expectKey = [](ServerConfig c, const std::string& key) {
    try {
      c.validate();
      FAIL() << key << " accepted";
    } catch (const ecar::Error& e) {
      EXPECT_NE(std::string(e.what()).find("'" + key + "'"), std::string::npos) << e.what();
    }
  };
  EXPECT_NO_THROW(ServerConfig().validate());
  ServerConfig c;
  c.sync_mode = "fast";
  expectKey(c, "sync_mode");
  c = ServerConfig();
  c.workers = 0;
  expectKey(c, "workers");
  c = ServerConfig();
  c.device_timeout = -1;
  expectKey(c, "device_timeout");
  c = ServerConfig();
  c.max_upload_bytes = 10;
  expectKey(c, "max_upload_bytes");
  c = ServerConfig();
  c.marker_rate = -2;
  expectKey(c, "marker_rate");
  c = ServerConfig();
  c.uplink_capacity = -1.0;
  expectKey(c, "uplink_capacity");
  c = ServerConfig();
  c.uplink_utilisation = 0.0;
  expectKey(c, "uplink_utilisation");
  c = ServerConfig();
  c.graph_plane_refresh = 0;
  expectKey(c, "planes/graph_plane_refresh");
  c = ServerConfig();
  c.plane_resend_offset = -1.0;
  expectKey(c, "planes/resend");
  c = ServerConfig();
  c.autosave_period = 0.1;
  expectKey(c, "autosave_period");
  c = ServerConfig();
  c.loop_min_inliers = 3;
  expectKey(c, "loop_min_inliers");
  c = ServerConfig();
  c.odometry_sigma_min = 0.0;
  expectKey(c, "odometry_sigma_min");
  c = ServerConfig();
  c.odometry_sigma_walk = -0.01;
  expectKey(c, "odometry_sigma_walk");
  c = ServerConfig();
  c.ba_whole_map_keyframes = -1;
  expectKey(c, "ba_whole_map_keyframes");
  c = ServerConfig();
  c.loop_odometry_max_gap = 0.0;
  expectKey(c, "loop_odometry_max_gap");
  c.loop_odometry_max_gap = std::nan("");
  expectKey(c, "loop_odometry_max_gap");
  c = ServerConfig();
  c.loop_odometry_min_hops = 0;
  expectKey(c, "loop_odometry_min_hops");
  c = ServerConfig();
  c.loop_odometry_max_drift_per_link = std::nan("");
  expectKey(c, "loop_odometry_max_drift_per_link");
  c = ServerConfig();
  c.background_nice = 20;
  expectKey(c, "background_nice");
  c.background_nice = 7;
  EXPECT_EQ(c.slamConfig().background_nice, 7);
  EXPECT_FALSE(ServerConfig().slamConfig().synchronous_mapping);
}

TEST(ServerConfigTest, AutosaveGoesBesideTheDatabaseUnlessSaidOtherwise) {
  ServerConfig c;
  c.vo.database_path = "/var/lib/ecar/vo.sqlite";
  EXPECT_EQ(c.autosavePath(), "/var/lib/ecar/vo.autosave.ecarmap");
  c.vo.database_path = ":memory:";
  EXPECT_EQ(c.autosavePath(), "");  // nothing on disk to sit beside
  c.autosave_file = "/tmp/x.ecarmap";
  EXPECT_EQ(c.autosavePath(), "/tmp/x.ecarmap");
  c.autosave_file = "none";
  c.vo.database_path = "/var/lib/ecar/vo.sqlite";
  EXPECT_EQ(c.autosavePath(), "");
}

// A resume from the server's own autosave merges the VOs (newest version of
// each), any other map_file replaces them.
TEST(ServerConfigTest, MapFileIsTheAutosaveHoweverItIsWritten) {
  ServerConfig c;
  c.vo.database_path = "/var/lib/ecar/vo.sqlite";
  EXPECT_FALSE(c.mapFileIsAutosave());  // no map_file
  c.map_file = "/var/lib/ecar/vo.autosave.ecarmap";
  EXPECT_TRUE(c.mapFileIsAutosave());
  c.map_file = "/var/lib/ecar/maps/../vo.autosave.ecarmap";
  EXPECT_TRUE(c.mapFileIsAutosave());
  c.map_file = "/var/lib/ecar/office.ecarmap";
  EXPECT_FALSE(c.mapFileIsAutosave());
  c.map_file = "/var/lib/ecar/vo.autosave.ecarmap";
  c.autosave_file = "none";
  EXPECT_FALSE(c.mapFileIsAutosave());
  c.autosave_file = "/srv/session.ecarmap";
  c.map_file = "/srv/session.ecarmap";
  EXPECT_TRUE(c.mapFileIsAutosave());
}

TEST(ServerConfigTest, SlamKeysReachTheCore) {
  ServerConfig c;
  c.loop_closing = false;
  c.loop_min_inliers = 55;
  c.loop_global_ba = false;
  c.loop_by_odometry = false;
  c.loop_odometry_max_gap = 1.5;
  c.odometry_sigma_fraction = 0.05;
  c.odometry_sigma_walk = 0.02;
  c.odometry_sigma_min = 0.003;
  c.ba_whole_map_keyframes = 12;
  const ecar::SlamConfig slam = c.slamConfig();
  EXPECT_FALSE(slam.loops.enabled);
  EXPECT_EQ(slam.loops.min_inliers, 55);
  EXPECT_FALSE(slam.loops.global_ba);
  EXPECT_FALSE(slam.loops.by_odometry);
  EXPECT_DOUBLE_EQ(slam.loops.odometry_max_gap, 1.5);
  EXPECT_DOUBLE_EQ(slam.odometry_sigma_fraction, 0.05);
  EXPECT_DOUBLE_EQ(slam.odometry_sigma_walk, 0.02);
  EXPECT_DOUBLE_EQ(slam.odometry_sigma_min, 0.003);
  EXPECT_EQ(slam.ba_whole_map_keyframes, 12);
  EXPECT_NEAR(slam.odometrySigma(0.04), 0.003 + 0.02 * 0.2 + 0.05 * 0.04, 1e-12);
}

TEST(ServerConfigTest, CoreConfigsCarryTheKeys) {
  ServerConfig c;
  c.position_tolerance = 0.003;
  c.graph_plane_refresh = 4;
  c.plane_resend_extent = 0.5;
  c.edgeslam_keyframes = 7;
  c.device_timeout = 3.0;
  c.keyframe_queue = 6;
  c.grid.cell_size = 0.2;
  c.vo_share = "direct";
  c.graph_keyframe_planes = false;
  const ecar::LocalGraphComposerConfig composer = c.composerConfig();
  EXPECT_DOUBLE_EQ(composer.position_tolerance, 0.003);
  EXPECT_EQ(composer.plane_refresh, 4);
  EXPECT_DOUBLE_EQ(composer.plane_resend_extent, 0.5);
  EXPECT_EQ(composer.edgeslam_keyframes, 7);
  const ecar::GlobalGraphConfig graph = c.graphConfig(1234);
  EXPECT_EQ(graph.slam.first_epoch, 1234u);
  EXPECT_DOUBLE_EQ(graph.devices.device_timeout, 3.0);
  EXPECT_EQ(graph.devices.default_keyframe_queue, 6u);
  EXPECT_DOUBLE_EQ(graph.vo.cell_size, 0.2);
  const ecar::GridConnectionConfig grid = c.gridConnectionConfig();
  EXPECT_FALSE(grid.objects);  // VOs shared directly
  EXPECT_FALSE(grid.keyframe_planes);
}

TEST(ServerConfigTest, OneGraphPerManagerWithAnEpochFromTheClock) {
  const auto a = sharedGraph("/test_a", ServerConfig());
  const auto b = sharedGraph("/test_a", ServerConfig());
  const auto c = sharedGraph("/test_c", ServerConfig());
  EXPECT_EQ(a.get(), b.get());
  EXPECT_NE(a.get(), c.get());
  EXPECT_GT(a->epoch(), 1u);
}

}  // namespace
}  // namespace ecar_server
