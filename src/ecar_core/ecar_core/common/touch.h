// Touches on a device's camera image (ecar_msgs/Touch): a user's (the device
// turns them into interactions, device/device_objects.h) or scripted frame by
// frame. Scenes script them (sim/scene.h, `touches:`), the generator writes them
// to a dataset's touches.txt (io/dataset_writer.h), Dataset reads them back
// (io/dataset.h) and the dataset player publishes them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include <Eigen/Core>

namespace ecar {

/// Stroke phase of a touch; the values of ecar_msgs/Touch's BEGIN, MOVE, END.
enum class TouchPhase : uint8_t { kBegin = 0, kMove = 1, kEnd = 2 };

/// "begin", "move" or "end".
const char* toString(TouchPhase phase);
/// The inverse of toString; nullopt for any other text (callers name the file).
std::optional<TouchPhase> parseTouchPhase(const std::string& name);

/// A touch on the camera image, field for field ecar_msgs/Touch.
struct Touch {
  /// Pixel touched (column, row; origin top-left, centre of the first pixel at 0, 0).
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();
  TouchPhase phase = TouchPhase::kBegin;
  uint8_t r = 255, g = 255, b = 255;  ///< stroke colour
  double width = 0.02;                ///< stroke width, metres
};

/// One scripted touch on the image of one frame of a dataset.
struct TouchEvent : Touch {
  TouchEvent() {
    g = 64;  // a scripted stroke is orange unless the script says otherwise
    b = 32;
    width = 0.03;
  }
  double timestamp = 0.0;  ///< the stamp of frame `frame`, seconds
  size_t frame = 0;        ///< index of the frame in the dataset (0 = first)
};

/// Checks that `phases` form whole strokes: BEGIN, any MOVEs, END, repeated.
/// Returns the index of the first event that breaks the pattern (a MOVE or END
/// outside a stroke, a BEGIN inside one), or size() when the last stroke is
/// left open, or nullopt when all is well. `open_at_end_ok` accepts an open
/// last stroke.
template <typename Range, typename PhaseOf>
std::optional<size_t> firstIllFormedTouch(const Range& events, PhaseOf phase_of,
                                          bool open_at_end_ok = false) {
  bool open = false;
  size_t i = 0;
  for (const auto& e : events) {
    const TouchPhase p = phase_of(e);
    if ((p == TouchPhase::kBegin) == open) return i;
    open = p != TouchPhase::kEnd;
    ++i;
  }
  if (open && !open_at_end_ok) return i;
  return std::nullopt;
}

}  // namespace ecar
