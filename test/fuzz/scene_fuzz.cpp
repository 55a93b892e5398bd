// Fuzz target: a scene file (ecar::loadScene: YAML, every key's check, the
// devices' routes and scripted touches). Errors must be ecar::Error (yaml-cpp's
// exceptions included, wrapped by the reader).
#include <cstdint>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/scene.h"
#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = ecar_fuzz::scratchPath(".yaml");
  if (!ecar_fuzz::writeFile(path, data, size)) return 0;
  try {
    ecar::loadScene(path);
  } catch (const ecar::Error&) {
  }
  return 0;
}
