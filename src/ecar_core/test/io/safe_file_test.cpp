// Files named by service callers: the map folder's rules, reading that refuses
// links, FIFOs, folders and oversized files without blocking, and atomic writes
// that neither write through a planted temporary nor replace a link.
#include "ecar_core/io/safe_file.h"

#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "ecar_core/io/atomic_file.h"
#include "ecar_core/io/map_file.h"
#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::contains;
using ecar::testing::errorOf;
using ecar::testing::readBytes;
using ecar::testing::TempDir;
using ecar::testing::writeBytes;

namespace fs = std::filesystem;

TEST(MapFolderTest, ResolvesFileNamesAndPathsInTheFolderOnly) {
  const TempDir tmp("ecar_safe_file_test");
  const std::string dir = tmp.path() + "/maps";
  const MapFolder folder(dir);  // created
  ASSERT_TRUE(fs::is_directory(dir));
  const std::string canonical = fs::canonical(dir).string();
  EXPECT_EQ(folder.path(), canonical);
  EXPECT_EQ(folder.resolve("office.ecarmap"), canonical + "/office.ecarmap");
  EXPECT_EQ(folder.resolve(dir + "/office.ecarmap"), canonical + "/office.ecarmap");
  EXPECT_EQ(folder.resolve(dir + "/./office.ecarmap"), canonical + "/office.ecarmap");

  struct Bad {
    std::string path, why;
  };
  const std::vector<Bad> bad = {
      {"", "empty"},
      {"../office.ecarmap", "not a subfolder or '..'"},
      {"sub/office.ecarmap", "not a subfolder or '..'"},
      {dir + "/../office.ecarmap", "outside the map folder"},
      {dir + "/sub/office.ecarmap", "outside the map folder"},
      {"/etc/passwd", "outside the map folder"},
      {"vo.sqlite", "must end in .ecarmap"},
      {".ecarmap", "must end in .ecarmap"},
      {"office.ecarmap.tmp", "must end in .ecarmap"},
      {"a\nb.ecarmap", "control character"},
      {std::string(300, 'a') + ".ecarmap", "longer than 255"},
  };
  for (const Bad& b : bad) {
    const std::string e = errorOf([&] { folder.resolve(b.path); });
    EXPECT_TRUE(contains(e, b.why)) << b.path << ": " << e;
    if (!b.path.empty() && b.path.size() < 100) {
      EXPECT_TRUE(contains(e, b.path)) << e;
    }
  }
  // A file where the folder should be.
  writeBytes(tmp.path() + "/plain", {1, 2, 3});
  EXPECT_TRUE(contains(errorOf([&] { MapFolder(tmp.path() + "/plain"); }), "is not a folder"));
}

TEST(SafeFileTest, ReadsRegularFilesAndRefusesEverythingElseWithoutBlocking) {
  const TempDir tmp("ecar_safe_file_test");
  const std::string file = tmp.path() + "/a.ecarmap";
  writeBytes(file, {1, 2, 3, 4, 5});
  EXPECT_EQ(readRegularFile(file, 5, "map file"), (std::vector<uint8_t>{1, 2, 3, 4, 5}));
  EXPECT_TRUE(contains(errorOf([&] { readRegularFile(file, 4, "map file"); }),
                       "5 bytes, more than the limit of 4"));

  const std::string link = tmp.path() + "/link.ecarmap";
  ASSERT_EQ(::symlink(file.c_str(), link.c_str()), 0);
  EXPECT_TRUE(contains(errorOf([&] { readRegularFile(link, 100, "map file"); }),
                       "is a symbolic link (not followed)"));

  // Opening a FIFO for reading would wait for a writer forever: refused at once.
  const std::string fifo = tmp.path() + "/fifo.ecarmap";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const auto start = std::chrono::steady_clock::now();
  EXPECT_TRUE(contains(errorOf([&] { readRegularFile(fifo, 100, "map file"); }), "a FIFO"));
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(2));

  EXPECT_TRUE(contains(errorOf([&] { readRegularFile(tmp.path(), 100, "map file"); }), "a folder"));
  EXPECT_TRUE(
      contains(errorOf([&] { readRegularFile("/dev/zero", 100, "map file"); }), "a device"));
  EXPECT_TRUE(contains(errorOf([&] { readRegularFile(tmp.path() + "/none", 100, "map file"); }),
                       "cannot open"));
  // The map reader goes through it: a FIFO and an oversized file are refused unread.
  EXPECT_TRUE(contains(errorOf([&] { MapFileReader::open(fifo); }), "a FIFO"));
  EXPECT_TRUE(contains(errorOf([&] { MapFileReader::open(file, 2); }), "more than the limit"));
}

TEST(SafeFileTest, AtomicWritesRefuseLinksAndPlantedTemporaries) {
  const TempDir tmp("ecar_safe_file_test");
  const std::string target = tmp.path() + "/victim";
  writeBytes(target, {9, 9});
  // A link at the destination is refused, not replaced and not written through.
  const std::string link = tmp.path() + "/map.ecarmap";
  ASSERT_EQ(::symlink(target.c_str(), link.c_str()), 0);
  EXPECT_TRUE(
      contains(errorOf([&] { writeFileAtomically(link, {1}, "map file"); }), "is a symbolic link"));
  EXPECT_EQ(readBytes(target), (std::vector<uint8_t>{9, 9}));
  EXPECT_TRUE(fs::is_symlink(link));
  // A folder at the destination is refused.
  fs::create_directory(tmp.path() + "/dir.ecarmap");
  EXPECT_TRUE(
      contains(errorOf([&] { writeFileAtomically(tmp.path() + "/dir.ecarmap", {1}, "map file"); }),
               "is a folder"));

  // Links planted under every temporary name the next writes could use: each write fails
  // (the temporary is created exclusively) and the victim is untouched.
  const std::string path = tmp.path() + "/b.ecarmap";
  for (int n = 0; n < 64; ++n) {
    const std::string planted =
        path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(n);
    ASSERT_EQ(::symlink(target.c_str(), planted.c_str()), 0);
  }
  const std::string e = errorOf([&] { writeFileAtomically(path, {7, 7, 7}, "map file"); });
  EXPECT_TRUE(contains(e, "cannot create its temporary file")) << e;
  EXPECT_TRUE(contains(e, "File exists")) << e;
  EXPECT_FALSE(fs::exists(path));
  EXPECT_EQ(readBytes(target), (std::vector<uint8_t>{9, 9}));
  // A regular file is replaced.
  writeFileAtomically(tmp.path() + "/c.ecarmap", {1, 2}, "map file");
  writeFileAtomically(tmp.path() + "/c.ecarmap", {3}, "map file");
  EXPECT_EQ(readBytes(tmp.path() + "/c.ecarmap"), (std::vector<uint8_t>{3}));
  // A file written from parts is the parts one after the other.
  const std::vector<uint8_t> head = {1, 2, 3}, tail = {4, 5};
  writeFilePartsAtomically(tmp.path() + "/c.ecarmap",
                           {{head.data(), head.size()}, {nullptr, 0}, {tail.data(), tail.size()}},
                           "map file");
  EXPECT_EQ(readBytes(tmp.path() + "/c.ecarmap"), (std::vector<uint8_t>{1, 2, 3, 4, 5}));
}

}  // namespace
}  // namespace ecar
