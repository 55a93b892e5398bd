// Place recognition: synthetic places with known identity (random descriptors,
// noisy re-observations), real KITTI frames (neighbours in time are the same
// place), index maintenance, bad input and concurrent use.
#include "ecar_core/slam/place_recognition.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <numeric>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

cv::Mat randomDescriptors(int rows, std::mt19937* rng) {
  cv::Mat d(rows, 32, CV_8U);
  uint32_t* words = d.ptr<uint32_t>();  // continuous, 8 words a row
  for (int i = 0; i < rows * 8; ++i) words[i] = (*rng)();
  return d;
}

// Flips `flips` distinct bits of a 32-byte descriptor.
void flipBits(uint8_t* descriptor, int flips, std::mt19937* rng) {
  std::array<uint8_t, 256> bits;
  std::iota(bits.begin(), bits.end(), 0);
  for (int i = 0; i < flips; ++i) {
    std::swap(bits[i], bits[i + (*rng)() % (256 - i)]);
    descriptor[bits[i] >> 3] ^= static_cast<uint8_t>(1u << (bits[i] & 7));
  }
}

// A re-observation of a place: 60% of its descriptors with 10-25 bit flips
// each, plus 40% unrelated descriptors.
cv::Mat noisyObservation(const cv::Mat& place, std::mt19937* rng) {
  const int seen = place.rows * 6 / 10;
  cv::Mat q = randomDescriptors(place.rows, rng);
  std::vector<int> rows(place.rows);
  for (int i = 0; i < place.rows; ++i) rows[i] = i;
  std::shuffle(rows.begin(), rows.end(), *rng);
  for (int i = 0; i < seen; ++i) {
    place.row(rows[i]).copyTo(q.row(i));
    flipBits(q.ptr<uint8_t>(i), 10 + static_cast<int>((*rng)() % 16), rng);
  }
  return q;
}

TEST(PlaceIndexTest, SyntheticPlacesAreRecognisedDespiteNoiseAndClutter) {
  std::mt19937 rng(7);
  constexpr int kPlaces = 300;
  std::vector<cv::Mat> places;
  PlaceIndex index;
  for (int p = 0; p < kPlaces; ++p) {
    places.push_back(randomDescriptors(500, &rng));
    index.add(KeyFrameId(p + 1), places.back());
  }
  ASSERT_EQ(index.size(), static_cast<size_t>(kPlaces));

  int first = 0;
  double worst_best_score = 1.0;
  for (int p = 0; p < kPlaces; ++p) {
    const auto candidates = index.query(noisyObservation(places[p], &rng));
    ASSERT_FALSE(candidates.empty());
    if (candidates[0].keyframe == KeyFrameId(p + 1)) {
      ++first;
      worst_best_score = std::min(worst_best_score, candidates[0].score);
    }
    for (size_t i = 1; i < candidates.size(); ++i) {
      EXPECT_LE(candidates[i].score, candidates[i - 1].score);
      EXPECT_GE(candidates[i].score, 0.6 * candidates[0].score);
    }
  }
  RecordProperty("ranked_first", first);
  RecordProperty("worst_true_score", std::to_string(worst_best_score));
  EXPECT_GE(first, kPlaces * 95 / 100);
  EXPECT_GT(worst_best_score, 0.1);

  // An unrelated scene matches nothing well.
  double unrelated_best = 0.0;
  for (int i = 0; i < 5; ++i) {
    const auto candidates = index.query(randomDescriptors(500, &rng));
    ASSERT_FALSE(candidates.empty());
    unrelated_best = std::max(unrelated_best, candidates[0].score);
  }
  RecordProperty("unrelated_best_score", std::to_string(unrelated_best));
  EXPECT_LT(unrelated_best, 0.1);
  // The same descriptors score 1.
  const auto same = index.query(places[42]);
  ASSERT_FALSE(same.empty());
  EXPECT_EQ(same[0].keyframe, KeyFrameId(43));
  EXPECT_NEAR(same[0].score, 1.0, 1e-4);
}

