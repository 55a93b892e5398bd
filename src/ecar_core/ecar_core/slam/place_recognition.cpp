#include "ecar_core/slam/place_recognition.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/features.h"

namespace ecar {

namespace {

// Per table, `bits` distinct descriptor bit positions (as byte index and
// mask): a partial Fisher-Yates shuffle of 0..255 (rng() % n rather than a
// distribution, so the same on every platform).
void drawBitPositions(uint32_t seed, int tables, int bits, std::vector<uint8_t>* bytes,
                      std::vector<uint8_t>* masks) {
  std::mt19937 rng(seed);
  for (int t = 0; t < tables; ++t) {
    std::array<uint16_t, 8 * kDescriptorBytes> pool;
    std::iota(pool.begin(), pool.end(), 0);
    for (int b = 0; b < bits; ++b) {
      const size_t j = b + rng() % (pool.size() - b);
      std::swap(pool[b], pool[j]);
      bytes->push_back(static_cast<uint8_t>(pool[b] >> 3));
      masks->push_back(static_cast<uint8_t>(1u << (pool[b] & 7)));
    }
  }
}

// A posting packs the document index in 24 bits and the count in 8.
constexpr uint32_t kMaxDocuments = 1u << 24;
constexpr uint32_t kMaxCount = 255;
// The document-frequency cut-off applies from this many keyframes on.
constexpr size_t kMinDocumentsForStopWords = 20;

uint32_t postingDocument(uint32_t posting) { return posting >> 8; }
uint32_t postingCount(uint32_t posting) { return posting & kMaxCount; }

// Word keys stored as (table << 24) | word: tables < 255 and bits <= 24, so
// all ones is never a key.
constexpr uint32_t kEmptyKey = 0xffffffffu;

uint32_t compactKey(uint64_t key) {
  return static_cast<uint32_t>(key >> 32) << 24 | static_cast<uint32_t>(key);
}

// Fibonacci hashing: the top `64 - shift` bits of the key times 2^64 / phi.
size_t hashKey(uint32_t key, int shift) {
  return static_cast<size_t>((key * 0x9E3779B97F4A7C15ull) >> shift);
}

void checkDescriptors(const cv::Mat& descriptors, const char* where) {
  if (descriptors.empty()) return;
  if (descriptors.dims != 2 || descriptors.type() != CV_8UC1 ||
      descriptors.cols != kDescriptorBytes) {
    throw Error(std::string(where) + ": descriptors must be N x 32 CV_8U (ORB), got " +
                std::to_string(descriptors.rows) + " x " + std::to_string(descriptors.cols) + " " +
                cv::typeToString(descriptors.type()));
  }
}

// How many words ahead the hash entries and posting lists are prefetched:
// a query is bound by memory latency, one or two cache misses per word.
constexpr size_t kPrefetchAhead = 16;

struct WordCount {
  uint64_t key;
  uint32_t count;  ///< saturated at kMaxCount
  uint32_t slot;   ///< WordSlots::kAbsent until looked up
};

// Collapses sorted word keys into distinct words with their counts.
void countWords(const std::vector<uint64_t>& keys, std::vector<WordCount>* words) {
  words->clear();
  for (size_t i = 0; i < keys.size();) {
    size_t j = i + 1;
    while (j < keys.size() && keys[j] == keys[i]) ++j;
    words->push_back({keys[i], static_cast<uint32_t>(std::min<size_t>(j - i, kMaxCount)), 0});
    i = j;
  }
}

// Sorts keys[0, n) of one table by word (their low `bits` bits): a stable
// least-significant-digit radix sort, 8 bits a pass.
void radixSortWords(uint64_t* keys, size_t n, int bits) {
  thread_local std::vector<uint64_t> buffer;
  buffer.resize(n);
  uint64_t* from = keys;
  uint64_t* to = buffer.data();
  for (int shift = 0; shift < bits; shift += 8) {
    size_t start[257] = {};
    for (size_t i = 0; i < n; ++i) ++start[((from[i] >> shift) & 0xff) + 1];
    for (int digit = 1; digit <= 256; ++digit) start[digit] += start[digit - 1];
    for (size_t i = 0; i < n; ++i) to[start[(from[i] >> shift) & 0xff]++] = from[i];
    std::swap(from, to);
  }
  if (from != keys) std::copy(from, from + n, keys);
}

// Per-thread query scratch, so that a query allocates nothing once warm.
struct QueryScratch {
  struct List {  ///< a query word's posting list
    const uint32_t* postings;
    uint32_t df;
    float weight;  ///< idf^2 * count in the query
  };
  struct Accumulator {  ///< per document
    float dot;
    uint32_t shared;
  };
  struct Scored {
    float score;
    uint32_t document;
  };
  std::vector<uint64_t> keys;
  std::vector<WordCount> words;
  std::vector<List> lists;
  std::vector<Accumulator> accumulators;
  std::vector<Scored> scored;
};

QueryScratch& queryScratch() {
  thread_local QueryScratch scratch;
  return scratch;
}

}  // namespace

// ---------------------------------------------------------------- WordSlots

uint32_t PlaceIndex::WordSlots::find(uint64_t key) const {
  if (entries_.empty()) return kAbsent;
  const uint32_t k = compactKey(key);
  const size_t mask = entries_.size() - 1;
  for (size_t i = hashKey(k, shift_);; i = (i + 1) & mask) {
    if (entries_[i].key == k) return entries_[i].slot;
    if (entries_[i].key == kEmptyKey) return kAbsent;
  }
}

void PlaceIndex::WordSlots::prefetch(uint64_t key) const {
  if (!entries_.empty()) __builtin_prefetch(&entries_[hashKey(compactKey(key), shift_)]);
}

uint32_t PlaceIndex::WordSlots::findOrInsert(uint64_t key) {
  if (2 * (size_ + 1) > entries_.size()) grow();
  const uint32_t k = compactKey(key);
  const size_t mask = entries_.size() - 1;
  for (size_t i = hashKey(k, shift_);; i = (i + 1) & mask) {
    if (entries_[i].key == k) return entries_[i].slot;
    if (entries_[i].key == kEmptyKey) {
      entries_[i] = {k, static_cast<uint32_t>(size_)};
      return static_cast<uint32_t>(size_++);
    }
  }
}

void PlaceIndex::WordSlots::grow() {
  std::vector<Entry> old(std::max<size_t>(1024, 2 * entries_.size()), Entry{kEmptyKey, 0});
  old.swap(entries_);
  shift_ = 64;
  for (size_t n = entries_.size(); n > 1; n >>= 1) --shift_;
  const size_t mask = entries_.size() - 1;
  for (const Entry& e : old) {
    if (e.key == kEmptyKey) continue;
    size_t i = hashKey(e.key, shift_);
    while (entries_[i].key != kEmptyKey) i = (i + 1) & mask;
    entries_[i] = e;
  }
}

size_t PlaceIndex::WordSlots::memoryBytes() const { return entries_.capacity() * sizeof(Entry); }

// --------------------------------------------------------------- PlaceIndex

PlaceIndex::PlaceIndex(const PlaceIndexConfig& config) : config_(config) {
  if (config_.tables < 1 || config_.tables > 255) {
    throw Error("PlaceIndexConfig.tables must be in [1, 255], got " +
                std::to_string(config_.tables));
  }
  if (config_.bits < 1 || config_.bits > 24) {
    throw Error("PlaceIndexConfig.bits must be in [1, 24], got " + std::to_string(config_.bits));
  }
  if (!(config_.max_document_frequency > 0.0 && config_.max_document_frequency <= 1.0)) {
    throw Error("PlaceIndexConfig.max_document_frequency must be in (0, 1], got " +
                std::to_string(config_.max_document_frequency));
  }
  drawBitPositions(config_.seed, config_.tables, config_.bits, &bit_bytes_, &bit_masks_);
}

void PlaceIndex::hashDescriptors(const cv::Mat& descriptors, std::vector<uint64_t>* keys) const {
  const size_t rows = static_cast<size_t>(descriptors.rows);
  const int bits = config_.bits;
  keys->resize(rows * config_.tables);
  // Table by table, so that sorting each table's block by word sorts all.
  for (int t = 0; t < config_.tables; ++t) {
    const uint8_t* bytes = &bit_bytes_[t * bits];
    const uint8_t* masks = &bit_masks_[t * bits];
    uint64_t* out = keys->data() + t * rows;
    for (size_t r = 0; r < rows; ++r) {
      const uint8_t* d = descriptors.ptr<uint8_t>(static_cast<int>(r));
      uint32_t word = 0;
      for (int b = 0; b < bits; ++b) {
        word |= static_cast<uint32_t>((d[bytes[b]] & masks[b]) != 0) << b;
      }
      out[r] = static_cast<uint64_t>(t) << 32 | word;
    }
    radixSortWords(out, rows, bits);
  }
}

void PlaceIndex::updateNorms(const std::vector<uint32_t>& postings, size_t old_df, size_t new_df) {
  const double log_old = std::log(static_cast<double>(old_df));
  const double log_new = std::log(static_cast<double>(new_df));
  const double d1 = log_new - log_old;
  const double d2 = log_new * log_new - log_old * log_old;
  for (uint32_t posting : postings) {
    const double c2 = static_cast<double>(postingCount(posting) * postingCount(posting));
    NormTerms& terms = norm_terms_[postingDocument(posting)];
    terms.s1 += c2 * d1;
    terms.s2 += c2 * d2;
  }
}

void PlaceIndex::add(KeyFrameId id, const cv::Mat& descriptors) {
  if (!id.valid()) throw Error("PlaceIndex::add: invalid keyframe id 0");
  checkDescriptors(descriptors, "PlaceIndex::add");
  std::vector<uint64_t> keys;
  hashDescriptors(descriptors, &keys);

  std::unique_lock<std::shared_mutex> lock(mutex_);
  removeLocked(id);
  uint32_t document;
  if (!free_documents_.empty()) {
    document = free_documents_.back();
    free_documents_.pop_back();
  } else {
    if (documents_.size() >= kMaxDocuments) {
      throw Error("PlaceIndex::add: more than " + std::to_string(kMaxDocuments) + " keyframes");
    }
    document = static_cast<uint32_t>(documents_.size());
    documents_.emplace_back();
    norm_terms_.emplace_back();
  }
  std::vector<WordCount> words;
  countWords(keys, &words);
  for (size_t i = 0; i < words.size(); ++i) {
    if (i + kPrefetchAhead < words.size()) word_slots_.prefetch(words[i + kPrefetchAhead].key);
    words[i].slot = word_slots_.findOrInsert(words[i].key);
  }
  postings_.resize(word_slots_.size());
  std::vector<uint32_t> word_slots;
  word_slots.reserve(words.size());
  NormTerms terms;
  for (size_t i = 0; i < words.size(); ++i) {
    if (i + kPrefetchAhead < words.size()) {
      __builtin_prefetch(postings_[words[i + kPrefetchAhead].slot].data());
    }
    const uint32_t count = words[i].count;
    std::vector<uint32_t>& postings = postings_[words[i].slot];
    if (!postings.empty()) updateNorms(postings, postings.size(), postings.size() + 1);
    postings.push_back(document << 8 | count);
    const double log_df = std::log(static_cast<double>(postings.size()));
    const double c2 = static_cast<double>(count * count);
    terms.s0 += c2;
    terms.s1 += c2 * log_df;
    terms.s2 += c2 * log_df * log_df;
    word_slots.push_back(words[i].slot);
  }
  documents_[document] = Document{id, std::move(word_slots)};
  norm_terms_[document] = terms;
  document_of_[id] = document;
}

void PlaceIndex::remove(KeyFrameId id) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  removeLocked(id);
}

