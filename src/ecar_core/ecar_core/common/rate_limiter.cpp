#include "ecar_core/common/rate_limiter.h"

#include <algorithm>
#include <cmath>

#include "ecar_core/common/error.h"

namespace ecar {

RateLimiter::RateLimiter(double rate, double burst) : rate_(rate), burst_(burst) {
  if (!std::isfinite(rate) || rate < 0.0) throw Error("rate limit: rate must be >= 0 per second");
  if (!std::isfinite(burst) || burst < 1.0) throw Error("rate limit: burst must be >= 1");
}

bool RateLimiter::allow(const std::string& name, double now) {
  if (rate_ <= 0.0) return true;
  if (buckets_.size() > kMaxNames) {
    for (auto it = buckets_.begin(); it != buckets_.end();) {
      const bool full = it->second.tokens + (now - it->second.at) * rate_ >= burst_;
      it = full ? buckets_.erase(it) : std::next(it);
    }
  }
  auto [it, added] = buckets_.try_emplace(name, Bucket{burst_, now});
  Bucket& b = it->second;
  if (!added) {
    b.tokens = std::min(burst_, b.tokens + std::max(0.0, now - b.at) * rate_);
    b.at = now;
  }
  if (b.tokens < 1.0 - 1e-9) return false;  // (refills summed in floating point)
  b.tokens -= 1.0;
  return true;
}

}  // namespace ecar
