// One-against-many Hamming search over ORB descriptors: the brute-force
// matchers (relocalisation, place verification) compare every query
// descriptor with hundreds of others. A DescriptorBlock keeps them in blocks of
// eight, word by word (the first 64-bit words of eight descriptors, then their
// second words, ...), so that eight distances are computed at once (AVX-512
// VPOPCNTDQ, or AVX2 in two halves of four); the instruction set is chosen at run time from what
// the CPU offers, with a portable fallback. Every path gives the same answer as
// descriptorDistance() in a loop.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace ecar {

class DescriptorBlock {
 public:
  /// The nearest of the searched descriptors and the second-nearest distance.
  struct Nearest {
    int index = -1;        ///< first index at the smallest distance; -1 if none searched
    int distance = kNone;  ///< kNone if none searched
    int second = kNone;    ///< second smallest distance (may equal `distance`); kNone if < 2
  };
  static constexpr int kNone = 1 << 16;  ///< above every distance (0..256)

  /// Which code computes the distances.
  enum class Kernel { kPortable, kAvx2, kAvx512 };
  /// The fastest kernel this CPU runs (AVX-512 needs VPOPCNTDQ).
  static Kernel bestKernel();
  /// The kernel blocks use: bestKernel(), or the one the environment variable
  /// ECAR_DESCRIPTOR_KERNEL names (portable, avx2, avx512: for timing them
  /// side by side) if this CPU runs it. Read once.
  static Kernel defaultKernel();

  DescriptorBlock() = default;
  /// Every row of an N x 32 CV_8U matrix.
  explicit DescriptorBlock(const cv::Mat& descriptors);

  void clear();
  void reserve(size_t n);
  void push_back(const uint8_t* descriptor);  ///< 32 bytes
  size_t size() const { return size_; }

  /// The nearest of descriptors [0, end) (end <= size()) to `query` (32 bytes).
  Nearest nearest(const uint8_t* query, size_t end) const { return nearest(query, end, kernel_); }
  Nearest nearest(const uint8_t* query) const { return nearest(query, size_, kernel_); }
  /// With a given kernel (tests compare them); one this CPU does not run
  /// falls back to bestKernel().
  Nearest nearest(const uint8_t* query, size_t end, Kernel kernel) const;

 private:
  /// Blocks of eight descriptors, each four runs of eight words: word w of
  /// descriptor i is words_[32 * (i / 8) + 8 * w + i % 8]; the last block's
  /// unused lanes are zero (and never searched).
  std::vector<uint64_t> words_;
  size_t size_ = 0;
  Kernel kernel_ = defaultKernel();
};

}  // namespace ecar