void PlaceIndex::removeLocked(KeyFrameId id) {
  const auto it = document_of_.find(id);
  if (it == document_of_.end()) return;
  const uint32_t document = it->second;
  document_of_.erase(it);
  for (uint32_t slot : documents_[document].word_slots) {
    std::vector<uint32_t>& postings = postings_[slot];
    const auto p = std::find_if(postings.begin(), postings.end(), [document](uint32_t posting) {
      return postingDocument(posting) == document;
    });
    *p = postings.back();
    postings.pop_back();
    if (postings.empty()) {
      std::vector<uint32_t>().swap(postings);
    } else {
      updateNorms(postings, postings.size() + 1, postings.size());
    }
  }
  documents_[document] = Document();
  norm_terms_[document] = NormTerms();
  free_documents_.push_back(document);
}

void PlaceIndex::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  word_slots_ = WordSlots();
  postings_.clear();
  documents_.clear();
  norm_terms_.clear();
  free_documents_.clear();
  document_of_.clear();
}

size_t PlaceIndex::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return document_of_.size();
}

std::vector<PlaceCandidate> PlaceIndex::query(const cv::Mat& descriptors, size_t max_results,
                                              double min_relative_score) const {
  checkDescriptors(descriptors, "PlaceIndex::query");
  if (descriptors.empty() || max_results == 0) return {};
  QueryScratch& scratch = queryScratch();
  hashDescriptors(descriptors, &scratch.keys);
  std::vector<WordCount>& words = scratch.words;
  countWords(scratch.keys, &words);

  std::shared_lock<std::shared_mutex> lock(mutex_);
  const size_t n = document_of_.size();
  if (n == 0) return {};
  scratch.accumulators.assign(documents_.size(), QueryScratch::Accumulator{0.0f, 0});
  const double log_n = std::log(static_cast<double>(n + 1));
  const double max_df = n >= kMinDocumentsForStopWords
                            ? config_.max_document_frequency * static_cast<double>(n)
                            : static_cast<double>(n);

  for (size_t i = 0; i < words.size(); ++i) {
    if (i + kPrefetchAhead < words.size()) word_slots_.prefetch(words[i + kPrefetchAhead].key);
    words[i].slot = word_slots_.find(words[i].key);
  }
  // The posting lists to visit and their weights, skipping stop words.
  double query_norm2 = 0.0;
  scratch.lists.clear();
  for (size_t i = 0; i < words.size(); ++i) {
    const size_t ahead = i + kPrefetchAhead;
    if (ahead < words.size() && words[ahead].slot != WordSlots::kAbsent) {
      __builtin_prefetch(&postings_[words[ahead].slot]);
    }
    if (words[i].slot == WordSlots::kAbsent) continue;
    const std::vector<uint32_t>& postings = postings_[words[i].slot];
    const size_t df = postings.size();
    if (df == 0 || static_cast<double>(df) > max_df) continue;
    const double idf = log_n - std::log(static_cast<double>(df));
    const double count = words[i].count;
    query_norm2 += count * idf * count * idf;
    scratch.lists.push_back(
        {postings.data(), static_cast<uint32_t>(df), static_cast<float>(count * idf * idf)});
  }

  // Votes: for each shared word, idf^2 * count in the query * count in the keyframe.
  const std::vector<QueryScratch::List>& lists = scratch.lists;
  QueryScratch::Accumulator* accumulators = scratch.accumulators.data();
  for (size_t i = 0; i < lists.size(); ++i) {
    if (i + kPrefetchAhead < lists.size()) __builtin_prefetch(lists[i + kPrefetchAhead].postings);
    const float weight = lists[i].weight;
    for (uint32_t k = 0; k < lists[i].df; ++k) {
      const uint32_t posting = lists[i].postings[k];
      QueryScratch::Accumulator& acc = accumulators[postingDocument(posting)];
      acc.dot += weight * static_cast<float>(postingCount(posting));
      ++acc.shared;
    }
  }

  // Cosine of each document sharing a word.
  scratch.scored.clear();
  for (uint32_t document = 0; document < documents_.size(); ++document) {
    if (accumulators[document].shared == 0) continue;
    const NormTerms& t = norm_terms_[document];
    const double norm2 = log_n * log_n * t.s0 - 2.0 * log_n * t.s1 + t.s2;
    const double score =
        accumulators[document].dot / std::sqrt(std::max(query_norm2 * norm2, 1e-300));
    scratch.scored.push_back({static_cast<float>(std::min(score, 1.0)), document});
  }
  const size_t k = std::min(max_results, scratch.scored.size());
  std::partial_sort(scratch.scored.begin(), scratch.scored.begin() + k, scratch.scored.end(),
                    [this](const QueryScratch::Scored& a, const QueryScratch::Scored& b) {
                      if (a.score != b.score) return a.score > b.score;
                      return documents_[a.document].id < documents_[b.document].id;
                    });
  std::vector<PlaceCandidate> candidates;
  candidates.reserve(k);
  for (size_t i = 0; i < k; ++i) {
    const QueryScratch::Scored& s = scratch.scored[i];
    if (s.score < min_relative_score * scratch.scored[0].score) break;
    PlaceCandidate c;
    c.keyframe = documents_[s.document].id;
    c.score = s.score;
    c.shared_words = static_cast<int>(accumulators[s.document].shared);
    candidates.push_back(c);
  }
  return candidates;
}

