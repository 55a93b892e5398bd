// Shared helpers of the fuzz targets (libFuzzer, clang -fsanitize=fuzzer).
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

namespace ecar_fuzz {

/// A file of this process for inputs that must be read from a path.
inline const std::string& scratchPath(const char* suffix) {
  static const std::string path =
      "/tmp/ecar_fuzz_" + std::to_string(::getpid()) + std::string(suffix);
  return path;
}

/// Writes `data` to `path` (truncating); false when it cannot.
inline bool writeFile(const std::string& path, const uint8_t* data, size_t size) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) return false;
  const bool ok = size == 0 || std::fwrite(data, 1, size, f) == size;
  return std::fclose(f) == 0 && ok;
}

}  // namespace ecar_fuzz
