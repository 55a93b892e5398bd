// A worker pool for per-device jobs: jobs of different devices run in
// parallel, one device's jobs run in order and one at a time, and each device
// has a bounded queue that drops its oldest job when full. ROS-free.
//
//   DeviceWorkQueue pool(2, 3);
//   if (pool.push("device_0", [] { ... })) warn("dropped the oldest");
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace ecar_server {

class DeviceWorkQueue {
 public:
  using Job = std::function<void()>;

  /// `workers` threads (>= 1); at most `capacity` (>= 1) waiting jobs per device.
  DeviceWorkQueue(int workers, size_t capacity);
  /// Drops the waiting jobs, waits for the running ones, joins the threads.
  ~DeviceWorkQueue();
  DeviceWorkQueue(const DeviceWorkQueue&) = delete;
  DeviceWorkQueue& operator=(const DeviceWorkQueue&) = delete;

  /// Queues a job of `device`; returns true when the queue was full and its
  /// oldest waiting job was dropped to make room. Thread-safe.
  bool push(const std::string& device, Job job);
  /// Drops the device's waiting jobs; `on_idle` runs once the device has no
  /// running job: right now (on the caller's thread) or, when one is running,
  /// on its worker right after it. Jobs pushed later run after `on_idle`.
  void removeDevice(const std::string& device, Job on_idle);
  /// Jobs of `device` waiting (not running).
  size_t waiting(const std::string& device) const;
  /// Blocks until no job is waiting or running (for tests).
  void waitIdle() const;

 private:
  struct DeviceQueue {
    std::deque<Job> jobs;
    bool running = false;
    bool scheduled = false;  ///< in ready_
    Job on_idle;
  };
  void run();
  void scheduleLocked(const std::string& device, DeviceQueue* q);

  const size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable work_cv_;
  mutable std::condition_variable idle_cv_;
  std::map<std::string, DeviceQueue> queues_;
  std::deque<std::string> ready_;
  int running_ = 0;
  bool stop_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace ecar_server
