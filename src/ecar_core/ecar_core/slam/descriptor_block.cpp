#include "ecar_core/slam/descriptor_block.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "ecar_core/common/error.h"

#if defined(__x86_64__) && defined(__GNUC__)
#define ECAR_X86_KERNELS 1
#include <immintrin.h>
#endif

namespace ecar {
namespace {

constexpr size_t kLanes = 8;
constexpr size_t kBlockWords = 4 * kLanes;

using Nearest = DescriptorBlock::Nearest;

/// The answer from per-lane minima: lane l saw its smallest distance best[l]
/// first at index[l] (-1: nothing searched) and its second smallest second[l].
template <typename Int>
Nearest reduceLanes(const Int* best, const Int* second, const Int* index) {
  Nearest r;
  int lane = -1;
  for (size_t l = 0; l < kLanes; ++l) {
    if (index[l] < 0) continue;
    if (lane < 0 || best[l] < best[lane] || (best[l] == best[lane] && index[l] < index[lane])) {
      lane = static_cast<int>(l);
    }
  }
  if (lane < 0) return r;
  r.index = static_cast<int>(index[lane]);
  r.distance = static_cast<int>(best[lane]);
  r.second = static_cast<int>(second[lane]);
  for (size_t l = 0; l < kLanes; ++l) {
    if (static_cast<int>(l) != lane) r.second = std::min(r.second, static_cast<int>(best[l]));
  }
  return r;
}

Nearest nearestPortable(const uint64_t* words, size_t end, const uint64_t* q) {
  Nearest r;
  for (size_t i = 0; i < end; ++i) {
    const uint64_t* w = words + kBlockWords * (i / kLanes) + i % kLanes;
    const int d = __builtin_popcountll(w[0] ^ q[0]) + __builtin_popcountll(w[8] ^ q[1]) +
                  __builtin_popcountll(w[16] ^ q[2]) + __builtin_popcountll(w[24] ^ q[3]);
    if (d < r.distance) {
      r.second = r.distance;
      r.distance = d;
      r.index = static_cast<int>(i);
    } else if (d < r.second) {
      r.second = d;
    }
  }
  return r;
}

#ifdef ECAR_X86_KERNELS
__attribute__((target("avx512f,avx512vpopcntdq"))) Nearest nearestAvx512(const uint64_t* words,
                                                                         size_t end,
                                                                         const uint64_t* q) {
  const __m512i q0 = _mm512_set1_epi64(static_cast<int64_t>(q[0]));
  const __m512i q1 = _mm512_set1_epi64(static_cast<int64_t>(q[1]));
  const __m512i q2 = _mm512_set1_epi64(static_cast<int64_t>(q[2]));
  const __m512i q3 = _mm512_set1_epi64(static_cast<int64_t>(q[3]));
  const __m512i none = _mm512_set1_epi64(DescriptorBlock::kNone);
  const __m512i eight = _mm512_set1_epi64(8);
  __m512i best = none, second = none, index = _mm512_set1_epi64(-1);
  __m512i lane = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
  const size_t blocks = (end + kLanes - 1) / kLanes;
  for (size_t b = 0; b < blocks; ++b) {
    const uint64_t* w = words + kBlockWords * b;
    __m512i d = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(w), q0));
    d = _mm512_add_epi64(d, _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(w + 8), q1)));
    d = _mm512_add_epi64(d, _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(w + 16), q2)));
    d = _mm512_add_epi64(d, _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(w + 24), q3)));
    if (b + 1 == blocks && end % kLanes) {
      d = _mm512_mask_mov_epi64(none, static_cast<__mmask8>((1u << (end % kLanes)) - 1), d);
    }
    const __mmask8 closer = _mm512_cmplt_epu64_mask(d, best);
    // (The zero-masked forms with every lane kept: GCC 12's unmasked ones
    // start from an undefined register, which -Wmaybe-uninitialized reports.)
    second = _mm512_maskz_min_epu64(0xff, second, _mm512_maskz_max_epu64(0xff, best, d));
    best = _mm512_maskz_min_epu64(0xff, best, d);
    index = _mm512_mask_mov_epi64(index, closer, lane);
    lane = _mm512_add_epi64(lane, eight);
  }
  alignas(64) int64_t b[kLanes], s[kLanes], i[kLanes];
  _mm512_store_si512(b, best);
  _mm512_store_si512(s, second);
  _mm512_store_si512(i, index);
  return reduceLanes(b, s, i);
}

/// Per-byte popcount of x (pshufb on a nibble table), added to the bytes of acc.
__attribute__((target("avx2"))) inline __m256i addBytePopcounts(__m256i acc, __m256i x) {
  const __m256i table = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2,
                                         1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low = _mm256_set1_epi8(0x0f);
  const __m256i lo = _mm256_shuffle_epi8(table, _mm256_and_si256(x, low));
  const __m256i hi = _mm256_shuffle_epi8(table, _mm256_and_si256(_mm256_srli_epi16(x, 4), low));
  return _mm256_add_epi8(acc, _mm256_add_epi8(lo, hi));
}

