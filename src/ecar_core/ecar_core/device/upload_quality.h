// The JPEG quality of a device's uploads on a shared uplink. The server gives
// each device its share of the devices' uplink (LocalGraph.upload_budget,
// bytes/s: the link's capacity times a target utilisation over the devices
// uploading); the device uploads at its configured quality while that fits,
// and lower when it does not, down to a floor. Without a budget nothing
// changes. Twenty devices on the paper's campus uplink (3.5 MB/s) get
// 87.5 kB/s each at utilisation 0.5, about 12 kB per upload at 7.5 uploads/s,
// where quality 70 makes 50 kB: uploading that anyway fills the link, and every
// upload then waits behind the others' (issue 13: 2.1 s median at 20 devices).
// What lower qualities cost in tracking accuracy is E4's sweep
// (scripts/reproduce.sh).
//
// The size of an upload at quality q is predicted as c * r(q): r is JPEG's
// relative size against quality 70 (a fixed curve, measured on the synthetic
// scenes; KITTI 07's is within 10% of it), c the scene's complexity, followed
// from the sizes of the uploads sent (an exponential average of size / r(q));
// the upload rate is that of the last 17 uploads.
//
//   UploadQuality quality(config);
//   quality.setBudget(graph.upload_budget);              // 0: none
//   const int q = quality.next();                        // for the next upload
//   ... encode at q, send ...
//   quality.sent(q, wire_bytes, now_seconds);
//
// The server side is UplinkShare: each upload counts its device as uploading
// for active_window seconds, and gets capacity * utilisation over the devices
// uploading as its budget.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <unordered_map>

namespace ecar {

struct UploadQualityConfig {
  int max_quality = 70;  ///< without a budget, and at most (1..100): the device's jpeg_quality
  int min_quality = 10;  ///< a budget never brings it lower (1..max_quality)
  /// A higher quality is taken only when its predicted rate fills at most
  /// this fraction of the budget (a lower one as soon as the rate exceeds
  /// it): no flipping between two levels on every upload. In (0, 1].
  double raise_fraction = 0.9;
  /// Weight of the newest upload in the average of the sizes, (0, 1]. The
  /// rate is that of the last 17 uploads (16 intervals, about 2 s).
  double smoothing = 0.25;
  /// Intervals between uploads longer than this (s) are pauses (a stall, a
  /// reconnection), not the device's rate: left out of the rate.
  double max_interval = 2.0;
  /// Uploads per second assumed until two were sent (every 4th frame at
  /// 30 fps), > 0.
  double nominal_rate = 7.5;
};

class UploadQuality {
 public:
  /// Throws ecar::Error naming the field of a value out of range.
  explicit UploadQuality(const UploadQualityConfig& config = UploadQualityConfig());

  /// The device's share of the uplink, bytes/s (<= 0 or not finite: none).
  void setBudget(double bytes_per_second);
  /// A new configured quality (dynamic_reconfigure), clamped to 1..100; the
  /// floor follows it when above.
  void setMaxQuality(int quality);

  /// The quality of the next upload: max_quality without a budget or before
  /// a size was seen, else the highest that the predicted size at the
  /// current rate keeps within the budget (min_quality at least).
  int next() const { return current_; }
  /// An upload of `bytes` (its wire size) encoded at `quality`, sent at
  /// `stamp` (seconds on a monotonic clock).
  void sent(int quality, size_t bytes, double stamp);
  /// A size seen without an upload (the first image encoded, a cached JPEG):
  /// the complexity, so that the first upload already fits.
  void observe(int quality, size_t bytes);
  /// Whether a size was seen (sent or observe).
  bool hasSize() const { return complexity_ > 0.0; }
  void setNominalRate(double uploads_per_second);

  double budget() const { return budget_; }
  /// Uploads per second: measured, or nominal_rate until two were sent.
  double rate() const { return rate_ > 0.0 ? rate_ : config_.nominal_rate; }
  /// Predicted bytes of an upload at `quality` (0 before the first upload).
  double predictedBytes(int quality) const;
  /// Whether even min_quality exceeds the budget at the current rate.
  bool overBudget() const;

  /// JPEG size at `quality` relative to quality 70 (the curve above).
  static double relativeSize(int quality);

 private:
  void choose();

  UploadQualityConfig config_;
  double budget_ = 0.0;
  double complexity_ = 0.0;  ///< bytes at quality 70 (0: none seen)
  /// Send stamps of the latest uploads (a ring; the rate is their count over
  /// their span: an average of intervals would follow a device that uploads
  /// frames 3 and 4 of two slots 33 ms apart, then waits 233 ms).
  std::array<double, 17> window_{};
  size_t window_count_ = 0, window_newest_ = 0;
  double rate_ = 0.0;  ///< uploads/s over the window (0: fewer than two seen)
  int current_ = 70;
};

struct UplinkShareConfig {
  double capacity = 0.0;       ///< bytes/s of the devices' shared uplink (0: unknown, no budgets)
  double utilisation = 0.5;    ///< of it, what the uploads may fill together, (0, 1]
  double active_window = 3.0;  ///< s: a device that uploaded within this is uploading
  /// Each of `devices` devices' budget, bytes/s (0 without a capacity), as a
  /// LocalGraph.upload_budget holds it.
  uint32_t budgetFor(size_t devices) const;
};

/// Budgets of the devices sharing one uplink. Not thread-safe.
class UplinkShare {
 public:
  /// Throws ecar::Error naming the field of a value out of range.
  explicit UplinkShare(const UplinkShareConfig& config = UplinkShareConfig());
  /// An upload of `device` at `stamp` (s, monotonic): its budget,
  /// config().budgetFor(the devices uploading).
  uint32_t onUpload(const std::string& device, double stamp);
  /// The device left (disconnected, timed out).
  void remove(const std::string& device) { last_upload_.erase(device); }
  /// Devices that uploaded within active_window of `now`.
  size_t uploading(double now) const;
  const UplinkShareConfig& config() const { return config_; }

 private:
  UplinkShareConfig config_;
  std::unordered_map<std::string, double> last_upload_;
};

}  // namespace ecar
