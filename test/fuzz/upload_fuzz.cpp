// Fuzz target: an upload as the server checks and decodes it. The first byte
// picks the part: odd = the JPEG bytes themselves (format, header and size
// checks, then libturbojpeg); even = the message's fields (ecar_bridge::fromMsg:
// gravity, odometry, stamps) with the rest as the image. After every input a
// valid JPEG must still decode on this thread: a failure must not leave state
// behind that refuses the next uploads (libturbojpeg's handle did).
#include <fuzzer/FuzzedDataProvider.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ecar_bridge/device_messages.h"
#include "ecar_core/common/error.h"

namespace {

double anyDouble(FuzzedDataProvider* in) {
  // Finite, huge, NaN and infinite values all come up.
  return in->ConsumeFloatingPoint<double>();
}

/// A valid 64x48 upload, encoded once.
const ecar_msgs::Upload& validUpload() {
  static const ecar_msgs::Upload upload = [] {
    ecar_msgs::Upload u;
    u.image.format = "jpeg";
    cv::Mat img(48, 64, CV_8UC1);
    cv::randu(img, 0, 255);
    cv::imencode(".jpg", img, u.image.data);
    return u;
  }();
  return upload;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  ecar_msgs::Upload upload;
  const bool fields = in.ConsumeIntegral<uint8_t>() % 2 == 0;
  if (fields) {
    upload.device_id = in.ConsumeRandomLengthString(80);
    upload.frame_index = in.ConsumeIntegral<uint32_t>();
    upload.header.stamp.sec = in.ConsumeIntegral<uint32_t>();
    upload.has_gravity = in.ConsumeBool();
    upload.gravity.x = anyDouble(&in);
    upload.gravity.y = anyDouble(&in);
    upload.gravity.z = anyDouble(&in);
    upload.has_odometry = in.ConsumeBool();
    auto& p = upload.odometry.position;
    auto& q = upload.odometry.orientation;
    p.x = anyDouble(&in), p.y = anyDouble(&in), p.z = anyDouble(&in);
    q.x = anyDouble(&in), q.y = anyDouble(&in), q.z = anyDouble(&in), q.w = anyDouble(&in);
    upload.image.format = in.ConsumeRandomLengthString(32);
    try {
      ecar_bridge::fromMsg(upload);
    } catch (const ecar::Error&) {
    }
  } else {
    upload.image.format = "jpeg";
  }
  upload.image.data = in.ConsumeRemainingBytes<uint8_t>();
  cv::Mat image;
  try {
    // A small camera, so that the fuzzer reaches decoding with small inputs.
    ecar_bridge::decodeImage(upload, 64, 48, &image);
  } catch (const ecar::Error&) {
  }
  try {
    ecar_bridge::decodeImage(validUpload(), 64, 48, &image);
  } catch (const ecar::Error& e) {
    std::fprintf(stderr, "a valid JPEG no longer decodes after this input: %s\n", e.what());
    std::abort();
  }
  return 0;
}
