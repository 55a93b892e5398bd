// Uploads every Nth frame, also when the device skipped frames while busy.
#include "ecar_core/device/upload_schedule.h"

#include <vector>

#include <gtest/gtest.h>

namespace ecar {
namespace {

std::vector<uint32_t> uploadsOf(const std::vector<uint32_t>& seqs, int every) {
  UploadSchedule schedule;
  std::vector<uint32_t> uploads;
  for (uint32_t seq : seqs) {
    if (!schedule.due(seq, every)) continue;
    schedule.uploaded(seq, every);
    uploads.push_back(seq);
  }
  return uploads;
}

TEST(UploadSchedule, EveryNthFrameWhenNoneIsSkipped) {
  std::vector<uint32_t> seqs;
  for (uint32_t i = 0; i < 13; ++i) seqs.push_back(i);
  EXPECT_EQ(uploadsOf(seqs, 4), (std::vector<uint32_t>{0, 4, 8, 12}));
  EXPECT_EQ(uploadsOf(seqs, 1), seqs);
}

TEST(UploadSchedule, ASkippedUploadFrameMovesTheUploadToTheNextFrame) {
  // Frames 4 and 8-9 skipped: 5 and 10 are uploaded instead, 12 on time.
  EXPECT_EQ(uploadsOf({0, 1, 2, 3, 5, 6, 7, 10, 11, 12}, 4), (std::vector<uint32_t>{0, 5, 10, 12}));
  // A whole slot skipped: no upload for it, none doubled after.
  EXPECT_EQ(uploadsOf({0, 3, 9, 11, 13}, 4), (std::vector<uint32_t>{0, 9, 13}));
}

TEST(UploadSchedule, AnUploadNotMadeStaysDue) {
  UploadSchedule schedule;
  EXPECT_TRUE(schedule.due(4, 4));
  // Not uploaded (not connected yet): frame 5 of the same slot is still due.
  EXPECT_TRUE(schedule.due(5, 4));
  schedule.uploaded(5, 4);
  EXPECT_FALSE(schedule.due(6, 4));
  EXPECT_TRUE(schedule.due(8, 4));
}

TEST(UploadSchedule, APlayerStartingOverStartsANewSlot) {
  EXPECT_EQ(uploadsOf({8, 9, 10, 11, 0, 1, 4}, 4), (std::vector<uint32_t>{8, 0, 4}));
}

}  // namespace
}  // namespace ecar
