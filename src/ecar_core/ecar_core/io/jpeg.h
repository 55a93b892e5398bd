// Uploaded JPEGs, checked before they are decoded: the header's size against
// the camera's and the byte count against what such an image can take, so that
// neither another format's decoder nor a decompression bomb is ever reached.
//
//   const JpegHeader h = readJpegHeader(data, size);   // throws: not a JPEG
//   checkJpegFits(h, size, camera.width(), camera.height());
//   cv::Mat gray = decodeJpegGray(data, size, &h);     // libturbojpeg, straight to grey
//
// Thread-safety: reentrant (each call has its own libturbojpeg handle).
#pragma once

#include <cstddef>
#include <cstdint>

#include <opencv2/core.hpp>

namespace ecar {

struct JpegHeader {
  int width = 0;
  int height = 0;
};

/// The size in a JPEG's header (libturbojpeg), without decoding anything.
/// Throws ecar::Error ("not a JPEG ...") for other formats and for a header
/// that does not parse.
JpegHeader readJpegHeader(const uint8_t* data, size_t size);

/// Throws ecar::Error naming both sizes when the header's size is not
/// `width` x `height`, or when `size` bytes are more than such an image can
/// reasonably take (8 bytes per pixel + 64 KiB: a quality-100 colour JPEG
/// takes about 3).
void checkJpegFits(const JpegHeader& header, size_t size, int width, int height);

/// Decodes to 8-bit grey (libturbojpeg) into `out`, reusing its buffer when
/// it has the right size. `header` from readJpegHeader (read again when null).
/// Throws ecar::Error when the data does not decode cleanly: a truncated or
/// damaged image (libjpeg's warnings included) or a progressive one of more
/// than 500 scans.
void decodeJpegGray(const uint8_t* data, size_t size, cv::Mat* out,
                    const JpegHeader* header = nullptr);

}  // namespace ecar
