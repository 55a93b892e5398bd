#include "ecar_core/io/jpeg.h"

#include <turbojpeg.h>

#include <string>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

/// A decompression handle, destroyed on scope exit.
///
/// libturbojpeg (2.1) leaves a handle unusable after some errors: a header that
/// fails inside libjpeg's marker reader (e.g. "Unsupported marker type 0x53")
/// skips the abort that resets the decompressor, and every later call on that
/// handle fails with the same message, valid JPEGs included. So a handle that
/// failed is replaced (renew()) before its error is reported: one hostile upload
/// must not make a server thread refuse every upload after it.
class Decompressor {
 public:
  Decompressor() : handle_(create()) {}
  ~Decompressor() { tjDestroy(handle_); }
  Decompressor(const Decompressor&) = delete;
  Decompressor& operator=(const Decompressor&) = delete;
  tjhandle get() const { return handle_; }

  /// A fresh handle in place of this one (after a failure).
  void renew() {
    tjhandle fresh = create();
    tjDestroy(handle_);
    handle_ = fresh;
  }

 private:
  static tjhandle create() {
    tjhandle h = tjInitDecompress();
    if (h == nullptr) throw Error("JPEG: cannot create a libturbojpeg decompressor");
    return h;
  }
  tjhandle handle_;
};

/// libturbojpeg's message for the last error of `handle`.
std::string lastError(tjhandle handle) {
  const char* text = tjGetErrorStr2(handle);
  return text != nullptr ? text : "unknown error";
}

/// A JPEG starts with SOI (FF D8) and a marker.
bool hasJpegSignature(const uint8_t* data, size_t size) {
  return size >= 4 && data[0] == 0xFF && data[1] == 0xD8 && data[2] == 0xFF;
}

JpegHeader readHeader(Decompressor& d, const uint8_t* data, size_t size) {
  if (data == nullptr || size == 0) throw Error("not a JPEG: no bytes");
  if (!hasJpegSignature(data, size)) {
    throw Error("not a JPEG (" + std::to_string(size) + " bytes without the FF D8 FF start)");
  }
  int width = 0, height = 0, subsampling = 0, colorspace = 0;
  if (tjDecompressHeader3(d.get(), data, static_cast<unsigned long>(size), &width, &height,
                          &subsampling, &colorspace) != 0) {
    const std::string error = lastError(d.get());
    d.renew();
    throw Error("not a JPEG: its header does not parse (" + error + ")");
  }
  if (width <= 0 || height <= 0) throw Error("not a JPEG: its header gives no size");
  return {width, height};
}

/// One handle per thread, made on its first use (creating one per image costs as much as a
/// tenth of decoding it).
Decompressor& threadDecompressor() {
  thread_local Decompressor d;
  return d;
}

}  // namespace

JpegHeader readJpegHeader(const uint8_t* data, size_t size) {
  return readHeader(threadDecompressor(), data, size);
}

void checkJpegFits(const JpegHeader& header, size_t size, int width, int height) {
  if (header.width != width || header.height != height) {
    throw Error("JPEG of " + std::to_string(header.width) + "x" + std::to_string(header.height) +
                ", not the camera's " + std::to_string(width) + "x" + std::to_string(height));
  }
  const size_t limit = static_cast<size_t>(width) * static_cast<size_t>(height) * 8 + 65536;
  if (size > limit) {
    throw Error("JPEG of " + std::to_string(size) + " bytes, more than a " + std::to_string(width) +
                "x" + std::to_string(height) + " image may take (" + std::to_string(limit) + ")");
  }
}

void decodeJpegGray(const uint8_t* data, size_t size, cv::Mat* out, const JpegHeader* header) {
  Decompressor& d = threadDecompressor();
  const JpegHeader h = header != nullptr ? *header : readHeader(d, data, size);
  out->create(h.height, h.width, CV_8UC1);
  // Strict: a warning (e.g. a truncated file, whose missing rows would be grey) fails the
  // image, and a progressive JPEG may not have more than 500 scans (a CPU bomb otherwise).
  const int flags = TJFLAG_NOREALLOC | TJFLAG_STOPONWARNING | TJFLAG_LIMITSCANS;
  if (tjDecompress2(d.get(), data, static_cast<unsigned long>(size), out->data, h.width,
                    static_cast<int>(out->step[0]), h.height, TJPF_GRAY, flags) != 0) {
    const std::string error = lastError(d.get());
    d.renew();
    throw Error("JPEG does not decode (" + std::to_string(size) + " bytes): " + error);
  }
}

}  // namespace ecar
