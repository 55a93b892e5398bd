// Uploaded JPEGs: the header read without decoding, the size checks that run
// before decoding, and strict decoding to grey (equal to OpenCV's decoder).
#include "ecar_core/io/jpeg.h"

#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::contains;
using ecar::testing::errorOf;

cv::Mat pattern(int width, int height) {
  cv::Mat img(height, width, CV_8UC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x)
      img.at<uint8_t>(y, x) = static_cast<uint8_t>((x * 7 + y * 3) % 251);
  }
  cv::circle(img, cv::Point(width / 2, height / 2), height / 4, cv::Scalar(255), -1);
  return img;
}

std::vector<uint8_t> encode(const cv::Mat& img, const std::string& ext, int quality = 90) {
  std::vector<uint8_t> bytes;
  std::vector<int> options;
  if (ext == ".jpg") options = {cv::IMWRITE_JPEG_QUALITY, quality};
  EXPECT_TRUE(cv::imencode(ext, img, bytes, options));
  return bytes;
}

TEST(JpegTest, ReadsTheHeaderAndDecodesToGreyLikeOpenCv) {
  const cv::Mat img = pattern(160, 120);
  for (const cv::Mat& source : {img, [&] {
                                  cv::Mat colour;
                                  cv::cvtColor(img, colour, cv::COLOR_GRAY2BGR);
                                  return colour;
                                }()}) {
    const std::vector<uint8_t> jpeg = encode(source, ".jpg");
    const JpegHeader h = readJpegHeader(jpeg.data(), jpeg.size());
    EXPECT_EQ(h.width, 160);
    EXPECT_EQ(h.height, 120);
    checkJpegFits(h, jpeg.size(), 160, 120);
    cv::Mat gray;
    decodeJpegGray(jpeg.data(), jpeg.size(), &gray, &h);
    ASSERT_EQ(gray.type(), CV_8UC1);
    ASSERT_EQ(gray.size(), cv::Size(160, 120));
    const cv::Mat reference = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
    double max_diff = 0.0;
    cv::minMaxLoc(cv::abs(gray - reference), nullptr, &max_diff);
    EXPECT_LE(max_diff, 1.0);  // the same library underneath
    // The buffer is reused when the size matches.
    const uint8_t* buffer = gray.data;
    decodeJpegGray(jpeg.data(), jpeg.size(), &gray);
    EXPECT_EQ(gray.data, buffer);
  }
}

TEST(JpegTest, RefusesOtherFormatsWrongSizesBombsAndDamageBeforeOrWhileDecoding) {
  const cv::Mat img = pattern(160, 120);
  const std::vector<uint8_t> jpeg = encode(img, ".jpg");
  // Other formats never reach a decoder.
  const std::vector<uint8_t> png = encode(img, ".png");
  EXPECT_TRUE(contains(errorOf([&] { readJpegHeader(png.data(), png.size()); }), "not a JPEG"));
  EXPECT_TRUE(contains(errorOf([&] { readJpegHeader(nullptr, 0); }), "no bytes"));
  const std::vector<uint8_t> junk(1000, 0xAB);
  EXPECT_TRUE(contains(errorOf([&] { readJpegHeader(junk.data(), junk.size()); }), "not a JPEG"));
  std::vector<uint8_t> soi_only = {0xFF, 0xD8, 0xFF, 0xE0, 0, 0};
  const std::string soi_error = errorOf([&] { readJpegHeader(soi_only.data(), soi_only.size()); });
  EXPECT_TRUE(contains(soi_error, "not a JPEG")) << soi_error;

  // A header of another size than the camera's: refused before any decoding.
  const JpegHeader h = readJpegHeader(jpeg.data(), jpeg.size());
  EXPECT_TRUE(contains(errorOf([&] { checkJpegFits(h, jpeg.size(), 640, 480); }),
                       "JPEG of 160x120, not the camera's 640x480"));
  // A huge image claimed in a small header (a decompression bomb) is refused the same way.
  const std::vector<uint8_t> big = encode(cv::Mat(4000, 6000, CV_8UC1, cv::Scalar(0)), ".jpg", 50);
  const JpegHeader hb = readJpegHeader(big.data(), big.size());
  EXPECT_EQ(hb.width, 6000);
  EXPECT_TRUE(
      contains(errorOf([&] { checkJpegFits(hb, big.size(), 160, 120); }), "not the camera's"));
  // More bytes than such an image takes.
  EXPECT_TRUE(contains(errorOf([&] { checkJpegFits(h, 160 * 120 * 8 + 65537, 160, 120); }),
                       "more than a 160x120 image may take"));

  // Truncated or damaged data fails instead of giving grey rows.
  cv::Mat gray;
  const std::vector<uint8_t> cut(jpeg.begin(), jpeg.begin() + static_cast<long>(jpeg.size() / 2));
  EXPECT_TRUE(
      contains(errorOf([&] { decodeJpegGray(cut.data(), cut.size(), &gray); }), "does not decode"));
  std::vector<uint8_t> damaged = jpeg;
  for (size_t i = damaged.size() / 2; i < damaged.size() / 2 + 64; ++i) damaged[i] = 0xFF;
  EXPECT_FALSE(errorOf([&] { decodeJpegGray(damaged.data(), damaged.size(), &gray); }).empty());
}

// A header that fails inside libjpeg's marker reader left libturbojpeg's
// handle broken: every later header on that thread failed with the same
// message (found by the soak: one hostile upload, then every device's uploads
// dropped on that server thread). The handle is replaced after a failure.
TEST(JpegTest, AFailureDoesNotBreakTheNextImages) {
  const cv::Mat img = pattern(160, 120);
  const std::vector<uint8_t> jpeg = encode(img, ".jpg");
  const std::vector<uint8_t> poison = {0xFF, 0xD8, 0xFF, 0x53, 0x00, 0x04, 0, 0, 0, 0, 0, 0};
  for (int round = 0; round < 3; ++round) {
    const std::string error = errorOf([&] { readJpegHeader(poison.data(), poison.size()); });
    EXPECT_TRUE(contains(error, "Unsupported marker type 0x53")) << error;
    const JpegHeader h = readJpegHeader(jpeg.data(), jpeg.size());
    EXPECT_EQ(h.width, 160);
    cv::Mat gray;
    EXPECT_FALSE(errorOf([&] { decodeJpegGray(poison.data(), poison.size(), &gray); }).empty());
    decodeJpegGray(jpeg.data(), jpeg.size(), &gray);
    EXPECT_EQ(gray.size(), cv::Size(160, 120));
    // A decoding failure (damaged data after a good header) too.
    std::vector<uint8_t> cut(jpeg.begin(), jpeg.begin() + static_cast<long>(jpeg.size() / 2));
    EXPECT_FALSE(errorOf([&] { decodeJpegGray(cut.data(), cut.size(), &gray); }).empty());
    decodeJpegGray(jpeg.data(), jpeg.size(), &gray, &h);
    EXPECT_EQ(gray.size(), cv::Size(160, 120));
  }
}

}  // namespace
}  // namespace ecar