size_t PlaceIndex::memoryBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  size_t bytes = word_slots_.memoryBytes();
  bytes += postings_.capacity() * sizeof(std::vector<uint32_t>);
  for (const auto& postings : postings_) bytes += postings.capacity() * sizeof(uint32_t);
  bytes += documents_.capacity() * sizeof(Document);
  for (const Document& d : documents_) bytes += d.word_slots.capacity() * sizeof(uint32_t);
  bytes += norm_terms_.capacity() * sizeof(NormTerms);
  bytes += free_documents_.capacity() * sizeof(uint32_t);
  // Hash nodes (key, value, next pointer) and buckets.
  bytes += document_of_.size() * (sizeof(std::pair<KeyFrameId, uint32_t>) + sizeof(void*)) +
           document_of_.bucket_count() * sizeof(void*);
  return bytes;
}

// ------------------------------------------------------------ KeypointIndex

KeypointIndex::KeypointIndex(const KeypointIndexConfig& config) : config_(config) {
  if (config_.tables < 1 || config_.tables > 64) {
    throw Error("KeypointIndexConfig.tables must be in [1, 64], got " +
                std::to_string(config_.tables));
  }
  if (config_.bits < 1 || config_.bits > 20) {
    throw Error("KeypointIndexConfig.bits must be in [1, 20], got " + std::to_string(config_.bits));
  }
  drawBitPositions(config_.seed, config_.tables, config_.bits, &bit_bytes_, &bit_masks_);
  buckets_.resize(static_cast<size_t>(config_.tables) << config_.bits);
}

