// Names and priorities of the library's own threads. Tracking answers a device
// waiting for its local graph; local mapping and loop closing can wait a few
// milliseconds. On a machine whose cores are busy, a background thread with a
// higher niceness leaves the cores to the threads a device waits for.
#pragma once

#include <string>

namespace ecar {

/// What a background thread is called and how nice it is.
struct ThreadOptions {
  std::string name;  ///< shown by top -H and gdb (Linux keeps the first 15 characters)
  int nice = 0;      ///< niceness added to the thread's (0..19; 0: the creator's priority)
};

/// Names the calling thread (no effect where the platform cannot).
void nameThisThread(const std::string& name);

/// Raises the calling thread's niceness by `nice` (0..19) on Linux, where each
/// thread has its own; elsewhere does nothing. Returns false when the system
/// refused (it never refuses a higher niceness to an unprivileged thread).
bool lowerThisThreadPriority(int nice);

/// Both, at the start of a thread's loop.
void applyThreadOptions(const ThreadOptions& options);

}  // namespace ecar
