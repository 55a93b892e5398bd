// The dataset player's schedule: when each frame is due on the wall clock.
#pragma once

#include <chrono>

namespace ecar_sim {

/// Plays dataset time at `rate` dataset seconds per wall second, as a camera
/// does: a frame is due one frame interval (divided by the rate) after the one
/// before it was due, however soon its consumer was done with that one. A
/// consumer that is late (done after the next frame was due) gets the next
/// frame at once, and the schedule goes on from there: playback never runs
/// ahead of the rate, and never tries to catch up on time already lost.
class PlaybackClock {
 public:
  using Clock = std::chrono::steady_clock;

  /// rate > 0 (the player checks it).
  explicit PlaybackClock(double rate) : rate_(rate) {}

  /// The frame at dataset time `t` is due at `now`; the later ones follow.
  void restart(Clock::time_point now, double t) {
    anchor_wall_ = now;
    anchor_t_ = t;
  }

  /// When the frame at dataset time `t` is due.
  Clock::time_point dueAt(double t) const {
    return anchor_wall_ + std::chrono::duration_cast<Clock::duration>(
                              std::chrono::duration<double>((t - anchor_t_) / rate_));
  }

  /// The consumer was done with a frame at `now`; `t_next` is the dataset time
  /// of the next frame. Returns true when that frame was already due (the
  /// consumer was late): it is due at `now` instead.
  bool consumerDone(Clock::time_point now, double t_next) {
    if (now <= dueAt(t_next)) return false;
    restart(now, t_next);
    return true;
  }

 private:
  double rate_;
  Clock::time_point anchor_wall_{};
  double anchor_t_ = 0.0;
};

}  // namespace ecar_sim
