// ecar_msgs/LocalGraph <-> ecar::LocalGraph (sync/local_graph.h): the one
// encoding of the local graph for the server that sends it and the device
// that reads it. The wire format lives only here:
//   TrackedPoint: u, v in 1/8 px (uint16, clamped to [0, 8191.875]), angle in
//     256 steps of 1.40625 degrees, octave clamped to [0, 255]: 10 bytes;
//   PointPosition: float32 position naming its point by a 16-bit index into
//     LocalGraph.points: 14 bytes.
// The timing fields (upload_sent, server_received, server_sent, tracking_time,
// server_time) and header.stamp are the publisher's to set.
#pragma once

#include <string>
#include <vector>

#include <ecar_msgs/KeyFrameInfo.h>
#include <ecar_msgs/LocalGraph.h>
#include <ecar_msgs/MapPointFull.h>
#include <ecar_msgs/TrackedPoint.h>

#include "ecar_core/sync/local_graph.h"

namespace ecar_bridge {

ecar_msgs::TrackedPoint toMsg(const ecar::GraphPoint& p);
ecar::GraphPoint fromMsg(const ecar_msgs::TrackedPoint& msg);

ecar_msgs::MapPointFull toMsg(const ecar::GraphMapPoint& p);
/// Throws ecar::Error naming `field` on a non-finite position or normal or an
/// invalid distance range.
ecar::GraphMapPoint fromMsg(const ecar_msgs::MapPointFull& msg,
                            const std::string& field = "map_point");

ecar_msgs::KeyFrameInfo toMsg(const ecar::GraphKeyFrame& kf);
/// Throws ecar::Error naming `field` on a bad pose.
ecar::GraphKeyFrame fromMsg(const ecar_msgs::KeyFrameInfo& msg,
                            const std::string& field = "keyframe");

/// Fills every field of `msg` but header.stamp and the timing fields;
/// header.frame_id is "map". Positions must be of points in `points`, in their
/// order (as the composer emits them); throws ecar::Error otherwise, or when
/// there are more than 65535 points.
void toMsg(const ecar::LocalGraph& graph, ecar_msgs::LocalGraph* msg);
/// Most entries a local graph may hold, per list (fromMsg refuses more).
constexpr size_t kMaxGraphPoints = 65535;
constexpr size_t kMaxGraphKeyFrames = 1000;
constexpr size_t kMaxGraphMapPoints = 200000;
constexpr size_t kMaxGraphPlanes = 4096;
constexpr size_t kMaxGraphObjects = 100000;
constexpr size_t kMaxPlaneBoundary = 4096;

/// Reads a local graph. Throws ecar::Error naming the field and the bound
/// when a list is longer than its kMaxGraph* (positions: than the points), on an unknown
/// status or sync mode, a bad pose (when the status is tracked), a position
/// whose index is not among the points or that is not finite, a bad keyframe
/// or map point. A bad plane or object is left out with its reason appended
/// to *skipped when `skipped` is given; without it, it throws too.
ecar::LocalGraph fromMsg(const ecar_msgs::LocalGraph& msg,
                         std::vector<std::string>* skipped = nullptr);

}  // namespace ecar_bridge
