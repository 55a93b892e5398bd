// A device's upload quality within the uplink share the server gives it.
#include "ecar_core/device/upload_quality.h"

#include <cmath>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

constexpr double kPeriod = 1.0 / 7.5;  // every 4th frame at 30 fps

/// A textured 640x480 grey image with sensor noise, as the scenes render.
cv::Mat texturedImage(int seed) {
  cv::RNG rng(seed);
  cv::Mat image(480, 640, CV_8UC1, cv::Scalar(128));
  for (int i = 0; i < 400; ++i) {
    const cv::Point c(rng.uniform(0, 640), rng.uniform(0, 480));
    cv::circle(image, c, rng.uniform(3, 40), cv::Scalar(rng.uniform(0, 255)), cv::FILLED);
  }
  cv::Mat noise(image.size(), CV_16SC1);
  rng.fill(noise, cv::RNG::NORMAL, 0, 2.0);
  cv::Mat noisy;
  image.convertTo(noisy, CV_16SC1);
  noisy += noise;
  noisy.convertTo(image, CV_8UC1);
  return image;
}

size_t jpegBytes(const cv::Mat& image, int quality) {
  std::vector<uint8_t> jpeg;
  cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, quality});
  return jpeg.size() + 200;  // the Upload message's other fields
}

TEST(UploadQuality, WithoutABudgetEveryUploadIsAtTheConfiguredQuality) {
  UploadQuality q;
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(q.next(), 70);
    q.sent(q.next(), 50000, i * kPeriod);
  }
  q.setBudget(0.0);
  EXPECT_EQ(q.next(), 70);
  q.setBudget(std::nan(""));
  EXPECT_EQ(q.next(), 70);
  EXPECT_FALSE(q.overBudget());
}

TEST(UploadQuality, ABudgetThatFitsKeepsTheConfiguredQuality) {
  UploadQuality q;
  q.setBudget(1e6);  // 133 kB per upload at 7.5 per second
  for (int i = 0; i < 20; ++i) q.sent(q.next(), 50000, i * kPeriod);
  EXPECT_EQ(q.next(), 70);
  EXPECT_NEAR(q.rate(), 7.5, 1e-6);
}

TEST(UploadQuality, RealJpegsSettleWithinTheBudgetAndUseIt) {
  // The campus uplink's 3.5 MB/s at utilisation 0.5 over 8 devices.
  const double budget = 3.5e6 * 0.5 / 8;
  const cv::Mat image = texturedImage(1);
  const double at70 = static_cast<double>(jpegBytes(image, 70)) / kPeriod;
  ASSERT_GT(at70, 1.3 * budget) << "the test image must not fit the budget at quality 70";
  UploadQuality q;
  q.setBudget(budget);
  std::set<int> late_qualities;
  double late_bytes = 0.0;
  for (int i = 0; i < 60; ++i) {
    const int quality = q.next();
    const size_t bytes = jpegBytes(image, quality);
    q.sent(quality, bytes, i * kPeriod);
    if (i >= 30) {
      late_qualities.insert(quality);
      late_bytes += static_cast<double>(bytes);
    }
  }
  const double rate = late_bytes / (30 * kPeriod);
  EXPECT_LE(rate, budget) << "quality " << q.next();
  EXPECT_GE(rate, 0.75 * budget) << "quality " << q.next() << ": the budget is not used";
  EXPECT_LT(q.next(), 70);
  EXPECT_GE(q.next(), 10);
  EXPECT_EQ(late_qualities.size(), 1u) << "the quality keeps changing";
  EXPECT_FALSE(q.overBudget());
}

TEST(UploadQuality, AnotherImageOfTheSameBudgetGetsItsOwnQuality) {
  // A detailed image needs a lower quality than a plain one for the same bytes.
  const double budget = 150000.0;
  cv::Mat plain;
  cv::GaussianBlur(texturedImage(2), plain, cv::Size(9, 9), 3.0);
  const cv::Mat detailed = texturedImage(2);
  int settled[2] = {0, 0};
  for (int k = 0; k < 2; ++k) {
    const cv::Mat& image = k == 0 ? plain : detailed;
    UploadQuality q;
    q.setBudget(budget);
    for (int i = 0; i < 40; ++i) q.sent(q.next(), jpegBytes(image, q.next()), i * kPeriod);
    settled[k] = q.next();
    EXPECT_LE(static_cast<double>(jpegBytes(image, settled[k])) / kPeriod, budget) << k;
  }
  EXPECT_GT(settled[0], settled[1]);
}

TEST(UploadQuality, AnObservedSizeMakesTheFirstUploadFit) {
  // The server's budget comes with the connection, before the first upload:
  // a size seen (the first image encoded, a cached JPEG) sets the quality.
  UploadQuality q;
  q.setBudget(200000.0);  // 26.7 kB per upload at the nominal 7.5 per second
  EXPECT_EQ(q.next(), 70);
  q.observe(70, 50000);
  EXPECT_LT(q.next(), 70);
  EXPECT_LE(q.predictedBytes(q.next()) * 7.5, 200000.0);
  EXPECT_GT(q.predictedBytes(q.next() + 1) * 7.5, 0.9 * 200000.0);
  // A light device playing at a quarter of real time uploads less often.
  q.setNominalRate(7.5 / 4);
  EXPECT_EQ(q.next(), 70);
}

