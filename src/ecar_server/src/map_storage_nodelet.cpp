// MapStorage: /ecar/save_map and /ecar/load_map (ecar_msgs/SaveMap, LoadMap)
// write and read the server's whole map (keyframes, points, planes, grid
// links, VOs) to one file, and the parameter map_file ("" = none) loads one at
// startup, so that a session resumes in the same coordinate system (when it is
// the server's own autosave, its VOs are merged with the database's, newest
// version first, so a resume after a crash loses no acknowledged change). The work
// is the global graph's (ecar::GlobalGraph::save / load); a failure is
// answered with success = false and a message naming the path and the
// problem, and the server goes on with the map it had. Devices notice a load
// by the map epoch of their next local graph. The map is also saved every
// autosave_period seconds and when the server shuts down (autosave_file).
//
// The services' callers name a file in one folder only (map_dir): a file name
// ending in .ecarmap, or an absolute path in that folder. Nothing else is
// written or read for them: not the VO database, not a file reached through a
// link (never followed), not a FIFO (refused without waiting), not a file over
// max_map_mb. map_file and autosave_file come from the operator's
// configuration and may lie anywhere.
//
// It also returns the process's free heap pages to the system every
// heap_trim_period seconds and after every save (ecar::trimHeap): the saves
// make the server's largest short-lived buffers.
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include <ecar_msgs/LoadMap.h>
#include <ecar_msgs/SaveMap.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/common/heap.h"
#include "ecar_core/io/safe_file.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