TEST(PlaceIndexTest, SingleKeyframeIndexMatchesItself) {
  std::mt19937 rng(3);
  PlaceIndex index;
  const cv::Mat d = randomDescriptors(300, &rng);
  index.add(KeyFrameId(9), d);
  const auto candidates = index.query(d);
  ASSERT_EQ(candidates.size(), 1u);
  EXPECT_EQ(candidates[0].keyframe, KeyFrameId(9));
  EXPECT_NEAR(candidates[0].score, 1.0, 1e-4);
  EXPECT_GT(candidates[0].shared_words, 0);
}

TEST(PlaceIndexTest, WordsInMostKeyframesAreIgnored) {
  // 30 keyframes see the same 200 "floor" descriptors and 300 of their own.
  std::mt19937 rng(17);
  const cv::Mat floor = randomDescriptors(200, &rng);
  std::vector<cv::Mat> own;
  PlaceIndex index;
  for (int k = 1; k <= 30; ++k) {
    own.push_back(randomDescriptors(300, &rng));
    cv::Mat d;
    cv::vconcat(floor, own.back(), d);
    index.add(KeyFrameId(k), d);
  }
  EXPECT_TRUE(index.query(floor).empty()) << "floor words are in every keyframe";
  cv::Mat q;
  cv::vconcat(floor, noisyObservation(own[11], &rng), q);
  const auto candidates = index.query(q);
  ASSERT_FALSE(candidates.empty());
  EXPECT_EQ(candidates[0].keyframe, KeyFrameId(12));
}

