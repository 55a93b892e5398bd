// The heap statistics and trim the server relies on to keep its resident size
// near what it uses: memory freed in the middle of an arena stays resident
// until trimHeap() gives its pages back.
#include "ecar_core/common/heap.h"

#include <cstdlib>
#include <cstring>
#include <vector>

#include <gtest/gtest.h>

#if defined(__SANITIZE_ADDRESS__)
#define ECAR_OWN_ALLOCATOR 1  // AddressSanitizer's allocator replaces glibc's
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define ECAR_OWN_ALLOCATOR 1
#endif
#endif

namespace ecar {
namespace {

constexpr size_t kMB = 1024 * 1024;

TEST(HeapTest, FreedMemoryInTheMiddleOfTheHeapIsReturnedByATrim) {
#if defined(ECAR_OWN_ALLOCATOR) || !defined(__GLIBC__)
  GTEST_SKIP() << "glibc's allocator only";
#else
  const HeapStats start = heapStats();
  ASSERT_TRUE(start.available);
  ASSERT_GT(start.resident, 0u);
  // 64 MB in 64 kB blocks (below the mmap threshold: inside the arena), each
  // written so that its pages are resident.
  std::vector<char*> blocks(1024);
  for (char*& b : blocks) {
    b = static_cast<char*>(std::malloc(64 * 1024));
    ASSERT_NE(b, nullptr);
    std::memset(b, 1, 64 * 1024);
  }
  const HeapStats full = heapStats();
  EXPECT_GE(full.in_use, start.in_use + 60 * kMB);
  EXPECT_GE(full.resident, start.resident + 60 * kMB);
  // Free all but the last: it pins the top, so the allocator cannot shrink the
  // heap and the freed pages stay resident.
  for (size_t i = 0; i + 1 < blocks.size(); ++i) std::free(blocks[i]);
  const HeapStats freed = heapStats();
  EXPECT_LE(freed.in_use, start.in_use + 4 * kMB);
  EXPECT_GE(freed.free_held, 60 * kMB);
  EXPECT_GE(freed.resident, start.resident + 50 * kMB) << "the allocator already gave it back";

  const HeapTrim trim = trimHeap();
  EXPECT_GE(trim.milliseconds, 0.0);
  EXPECT_GE(trim.before.resident, freed.resident - 4 * kMB);
  EXPECT_LE(trim.after.resident + 50 * kMB, trim.before.resident)
      << "resident " << trim.before.resident / kMB << " -> " << trim.after.resident / kMB << " MB";
  std::free(blocks.back());
#endif
}

TEST(HeapTest, TrimIsHarmlessWhenNothingIsFree) {
  const HeapTrim first = trimHeap();
  const HeapTrim second = trimHeap();
  EXPECT_GE(second.milliseconds, 0.0);
  EXPECT_EQ(first.after.available, second.after.available);
  std::vector<int> v(1000, 7);  // the heap still works after two trims
  EXPECT_EQ(v[999], 7);
}

}  // namespace
}  // namespace ecar
