#include "ecar_core/sync/local_graph.h"

#include "ecar_core/common/error.h"

namespace ecar {

const char* toString(SyncMode mode) { return mode == SyncMode::kEdgeSlam ? "edgeslam" : "ecar"; }

SyncMode parseSyncMode(const std::string& text) {
  if (text == "ecar") return SyncMode::kEcar;
  if (text == "edgeslam") return SyncMode::kEdgeSlam;
  throw Error("sync_mode must be 'ecar' or 'edgeslam' (got '" + text + "')");
}

}  // namespace ecar
