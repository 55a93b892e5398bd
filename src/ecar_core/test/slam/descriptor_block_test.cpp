// The one-against-many descriptor search: every kernel this CPU runs gives
// what descriptorDistance() in a loop gives (nearest index, its distance, the
// second distance), on random descriptors, near copies, exact ties and every
// block remainder; bad input is refused.
#include "ecar_core/slam/descriptor_block.h"

#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/features.h"

namespace ecar {
namespace {

using Kernel = DescriptorBlock::Kernel;

DescriptorBlock::Nearest reference(const cv::Mat& d, size_t end, const uint8_t* query) {
  DescriptorBlock::Nearest r;
  for (size_t i = 0; i < end; ++i) {
    const int dist = descriptorDistance(query, d.ptr<uint8_t>(static_cast<int>(i)));
    if (dist < r.distance) {
      r.second = r.distance;
      r.distance = dist;
      r.index = static_cast<int>(i);
    } else if (dist < r.second) {
      r.second = dist;
    }
  }
  return r;
}

std::vector<Kernel> kernelsHere() {
  std::vector<Kernel> kernels = {Kernel::kPortable};
  if (DescriptorBlock::bestKernel() >= Kernel::kAvx2) kernels.push_back(Kernel::kAvx2);
  if (DescriptorBlock::bestKernel() >= Kernel::kAvx512) kernels.push_back(Kernel::kAvx512);
  return kernels;
}

TEST(DescriptorBlockTest, EveryKernelFindsWhatTheScalarLoopFinds) {
  std::mt19937 rng(11);
  const std::vector<Kernel> kernels = kernelsHere();
  RecordProperty("kernels", static_cast<int>(kernels.size()));
  int checked = 0;
  for (const int n : {0, 1, 2, 7, 8, 9, 15, 16, 17, 63, 200, 1001}) {
    cv::Mat d(n, 32, CV_8U);
    if (n > 0) cv::randu(d, 0, 256);
    // Ties: a few rows repeated further on.
    for (int r = 0; r + 5 < n; r += 6) d.row(r).copyTo(d.row(r + 5));
    const DescriptorBlock block(d);
    ASSERT_EQ(block.size(), static_cast<size_t>(n));
    std::vector<cv::Mat> queries;
    for (int k = 0; k < 20; ++k) {
      cv::Mat q(1, 32, CV_8U);
      cv::randu(q, 0, 256);
      if (n > 0 && k % 2 == 0) {
        // A near copy of a row (a re-observation): a few bits flipped.
        d.row(static_cast<int>(rng() % n)).copyTo(q);
        for (int f = 0; f < k; ++f) q.at<uint8_t>(0, rng() % 32) ^= 1u << (rng() % 8);
      }
      queries.push_back(q);
    }
    for (const cv::Mat& q : queries) {
      for (const size_t end : {static_cast<size_t>(n), static_cast<size_t>(n / 2)}) {
        const auto want = reference(d, end, q.ptr<uint8_t>());
        for (const Kernel kernel : kernels) {
          const auto got = block.nearest(q.ptr<uint8_t>(), end, kernel);
          EXPECT_EQ(got.index, want.index)
              << "n " << n << " end " << end << " kernel " << static_cast<int>(kernel);
          EXPECT_EQ(got.distance, want.distance) << "n " << n << " end " << end;
          EXPECT_EQ(got.second, want.second) << "n " << n << " end " << end;
          ++checked;
        }
      }
    }
  }
  EXPECT_EQ(checked, 12 * 20 * 2 * static_cast<int>(kernels.size()));
  // An exact copy is found at distance 0, the first of its twins.
  cv::Mat d(30, 32, CV_8U);
  cv::randu(d, 0, 256);
  d.row(4).copyTo(d.row(21));
  DescriptorBlock block;
  for (int r = 0; r < d.rows; ++r) block.push_back(d.ptr<uint8_t>(r));
  for (const Kernel kernel : kernels) {
    const auto got = block.nearest(d.ptr<uint8_t>(21), block.size(), kernel);
    EXPECT_EQ(got.index, 4);
    EXPECT_EQ(got.distance, 0);
    EXPECT_EQ(got.second, 0);
  }
  block.clear();
  EXPECT_EQ(block.nearest(d.ptr<uint8_t>(0)).index, -1);
}

TEST(DescriptorBlockTest, MatricesThatAreNotOrbDescriptorsAreRefused) {
  EXPECT_THROW(DescriptorBlock(cv::Mat(3, 16, CV_8U, cv::Scalar(0))), Error);
  EXPECT_THROW(DescriptorBlock(cv::Mat(3, 32, CV_32F, cv::Scalar(0))), Error);
  EXPECT_EQ(DescriptorBlock(cv::Mat()).size(), 0u);
}

}  // namespace
}  // namespace ecar
