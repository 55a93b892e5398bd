// Which camera frames a device uploads.
#pragma once

#include <cstdint>
#include <optional>

namespace ecar {

/// Every `every` frames by header.seq: the first frame that comes in each slot
/// of that many (seq / every), so that frames skipped while the device was busy
/// (a camera driver keeps only the newest) do not skip uploads. Without skips
/// that is seq % every == 0. A player that starts over (seq back to 0) starts
/// a new slot.
class UploadSchedule {
 public:
  /// Whether frame `seq` is due for upload at `every` (>= 1).
  bool due(uint32_t seq, int every) const {
    return !last_slot_ || slotOf(seq, every) != *last_slot_;
  }
  /// Frame `seq` was uploaded.
  void uploaded(uint32_t seq, int every) { last_slot_ = slotOf(seq, every); }

 private:
  static uint32_t slotOf(uint32_t seq, int every) { return seq / static_cast<uint32_t>(every); }
  std::optional<uint32_t> last_slot_;
};

}  // namespace ecar
