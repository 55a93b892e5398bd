// Place recognition without a trained vocabulary: an inverted index over
// locality-sensitive hashes of ORB descriptors. Each of `tables` hash functions
// takes `bits` fixed random bit positions of the 256-bit descriptor as a word;
// descriptors within a small Hamming distance share words with high
// probability. Keyframes are scored by tf-idf weighted word votes, so a query
// touches only the keyframes that share words with it: it scales to thousands.
//
// Score: the cosine of the tf-idf vectors of the query and of a keyframe, with
// idf = log((N + 1) / df) (N keyframes, df of them containing the word; the +1
// keeps a word seen in every keyframe weakly positive, so a single-keyframe
// index still works). Words the index does not hold and words skipped for their
// document frequency are left out of the query's vector.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <shared_mutex>
#include <unordered_map>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/common/types.h"

namespace ecar {

struct PlaceIndexConfig {
  int tables = 8;        ///< hash functions per descriptor (1..255)
  int bits = 16;         ///< bits per word (1..24)
  uint32_t seed = 1234;  ///< bit positions are drawn from this seed
  /// Words present in more than this fraction of keyframes carry no
  /// information and are skipped at query time (floor, texture-less repeats).
  /// Applied once the index holds at least 20 keyframes. In (0, 1].
  double max_document_frequency = 0.2;
};

struct PlaceCandidate {
  KeyFrameId keyframe;
  double score = 0.0;  ///< normalised to [0, 1]
  int shared_words = 0;
};

/// Thread-safe: add/remove take an exclusive lock, query a shared lock.
/// Descriptors are hashed before the lock is taken.
class PlaceIndex {
 public:
  /// Throws ecar::Error naming the config field if a value is out of range.
  explicit PlaceIndex(const PlaceIndexConfig& config = PlaceIndexConfig());

  /// Indexes a keyframe's descriptors (N x 32, CV_8U). Re-adding an id replaces it.
  /// Throws ecar::Error for an invalid id or another descriptor type. Cost:
  /// about that of a query (the norms of keyframes sharing its words change).
  void add(KeyFrameId id, const cv::Mat& descriptors);
  /// Removing an id that is not indexed does nothing.
  void remove(KeyFrameId id);
  /// Removes every keyframe (the map was replaced).
  void clear();
  size_t size() const;

  /// The best `max_results` keyframes for the descriptors, best first; only
  /// those with a score of at least min_score of the best one. Empty for an
  /// empty index or no descriptors; throws ecar::Error for another descriptor
  /// type than N x 32 CV_8U.
  std::vector<PlaceCandidate> query(const cv::Mat& descriptors, size_t max_results = 5,
                                    double min_relative_score = 0.6) const;

  /// Estimate of the heap memory held by the index (bytes).
  size_t memoryBytes() const;

 private:
  /// Open-addressing hash map from a word key ((table << 32) | word) to a dense
  /// word slot. Slots are never freed: a word that leaves the index keeps its
  /// slot with an empty posting list.
  class WordSlots {
   public:
    static constexpr uint32_t kAbsent = 0xffffffffu;
    uint32_t find(uint64_t key) const;  ///< kAbsent if the key was never inserted
    void prefetch(uint64_t key) const;  ///< brings the key's entry into the cache
    /// The key's slot; inserts it with slot `size()` if absent.
    uint32_t findOrInsert(uint64_t key);
    size_t size() const { return size_; }
    size_t memoryBytes() const;

   private:
    struct Entry {
      uint32_t key;  ///< (table << 24) | word; all ones where free
      uint32_t slot;
    };
    void grow();
    /// Linear probing; a power of two, at most half full.
    std::vector<Entry> entries_;
    int shift_ = 64;  ///< 64 - log2(entries_.size()): a hash is its top bits
    size_t size_ = 0;
  };

  /// One indexed keyframe ("document").
  struct Document {
    KeyFrameId id;                     ///< invalid for a free document index
    std::vector<uint32_t> word_slots;  ///< its distinct words
  };
  /// A document's squared tf-idf norm is L^2 s0 - 2 L s1 + s2 with
  /// L = log(N + 1): the sums over its words of c^2, c^2 log(df) and
  /// c^2 log(df)^2 (c: count of the word in it). s1 and s2 are updated when the
  /// df of one of its words changes, so a query needs no pass over its words.
  struct NormTerms {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0;
  };

