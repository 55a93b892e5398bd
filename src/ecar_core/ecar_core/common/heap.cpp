#include "ecar_core/common/heap.h"

#include <unistd.h>

#include <chrono>
#include <cstdio>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace ecar {
namespace {

size_t residentBytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long size = 0, resident = 0;
  const bool read = std::fscanf(f, "%lu %lu", &size, &resident) == 2;
  std::fclose(f);
  const long page = ::sysconf(_SC_PAGESIZE);
  return read && page > 0 ? static_cast<size_t>(resident) * static_cast<size_t>(page) : 0;
}

}  // namespace

HeapStats heapStats() {
  HeapStats stats;
  stats.resident = residentBytes();
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
  const struct mallinfo2 info = ::mallinfo2();
  stats.available = true;
  stats.in_use = info.uordblks + info.hblkhd;
  stats.free_held = info.fordblks;
#endif
  return stats;
}

HeapTrim trimHeap() {
  HeapTrim trim;
  trim.before = heapStats();
  const auto start = std::chrono::steady_clock::now();
#if defined(__GLIBC__)
  ::malloc_trim(0);
#endif
  trim.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  trim.after = heapStats();
  return trim;
}

}  // namespace ecar
