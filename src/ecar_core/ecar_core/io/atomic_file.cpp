#include "ecar_core/io/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"
#include "ecar_core/io/safe_file.h"

namespace ecar {
namespace {

std::string errnoText() { return std::strerror(errno); }

// Writes all of `bytes` to the open descriptor `fd`.
bool writeAll(int fd, const ByteSpan& bytes) {
  size_t done = 0;
  while (done < bytes.size) {
    const ssize_t n = ::write(fd, bytes.data + done, bytes.size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    done += static_cast<size_t>(n);
  }
  return true;
}

}  // namespace

void writeFileAtomically(const std::string& path, const std::vector<uint8_t>& bytes,
                         const std::string& what) {
  writeFilePartsAtomically(path, {{bytes.data(), bytes.size()}}, what);
}

void writeFilePartsAtomically(const std::string& path, const std::vector<ByteSpan>& parts,
                              const std::string& what) {
  // A name of its own per write: two writers of one path never share it.
  static std::atomic<uint32_t> writes{0};
  checkReplaceable(path, what);
  const std::string tmp =
      path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(writes++);
  // Exclusively: a file or link planted under the temporary name is an error, never written
  // through.
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0) {
    throw Error(what + ": cannot create its temporary file " + quote(tmp) + ": " + errnoText());
  }
  bool written = true;
  for (const ByteSpan& part : parts) written = written && writeAll(fd, part);
  if (!written || ::fsync(fd) != 0) {
    const std::string why = errnoText();
    ::close(fd);
    ::unlink(tmp.c_str());
    throw Error(what + ": writing " + quote(tmp) + " failed: " + why);
  }
  if (::close(fd) != 0) {
    const std::string why = errnoText();
    ::unlink(tmp.c_str());
    throw Error(what + ": closing " + quote(tmp) + " failed: " + why);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = errnoText();
    ::unlink(tmp.c_str());
    throw Error(what + ": cannot rename " + quote(tmp) + " to it: " + why);
  }
  // The rename itself reaches the disk with its directory.
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace ecar
