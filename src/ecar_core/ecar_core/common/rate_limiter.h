// Token buckets by name: each name may act `rate` times a second on average and
// `burst` times at once (the server's per-device interaction limit).
//
//   RateLimiter limit(50.0, 100.0);
//   if (!limit.allow("device_0", steadySeconds())) { ...reject... }
//
// Thread-safety: none; the caller serialises (GridConnection::apply holds its lock).
#pragma once

#include <cstddef>
#include <string>
#include <unordered_map>

namespace ecar {

class RateLimiter {
 public:
  /// `rate` per second (0 = unlimited), `burst` >= 1. Throws ecar::Error otherwise.
  RateLimiter(double rate, double burst);

  /// Takes one token of `name` at `now` (seconds, any monotonic clock); false
  /// when it has none left. Names idle long enough to have a full bucket are
  /// forgotten once more than kMaxNames are held, so the state stays bounded.
  bool allow(const std::string& name, double now);
  size_t size() const { return buckets_.size(); }

  static constexpr size_t kMaxNames = 1024;

 private:
  struct Bucket {
    double tokens = 0.0;
    double at = 0.0;  ///< when tokens was computed
  };
  double rate_, burst_;
  std::unordered_map<std::string, Bucket> buckets_;
};

}  // namespace ecar