TEST(PlaceIndexTest, KittiFramesFindTheirNeighbours) {
  const std::string dir = "/work/shared/data/kitti07_0-159/image_0/";
  if (!std::filesystem::exists(dir + "000000.png")) GTEST_SKIP() << "no KITTI frames in " << dir;
  constexpr int kFrames = 80, kEvery = 5;
  auto orb = cv::ORB::create(1000);
  std::vector<cv::Mat> descriptors(kFrames);
  for (int i = 0; i < kFrames; ++i) {
    char name[16];
    std::snprintf(name, sizeof(name), "%06d.png", i);
    const cv::Mat gray = cv::imread(dir + name, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(gray.empty()) << dir + name;
    std::vector<cv::KeyPoint> keypoints;
    orb->detectAndCompute(gray, cv::noArray(), keypoints, descriptors[i]);
    ASSERT_GT(descriptors[i].rows, 500) << name;
  }
  // Keyframe ids are frame + 1 (0 is not a valid id).
  PlaceIndex index;
  for (int i = 0; i < kFrames; i += kEvery) index.add(KeyFrameId(i + 1), descriptors[i]);

  int queries = 0, near = 0;
  for (int i = 0; i < kFrames; ++i) {
    if (i % kEvery == 0) continue;
    ++queries;
    const auto candidates = index.query(descriptors[i]);
    ASSERT_FALSE(candidates.empty()) << "frame " << i;
    const int frame = static_cast<int>(candidates[0].keyframe.value) - 1;
    if (std::abs(frame - i) <= 5) ++near;
  }
  RecordProperty("near", near);
  RecordProperty("queries", queries);
  EXPECT_GE(near, queries * 90 / 100) << near << " of " << queries;
}

TEST(PlaceIndexTest, RemoveAndReplace) {
  std::mt19937 rng(11);
  std::vector<cv::Mat> places;
  PlaceIndex index;
  for (int p = 1; p <= 10; ++p) {
    places.push_back(randomDescriptors(300, &rng));
    index.add(KeyFrameId(p), places.back());
  }
  const cv::Mat query3 = noisyObservation(places[2], &rng);
  ASSERT_EQ(index.query(query3).at(0).keyframe, KeyFrameId(3));

  index.remove(KeyFrameId(3));
  EXPECT_EQ(index.size(), 9u);
  for (const auto& c : index.query(query3, 10, 0.0)) EXPECT_NE(c.keyframe, KeyFrameId(3));
  index.remove(KeyFrameId(3));  // not indexed: nothing happens
  index.remove(KeyFrameId(99));
  EXPECT_EQ(index.size(), 9u);

  // Re-adding id 7 with place 3's descriptors replaces its old content.
  index.add(KeyFrameId(7), places[2]);
  EXPECT_EQ(index.size(), 9u);
  EXPECT_EQ(index.query(query3).at(0).keyframe, KeyFrameId(7));
  // Its old descriptors now find it no better than any other keyframe.
  const auto old7 = index.query(places[6], 10, 0.0);
  ASSERT_FALSE(old7.empty());
  EXPECT_LT(old7[0].score, 0.1) << "old content of 7 still indexed";
  // And back: id 3 again, its own descriptors.
  index.add(KeyFrameId(3), places[2]);
  const auto both = index.query(places[2], 2, 0.0);
  ASSERT_EQ(both.size(), 2u);
  EXPECT_NEAR(both[0].score, 1.0, 1e-4);
  EXPECT_NEAR(both[1].score, 1.0, 1e-4);
  EXPECT_EQ(both[0].keyframe, KeyFrameId(3));  // ties by id
  EXPECT_EQ(both[1].keyframe, KeyFrameId(7));

  // Removing everything leaves an empty index.
  for (int p = 1; p <= 10; ++p) index.remove(KeyFrameId(p));
  EXPECT_EQ(index.size(), 0u);
  EXPECT_TRUE(index.query(query3).empty());
}

TEST(PlaceIndexTest, EmptyAndInvalidInput) {
  std::mt19937 rng(5);
  PlaceIndex index;
  EXPECT_TRUE(index.query(randomDescriptors(100, &rng)).empty()) << "empty index";
  index.add(KeyFrameId(1), randomDescriptors(100, &rng));
  EXPECT_TRUE(index.query(cv::Mat()).empty()) << "empty query";
  EXPECT_TRUE(index.query(randomDescriptors(100, &rng), 0).empty()) << "max_results 0";

  const cv::Mat floats(100, 32, CV_32F, cv::Scalar(0.5));
  try {
    index.query(floats);
    ADD_FAILURE() << "a CV_32F query was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("CV_8U"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("CV_32F"), std::string::npos) << e.what();
  }
  EXPECT_THROW(index.add(KeyFrameId(2), floats), Error);
  EXPECT_THROW(index.add(KeyFrameId(2), cv::Mat(10, 64, CV_8U, cv::Scalar(0))), Error);
  EXPECT_THROW(index.add(KeyFrameId(), randomDescriptors(10, &rng)), Error);
  EXPECT_EQ(index.size(), 1u);

  // A keyframe without descriptors is indexed but never found.
  index.add(KeyFrameId(3), cv::Mat());
  EXPECT_EQ(index.size(), 2u);
  for (const auto& c : index.query(randomDescriptors(100, &rng), 10, 0.0)) {
    EXPECT_NE(c.keyframe, KeyFrameId(3));
  }

  PlaceIndexConfig bad;
  bad.bits = 30;
  try {
    PlaceIndex bad_index(bad);
    ADD_FAILURE() << "bits 30 was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bits"), std::string::npos) << e.what();
  }
  bad = PlaceIndexConfig();
  bad.max_document_frequency = 0.0;
  EXPECT_THROW(PlaceIndex{bad}, Error);
}

TEST(PlaceIndexTest, ConcurrentAddRemoveAndQuery) {
  std::mt19937 rng(13);
  std::vector<cv::Mat> places;
  for (int p = 0; p < 40; ++p) places.push_back(randomDescriptors(200, &rng));
  PlaceIndex index;
  for (int p = 0; p < 20; ++p) index.add(KeyFrameId(p + 1), places[p]);

  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(300);
  std::atomic<int> bad_results{0}, queries{0}, writes{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      std::mt19937 thread_rng(100 + t);
      while (std::chrono::steady_clock::now() < deadline) {
        const int p = static_cast<int>(thread_rng() % places.size());
        if (t < 2) {  // writers: add, replace and remove the second half
          const KeyFrameId id(static_cast<uint32_t>(21 + thread_rng() % 20));
          if (thread_rng() % 3 == 0) {
            index.remove(id);
          } else {
            index.add(id, places[p]);
          }
          ++writes;
        } else {  // readers: the first half is never changed
          const auto candidates = index.query(places[p % 20], 3, 0.0);
          bool found = false;
          for (const auto& c : candidates) {
            if (c.keyframe.value < 1 || c.keyframe.value > 40) ++bad_results;
            found = found || c.keyframe == KeyFrameId(p % 20 + 1);
          }
          if (!found) ++bad_results;
          ++queries;
        }
      }
    });
  }
  for (auto& thread : threads) thread.join();
  EXPECT_EQ(bad_results.load(), 0);
  EXPECT_GT(queries.load(), 10);
  EXPECT_GT(writes.load(), 10);
  EXPECT_GE(index.size(), 20u);
  EXPECT_LE(index.size(), 40u);
}

