// Elapsed wall time, for the timings the modules report.
#pragma once

#include <chrono>

namespace ecar {

/// Milliseconds since `start` on the steady clock.
inline double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace ecar
