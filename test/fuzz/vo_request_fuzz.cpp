// Fuzz target: a sequence of VO requests (register, manipulate, delete) from
// several devices against the server's store with the grid attachment, as
// GridConnection applies them. Besides crashes, it checks the store's own
// accounting after every request.
#include <fuzzer/FuzzedDataProvider.h>

#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/structure/vo_store.h"

namespace {

Eigen::Vector3d vec(FuzzedDataProvider* in) {
  // Mostly small values around the origin, now and then anything at all.
  if (in->ConsumeIntegralInRange<int>(0, 7) == 0) {
    return {in->ConsumeFloatingPoint<double>(), in->ConsumeFloatingPoint<double>(),
            in->ConsumeFloatingPoint<double>()};
  }
  return {in->ConsumeFloatingPointInRange<double>(-20, 20),
          in->ConsumeFloatingPointInRange<double>(-20, 20),
          in->ConsumeFloatingPointInRange<double>(-3, 3)};
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  ecar::VoStoreConfig config;
  config.database_path = ":memory:";
  config.max_objects = 64;
  config.max_tombstones = 16;
  config.policy = static_cast<ecar::VoPolicy>(in.ConsumeIntegralInRange<int>(0, 2));
  ecar::VoStore store(config);
  ecar::GridMap grid;
  const char* devices[] = {"device_0", "device_1", "rviz", ""};
  while (in.remaining_bytes() > 0) {
    const std::string device = devices[in.ConsumeIntegralInRange<int>(0, 3)];
    ecar::VirtualObject vo;
    vo.kind = static_cast<ecar::VoKind>(in.ConsumeIntegralInRange<int>(0, 2));
    vo.position = vec(&in);
    vo.start = vec(&in);
    vo.end = vec(&in);
    vo.normal = vec(&in);
    vo.width = in.ConsumeFloatingPointInRange<float>(-0.1f, 0.7f);
    vo.owner = device;
    const ecar::ObjectId id(in.ConsumeIntegralInRange<uint32_t>(0, 70));
    const uint32_t base = in.ConsumeIntegralInRange<uint32_t>(0, 8);
    ecar::VoOutcome out;
    switch (in.ConsumeIntegralInRange<int>(0, 3)) {
      case 0:
        out = store.registerObject(vo);
        break;
      case 1:
        out = store.manipulate(id, base, vo, device);
        break;
      case 2:
        out = store.remove(id, base, device);
        break;
      default:
        store.compactTombstones(ecar::steadySeconds() + in.ConsumeFloatingPoint<double>());
        continue;
    }
    if (out.accepted) {
      if (const auto now = store.get(out.id)) {
        grid.attachObject(*now, config.cell_size, config.attach_margin);
      }
    } else if (out.reason.empty()) {
      std::abort();  // every rejection names its reason
    }
    if (store.numLive() > config.max_objects || store.numTombstones() > config.max_tombstones ||
        store.numLive() + store.numTombstones() != store.numObjects()) {
      std::abort();
    }
  }
  return 0;
}