void KeypointIndex::wordsOf(const uint8_t* d, uint32_t* words) const {
  const int bits = config_.bits;
  for (int t = 0; t < config_.tables; ++t) {
    const uint8_t* bytes = &bit_bytes_[t * bits];
    const uint8_t* masks = &bit_masks_[t * bits];
    uint32_t word = 0;
    for (int b = 0; b < bits; ++b)
      word |= static_cast<uint32_t>((d[bytes[b]] & masks[b]) != 0) << b;
    words[t] = static_cast<uint32_t>(t) << bits | word;
  }
}

void KeypointIndex::add(KeyFrameId id, const cv::Mat& descriptors, const std::vector<int>& rows) {
  if (!id.valid()) throw Error("KeypointIndex::add: invalid keyframe id 0");
  checkDescriptors(descriptors, "KeypointIndex::add");
  for (int r : rows) {
    if (r < 0 || r >= descriptors.rows) {
      throw Error("KeypointIndex::add: row " + std::to_string(r) + " out of range");
    }
  }
  std::vector<uint32_t> words(config_.tables);
  std::unique_lock<std::shared_mutex> lock(mutex_);
  removeLocked(id);
  std::vector<uint32_t>& mine = entries_of_[id];
  for (int r : rows) {
    uint32_t e;
    if (!free_entries_.empty()) {
      e = free_entries_.back();
      free_entries_.pop_back();
    } else {
      e = static_cast<uint32_t>(entries_.size());
      entries_.emplace_back();
    }
    Entry& entry = entries_[e];
    entry.keyframe = id;
    entry.row = r;
    std::copy(descriptors.ptr<uint8_t>(r), descriptors.ptr<uint8_t>(r) + kDescriptorBytes,
              entry.descriptor.begin());
    wordsOf(entry.descriptor.data(), words.data());
    for (uint32_t w : words) buckets_[w].push_back(e);
    mine.push_back(e);
  }
}

