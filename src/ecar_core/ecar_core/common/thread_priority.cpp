#include "ecar_core/common/thread_priority.h"

#ifdef __linux__
#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

#include <algorithm>

namespace ecar {

void nameThisThread(const std::string& name) {
#ifdef __linux__
  if (!name.empty()) pthread_setname_np(pthread_self(), name.substr(0, 15).c_str());
#else
  (void)name;
#endif
}

bool lowerThisThreadPriority(int nice) {
  nice = std::clamp(nice, 0, 19);
  if (nice == 0) return true;
#ifdef __linux__
  // PRIO_PROCESS with a thread id sets that thread's niceness only (Linux).
  const auto tid = static_cast<id_t>(syscall(SYS_gettid));
  const int current = getpriority(PRIO_PROCESS, tid);
  return setpriority(PRIO_PROCESS, tid, std::min(19, current + nice)) == 0;
#else
  return true;
#endif
}

void applyThreadOptions(const ThreadOptions& options) {
  nameThisThread(options.name);
  lowerThisThreadPriority(options.nice);
}

}  // namespace ecar
