// Fuzz target: an upload as the server checks and decodes it. The first byte
// picks the part: odd = the JPEG bytes themselves (format, header and size
// checks, then libturbojpeg); even = the message's fields (ecar_bridge::fromMsg:
// gravity, odometry, stamps) with the rest as the image.
#include <fuzzer/FuzzedDataProvider.h>

#include <cstdint>

#include <opencv2/core.hpp>

#include "ecar_bridge/device_messages.h"
#include "ecar_core/common/error.h"

namespace {

double anyDouble(FuzzedDataProvider* in) {
  // Finite, huge, NaN and infinite values all come up.
  return in->ConsumeFloatingPoint<double>();
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
  return 0;
}
