// The alignment worker pool: order per device, one job of a device at a time,
// devices in parallel, the bounded queue, and removal.
#include "ecar_server/device_work_queue.h"

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

#include <gtest/gtest.h>

namespace ecar_server {
namespace {

using namespace std::chrono_literals;

TEST(DeviceWorkQueueTest, OneDevicesJobsRunInOrderOneAtATime) {
  DeviceWorkQueue pool(4, 100);
  std::mutex m;
  std::vector<int> order;
  std::atomic<int> inside{0}, max_inside{0};
  for (int i = 0; i < 20; ++i) {
    pool.push("a", [&, i] {
      const int now = ++inside;
      max_inside = std::max(max_inside.load(), now);
      std::this_thread::sleep_for(1ms);
      {
        std::lock_guard<std::mutex> lock(m);
        order.push_back(i);
      }
      --inside;
    });
  }
  pool.waitIdle();
  ASSERT_EQ(order.size(), 20u);
  for (int i = 0; i < 20; ++i) EXPECT_EQ(order[i], i);
  EXPECT_EQ(max_inside.load(), 1);
}

TEST(DeviceWorkQueueTest, DevicesRunInParallel) {
  DeviceWorkQueue pool(2, 10);
  std::atomic<int> inside{0}, max_inside{0};
  for (const char* d : {"a", "b"}) {
    pool.push(d, [&] {
      const int now = ++inside;
      max_inside = std::max(max_inside.load(), now);
      std::this_thread::sleep_for(50ms);
      --inside;
    });
  }
  pool.waitIdle();
  EXPECT_EQ(max_inside.load(), 2);
}

TEST(DeviceWorkQueueTest, AFullQueueDropsTheOldest) {
  DeviceWorkQueue pool(1, 2);
  std::atomic<bool> release{false};
  std::vector<int> ran;
  std::mutex m;
  pool.push("a", [&] {
    while (!release) std::this_thread::sleep_for(1ms);
  });
  std::this_thread::sleep_for(20ms);  // the blocker is running
  int dropped = 0;
  for (int i = 0; i < 4; ++i) {
    dropped += pool.push("a", [&, i] {
      std::lock_guard<std::mutex> lock(m);
      ran.push_back(i);
    });
  }
  EXPECT_EQ(dropped, 2);
  EXPECT_EQ(pool.waiting("a"), 2u);
  release = true;
  pool.waitIdle();
  EXPECT_EQ(ran, (std::vector<int>{2, 3}));
}

TEST(DeviceWorkQueueTest, RemovalWaitsForTheRunningJob) {
  DeviceWorkQueue pool(2, 10);
  std::atomic<bool> release{false}, job_done{false}, removed{false}, removed_after_job{false};
  pool.push("a", [&] {
    while (!release) std::this_thread::sleep_for(1ms);
    job_done = true;
  });
  std::atomic<bool> never{false};
  std::this_thread::sleep_for(20ms);
  pool.push("a", [&] { never = true; });
  pool.removeDevice("a", [&] {
    removed_after_job = job_done.load();
    removed = true;
  });
  EXPECT_FALSE(removed.load());
  release = true;
  pool.waitIdle();
  EXPECT_TRUE(removed.load());
  EXPECT_TRUE(removed_after_job.load());
  EXPECT_FALSE(never.load());
  // An idle (or unknown) device is removed at once; it may come back.
  bool now = false;
  pool.removeDevice("b", [&] { now = true; });
  EXPECT_TRUE(now);
  std::atomic<bool> back{false};
  pool.push("a", [&] { back = true; });
  pool.waitIdle();
  EXPECT_TRUE(back.load());
}

}  // namespace
}  // namespace ecar_server