__attribute__((target("avx2"))) Nearest nearestAvx2(const uint64_t* words, size_t end,
                                                    const uint64_t* q) {
  __m256i qw[4];
  for (int w = 0; w < 4; ++w) qw[w] = _mm256_set1_epi64x(static_cast<int64_t>(q[w]));
  const __m256i zero = _mm256_setzero_si256();
  const __m256i none = _mm256_set1_epi32(DescriptorBlock::kNone);
  const __m256i eight = _mm256_set1_epi32(8);
  // Distances of a block in 32-bit lanes: the four of lanes 0-3 in the low
  // halves of the 64-bit sums, lanes 4-7 in the high halves.
  const __m256i offsets = _mm256_set_epi32(7, 3, 6, 2, 5, 1, 4, 0);
  __m256i best = none, second = none, index = _mm256_set1_epi32(-1), lane = offsets;
  const size_t blocks = (end + kLanes - 1) / kLanes;
  for (size_t b = 0; b < blocks; ++b) {
    const uint64_t* w = words + kBlockWords * b;
    __m256i bytes0 = zero, bytes1 = zero;  // at most 4 x 8 per byte
    for (int k = 0; k < 4; ++k) {
      const __m256i* run = reinterpret_cast<const __m256i*>(w + 8 * k);
      bytes0 = addBytePopcounts(bytes0, _mm256_xor_si256(_mm256_loadu_si256(run), qw[k]));
      bytes1 = addBytePopcounts(bytes1, _mm256_xor_si256(_mm256_loadu_si256(run + 1), qw[k]));
    }
    __m256i d = _mm256_or_si256(_mm256_sad_epu8(bytes0, zero),
                                _mm256_slli_epi64(_mm256_sad_epu8(bytes1, zero), 32));
    if (b + 1 == blocks && end % kLanes) {
      const __m256i valid =
          _mm256_cmpgt_epi32(_mm256_set1_epi32(static_cast<int>(end % kLanes)), offsets);
      d = _mm256_blendv_epi8(none, d, valid);
    }
    const __m256i closer = _mm256_cmpgt_epi32(best, d);  // values < 2^31
    second = _mm256_min_epu32(second, _mm256_max_epu32(best, d));
    best = _mm256_min_epu32(best, d);
    index = _mm256_blendv_epi8(index, lane, closer);
    lane = _mm256_add_epi32(lane, eight);
  }
  alignas(32) int32_t b[kLanes], s[kLanes], i[kLanes];
  _mm256_store_si256(reinterpret_cast<__m256i*>(b), best);
  _mm256_store_si256(reinterpret_cast<__m256i*>(s), second);
  _mm256_store_si256(reinterpret_cast<__m256i*>(i), index);
  return reduceLanes(b, s, i);
}
#endif

}  // namespace

DescriptorBlock::Kernel DescriptorBlock::bestKernel() {
#ifdef ECAR_X86_KERNELS
  static const Kernel best = [] {
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vpopcntdq")) {
      return Kernel::kAvx512;
    }
    if (__builtin_cpu_supports("avx2")) return Kernel::kAvx2;
    return Kernel::kPortable;
  }();
  return best;
#else
  return Kernel::kPortable;
#endif
}

DescriptorBlock::Kernel DescriptorBlock::defaultKernel() {
  static const Kernel chosen = [] {
    const Kernel best = bestKernel();
    const char* name = std::getenv("ECAR_DESCRIPTOR_KERNEL");
    if (!name || !*name) return best;
    const std::string n(name);
    Kernel wanted;
    if (n == "portable") {
      wanted = Kernel::kPortable;
    } else if (n == "avx2") {
      wanted = Kernel::kAvx2;
    } else if (n == "avx512") {
      wanted = Kernel::kAvx512;
    } else {
      std::fprintf(stderr, "ECAR_DESCRIPTOR_KERNEL=%s: not portable, avx2 or avx512; ignored\n",
                   name);
      return best;
    }
    if (wanted > best) {
      std::fprintf(stderr, "ECAR_DESCRIPTOR_KERNEL=%s: this CPU does not run it; ignored\n", name);
      return best;
    }
    return wanted;
  }();
  return chosen;
}

DescriptorBlock::DescriptorBlock(const cv::Mat& descriptors) {
  if (descriptors.empty()) return;
  if (descriptors.type() != CV_8U || descriptors.cols != 32) {
    throw Error("DescriptorBlock: descriptors must be N x 32 CV_8U, got " +
                std::to_string(descriptors.rows) + " x " + std::to_string(descriptors.cols) +
                " of type " + std::to_string(descriptors.type()));
  }
  reserve(static_cast<size_t>(descriptors.rows));
  for (int r = 0; r < descriptors.rows; ++r) push_back(descriptors.ptr<uint8_t>(r));
}

void DescriptorBlock::clear() {
  words_.clear();
  size_ = 0;
}

void DescriptorBlock::reserve(size_t n) {
  words_.reserve(kBlockWords * ((n + kLanes - 1) / kLanes));
}

void DescriptorBlock::push_back(const uint8_t* descriptor) {
  if (size_ % kLanes == 0) words_.resize(words_.size() + kBlockWords, 0);
  uint64_t* w = words_.data() + kBlockWords * (size_ / kLanes) + size_ % kLanes;
  for (int k = 0; k < 4; ++k) std::memcpy(w + 8 * k, descriptor + 8 * k, 8);
  ++size_;
}

DescriptorBlock::Nearest DescriptorBlock::nearest(const uint8_t* query, size_t end,
                                                  Kernel kernel) const {
  end = std::min(end, size_);
  kernel = std::min(kernel, bestKernel());
  uint64_t q[4];
  std::memcpy(q, query, sizeof(q));
  switch (kernel) {
#ifdef ECAR_X86_KERNELS
    case Kernel::kAvx512:
      return nearestAvx512(words_.data(), end, q);
    case Kernel::kAvx2:
      return nearestAvx2(words_.data(), end, q);
#endif
    default:
      return nearestPortable(words_.data(), end, q);
  }
}

}  // namespace ecar
