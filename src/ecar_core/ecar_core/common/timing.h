// Elapsed wall time, for the timings the modules report, and the calling
// thread's CPU time, for benchmarks on a busy machine.
#pragma once

#include <time.h>

#include <chrono>

namespace ecar {

/// Milliseconds since `start` on the steady clock.
inline double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

/// Seconds on the steady clock (monotonic; an arbitrary origin).
inline double steadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

/// CPU time of the calling thread, milliseconds (less inflated than wall time
/// when other processes share the cores).
inline double threadCpuMs() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

}  // namespace ecar