  // Word keys of each descriptor row (one per table), sorted.
  void hashDescriptors(const cv::Mat& descriptors, std::vector<uint64_t>* keys) const;
  // Requires the exclusive lock.
  void removeLocked(KeyFrameId id);
  // Updates the log(df) terms of every document in the posting list of a
  // word whose df changed from old_df to new_df (both > 0).
  void updateNorms(const std::vector<uint32_t>& postings, size_t old_df, size_t new_df);

  const PlaceIndexConfig config_;
  /// Per table, per bit: the byte of the descriptor and the mask of the bit.
  std::vector<uint8_t> bit_bytes_, bit_masks_;  ///< [table * bits + bit]

  mutable std::shared_mutex mutex_;
  // Everything below is guarded by mutex_.
  WordSlots word_slots_;
  /// Per word slot: the documents containing it, each packed as
  /// (document index << 8) | min(count, 255).
  std::vector<std::vector<uint32_t>> postings_;
  std::vector<Document> documents_;    ///< by document index
  std::vector<NormTerms> norm_terms_;  ///< by document index
  std::vector<uint32_t> free_documents_;
  std::unordered_map<KeyFrameId, uint32_t> document_of_;
};

/// Nearest-descriptor search over keyframe keypoints (those with map points),
/// for relocalisation and joining when whole-image scores fail: a view from
/// another direction shares only a few points with any keyframe, too few for
/// a bag-of-words score but enough for a pose once the individual matches are
/// found. Locality-sensitive hashing as in PlaceIndex (`tables` words of
/// `bits` fixed random bit positions, no training); every candidate is checked
/// with its exact Hamming distance. A query costs about (query descriptors x
/// tables x entries / 2^bits) distance computations.
struct KeypointIndexConfig {
  int tables = 12;       ///< hash functions per descriptor (1..64)
  int bits = 16;         ///< bits per word (1..20)
  uint32_t seed = 4321;  ///< bit positions are drawn from this seed
};

struct KeypointMatch {
  int query_row = 0;  ///< row of the query descriptors
  KeyFrameId keyframe;
  int row = 0;  ///< keypoint (descriptor row) of the keyframe
  int distance = 0;
};

/// Thread-safe: add/remove take an exclusive lock, query a shared lock.
class KeypointIndex {
 public:
  /// Throws ecar::Error naming the config field if a value is out of range.
  explicit KeypointIndex(const KeypointIndexConfig& config = KeypointIndexConfig());

  /// Indexes rows `rows` of a keyframe's descriptors (N x 32, CV_8U). Re-adding
  /// an id replaces it. Throws ecar::Error for an invalid id, another
  /// descriptor type or a row out of range.
  void add(KeyFrameId id, const cv::Mat& descriptors, const std::vector<int>& rows);
  void remove(KeyFrameId id);
  /// Removes every keyframe (the map was replaced).
  void clear();
  size_t size() const;  ///< indexed keyframes
  size_t entries() const;
  /// Estimate of the heap memory held by the index (bytes): it follows the
  /// keyframes indexed now, not the most ever indexed.
  size_t memoryBytes() const;

  /// For each query row, up to `per_row` indexed keypoints within
  /// `max_distance` bits, nearest first (ties by keyframe id, row). Rows are
  /// in query order.
  std::vector<KeypointMatch> query(const cv::Mat& descriptors, int max_distance, int per_row) const;

 private:
  struct Entry {
    KeyFrameId keyframe;  ///< invalid for a free entry
    int row = 0;
    std::array<uint8_t, 32> descriptor{};
  };
  void wordsOf(const uint8_t* descriptor, uint32_t* words) const;
  void removeLocked(KeyFrameId id);

  const KeypointIndexConfig config_;
  std::vector<uint8_t> bit_bytes_, bit_masks_;  ///< [table * bits + bit]
  mutable std::shared_mutex mutex_;
  std::vector<Entry> entries_;
  std::vector<uint32_t> free_entries_;
  std::vector<std::vector<uint32_t>> buckets_;  ///< [table << bits | word] -> entries
  std::unordered_map<KeyFrameId, std::vector<uint32_t>> entries_of_;
};

}  // namespace ecar
