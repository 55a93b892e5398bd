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

}  // namespace ecar

namespace std {
template <typename Tag>
struct hash<ecar::Id<Tag>> {
  size_t operator()(ecar::Id<Tag> id) const noexcept { return std::hash<uint32_t>()(id.value); }
};
}  // namespace std
