// The VO store's configuration and its names (vo.attach, vo.policy): parsing and validation.
#include <cmath>
#include <limits>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

const char* toString(VoAttachMode mode) {
  return mode == VoAttachMode::kKeyFrame ? "keyframe" : "grid";
}

VoAttachMode parseVoAttachMode(const std::string& text) {
  if (text == "grid") return VoAttachMode::kGrid;
  if (text == "keyframe") return VoAttachMode::kKeyFrame;
  throw Error("vo_attach: '" + text + "' is neither 'grid' nor 'keyframe'");
}

const char* toString(VoPolicy policy) {
  switch (policy) {
    case VoPolicy::kOpen:
      return "open";
    case VoPolicy::kOwnerDelete:
      return "owner_delete";
    case VoPolicy::kOwnerOnly:
      return "owner_only";
  }
  return "?";
}

VoPolicy parseVoPolicy(const std::string& text) {
  for (const VoPolicy p : {VoPolicy::kOpen, VoPolicy::kOwnerDelete, VoPolicy::kOwnerOnly}) {
    if (text == toString(p)) return p;
  }
  throw Error("vo.policy: '" + text + "' is none of 'open', 'owner_delete', 'owner_only'");
}

void VoStoreConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) { throw Error(key + ": " + why); };
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (database_path.empty()) fail("database_path", "must not be empty");
  if (synchronous != "full" && synchronous != "normal") {
    fail("synchronous", "'" + synchronous + "' is neither 'full' nor 'normal'");
  }
  if (!positive(cell_size) || cell_size > 10.0) fail("cell_size", "must be in (0, 10] m");
  if (!std::isfinite(attach_margin) || attach_margin < 0.0 || attach_margin >= cell_size / 2.0) {
    fail("attach_margin", "must be in [0, cell_size / 2) m");
  }
  if (attach_mode != VoAttachMode::kGrid && attach_mode != VoAttachMode::kKeyFrame) {
    fail("attach_mode", "must be grid or keyframe");
  }
  if (!map_min.allFinite() || !map_max.allFinite() || (map_min.array() >= map_max.array()).any()) {
    fail("map_min", "map bounds must be finite with map_min < map_max on every axis");
  }
  // Cell coordinates must stay well inside int32 and the CellKey hash's 21-bit fields.
  const double extent = std::max(map_min.cwiseAbs().maxCoeff(), map_max.cwiseAbs().maxCoeff());
  if (extent / cell_size >= (1 << 20)) {
    fail("map_max", "map bounds span more than 2^20 cells of cell_size from the origin");
  }
  if (!positive(min_line_length)) fail("min_line_length", "must be > 0 m");
  if (!positive(max_line_length) || max_line_length < min_line_length) {
    fail("max_line_length", "must be >= min_line_length");
  }
  if (!positive(max_width)) fail("max_width", "must be > 0 m");
  if (max_owner_length < 1) fail("max_owner_length", "must be >= 1");
  if (max_objects < 1 || max_objects >= std::numeric_limits<uint32_t>::max()) {
    fail("max_objects", "must be in [1, 2^32 - 1)");
  }
  if (policy != VoPolicy::kOpen && policy != VoPolicy::kOwnerDelete &&
      policy != VoPolicy::kOwnerOnly) {
    fail("policy", "must be open, owner_delete or owner_only");
  }
  if (!std::isfinite(tombstone_retention) || tombstone_retention < 0.0) {
    fail("tombstone_retention", "must be >= 0 s");
  }
  if (max_tombstones < 1) fail("max_tombstones", "must be >= 1");
  if (!std::isfinite(max_database_mb) || max_database_mb < 0.0) {
    fail("max_database_mb", "must be >= 0 (0 = unlimited)");
  }
}

}  // namespace ecar
