// Background threads are named and niced as their options say; the keyframe
// worker (the local mapper's and loop closer's queue) applies them on its thread.
#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "ecar_core/common/thread_priority.h"
#include "ecar_core/slam/keyframe_worker.h"

namespace ecar {
namespace {

int myNice() { return getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))); }

std::string myName() {
  char name[16] = {0};
  pthread_getname_np(pthread_self(), name, sizeof(name));
  return name;
}

TEST(ThreadPriorityTest, AThreadIsNicedByItsOwnAmountOnly) {
  const int base = myNice();
  if (base > 19 - 4) GTEST_SKIP() << "this test already runs at niceness " << base;
  int inside = -100;
  std::thread t([&] {
    EXPECT_TRUE(lowerThisThreadPriority(4));
    inside = myNice();
  });
  t.join();
  EXPECT_EQ(inside, base + 4);
  EXPECT_EQ(myNice(), base) << "the calling thread kept its priority";
  EXPECT_TRUE(lowerThisThreadPriority(0));
  EXPECT_EQ(myNice(), base) << "0 changes nothing";
}

TEST(ThreadPriorityTest, TheKeyFrameWorkerNamesAndNicesItsThread) {
  const int base = myNice();
  if (base > 19 - 3) GTEST_SKIP() << "this test already runs at niceness " << base;
  std::atomic<int> nice{-100};
  std::string name;
  std::atomic<bool> done{false};
  KeyFrameWorker worker([&](KeyFrameId) {
    nice = myNice();
    name = myName();
    done = true;
  });
  worker.startThread({"a_long_worker_name", 3});
  worker.push(KeyFrameId(7));
  for (int i = 0; i < 500 && !done; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  worker.stopThread();
  ASSERT_TRUE(done);
  EXPECT_EQ(nice, base + 3);
  EXPECT_EQ(name, "a_long_worker_n") << "Linux keeps 15 characters";
  EXPECT_EQ(myNice(), base);
}

}  // namespace
}  // namespace ecar
