// The player's schedule: as a camera, never ahead of the rate, and a late
// consumer gets the next frame at once without the schedule catching up.
#include "../src/playback_clock.h"

#include <gtest/gtest.h>

namespace ecar_sim {
namespace {

using Clock = PlaybackClock::Clock;
using std::chrono::milliseconds;

constexpr double kInterval = 1.0 / 30.0;  // s of dataset time between frames

double ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

TEST(PlaybackClock, AQuickConsumerDoesNotSpeedPlaybackUp) {
  PlaybackClock clock(1.0);
  const Clock::time_point t0 = Clock::now();
  clock.restart(t0, 0.0);
  for (int i = 0; i < 10; ++i) {
    const Clock::time_point published = clock.dueAt(i * kInterval);
    EXPECT_NEAR(ms(published - t0), i * 1000.0 * kInterval, 1e-3) << "frame " << i;
    // Done 2 ms after it was published: the next frame keeps its time.
    EXPECT_FALSE(clock.consumerDone(published + milliseconds(2), (i + 1) * kInterval));
  }
  EXPECT_NEAR(ms(clock.dueAt(10 * kInterval) - t0), 333.333, 1e-2);
}

TEST(PlaybackClock, ALateConsumerGetsTheNextFrameAtOnceAndTheScheduleGoesOnFromThere) {
  PlaybackClock clock(1.0);
  const Clock::time_point t0 = Clock::now();
  clock.restart(t0, 0.0);
  // Frame 0 took 50 ms: frame 1 (due at 33 ms) is due at once.
  const Clock::time_point done = t0 + milliseconds(50);
  EXPECT_TRUE(clock.consumerDone(done, kInterval));
  EXPECT_EQ(clock.dueAt(kInterval), done);
  // Frame 2 follows one interval after frame 1, not at its original 66.7 ms.
  EXPECT_NEAR(ms(clock.dueAt(2 * kInterval) - t0), 50.0 + 1000.0 * kInterval, 1e-3);
  // Done in time with frame 1: frame 2 keeps that time.
  EXPECT_FALSE(clock.consumerDone(done + milliseconds(10), 2 * kInterval));
  EXPECT_NEAR(ms(clock.dueAt(2 * kInterval) - t0), 50.0 + 1000.0 * kInterval, 1e-3);
}

TEST(PlaybackClock, TheRateScalesTheIntervals) {
  PlaybackClock fast(2.0), slow(0.5);
  const Clock::time_point t0 = Clock::now();
  fast.restart(t0, 10.0);
  slow.restart(t0, 10.0);
  EXPECT_NEAR(ms(fast.dueAt(11.0) - t0), 500.0, 1e-3);
  EXPECT_NEAR(ms(slow.dueAt(11.0) - t0), 2000.0, 1e-3);
  // Late by the same wall time: only the late one restarts.
  EXPECT_TRUE(fast.consumerDone(t0 + milliseconds(600), 11.0));
  EXPECT_FALSE(slow.consumerDone(t0 + milliseconds(600), 11.0));
}

}  // namespace
}  // namespace ecar_sim
