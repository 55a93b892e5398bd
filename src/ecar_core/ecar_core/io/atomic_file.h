// Writing a file so that a reader sees the old file or the new one, never a part.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace ecar {

/// Bytes owned elsewhere.
struct ByteSpan {
  const uint8_t* data = nullptr;
  size_t size = 0;
};

/// Writes `bytes` to a temporary file beside `path` (`path`.tmp.<pid>.<n>,
/// created exclusively: a planted file or link there is an error), flushes it
/// to disk, renames it over `path` and flushes the directory. `path` must be
/// absent or a regular file (a symbolic link or a folder there is refused,
/// not replaced).
/// Throws ecar::Error starting with `what` (e.g. "map file 'x'"), naming the
/// step and the system error; the temporary file is removed.
void writeFileAtomically(const std::string& path, const std::vector<uint8_t>& bytes,
                         const std::string& what);
/// writeFileAtomically for a file made of `parts` written one after the other (no copy
/// into one buffer: a large map file is written from its sections).
void writeFilePartsAtomically(const std::string& path, const std::vector<ByteSpan>& parts,
                              const std::string& what);

}  // namespace ecar
