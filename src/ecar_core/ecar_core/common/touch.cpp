#include "ecar_core/common/touch.h"

namespace ecar {

const char* toString(TouchPhase phase) {
  switch (phase) {
    case TouchPhase::kBegin:
      return "begin";
    case TouchPhase::kMove:
      return "move";
    case TouchPhase::kEnd:
      return "end";
  }
  return "unknown";
}

std::optional<TouchPhase> parseTouchPhase(const std::string& name) {
  for (TouchPhase p : {TouchPhase::kBegin, TouchPhase::kMove, TouchPhase::kEnd}) {
    if (name == toString(p)) return p;
  }
  return std::nullopt;
}

}  // namespace ecar
