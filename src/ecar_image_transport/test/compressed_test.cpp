// The "compressed" transport end to end through image_transport (publisher plugin ->
// sensor_msgs/CompressedImage -> subscriber plugin), run by compressed.test.
#include <gtest/gtest.h>

#include <cmath>
#include <mutex>
#include <vector>

#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/image_encodings.h>

namespace {

namespace enc = sensor_msgs::image_encodings;

// A smooth test pattern (JPEG keeps it within a few grey levels).
sensor_msgs::Image pattern(const std::string& encoding, uint32_t width, uint32_t height) {
  const uint32_t channels = encoding == enc::MONO8 ? 1 : 3;
  sensor_msgs::Image image;
  image.encoding = encoding;
  image.width = width;
  image.height = height;
  image.step = width * channels;
  image.data.resize(static_cast<size_t>(image.step) * height);
  for (uint32_t r = 0; r < height; ++r) {
    for (uint32_t c = 0; c < width; ++c) {
      for (uint32_t k = 0; k < channels; ++k) {
        const double v = 128.0 + 100.0 * std::sin(0.05 * c + 0.9 * k) * std::cos(0.04 * r);
        image.data[r * image.step + c * channels + k] = static_cast<uint8_t>(v);
      }
    }
  }
  return image;
}

double meanAbsDifference(const sensor_msgs::Image& a, const sensor_msgs::Image& b) {
  double sum = 0.0;
  for (size_t i = 0; i < a.data.size(); ++i) sum += std::abs(int(a.data[i]) - int(b.data[i]));
  return sum / static_cast<double>(a.data.size());
}

class Compressed : public ::testing::Test {
 protected:
  Compressed() : it_(nh_) {}

  void SetUp() override {
    pub_ = it_.advertise("image", 5);
    sub_ = it_.subscribe("image", 5, &Compressed::onImage, this,
                         image_transport::TransportHints("compressed"));
    raw_pub_ = nh_.advertise<sensor_msgs::CompressedImage>("image/compressed", 5);
    ASSERT_TRUE(waitFor([&] { return pub_.getNumSubscribers() > 0; }))
        << "the compressed subscriber never connected";
  }

  void onImage(const sensor_msgs::ImageConstPtr& image) {
    std::lock_guard<std::mutex> lock(mutex_);
    received_.push_back(image);
  }

  template <typename Predicate>
  bool waitFor(Predicate done, double seconds = 5.0) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::WallTime::now() < end) {
      ros::spinOnce();
      if (done()) return true;
      ros::WallDuration(0.01).sleep();
    }
    return false;
  }

  size_t count() {
    std::lock_guard<std::mutex> lock(mutex_);
    return received_.size();
  }

  sensor_msgs::ImageConstPtr roundTrip(const sensor_msgs::Image& image) {
    const size_t before = count();
    pub_.publish(image);
    if (!waitFor([&] { return count() > before; })) return nullptr;
    std::lock_guard<std::mutex> lock(mutex_);
    return received_.back();
  }

  ros::NodeHandle nh_;
  image_transport::ImageTransport it_;
  image_transport::Publisher pub_;
  image_transport::Subscriber sub_;
  ros::Publisher raw_pub_;
  std::mutex mutex_;
  std::vector<sensor_msgs::ImageConstPtr> received_;
};

TEST_F(Compressed, GreyAndColourArriveDecodedAsJpeg) {
  for (const std::string& encoding : {enc::MONO8, enc::BGR8}) {
    sensor_msgs::Image image = pattern(encoding, 160, 120);
    image.header.seq = 17;
    image.header.frame_id = "camera";
    image.header.stamp = ros::Time(12.5);
    const sensor_msgs::ImageConstPtr out = roundTrip(image);
    ASSERT_TRUE(out) << encoding << " image never arrived";
    EXPECT_EQ(out->encoding, encoding);
    EXPECT_EQ(out->width, 160u);
    EXPECT_EQ(out->height, 120u);
    EXPECT_EQ(out->header.frame_id, "camera");
    EXPECT_EQ(out->header.stamp, ros::Time(12.5));
    ASSERT_EQ(out->data.size(), image.data.size());
    EXPECT_LT(meanAbsDifference(*out, image), 3.0) << encoding;
  }
}

TEST_F(Compressed, PngIsLossless) {
  ros::param::set(pub_.getTopic() + "/compressed/format", "png");
  const sensor_msgs::Image image = pattern(enc::MONO8, 64, 48);
  const sensor_msgs::ImageConstPtr out = roundTrip(image);
  ros::param::set(pub_.getTopic() + "/compressed/format", "jpeg");
  ASSERT_TRUE(out);
  EXPECT_EQ(out->data, image.data);
}

TEST_F(Compressed, StrideIsHonoured) {
  sensor_msgs::Image image = pattern(enc::MONO8, 50, 20);
  sensor_msgs::Image padded = image;
  padded.step = 64;
  padded.data.assign(static_cast<size_t>(padded.step) * padded.height, 0);
  for (uint32_t r = 0; r < image.height; ++r) {
    std::copy(image.data.begin() + r * image.step, image.data.begin() + (r + 1) * image.step,
              padded.data.begin() + r * padded.step);
  }
  const sensor_msgs::ImageConstPtr out = roundTrip(padded);
  ASSERT_TRUE(out);
  EXPECT_EQ(out->step, 50u);
  EXPECT_LT(meanAbsDifference(*out, image), 3.0);
}

TEST_F(Compressed, BadInputIsDroppedAndTheNextImageArrives) {
  // Unsupported encoding and a truncated buffer: nothing is published.
  sensor_msgs::Image float_image = pattern(enc::MONO8, 8, 8);
  float_image.encoding = enc::TYPE_32FC1;
  pub_.publish(float_image);
  sensor_msgs::Image truncated = pattern(enc::BGR8, 32, 32);
  truncated.data.resize(100);
  pub_.publish(truncated);
  // Corrupt CompressedImage messages straight onto the topic: dropped by the subscriber.
  sensor_msgs::CompressedImage junk;
  junk.format = "mono8; jpeg compressed mono8";
  junk.data = {0xFF, 0xD8, 0xFF, 0x00, 0x12, 0x34};
  ASSERT_TRUE(waitFor([&] { return raw_pub_.getNumSubscribers() > 0; }));
  raw_pub_.publish(junk);
  junk.data.clear();
  raw_pub_.publish(junk);
  ros::WallDuration(0.3).sleep();
  ros::spinOnce();
  EXPECT_EQ(count(), 0u) << "bad input produced an image";
  const sensor_msgs::ImageConstPtr out = roundTrip(pattern(enc::MONO8, 40, 30));
  ASSERT_TRUE(out) << "no image after bad input";
  EXPECT_EQ(out->width, 40u);
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "compressed_test");
  ros::NodeHandle nh;
  return RUN_ALL_TESTS();
}
