// Files named by someone else: a folder they are confined to, and reading that
// neither follows a planted link, nor blocks on a FIFO, nor reads without bound.
//
//   const MapFolder maps("/home/me/.ros/ecar_maps");       // created when missing
//   const std::string path = maps.resolve(request.path);   // "office.ecarmap" or
//                                                          // "<folder>/office.ecarmap"
//   std::vector<uint8_t> bytes = readRegularFile(path, 64 << 20, "map file");
//
// Thread-safety: MapFolder is immutable after construction; readRegularFile is
// reentrant.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace ecar {

/// Reads the whole of `path`, which must be a regular file (not a symbolic
/// link, FIFO, device, socket or folder) of at most `max_bytes`. Opened with
/// O_NOFOLLOW and O_NONBLOCK, so a planted link is refused rather than
/// followed and a FIFO is refused rather than waited on. Throws ecar::Error
/// starting with `what` and the quoted path, naming the problem.
std::vector<uint8_t> readRegularFile(const std::string& path, size_t max_bytes,
                                     const std::string& what);

/// Throws ecar::Error (starting with `what` and the quoted path) when `path`
/// exists and is not a regular file, e.g. a symbolic link or a folder. For a
/// writer about to rename a new file over `path`.
void checkReplaceable(const std::string& path, const std::string& what);

/// The one folder that map files named by service callers live in.
class MapFolder {
 public:
  /// The extension every map file name must end with.
  static constexpr const char* kExtension = ".ecarmap";

  /// `folder` (absolute, or relative to the working directory) is created
  /// with its parents (mode 0700) when missing. Throws ecar::Error when it
  /// cannot be created or is not a folder.
  explicit MapFolder(const std::string& folder);

  /// The folder, absolute, its links resolved.
  const std::string& path() const { return path_; }

  /// The file a caller's `requested` path stands for: a plain file name
  /// ("office.ecarmap"), or an absolute path whose folder is this folder
  /// (spelled as configured or resolved). Throws ecar::Error naming the
  /// requested path and the rule it breaks: empty, a folder other than this
  /// one (including "..", subfolders and links to elsewhere), a name not ending
  /// in kExtension, or a name with control characters or over 255 bytes.
  std::string resolve(const std::string& requested) const;

 private:
  std::string configured_;  ///< as given, made absolute and lexically normal
  std::string path_;        ///< canonical
};

}  // namespace ecar