class MapStorageNodelet : public nodelet::Nodelet {
 public:
  ~MapStorageNodelet() override {
    save_srv_.shutdown();
    load_srv_.shutdown();
    autosave_timer_.stop();
    trim_timer_.stop();
    autosave("on shutdown");
  }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config);
    max_bytes_ = static_cast<size_t>(config.max_map_mb * 1024.0 * 1024.0);
    try {
      folder_.emplace(config.map_dir);
      NODELET_INFO("map_dir: save_map and load_map work in '%s'", folder_->path().c_str());
    } catch (const ecar::Error& e) {
      folder_error_ = std::string("map_dir: ") + e.what();
      NODELET_ERROR("%s; save_map and load_map will fail", folder_error_.c_str());
    }
    const std::string& map_file = config.map_file;
    if (!map_file.empty()) {
      std::string message;
      ecar::MapCounts counts;
      // Our own autosave is an older snapshot of the database: resuming from
      // it after a crash must keep what the database acknowledged since.
      const ecar::VoLoad vos =
          config.mapFileIsAutosave() ? ecar::VoLoad::kMergeNewer : ecar::VoLoad::kReplace;
      if (load(map_file, &counts, &message, vos)) {
        NODELET_INFO("map_file: %s", message.c_str());
      } else {
        NODELET_ERROR("map_file: %s; starting with an empty map", message.c_str());
      }
    }
    save_srv_ = nh.advertiseService(ecar_bridge::kSaveMapService, &MapStorageNodelet::onSave, this);
    load_srv_ = nh.advertiseService(ecar_bridge::kLoadMapService, &MapStorageNodelet::onLoad, this);
    NODELET_INFO("map storage: %s, %s", ecar_bridge::kSaveMapService, ecar_bridge::kLoadMapService);
    autosave_path_ = config.autosavePath();
    if (!autosave_path_.empty()) {
      autosave_timer_ =
          nh.createWallTimer(ros::WallDuration(config.autosave_period),
                             [this](const ros::WallTimerEvent&) { autosave("periodic"); });
      NODELET_INFO("autosave: every %.0f s and on shutdown to '%s'", config.autosave_period,
                   autosave_path_.c_str());
    }
    if (config.heap_trim_period > 0.0) {
      trim_timer_ = nh.createWallTimer(ros::WallDuration(config.heap_trim_period),
                                       [this](const ros::WallTimerEvent&) { trimHeap(); });
    }
  }

  // Gives the heap's free pages back to the system; says what it did (at
  // info level every 5 minutes).
  void trimHeap() {
    const ecar::HeapTrim t = ecar::trimHeap();
    if (!t.after.available) return;
    constexpr double kMB = 1024.0 * 1024.0;
    char text[200];
    std::snprintf(text, sizeof(text),
                  "heap %.1f MB in use, %.1f MB free in the allocator; resident %.1f -> %.1f MB "
                  "after a %.1f ms trim",
                  t.after.in_use / kMB, t.after.free_held / kMB, t.before.resident / kMB,
                  t.after.resident / kMB, t.milliseconds);
    NODELET_DEBUG("%s", text);
    NODELET_INFO_THROTTLE(300.0, "%s", text);
  }

  // Saves the map to the autosave file (nothing before a device connected).
  void autosave(const char* when) {
    if (autosave_path_.empty() || !graph_ || !graph_->hasMap()) return;
    try {
      const ecar::MapCounts c = graph_->save(autosave_path_);
      NODELET_DEBUG("autosave (%s): %s", when, describe(c).c_str());
      if (!autosaved_)
        NODELET_INFO("autosave (%s): %s to '%s'", when, describe(c).c_str(),
                     autosave_path_.c_str());
      autosaved_ = true;
    } catch (const std::exception& e) {
      NODELET_ERROR("autosave (%s) failed: %s", when, e.what());
    }
    if (trim_timer_.isValid()) trimHeap();
  }

  // The file a service caller's path stands for (ecar::MapFolder::resolve).
  std::string inFolder(const std::string& requested) const {
    if (!folder_) throw ecar::Error(folder_error_);
    return folder_->resolve(requested);
  }

  bool onSave(ecar_msgs::SaveMap::Request& req, ecar_msgs::SaveMap::Response& res) {
    try {
      const std::string path = inFolder(req.path);
      const ecar::MapCounts c = graph_->save(path);
      res.success = true;
      res.keyframes = c.keyframes;
      res.map_points = c.map_points;
      res.planes = c.planes;
      res.objects = c.objects;
      res.message = "saved " + describe(c) + " to '" + path + "'";
      NODELET_INFO("%s", res.message.c_str());
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what();
      NODELET_WARN("save_map failed: %s", e.what());
    }
    if (trim_timer_.isValid()) trimHeap();
    return true;
  }

  bool onLoad(ecar_msgs::LoadMap::Request& req, ecar_msgs::LoadMap::Response& res) {
    ecar::MapCounts c;
    try {
      res.success = load(inFolder(req.path), &c, &res.message);
    } catch (const ecar::Error& e) {
      res.success = false;
      res.message = e.what();
    }
    if (res.success) {
      res.keyframes = c.keyframes;
      res.map_points = c.map_points;
      res.planes = c.planes;
      res.objects = c.objects;
      NODELET_INFO("%s", res.message.c_str());
    } else {
      NODELET_WARN("load_map failed: %s", res.message.c_str());
    }
    return true;
  }

  // Loads `path`; false with `message` naming the path and the problem.
  bool load(const std::string& path, ecar::MapCounts* counts, std::string* message,
            ecar::VoLoad vos = ecar::VoLoad::kReplace) {
    try {
      if (path.empty()) throw ecar::Error("load_map: the path is empty");
      *counts = graph_->load(path, max_bytes_, vos);
      *message = "loaded " + describe(*counts) + " from '" + path + "', map epoch " +
                 std::to_string(graph_->epoch());
      if (vos == ecar::VoLoad::kMergeNewer) {
        *message += "; resumed from the autosave: " + std::to_string(counts->objects_from_file) +
                    " virtual objects from the file, " + std::to_string(counts->objects_kept) +
                    " as the database has them (the same, or changed since)";
      }
      if (!counts->orphan_objects.empty()) {
        // Kept in the store (and in the next save), shown to no device.
        std::string ids;
        for (const ecar::ObjectId id : counts->orphan_objects) {
          ids += (ids.empty() ? "" : ", ") + std::to_string(id.value);
        }
        *message += "; " + std::to_string(counts->orphan_objects.size()) +
                    " virtual objects belong to a map the file does not hold (kept, shown to "
                    "no device): " +
                    ids;
        NODELET_WARN("%s", message->c_str());
      }
      return true;
    } catch (const std::exception& e) {
      *message = e.what();
      return false;
    }
  }

  static std::string describe(const ecar::MapCounts& c) {
    char text[200];
    std::snprintf(text, sizeof(text),
                  "%u maps, %u keyframes, %u map points, %u planes, %u objects (%zu bytes, "
                  "%.0f ms)",
                  c.maps, c.keyframes, c.map_points, c.planes, c.objects, c.bytes, c.milliseconds);
    return text;
  }

  std::shared_ptr<ecar::GlobalGraph> graph_;
  ros::ServiceServer save_srv_, load_srv_;
  ros::WallTimer autosave_timer_, trim_timer_;
  std::string autosave_path_;
  bool autosaved_ = false;
  std::optional<ecar::MapFolder> folder_;  ///< map_dir (empty: it could not be made)
  std::string folder_error_;               ///< why not
  size_t max_bytes_ = ecar::kMaxMapFileBytes;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::MapStorageNodelet, nodelet::Nodelet)
