// Typed ids: a KeyFrameId cannot be passed where a MapPointId is expected.
// Ids are never reused within a map; 0 means "none".
#pragma once

#include <cstdint>
#include <functional>
#include <ostream>

namespace ecar {

template <typename Tag>
struct Id {
  uint32_t value = 0;
  constexpr Id() = default;
  constexpr explicit Id(uint32_t v) : value(v) {}
  constexpr bool valid() const { return value != 0; }
  friend constexpr bool operator==(Id a, Id b) { return a.value == b.value; }
  friend constexpr bool operator!=(Id a, Id b) { return a.value != b.value; }
  friend constexpr bool operator<(Id a, Id b) { return a.value < b.value; }
  friend std::ostream& operator<<(std::ostream& os, Id id) { return os << id.value; }
};

using KeyFrameId = Id<struct KeyFrameTag>;
using MapPointId = Id<struct MapPointTag>;
using PlaneId = Id<struct PlaneTag>;
using ObjectId = Id<struct ObjectTag>;
using DeviceId = Id<struct DeviceTag>;
using MapId = Id<struct MapTag>;  ///< a map of the atlas

/// A grid cell on the structure planes: (floor(X / cell), floor(Y / cell),
/// floor(Z / cell)) of a map point (X, Y, Z) for the grid's cell size (0.1 m).
struct CellKey {
  int32_t x = 0, y = 0, z = 0;
  friend constexpr bool operator==(CellKey a, CellKey b) {
    return a.x == b.x && a.y == b.y && a.z == b.z;
  }
  friend constexpr bool operator!=(CellKey a, CellKey b) { return !(a == b); }
  friend constexpr bool operator<(CellKey a, CellKey b) {
    return a.x != b.x ? a.x < b.x : a.y != b.y ? a.y < b.y : a.z < b.z;
  }
  friend std::ostream& operator<<(std::ostream& os, CellKey c) {
    return os << "(" << c.x << ", " << c.y << ", " << c.z << ")";
  }
};

}  // namespace ecar

namespace std {
template <>
struct hash<ecar::CellKey> {
  size_t operator()(ecar::CellKey c) const noexcept {
    // Three 21-bit fields: distinct for every cell within +-1 million cells (+-100 km at 0.1 m).
    const auto field = [](int32_t v) { return static_cast<uint64_t>(v) & 0x1FFFFFu; };
    return std::hash<uint64_t>()(field(c.x) | field(c.y) << 21 | field(c.z) << 42);
  }
};
template <typename Tag>
struct hash<ecar::Id<Tag>> {
  size_t operator()(ecar::Id<Tag> id) const noexcept { return std::hash<uint32_t>()(id.value); }
};
}  // namespace std
