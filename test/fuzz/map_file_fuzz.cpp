// Fuzz target: a map file loaded into a running server's global graph
// (GlobalGraph::load: the container, every section's decoder, the checks and
// limits, then the install). Errors must be ecar::Error; nothing may crash,
// hang, leak or allocate without bound.
#include <cstdint>
#include <memory>

#include "ecar_core/common/error.h"
#include "ecar_core/server/global_graph.h"
#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static std::unique_ptr<ecar::GlobalGraph> graph = [] {
    ecar::GlobalGraphConfig config;
    config.vo.database_path = ":memory:";
    config.atlas.several_maps = true;
    return std::make_unique<ecar::GlobalGraph>(config);
  }();
  const std::string& path = ecar_fuzz::scratchPath(".ecarmap");
  if (!ecar_fuzz::writeFile(path, data, size)) return 0;
  try {
    graph->load(path, size_t{64} << 20);
  } catch (const ecar::Error&) {
  }
  return 0;
}