TEST(UploadQuality, TheFloorHoldsWhenNothingFits) {
  UploadQualityConfig c;
  c.min_quality = 20;
  UploadQuality q(c);
  q.setBudget(10000.0);  // 1.3 kB per upload
  for (int i = 0; i < 20; ++i)
    q.sent(q.next(), 50000.0 * UploadQuality::relativeSize(q.next()), i * kPeriod);
  EXPECT_EQ(q.next(), 20);
  EXPECT_TRUE(q.overBudget());
}

TEST(UploadQuality, ALargerBudgetRaisesTheQualityAndNoneRestoresIt) {
  UploadQuality q;
  const auto bytes = [](int quality) { return 50000.0 * UploadQuality::relativeSize(quality); };
  q.setBudget(120000.0);  // 16 kB per upload
  int i = 0;
  for (; i < 20; ++i) q.sent(q.next(), bytes(q.next()), i * kPeriod);
  const int low = q.next();
  EXPECT_LE(bytes(low) * 7.5, 120000.0);
  q.setBudget(240000.0);  // fewer devices share the link now
  for (; i < 40; ++i) q.sent(q.next(), bytes(q.next()), i * kPeriod);
  EXPECT_GT(q.next(), low);
  EXPECT_LE(bytes(q.next()) * 7.5, 240000.0);
  q.setBudget(0.0);
  EXPECT_EQ(q.next(), 70);
}

TEST(UploadQuality, APauseIsNotTheUploadRate) {
  UploadQuality q;
  for (int i = 0; i < 10; ++i) q.sent(70, 50000, i * kPeriod);
  q.sent(70, 50000, 100.0);  // reconnected after a long silence
  q.sent(70, 50000, 100.0 + kPeriod);
  EXPECT_NEAR(q.rate(), 7.5, 1e-6);
}

TEST(UploadQuality, TheRateOfUnevenIntervalsIsTheirCountOverTheirSpan) {
  // A device that falls behind uploads the last frame of one slot and the first
  // of the next 33 ms apart, then waits 233 ms: still 7.5 uploads per second.
  UploadQuality q;
  double t = 0.0;
  for (int i = 0; i < 20; ++i) {
    q.sent(70, 50000, t);
    t += i % 2 == 0 ? 1.0 / 30 : 7.0 / 30;
  }
  EXPECT_NEAR(q.rate(), 7.5, 0.1);
}

TEST(UploadQuality, TheRelativeSizeGrowsWithTheQuality) {
  EXPECT_DOUBLE_EQ(UploadQuality::relativeSize(70), 1.0);
  for (int quality = 2; quality <= 100; ++quality) {
    EXPECT_GT(UploadQuality::relativeSize(quality), UploadQuality::relativeSize(quality - 1))
        << quality;
  }
  EXPECT_DOUBLE_EQ(UploadQuality::relativeSize(0), UploadQuality::relativeSize(1));
  EXPECT_DOUBLE_EQ(UploadQuality::relativeSize(500), UploadQuality::relativeSize(100));
}

TEST(UploadQuality, BadConfigsAreRefusedByName) {
  const auto message = [](const UploadQualityConfig& c) {
    try {
      UploadQuality q(c);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  UploadQualityConfig c;
  c.max_quality = 0;
  EXPECT_NE(message(c).find("max_quality"), std::string::npos);
  c = UploadQualityConfig();
  c.min_quality = 80;
  EXPECT_NE(message(c).find("min_quality"), std::string::npos);
  c = UploadQualityConfig();
  c.raise_fraction = 0.0;
  EXPECT_NE(message(c).find("raise_fraction"), std::string::npos);
  c = UploadQualityConfig();
  c.smoothing = std::nan("");
  EXPECT_NE(message(c).find("smoothing"), std::string::npos);
}

TEST(UplinkShare, TheCapacityIsSharedByTheDevicesUploading) {
  UplinkShareConfig c;
  c.capacity = 3.5e6;  // the paper's campus uplink
  c.utilisation = 0.5;
  UplinkShare share(c);
  EXPECT_DOUBLE_EQ(share.onUpload("device_0", 0.0), 1.75e6);
  EXPECT_DOUBLE_EQ(share.onUpload("device_1", 0.1), 1.75e6 / 2);
  EXPECT_DOUBLE_EQ(share.onUpload("device_0", 0.2), 1.75e6 / 2);
  for (int i = 2; i < 20; ++i) share.onUpload("device_" + std::to_string(i), 0.3);
  EXPECT_DOUBLE_EQ(share.onUpload("device_0", 0.4), 87500.0);
  EXPECT_EQ(share.uploading(0.4), 20u);
  // device_1 .. device_19 stop uploading: device_0 has the link again.
  EXPECT_DOUBLE_EQ(share.onUpload("device_0", 3.35), 1.75e6);
  EXPECT_DOUBLE_EQ(share.onUpload("device_1", 3.4), 1.75e6 / 2);
  share.remove("device_1");
  EXPECT_DOUBLE_EQ(share.onUpload("device_0", 3.5), 1.75e6);
}

TEST(UplinkShare, NoCapacityMeansNoBudget) {
  UplinkShare share;
  EXPECT_EQ(share.onUpload("device_0", 0.0), 0.0);
  UplinkShareConfig c;
  c.utilisation = 1.5;
  EXPECT_THROW(UplinkShare{c}, Error);
  c = UplinkShareConfig();
  c.capacity = -1.0;
  EXPECT_THROW(UplinkShare{c}, Error);
}

}  // namespace
}  // namespace ecar