TEST(KeypointIndexTest, FindsNearDescriptorsAndForgetsRemovedKeyframes) {
  std::mt19937 rng(5);
  KeypointIndex index;
  const cv::Mat a = randomDescriptors(300, &rng), b = randomDescriptors(300, &rng);
  std::vector<int> rows_a(300), rows_b;
  std::iota(rows_a.begin(), rows_a.end(), 0);
  for (int i = 0; i < 300; i += 2) rows_b.push_back(i);  // every other row only
  index.add(KeyFrameId(1), a, rows_a);
  index.add(KeyFrameId(2), b, rows_b);
  EXPECT_EQ(index.size(), 2u);
  EXPECT_EQ(index.entries(), 450u);
  // Queries: rows of b with 10 flipped bits, and unrelated descriptors.
  cv::Mat q = randomDescriptors(200, &rng);
  for (int i = 0; i < 100; ++i) {
    b.row(2 * i).copyTo(q.row(i));
    flipBits(q.ptr<uint8_t>(i), 10, &rng);
  }
  const auto hits = index.query(q, 50, 2);
  int found = 0, wrong = 0;
  for (const auto& h : hits) {
    EXPECT_LE(h.distance, 50);
    if (h.query_row < 100 && h.keyframe == KeyFrameId(2) && h.row == 2 * h.query_row) {
      ++found;
    } else {
      ++wrong;
    }
  }
  EXPECT_GE(found, 95);  // LSH recall at 10 bits
  EXPECT_LE(wrong, 2);   // random descriptors are ~128 bits apart
  index.remove(KeyFrameId(2));
  EXPECT_EQ(index.entries(), 300u);
  for (const auto& h : index.query(q, 50, 2)) EXPECT_NE(h.keyframe, KeyFrameId(2));
  EXPECT_THROW(index.add(KeyFrameId(3), a, {300}), Error);
  EXPECT_THROW(KeypointIndex(KeypointIndexConfig{0, 14, 1}), Error);
}

// A server culls keyframes all day: the index must hold what its 20 live
// keyframes need after 200 have come and gone, not every bucket they ever filled.
TEST(KeypointIndexTest, MemoryFollowsTheLiveKeyframesUnderChurn) {
  std::mt19937 rng(11);
  KeypointIndex index;
  const size_t empty = index.memoryBytes();
  std::vector<int> rows(300);
  std::iota(rows.begin(), rows.end(), 0);
  constexpr uint32_t kLive = 20;
  for (uint32_t id = 1; id <= kLive; ++id)
    index.add(KeyFrameId(id), randomDescriptors(300, &rng), rows);
  const size_t window = index.memoryBytes();
  ASSERT_GT(window, empty);
  for (uint32_t id = kLive + 1; id <= 200; ++id) {
    index.remove(KeyFrameId(id - kLive));
    index.add(KeyFrameId(id), randomDescriptors(300, &rng), rows);
  }
  EXPECT_EQ(index.size(), kLive);
  EXPECT_EQ(index.entries(), kLive * 300);
  const size_t churned = index.memoryBytes();
  EXPECT_LE(churned - empty, (window - empty) * 3 / 2)
      << "empty " << empty << " B, 20 keyframes " << window << " B, after churn " << churned
      << " B";
  for (uint32_t id = 181; id <= 200; ++id) index.remove(KeyFrameId(id));
  EXPECT_EQ(index.entries(), 0u);
  // Every bucket gave its memory back (12 tables x 6000 entries of 4 bytes);
  // the entry table and its free list stay for the next keyframes.
  const size_t tables = static_cast<size_t>(KeypointIndexConfig().tables);
  EXPECT_GE(window - index.memoryBytes(), tables * kLive * 300 * sizeof(uint32_t));
}

}  // namespace
}  // namespace ecar
