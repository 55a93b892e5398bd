// The process's heap as the C library's allocator sees it, and giving its free
// pages back to the system. glibc keeps freed memory in its arenas (one per
// thread that met contention, up to 8 per core) and returns it only from the top
// of each: a server whose threads allocate and free large buffers (map saves,
// bundle adjustment, decoded images) keeps a resident size well above what it
// uses, and that retention grows with time. Other C libraries: no statistics,
// and trimming does nothing.
#pragma once

#include <cstddef>

namespace ecar {

struct HeapStats {
  bool available = false;  ///< false where the C library gives no statistics
  size_t in_use = 0;       ///< bytes allocated and not freed (heap and mmapped blocks)
  size_t free_held = 0;    ///< bytes freed but kept by the allocator (resident or not)
  size_t resident = 0;     ///< the process's resident set (/proc/self/statm; 0 elsewhere)
};

/// The allocator's statistics now (glibc's mallinfo2 walks every arena) and the resident set.
HeapStats heapStats();

struct HeapTrim {
  HeapStats before, after;
  double milliseconds = 0.0;  ///< time the trim took (it holds each arena's lock in turn)
};

/// Returns the free pages of every arena to the system (glibc's malloc_trim(0),
/// which also releases free pages in the middle of an arena). Safe from any
/// thread at any time.
HeapTrim trimHeap();

}  // namespace ecar
