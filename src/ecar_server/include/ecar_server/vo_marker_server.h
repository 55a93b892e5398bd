// Interactive markers of the virtual objects for rviz: one marker per live VO
// (markers.h voInteractiveMarker) on an interactive_markers server. Dragging a
// marker moves its object within its plane through a callback the owner (the
// Interactions nodelet) routes like a device's MANIPULATE, from the user
// "rviz": throttled to drag_rate while the mouse moves, and once more on
// mouse-up. The markers follow the store: sync() inserts, moves and erases
// them by version.
//
//   VoMarkerServer markers(nh, "/ecar/vo_markers", "map", 5.0, get, move);
//   markers.sync(store.allObjects());  // from a timer
//
// Thread-safety: sync() may be called from any thread (calls are serialised).
// Feedback is handled on the server's own spinner thread; it calls `get` and
// `move` while holding the interactive marker server's lock, so those must not
// call sync() or wait for a thread that does.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <interactive_markers/interactive_marker_server.h>
#include <ros/ros.h>
#include <visualization_msgs/InteractiveMarkerFeedback.h>

#include "ecar_core/structure/vo_store.h"

namespace ecar_server {

class VoMarkerServer {
 public:
  /// The latest state of an object (a tombstone included); nullopt when unknown.
  using GetFn = std::function<std::optional<ecar::VirtualObject>(ecar::ObjectId)>;
  /// Applies a move of `id` from `base_version` to `state` (by the user "rviz").
  using MoveFn = std::function<ecar::VoOutcome(ecar::ObjectId id, uint32_t base_version,
                                               const ecar::VirtualObject& state)>;

  /// Starts the interactive marker server on `topic_ns` (its own spinner
  /// thread) and warns, through `nh`, about feedback naming no marker.
  /// `frame`: the frame of the objects' coordinates. `drag_rate` (Hz): moves
  /// sent during a drag; 0 = on mouse-up only.
  VoMarkerServer(ros::NodeHandle nh, const std::string& topic_ns, const std::string& frame,
                 double drag_rate, GetFn get, MoveFn move);
  ~VoMarkerServer();
  VoMarkerServer(const VoMarkerServer&) = delete;
  VoMarkerServer& operator=(const VoMarkerServer&) = delete;

  /// Brings the markers to `objects` (every stored object): a live object
  /// without a marker gets one, a marker whose object has another version is
  /// re-made at its state, and a marker whose object is a tombstone or absent
  /// is erased. Publishes the changes.
  void sync(const std::vector<ecar::VirtualObject>& objects);

  /// Markers shown (the live objects at the last sync).
  size_t size() const;

 private:
  void onFeedback(const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback);
  /// Warns about feedback for a name that is no marker (the interactive marker
  /// server drops it silently).
  void checkFeedbackName(const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback);
  /// Puts the marker of `id` back where its object is (a rejected move).
  void resetMarker(const ecar::VirtualObject& vo);

  const std::string frame_;
  const double drag_rate_;
  const GetFn get_;
  const MoveFn move_;
  std::unique_ptr<interactive_markers::InteractiveMarkerServer> server_;
  ros::Subscriber name_check_sub_;

  mutable std::mutex sync_mutex_;  // serialises sync(); guards shown_
  /// Object -> its state when its marker was last made or moved.
  std::map<ecar::ObjectId, ecar::VirtualObject> shown_;

  std::mutex drag_mutex_;                       // guards last_move_
  std::map<ecar::ObjectId, double> last_move_;  ///< steady seconds of the last drag move
};

}  // namespace ecar_server