void KeypointIndex::remove(KeyFrameId id) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  removeLocked(id);
}

void KeypointIndex::removeLocked(KeyFrameId id) {
  const auto it = entries_of_.find(id);
  if (it == entries_of_.end()) return;
  std::vector<uint32_t> words(config_.tables);
  for (uint32_t e : it->second) {
    wordsOf(entries_[e].descriptor.data(), words.data());
    for (uint32_t w : words) {
      std::vector<uint32_t>& bucket = buckets_[w];
      const auto p = std::find(bucket.begin(), bucket.end(), e);
      if (p != bucket.end()) {
        *p = bucket.back();
        bucket.pop_back();
        // An emptied bucket gives its memory back (as PlaceIndex's postings do): the
        // index holds what its keyframes need, not the most each bucket ever held.
        if (bucket.empty()) std::vector<uint32_t>().swap(bucket);
      }
    }
    entries_[e] = Entry();
    free_entries_.push_back(e);
  }
  entries_of_.erase(it);
}

void KeypointIndex::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  entries_.clear();
  free_entries_.clear();
  for (auto& bucket : buckets_) bucket.clear();
  entries_of_.clear();
}

size_t KeypointIndex::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return entries_of_.size();
}

size_t KeypointIndex::entries() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return entries_.size() - free_entries_.size();
}

