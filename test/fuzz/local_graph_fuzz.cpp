// Fuzz target: a local graph as a device reads it (ecar_bridge::fromMsg: every
// field's check and the lists' bounds) and applies its planes and VOs
// (ecar::DeviceObjects::applyGraph), then casts a touch and draws, as the
// device does next. The message is built from the input's bytes, field by field.
#include <fuzzer/FuzzedDataProvider.h>

#include <cstdint>
#include <string>
#include <vector>

#include "ecar_bridge/local_graph.h"
#include "ecar_core/common/error.h"
#include "ecar_core/device/device_objects.h"

namespace {

float anyFloat(FuzzedDataProvider* in) { return in->ConsumeFloatingPoint<float>(); }
double anyDouble(FuzzedDataProvider* in) { return in->ConsumeFloatingPoint<double>(); }

void point(FuzzedDataProvider* in, geometry_msgs::Point* p) {
  p->x = anyDouble(in), p->y = anyDouble(in), p->z = anyDouble(in);
}

ecar_msgs::LocalGraph graphFrom(FuzzedDataProvider* in) {
  ecar_msgs::LocalGraph g;
  g.device_id = "device_0";
  g.status = in->ConsumeIntegralInRange<uint8_t>(0, 4);
  g.sync_mode = in->ConsumeIntegralInRange<uint8_t>(0, 2);
  g.map_epoch = in->ConsumeIntegral<uint32_t>();
  g.map_id = in->ConsumeIntegral<uint32_t>();
  point(in, &g.pose.position);
  g.pose.orientation.x = anyDouble(in);
  g.pose.orientation.w = anyDouble(in);
  g.points.resize(in->ConsumeIntegralInRange<size_t>(0, 64));
  for (auto& p : g.points) {
    p.id = in->ConsumeIntegral<uint32_t>();
    p.u = in->ConsumeIntegral<uint16_t>();
    p.v = in->ConsumeIntegral<uint16_t>();
    p.octave = in->ConsumeIntegral<uint8_t>();
  }
  g.positions.resize(in->ConsumeIntegralInRange<size_t>(0, 80));
  for (auto& p : g.positions) {
    p.index = in->ConsumeIntegral<uint16_t>();
    p.x = anyFloat(in), p.y = anyFloat(in), p.z = anyFloat(in);
  }
  g.planes.resize(in->ConsumeIntegralInRange<size_t>(0, 6));
  for (auto& p : g.planes) {
    p.id = in->ConsumeIntegralInRange<uint32_t>(0, 8);
    p.version = in->ConsumeIntegral<uint32_t>();
    p.label = in->ConsumeIntegralInRange<uint8_t>(0, 5);
    p.normal.x = anyDouble(in), p.normal.y = anyDouble(in), p.normal.z = anyDouble(in);
    p.offset = anyDouble(in);
    p.boundary.resize(in->ConsumeIntegralInRange<size_t>(0, 12));
    for (auto& b : p.boundary) point(in, &b);
  }
  g.removed_planes.resize(in->ConsumeIntegralInRange<size_t>(0, 4));
  for (auto& id : g.removed_planes) id = in->ConsumeIntegralInRange<uint32_t>(0, 8);
  g.objects.resize(in->ConsumeIntegralInRange<size_t>(0, 8));
  for (auto& o : g.objects) {
    o.id = in->ConsumeIntegralInRange<uint32_t>(0, 10);
    o.version = in->ConsumeIntegral<uint32_t>();
    o.kind = in->ConsumeIntegralInRange<uint8_t>(0, 2);
    o.deleted = in->ConsumeBool();
    point(in, &o.position), point(in, &o.start), point(in, &o.end);
    o.normal.x = anyDouble(in), o.normal.y = anyDouble(in), o.normal.z = anyDouble(in);
    o.width = anyFloat(in);
    o.plane_id = in->ConsumeIntegralInRange<uint32_t>(0, 8);
    o.owner = in->ConsumeRandomLengthString(70);
  }
  return g;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  static const ecar::PinholeCamera camera = [] {
    ecar::CameraParams p;
    p.width = 64, p.height = 48, p.fx = p.fy = 50.0, p.cx = 32.0, p.cy = 24.0;
    return ecar::PinholeCamera(p);
  }();
  ecar::DeviceObjects objects(ecar::DeviceObjectsConfig{}, "device_0");
  while (in.remaining_bytes() > 0) {
    const ecar_msgs::LocalGraph msg = graphFrom(&in);
    ecar::LocalGraph graph;
    try {
      std::vector<std::string> skipped;
      graph = ecar_bridge::fromMsg(msg, &skipped);
    } catch (const ecar::Error&) {
      continue;
    }
    objects.applyGraph(graph.planes, graph.objects, graph.removed_planes);
    if (!ecar::tracked(graph.status)) continue;
    std::vector<ecar::ScreenLine> lines;
    objects.drawList(graph.T_w_c, camera, &lines);
    objects.cast(Eigen::Vector2d(in.ConsumeIntegralInRange<int>(0, 63),
                                 in.ConsumeIntegralInRange<int>(0, 47)),
                 graph.T_w_c, camera);
  }
  return 0;
}
