// The "compressed" image_transport plugins: JPEG (or PNG) in a
// sensor_msgs/CompressedImage on <topic>/compressed, with the format string of
// compressed_image_transport ("<encoding>; jpeg compressed <encoding>"), so
// either end may be that package's.
#include <string>
#include <vector>

#include <image_transport/simple_publisher_plugin.h>
#include <image_transport/simple_subscriber_plugin.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <opencv2/imgcodecs.hpp>
#include <pluginlib/class_list_macros.hpp>

namespace ecar_image_transport {
namespace enc = sensor_msgs::image_encodings;

class CompressedPublisher
    : public image_transport::SimplePublisherPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void publish(const sensor_msgs::Image& image, const PublishFn& publish_fn) const override {
    int type = 0;
    if (image.encoding == enc::MONO8) {
      type = CV_8UC1;
    } else if (image.encoding == enc::BGR8) {
      type = CV_8UC3;
    } else {
      ROS_WARN_THROTTLE(5.0, "%s: encoding '%s' not compressed (mono8 or bgr8 only)",
                        getTopic().c_str(), image.encoding.c_str());
      return;
    }
    if (image.step < image.width * (type == CV_8UC1 ? 1u : 3u) ||
        image.data.size() < static_cast<size_t>(image.step) * image.height) {
      ROS_WARN_THROTTLE(5.0, "%s: image of %ux%u with step %u and %zu bytes: not compressed",
                        getTopic().c_str(), image.width, image.height, image.step,
                        image.data.size());
      return;
    }
    const ros::NodeHandle& params = nh();
    std::string format = "jpeg";
    int quality = 80;
    params.param("format", format, format);
    params.param("jpeg_quality", quality, quality);
    const cv::Mat mat(static_cast<int>(image.height), static_cast<int>(image.width), type,
                      const_cast<uint8_t*>(image.data.data()), image.step);
    sensor_msgs::CompressedImage out;
    out.header = image.header;
    const bool png = format == "png";
    out.format = image.encoding + "; " + (png ? "png" : "jpeg") + " compressed " + image.encoding;
    std::vector<int> options;
    if (!png) options = {cv::IMWRITE_JPEG_QUALITY, std::max(1, std::min(100, quality))};
    if (!cv::imencode(png ? ".png" : ".jpg", mat, out.data, options)) {
      ROS_WARN_THROTTLE(5.0, "%s: %s encoding failed", getTopic().c_str(), png ? "PNG" : "JPEG");
      return;
    }
    publish_fn(out);
  }
};

class CompressedSubscriber
    : public image_transport::SimpleSubscriberPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void internalCallback(const sensor_msgs::CompressedImage::ConstPtr& msg,
                        const Callback& user_cb) override {
    cv::Mat mat;
    try {
      mat = cv::imdecode(cv::Mat(1, static_cast<int>(msg->data.size()), CV_8U,
                                 const_cast<uint8_t*>(msg->data.data())),
                         cv::IMREAD_UNCHANGED);
    } catch (const cv::Exception&) {
      mat.release();
    }
    if (mat.empty() || mat.depth() != CV_8U || (mat.channels() != 1 && mat.channels() != 3)) {
      ROS_WARN_THROTTLE(5.0,
                        "%s: compressed image of %zu bytes (format '%s') does not decode "
                        "to 8-bit grey or colour: dropped",
                        getTopic().c_str(), msg->data.size(), msg->format.c_str());
      return;
    }
    auto image = boost::make_shared<sensor_msgs::Image>();
    image->header = msg->header;
    image->height = static_cast<uint32_t>(mat.rows);
    image->width = static_cast<uint32_t>(mat.cols);
    image->encoding = mat.channels() == 1 ? enc::MONO8 : enc::BGR8;
    image->is_bigendian = false;
    image->step = static_cast<uint32_t>(mat.cols * mat.channels());
    image->data.resize(static_cast<size_t>(image->step) * image->height);
    for (int r = 0; r < mat.rows; ++r) {
      std::copy(mat.ptr<uint8_t>(r), mat.ptr<uint8_t>(r) + image->step,
                image->data.begin() + static_cast<long>(r) * image->step);
    }
    user_cb(image);
  }
};

}  // namespace ecar_image_transport

PLUGINLIB_EXPORT_CLASS(ecar_image_transport::CompressedPublisher, image_transport::PublisherPlugin)
PLUGINLIB_EXPORT_CLASS(ecar_image_transport::CompressedSubscriber,
                       image_transport::SubscriberPlugin)
