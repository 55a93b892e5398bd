// Private to the dataset reader (dataset.cpp, dataset_formats.cpp): the text
// parsing helpers, whose errors name "<file>:<line>", and Contents, what a
// format loader produces.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/dataset.h"
#include "ecar_core/io/trajectory.h"

namespace ecar::dataset_internal {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// Text parsing helpers. Every error names "<file>:<line>".

// One data line of a text file: its 1-based number and its fields.
struct TextLine {
  int number = 0;
  std::vector<std::string> fields;
};

/// "<file>:<line>".
std::string at(const fs::path& file, int line);

bool isFile(const fs::path& p);
bool isDirectory(const fs::path& p);

// Reads a text file, skipping blank lines and '#' comments. Fields are split on
// whitespace, or on commas (each trimmed) when `csv` is true.
std::vector<TextLine> readTextLines(const fs::path& file, bool csv);

void expectFields(const TextLine& line, size_t count, const fs::path& file,
                  const std::string& layout);
void expectAtLeastFields(const TextLine& line, size_t count, const fs::path& file,
                         const std::string& layout);

// Parses the whole of `s` as a finite double, independently of the C locale.
double parseNumber(const std::string& s, const fs::path& file, int line, const std::string& what);
Eigen::Vector3d parseVector3(const TextLine& line, size_t first, const fs::path& file,
                             const std::string& what);
int64_t parseNanoseconds(const std::string& s, const fs::path& file, int line);
double nsToSeconds(int64_t ns);

// Nearest rotation (in the Frobenius sense) to a 3x3 matrix that should be one.
// Throws when it is far from a rotation.
Eigen::Matrix3d orthonormalize(const Eigen::Matrix3d& M, const std::string& where);

// ---------------------------------------------------------------------------
// What a format loader produces.

struct Contents {
  std::optional<PinholeCamera> camera;
  std::vector<DatasetFrame> frames;
  std::vector<std::string> sources;  // "<list file>:<line>" of each frame
  std::vector<ImuSample> imu;
};

void addFrame(Contents* c, const fs::path& list, int line, double timestamp, const fs::path& image);
void requireFrames(const Contents& c, const fs::path& list);

// `timestamp filename` lists (TUM rgb.txt, our sim rgb.txt, KITTI rgb.txt);
// filenames are relative to `dir`.
void readImageList(const fs::path& dir, const fs::path& list, Contents* c);

std::vector<double> frameStamps(const Contents& c);

// Gives each frame the pose of `traj` nearest in time within max_dt (each pose
// used once, as TUM's associate.py does).
void attachGroundTruth(const Trajectory& traj, double max_dt, Contents* c);

PinholeCamera loadCameraOrThrow(const fs::path& path);

}  // namespace ecar::dataset_internal