size_t KeypointIndex::memoryBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  size_t bytes = entries_.capacity() * sizeof(Entry) + free_entries_.capacity() * sizeof(uint32_t);
  bytes += buckets_.capacity() * sizeof(std::vector<uint32_t>);
  for (const auto& bucket : buckets_) bytes += bucket.capacity() * sizeof(uint32_t);
  for (const auto& [id, rows] : entries_of_) {
    bytes += sizeof(id) + sizeof(rows) + sizeof(void*) + rows.capacity() * sizeof(uint32_t);
  }
  return bytes + entries_of_.bucket_count() * sizeof(void*);
}

std::vector<KeypointMatch> KeypointIndex::query(const cv::Mat& descriptors, int max_distance,
                                                int per_row) const {
  checkDescriptors(descriptors, "KeypointIndex::query");
  std::vector<KeypointMatch> out;
  if (descriptors.empty() || per_row <= 0) return out;
  std::vector<uint32_t> words(config_.tables);
  // Per entry: the stamp of the query row that last looked at it, so no entry
  // is checked twice for a row. Stamps grow across queries (no clearing of
  // millions of entries per query); the array restarts when they wrap.
  thread_local std::vector<uint32_t> seen;
  thread_local uint32_t stamp = 0;
  std::vector<std::pair<int, uint32_t>> hits;  // (distance, entry)
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (seen.size() < entries_.size()) seen.resize(entries_.size(), 0);
  if (stamp > std::numeric_limits<uint32_t>::max() - static_cast<uint32_t>(descriptors.rows) - 1) {
    std::fill(seen.begin(), seen.end(), 0);
    stamp = 0;
  }
  for (int r = 0; r < descriptors.rows; ++r) {
    const uint8_t* d = descriptors.ptr<uint8_t>(r);
    wordsOf(d, words.data());
    hits.clear();
    const uint32_t row_stamp = ++stamp;
    for (uint32_t w : words) {
      for (uint32_t e : buckets_[w]) {
        if (seen[e] == row_stamp) continue;
        seen[e] = row_stamp;
        const int dist = descriptorDistance(d, entries_[e].descriptor.data());
        if (dist <= max_distance) hits.emplace_back(dist, e);
      }
    }
    const size_t k = std::min<size_t>(per_row, hits.size());
    std::partial_sort(
        hits.begin(), hits.begin() + k, hits.end(), [this](const auto& a, const auto& b) {
          if (a.first != b.first) return a.first < b.first;
          const Entry& ea = entries_[a.second];
          const Entry& eb = entries_[b.second];
          return ea.keyframe != eb.keyframe ? ea.keyframe < eb.keyframe : ea.row < eb.row;
        });
    for (size_t i = 0; i < k; ++i) {
      const Entry& e = entries_[hits[i].second];
      out.push_back({r, e.keyframe, e.row, hits[i].first});
    }
  }
  return out;
}

}  // namespace ecar
