#include "ecar_core/device/upload_quality.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <utility>

#include "ecar_core/common/error.h"

namespace ecar {

namespace {

// JPEG bytes (libjpeg through OpenCV, 8-bit grey, 640x480) at a quality over
// those at quality 70: medians over 50 frames of the corridor and room scenes;
// KITTI 07's 1226x370 frames are within 10% of it.
constexpr std::array<std::pair<int, double>, 17> kRelativeSize = {{{1, 0.127},
                                                                   {3, 0.146},
                                                                   {5, 0.200},
                                                                   {10, 0.309},
                                                                   {15, 0.396},
                                                                   {20, 0.468},
                                                                   {25, 0.531},
                                                                   {30, 0.586},
                                                                   {40, 0.679},
                                                                   {50, 0.766},
                                                                   {60, 0.859},
                                                                   {70, 1.000},
                                                                   {80, 1.228},
                                                                   {85, 1.418},
                                                                   {90, 1.761},
                                                                   {95, 2.547},
                                                                   {100, 4.251}}};

}  // namespace

double UploadQuality::relativeSize(int quality) {
  quality = std::clamp(quality, 1, 100);
  for (size_t i = 1; i < kRelativeSize.size(); ++i) {
    const auto& [q1, r1] = kRelativeSize[i];
    if (quality > q1) continue;
    const auto& [q0, r0] = kRelativeSize[i - 1];
    return r0 + (r1 - r0) * static_cast<double>(quality - q0) / static_cast<double>(q1 - q0);
  }
  return kRelativeSize.back().second;
}

UploadQuality::UploadQuality(const UploadQualityConfig& config) : config_(config) {
  if (config_.max_quality < 1 || config_.max_quality > 100) {
    throw Error("upload quality: max_quality must be in 1..100");
  }
  if (config_.min_quality < 1 || config_.min_quality > config_.max_quality) {
    throw Error("upload quality: min_quality must be in 1..max_quality");
  }
  if (!(config_.raise_fraction > 0.0 && config_.raise_fraction <= 1.0)) {
    throw Error("upload quality: raise_fraction must be in (0, 1]");
  }
  if (!(config_.smoothing > 0.0 && config_.smoothing <= 1.0)) {
    throw Error("upload quality: smoothing must be in (0, 1]");
  }
  if (!(config_.max_interval > 0.0) || !std::isfinite(config_.max_interval)) {
    throw Error("upload quality: max_interval must be > 0");
  }
  if (!(config_.nominal_rate > 0.0) || !std::isfinite(config_.nominal_rate)) {
    throw Error("upload quality: nominal_rate must be > 0");
  }
  current_ = config_.max_quality;
}

void UploadQuality::setBudget(double bytes_per_second) {
  budget_ = std::isfinite(bytes_per_second) && bytes_per_second > 0.0 ? bytes_per_second : 0.0;
  choose();
}

void UploadQuality::setMaxQuality(int quality) {
  config_.max_quality = std::clamp(quality, 1, 100);
  config_.min_quality = std::min(config_.min_quality, config_.max_quality);
  current_ = std::clamp(current_, config_.min_quality, config_.max_quality);
  choose();
}

void UploadQuality::observe(int quality, size_t bytes) {
  if (bytes > 0) {
    const double w = config_.smoothing;
    const double c = static_cast<double>(bytes) / relativeSize(quality);
    complexity_ = complexity_ > 0.0 ? (1.0 - w) * complexity_ + w * c : c;
  }
  choose();
}

void UploadQuality::setNominalRate(double uploads_per_second) {
  if (std::isfinite(uploads_per_second) && uploads_per_second > 0.0) {
    config_.nominal_rate = uploads_per_second;
  }
  choose();
}

void UploadQuality::sent(int quality, size_t bytes, double stamp) {
  observe(quality, bytes);
  if (std::isfinite(stamp)) {
    // A pause (or a clock going back) starts the window again.
    const bool pause =
        window_count_ > 0 && (stamp - window_[window_newest_] > config_.max_interval ||
                              stamp <= window_[window_newest_]);
    if (pause) window_count_ = 0;
    window_newest_ = (window_newest_ + 1) % window_.size();
    window_[window_newest_] = stamp;
    window_count_ = std::min(window_count_ + 1, window_.size());
    if (window_count_ >= 2) {
      const size_t oldest = (window_newest_ + window_.size() + 1 - window_count_) % window_.size();
      rate_ = static_cast<double>(window_count_ - 1) / (stamp - window_[oldest]);
    }
  }
  choose();
}

double UploadQuality::predictedBytes(int quality) const {
  return complexity_ * relativeSize(quality);
}

bool UploadQuality::overBudget() const {
  return budget_ > 0.0 && complexity_ > 0.0 &&
         predictedBytes(config_.min_quality) * rate() > budget_;
}

void UploadQuality::choose() {
  if (budget_ <= 0.0 || complexity_ <= 0.0) {
    current_ = config_.max_quality;
    return;
  }
  const double rate = this->rate();
  const auto fits = [&](int q, double fraction) {
    return predictedBytes(q) * rate <= fraction * budget_;
  };
  // Down at once to the highest quality that fits; up only with headroom.
  int q = std::clamp(current_, config_.min_quality, config_.max_quality);
  while (q > config_.min_quality && !fits(q, 1.0)) --q;
  while (q < config_.max_quality && fits(q + 1, config_.raise_fraction)) ++q;
  current_ = q;
}

UplinkShare::UplinkShare(const UplinkShareConfig& config) : config_(config) {
  if (!(config_.capacity >= 0.0) || !std::isfinite(config_.capacity)) {
    throw Error("uplink share: capacity must be >= 0 bytes/s");
  }
  if (!(config_.utilisation > 0.0 && config_.utilisation <= 1.0)) {
    throw Error("uplink share: utilisation must be in (0, 1]");
  }
  if (!(config_.active_window > 0.0) || !std::isfinite(config_.active_window)) {
    throw Error("uplink share: active_window must be > 0 s");
  }
}

uint32_t UplinkShareConfig::budgetFor(size_t devices) const {
  if (!(capacity > 0.0)) return 0;
  const double share = capacity * utilisation / static_cast<double>(std::max<size_t>(1, devices));
  return static_cast<uint32_t>(std::min(share, 4e9));
}

uint32_t UplinkShare::onUpload(const std::string& device, double stamp) {
  last_upload_[device] = stamp;
  for (auto it = last_upload_.begin(); it != last_upload_.end();) {
    it = stamp - it->second > config_.active_window ? last_upload_.erase(it) : std::next(it);
  }
  return config_.budgetFor(uploading(stamp));
}

size_t UplinkShare::uploading(double now) const {
  size_t n = 0;
  for (const auto& entry : last_upload_) {
    if (now - entry.second <= config_.active_window) ++n;
  }
  return n;
}

}  // namespace ecar
