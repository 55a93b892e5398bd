#include "ecar_server/device_work_queue.h"

#include <algorithm>

#include "ecar_core/common/thread_priority.h"

namespace ecar_server {

DeviceWorkQueue::DeviceWorkQueue(int workers, size_t capacity)
    : capacity_(std::max<size_t>(1, capacity)) {
  for (int i = 0; i < std::max(1, workers); ++i) {
    threads_.emplace_back([this] {
      ecar::nameThisThread("ecar_align");
      run();
    });
  }
}

DeviceWorkQueue::~DeviceWorkQueue() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
    for (auto& kv : queues_) kv.second.jobs.clear();
  }
  work_cv_.notify_all();
  for (auto& t : threads_) t.join();
}

void DeviceWorkQueue::scheduleLocked(const std::string& device, DeviceQueue* q) {
  if (q->running || q->scheduled || q->jobs.empty()) return;
  q->scheduled = true;
  ready_.push_back(device);
  work_cv_.notify_one();
}

bool DeviceWorkQueue::push(const std::string& device, Job job) {
  std::lock_guard<std::mutex> lock(mutex_);
  DeviceQueue& q = queues_[device];
  bool dropped = false;
  if (q.jobs.size() >= capacity_) {
    q.jobs.pop_front();
    dropped = true;
  }
  q.jobs.push_back(std::move(job));
  scheduleLocked(device, &q);
  return dropped;
}

void DeviceWorkQueue::removeDevice(const std::string& device, Job on_idle) {
  std::unique_lock<std::mutex> lock(mutex_);
  const auto it = queues_.find(device);
  if (it == queues_.end() || !it->second.running) {
    if (it != queues_.end()) it->second.jobs.clear();
    lock.unlock();
    if (on_idle) on_idle();
    return;
  }
  it->second.jobs.clear();
  it->second.on_idle = std::move(on_idle);
}

size_t DeviceWorkQueue::waiting(const std::string& device) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = queues_.find(device);
  return it == queues_.end() ? 0 : it->second.jobs.size();
}

void DeviceWorkQueue::waitIdle() const {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_cv_.wait(lock, [this] { return ready_.empty() && running_ == 0; });
}

void DeviceWorkQueue::run() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    work_cv_.wait(lock, [this] { return stop_ || !ready_.empty(); });
    if (stop_) return;
    const std::string device = ready_.front();
    ready_.pop_front();
    DeviceQueue* q = &queues_[device];
    q->scheduled = false;
    if (q->jobs.empty()) continue;
    Job job = std::move(q->jobs.front());
    q->jobs.pop_front();
    q->running = true;
    ++running_;
    lock.unlock();
    try {
      job();
    } catch (...) {
      // Jobs report their own errors; one that escapes must not end the worker.
    }
    lock.lock();
    q = &queues_[device];  // std::map nodes are stable; re-looked up for clarity
    if (q->on_idle) {
      Job on_idle = std::move(q->on_idle);
      q->on_idle = nullptr;
      lock.unlock();
      on_idle();
      lock.lock();
      q = &queues_[device];
    }
    q->running = false;
    --running_;
    scheduleLocked(device, q);
    if (ready_.empty() && running_ == 0) idle_cv_.notify_all();
  }
}

}  // namespace ecar_server
