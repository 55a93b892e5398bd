#include "ecar_core/io/safe_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

std::string errnoText(int error) { return std::strerror(error); }

/// What a non-regular file is, for errors.
std::string kindOf(mode_t mode) {
  if (S_ISLNK(mode)) return "a symbolic link";
  if (S_ISDIR(mode)) return "a folder";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISCHR(mode) || S_ISBLK(mode)) return "a device";
  return "not a regular file";
}

/// Closes a descriptor when it goes out of scope.
struct FdCloser {
  int fd;
  ~FdCloser() {
    if (fd >= 0) ::close(fd);
  }
};

}  // namespace

std::vector<uint8_t> readRegularFile(const std::string& path, size_t max_bytes,
                                     const std::string& what) {
  const std::string where = what + " " + quote(path);
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    const int error = errno;
    if (error == ELOOP) throw Error(where + ": is a symbolic link (not followed)");
    throw Error(where + ": cannot open: " + errnoText(error));
  }
  FdCloser closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0) throw Error(where + ": cannot stat: " + errnoText(errno));
  if (!S_ISREG(st.st_mode)) throw Error(where + ": is " + kindOf(st.st_mode) + ", not a file");
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  if (size > max_bytes) {
    throw Error(where + ": " + std::to_string(size) + " bytes, more than the limit of " +
                std::to_string(max_bytes));
  }
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::read(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw Error(where + ": read error: " + errnoText(errno));
    if (n == 0) break;  // shrank while read
    done += static_cast<size_t>(n);
  }
  bytes.resize(done);
  return bytes;
}

void checkReplaceable(const std::string& path, const std::string& what) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return;  // absent (or unreachable: the write says why)
  if (!S_ISREG(st.st_mode)) {
    throw Error(what + " " + quote(path) + ": is " + kindOf(st.st_mode) +
                ", not a file: not replaced");
  }
}

MapFolder::MapFolder(const std::string& folder) {
  if (folder.empty()) throw Error("map folder: the path is empty");
  std::error_code ec;
  const fs::path absolute = fs::absolute(fs::path(folder), ec).lexically_normal();
  if (ec) throw Error("map folder " + quote(folder) + ": " + ec.message());
  configured_ = absolute.string();
  while (configured_.size() > 1 && configured_.back() == '/') configured_.pop_back();
  if (!fs::exists(absolute, ec)) {
    fs::create_directories(absolute, ec);
    if (ec) throw Error("map folder " + quote(folder) + ": cannot create it: " + ec.message());
    fs::permissions(absolute, fs::perms::owner_all, ec);
  }
  if (!fs::is_directory(absolute, ec)) {
    throw Error("map folder " + quote(folder) + ": is not a folder");
  }
  path_ = fs::canonical(absolute, ec).string();
  if (ec) throw Error("map folder " + quote(folder) + ": " + ec.message());
}

std::string MapFolder::resolve(const std::string& requested) const {
  const std::string where = "map path " + quote(requested);
  if (requested.empty())
    throw Error("map path: empty (give a file name ending in " + std::string(kExtension) + ")");
  const fs::path p(requested);
  std::string name;
  if (p.is_absolute()) {
    const fs::path normal = p.lexically_normal();
    const std::string parent = normal.parent_path().string();
    if (parent != configured_ && parent != path_) {
      throw Error(where + ": outside the map folder " + quote(path_) +
                  " (give a file name, or a path in that folder)");
    }
    name = normal.filename().string();
  } else {
    if (requested.find('/') != std::string::npos) {
      throw Error(where + ": a file name in the map folder " + quote(path_) +
                  " is expected, not a subfolder or '..'");
    }
    name = requested;
  }
  if (name.empty() || name == "." || name == "..") throw Error(where + ": no file name");
  if (name.size() > 255) throw Error(where + ": the file name is longer than 255 bytes");
  for (const char c : name) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) {
      throw Error(where + ": the file name has a control character");
    }
  }
  const std::string ext(kExtension);
  if (name.size() <= ext.size() || name.compare(name.size() - ext.size(), ext.size(), ext) != 0) {
    throw Error(where + ": the file name must end in " + ext +
                " (other files in the folder, such as the VO database, are not maps)");
  }
  return path_ + "/" + name;
}

}  // namespace ecar
