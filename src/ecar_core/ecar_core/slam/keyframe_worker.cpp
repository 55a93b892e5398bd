#include "ecar_core/slam/keyframe_worker.h"

namespace ecar {

void KeyFrameWorker::push(KeyFrameId kf) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    queue_.push_back(kf);
  }
  cv_.notify_one();
}

KeyFrameId KeyFrameWorker::next(bool wait) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (wait) cv_.wait(lock, [this] { return stop_ || !queue_.empty(); });
  if (queue_.empty()) return KeyFrameId();
  const KeyFrameId kf = queue_.front();
  queue_.pop_front();
  busy_ = true;
  return kf;
}

void KeyFrameWorker::processPending() {
  for (KeyFrameId kf = next(false); kf.valid(); kf = next(false)) {
    handle_(kf);
    busy_ = false;
  }
}

void KeyFrameWorker::run(const ThreadOptions& options) {
  applyThreadOptions(options);
  for (KeyFrameId kf = next(true); kf.valid(); kf = next(true)) {
    handle_(kf);
    busy_ = false;
  }
}

void KeyFrameWorker::startThread(const ThreadOptions& options) {
  if (thread_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = false;
  }
  thread_ = std::thread([this, options] { run(options); });
}

void KeyFrameWorker::stopThread() {
  if (!thread_.joinable()) return;
  {
    // Under the mutex: set between the thread's check of its wait condition
    // and its sleep, the wake-up would be lost and join() hang.
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void KeyFrameWorker::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  queue_.clear();
}

bool KeyFrameWorker::idle() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return queue_.empty() && !busy_;
}

}  // namespace ecar
