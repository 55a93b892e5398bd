// VoStore::mergeNewer: a server that resumes after a crash from its own autosave
// (an older snapshot of the same store) keeps what its database acknowledged
// since the snapshot was taken.
#include <algorithm>
#include <map>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <vector>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/vo_database.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar {

VoStore::MergeCounts VoStore::mergeNewer(const VoSnapshot& snapshot) {
  const std::string context = config_.database_path + ": merging the map file's VOs";
  checkVoSnapshot(snapshot, context);
  std::lock_guard<std::mutex> write(write_mutex_);
  MergeCounts counts;
  std::map<ObjectId, VoRecord> merged;
  {
    std::shared_lock<std::shared_mutex> state(state_mutex_);
    merged = objects_;
  }
  std::vector<ObjectId> taken;
  for (const VoRecord& r : snapshot.objects) {
    const auto it = merged.find(r.vo.id);
    if (it != merged.end() && it->second.vo.version >= r.vo.version) continue;
    merged[r.vo.id] = r;
    taken.push_back(r.vo.id);
  }
  counts.from_snapshot = taken.size();
  counts.kept = merged.size() - taken.size();
  const uint32_t next_id = std::max(next_id_, snapshot.next_id.value);
  VoSnapshot result;
  result.next_id = ObjectId(next_id);
  for (const auto& kv : merged) result.objects.push_back(kv.second);
  checkLimits(result, context);
  if (!taken.empty() || next_id != next_id_) {
    std::vector<const VoRecord*> rows;
    for (const ObjectId id : taken) rows.push_back(&merged.at(id));
    std::string error;
    const bool ok = db_->writeAll(rows, &error, next_id);
    if (!ok) throw Error(context + " failed: " + error);
  }
  install(std::move(merged), next_id);
  return counts;
}

}  // namespace ecar
