// Per-name token buckets: the burst goes at once, then the rate; names are
// independent; idle names are forgotten so the state stays bounded.
#include "ecar_core/common/rate_limiter.h"

#include <string>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

TEST(RateLimiterTest, BurstThenRatePerName) {
  RateLimiter limit(10.0, 5.0);
  int allowed = 0;
  for (int i = 0; i < 20; ++i) allowed += limit.allow("device_0", 100.0) ? 1 : 0;
  EXPECT_EQ(allowed, 5);                        // the burst
  EXPECT_TRUE(limit.allow("device_1", 100.0));  // another name has its own bucket
  EXPECT_FALSE(limit.allow("device_0", 100.05));
  EXPECT_TRUE(limit.allow("device_0", 100.1));  // one token per 0.1 s
  EXPECT_FALSE(limit.allow("device_0", 100.1));
  // One second at 10 a second: 10 more (the bucket refills to at most the burst).
  allowed = 0;
  for (int i = 1; i <= 100; ++i) allowed += limit.allow("device_0", 100.1 + 0.01 * i) ? 1 : 0;
  EXPECT_EQ(allowed, 10);
  allowed = 0;
  for (int i = 0; i < 20; ++i) allowed += limit.allow("device_0", 1000.0) ? 1 : 0;
  EXPECT_EQ(allowed, 5);
}

TEST(RateLimiterTest, UnlimitedBoundedAndValidated) {
  RateLimiter unlimited(0.0, 1.0);
  for (int i = 0; i < 1000; ++i) ASSERT_TRUE(unlimited.allow("x", 0.0));
  RateLimiter limit(1.0, 2.0);
  for (size_t i = 0; i < 3 * RateLimiter::kMaxNames; ++i) {
    limit.allow("name_" + std::to_string(i), static_cast<double>(i));
  }
  EXPECT_LE(limit.size(), RateLimiter::kMaxNames + 2);
  EXPECT_THROW(RateLimiter(-1.0, 1.0), Error);
  EXPECT_THROW(RateLimiter(1.0, 0.5), Error);
}

}  // namespace
}  // namespace ecar
