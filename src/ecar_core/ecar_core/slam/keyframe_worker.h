// A queue of keyframes handled one at a time, on the worker's own thread or,
// without one, on the caller's (processPending): the local mapper's and the
// loop closer's queue.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>

#include "ecar_core/common/thread_priority.h"
#include "ecar_core/common/types.h"

namespace ecar {

class KeyFrameWorker {
 public:
  explicit KeyFrameWorker(std::function<void(KeyFrameId)> handle) : handle_(std::move(handle)) {}
  /// Stops the thread (the owner stops it earlier when `handle` uses its members).
  ~KeyFrameWorker() { stopThread(); }
  KeyFrameWorker(const KeyFrameWorker&) = delete;
  KeyFrameWorker& operator=(const KeyFrameWorker&) = delete;

  /// Queues a keyframe (the thread, if running, takes it).
  void push(KeyFrameId kf);
  /// Handles every queued keyframe on the calling thread.
  void processPending();
  /// Starts the thread, named and niced as `options` say.
  void startThread(const ThreadOptions& options = {});
  /// Handles the keyframes still queued, then stops the thread.
  void stopThread();
  bool threaded() const { return thread_.joinable(); }
  /// Drops the queued keyframes (the one being handled finishes).
  void clear();
  /// Nothing queued and nothing being handled.
  bool idle() const;

 private:
  /// The next keyframe; invalid when the queue is empty (and, `wait`, stopping).
  KeyFrameId next(bool wait);
  void run(const ThreadOptions& options);

  const std::function<void(KeyFrameId)> handle_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<KeyFrameId> queue_;  // guarded by mutex_
  bool stop_ = false;             // guarded by mutex_: a stop is never missed
  std::atomic<bool> busy_{false};
  std::thread thread_;
};

}  // namespace ecar
