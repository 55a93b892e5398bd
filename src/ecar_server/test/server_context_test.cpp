// The device registry: connect, camera refusal, reconnect resets the mirror,
// timeout, listeners, map epoch, and config validation.
#include "ecar_server/server_context.h"

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar_server {
namespace {

ecar::PinholeCamera camera(double fx = 525.0, int width = 640) {
  ecar::CameraParams p;
  p.fx = p.fy = fx;
  p.width = width;
  return ecar::PinholeCamera(p);
}

struct Recorder : ContextListener {
  int slams = 0;
  std::vector<std::string> added, removed;
  void onSlamCreated(const std::shared_ptr<ecar::SlamSystem>&) override { ++slams; }
  void onDeviceAdded(const DeviceInfo& d) override { added.push_back(d.name); }
  void onDeviceRemoved(const DeviceInfo& d) override { removed.push_back(d.name); }
};

TEST(ServerContextTest, FirstCameraCreatesTheSlamAndOthersMustMatch) {
  ServerContext ctx(ServerConfig(), 1000);
  Recorder rec;
  ctx.addListener(&rec);
  EXPECT_EQ(ctx.slam(), nullptr);
  const auto a = ctx.connect("device_0", camera(), "", 0, 0.0);
  ASSERT_TRUE(a.accepted) << a.message;
  ASSERT_NE(ctx.slam(), nullptr);
  EXPECT_EQ(a.device.keyframe_queue, 10u);
  EXPECT_EQ(a.device.mode, ecar::SyncMode::kEcar);
  const auto b = ctx.connect("device_1", camera(600.0), "", 5, 0.0);
  EXPECT_FALSE(b.accepted);
  EXPECT_NE(b.message.find("intrinsics"), std::string::npos) << b.message;
  const auto c = ctx.connect("device_1", camera(525.0, 320), "", 5, 0.0);
  EXPECT_FALSE(c.accepted);
  EXPECT_NE(c.message.find("320x480"), std::string::npos) << c.message;
  const auto d = ctx.connect("device_1", camera(525.5), "edgeslam", 5, 0.0);
  ASSERT_TRUE(d.accepted) << d.message;
  EXPECT_EQ(d.device.mode, ecar::SyncMode::kEdgeSlam);
  EXPECT_EQ(d.device.keyframe_queue, 5u);
  EXPECT_NE(d.device.id, a.device.id);
  EXPECT_EQ(ctx.deviceName(d.device.id), "device_1");
  EXPECT_EQ(rec.slams, 1);
  EXPECT_EQ(rec.added, (std::vector<std::string>{"device_0", "device_1"}));
  ctx.removeListener(&rec);
}

TEST(ServerContextTest, BadNamesAndModesAreRefused) {
  ServerContext ctx(ServerConfig(), 1);
  EXPECT_FALSE(ctx.connect("", camera(), "", 0, 0.0).accepted);
  EXPECT_FALSE(ctx.connect("0dev", camera(), "", 0, 0.0).accepted);
  EXPECT_FALSE(ctx.connect("dev/ice", camera(), "", 0, 0.0).accepted);
  const auto r = ctx.connect("device_0", camera(), "full", 0, 0.0);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.message.find("sync_mode"), std::string::npos) << r.message;
}

TEST(ServerContextTest, ReconnectResetsTheMirrorAndKeepsTheId) {
  ServerContext ctx(ServerConfig(), 1);
  Recorder rec;
  ctx.addListener(&rec);
  const auto a = ctx.connect("device_0", camera(), "", 0, 0.0);
  ASSERT_TRUE(ctx.withMirror("device_0", [](ecar::DeviceMirror& m) {
    m.setHeld(ecar::MapPointId(1), 1);
    m.pushKeyFrame({ecar::MapPointId(1)});
  }));
  const auto b = ctx.connect("device_0", camera(), "", 3, 1.0);
  EXPECT_TRUE(b.reconnected);
  EXPECT_EQ(b.device.id, a.device.id);
  size_t held = 99, queue = 0;
  ctx.withMirror("device_0", [&](ecar::DeviceMirror& m) {
    held = m.numPoints();
    queue = m.queueLength();
  });
  EXPECT_EQ(held, 0u);
  EXPECT_EQ(queue, 3u);
  EXPECT_EQ(rec.added.size(), 1u);  // no second "added"
  EXPECT_FALSE(ctx.withMirror("device_9", [](ecar::DeviceMirror&) {}));
  ctx.removeListener(&rec);
}

TEST(ServerContextTest, SilentDevicesAreDroppedAndMayComeBack) {
  ServerConfig config;
  config.device_timeout = 10.0;
  ServerContext ctx(config, 1);
  Recorder rec;
  ctx.addListener(&rec);
  const auto a = ctx.connect("device_0", camera(), "", 0, 0.0);
  ctx.connect("device_1", camera(), "", 0, 0.0);
  EXPECT_TRUE(ctx.touch("device_1", 8.0));
  EXPECT_FALSE(ctx.touch("device_7", 8.0));
  EXPECT_TRUE(ctx.removeSilent(9.0).empty());
  EXPECT_EQ(ctx.removeSilent(12.0), (std::vector<std::string>{"device_0"}));
  EXPECT_EQ(rec.removed, (std::vector<std::string>{"device_0"}));
  EXPECT_FALSE(ctx.device("device_0").has_value());
  EXPECT_FALSE(ctx.touch("device_0", 12.0));
  const auto b = ctx.connect("device_0", camera(), "", 0, 13.0);
  EXPECT_TRUE(b.accepted);
  EXPECT_FALSE(b.reconnected);
  EXPECT_EQ(b.device.id, a.device.id);
  EXPECT_TRUE(ctx.disconnect("device_1"));
  EXPECT_FALSE(ctx.disconnect("device_1"));
  EXPECT_EQ(ctx.devices().size(), 1u);
  ctx.removeListener(&rec);
}

TEST(ServerContextTest, LateListenersGetTheStateReplayed) {
  ServerContext ctx(ServerConfig(), 1);
  ctx.connect("device_0", camera(), "", 0, 0.0);
  Recorder rec;
  ctx.addListener(&rec);
  EXPECT_EQ(rec.slams, 1);
  EXPECT_EQ(rec.added, (std::vector<std::string>{"device_0"}));
  ctx.removeListener(&rec);
}

TEST(ServerContextTest, EpochDiffersPerStartAndSharedPerKey) {
  EXPECT_EQ(ServerContext(ServerConfig(), 77).mapEpoch(), 77u);
  const auto a = ServerContext::get("/test_a", ServerConfig());
  const auto b = ServerContext::get("/test_a", ServerConfig());
  const auto c = ServerContext::get("/test_c", ServerConfig());
  EXPECT_EQ(a.get(), b.get());
  EXPECT_NE(a.get(), c.get());
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
  EXPECT_FALSE(ServerConfig().slamConfig().synchronous_mapping);
}

}  // namespace
}  // namespace ecar_server
