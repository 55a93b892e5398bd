"""What a session records while it runs, from the topics of the server, devices and players.

Collector subscribes (rospy, one subscriber per topic) to /ecar/metrics (one row per round
trip), /ecar/objects (every accepted VO change), and per device to device_frame (the
device's pose, status and held VOs on every camera frame), local_graph (the server's pose of
an upload and the planes), interaction_result and player/finished. Messages arrive
deserialised by genpy; statuses are compared with the messages' own constants. Callbacks run
on rospy's threads: every field is guarded by `lock`.

Records holds what was measured and is filled by its callbacks (tested without ROS running);
Collector subscribes them. The records (see FrameRecord) are what `evaluating` and
`structure` read; `structure` saves and restores them (vo_raw.json.gz) for --reevaluate.
"""

import collections
import threading
import time

import rospy
from ecar_msgs.msg import (DeviceFrame, InteractionResult, LocalGraph, RoundTripMetrics,
                           VirtualObject)
from sensor_msgs.msg import Image
from std_msgs.msg import Bool

# One device frame: status (DeviceFrame.NOT_INITIALISED, OK, LOST), the device's pose in the
# map (position xyz, orientation xyzw), whether it was uploaded, its tracking time (s), the
# wall time it arrived, the VOs it held {object id: version} and when (wall time, device clock)
# each held version arrived on the device {object id: seconds} (DeviceFrame.object_received; 0
# left out).
FrameRecord = collections.namedtuple(
    "FrameRecord",
    "status position orientation uploaded tracking_time wall held received map_id",
    defaults=(None, 0))

# Progress of one device so far: frames received, uploads, local graphs, and the wall times
# of its first and last frame (None before the first).
DeviceProgress = collections.namedtuple("DeviceProgress",
                                        "frames uploads graphs first_wall last_wall")

# LocalGraph statuses whose pose is the server's estimate of the upload's camera.
SERVER_POSE_STATUSES = (LocalGraph.OK, LocalGraph.RELOCALISED)


def pose_tuples(pose):
    """((x, y, z), (qx, qy, qz, qw)) of a geometry_msgs/Pose."""
    p, q = pose.position, pose.orientation
    return (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)


def plane_entry(plane, map_id=0):
    """A plane as the records keep it (in the frame of server map `map_id`), or None without a
    boundary."""
    if not plane.boundary:
        return None
    n = len(plane.boundary)
    return {"id": plane.id, "map": map_id, "label": plane.label, "version": plane.version,
            "normal": (plane.normal.x, plane.normal.y, plane.normal.z), "offset": plane.offset,
            "centroid": (sum(p.x for p in plane.boundary) / n,
                         sum(p.y for p in plane.boundary) / n,
                         sum(p.z for p in plane.boundary) / n),
            "points": plane.num_points}


class Records:
    """What the session measured, filled by the on_* callbacks; guarded by `lock`:

    metrics        [dict per round trip] (the rows of metrics.csv)
    device_frames  {device: {frame index: FrameRecord}}
    server_poses   {device: {frame index: (position, orientation)}} of the local graphs
                   with a server pose (LocalGraph.OK or RELOCALISED)
    server_maps    {device: {frame index: LocalGraph.map_id}} of the same graphs
    graphs         {device: local graphs received}
    graph_walls    {device: [wall time of each local graph]}
    objects        [(wall, VirtualObject)] every accepted change
    results        {device: {"accepted": n, "rejected": {reason: n}}}
    planes         {plane id: newest state any device received (plane_entry, with the map
                   of the graph that brought it)}, without the planes the server removed
                   since (LocalGraph.removed_planes)
    removed_planes {plane ids the server told a device it removed (fused into another)}
    finished       {device: the player has played the whole dataset}
    """

    def __init__(self, devices):
        self.devices = list(devices)
        self.lock = threading.Lock()
        self.metrics = []
        self.device_frames = {d: {} for d in devices}
        self.server_poses = {d: {} for d in devices}
        self.server_maps = {d: {} for d in devices}
        self.graphs = {d: 0 for d in devices}
        self.graph_walls = {d: [] for d in devices}
        self.objects = []
        self.results = {d: {"accepted": 0, "rejected": {}} for d in devices}
        self.planes = {}
        self.removed_planes = set()
        self.finished = {d: False for d in devices}
        self.first_frame_wall = {}
        self.last_frame_wall = {}
        self.last_activity = time.time()

    def on_metrics(self, m):
        """An ecar_msgs/RoundTripMetrics: one row of metrics.csv (times in ms)."""
        row = {
            "device": m.device_id, "frame": m.frame_index, "bytes_up": m.bytes_up,
            "bytes_down": m.bytes_down, "points": m.points, "positions": m.positions,
            "latency_ms": 1e3 * m.latency, "upload_ms": 1e3 * m.upload_time,
            "server_ms": 1e3 * m.server_time, "receive_ms": 1e3 * m.receive_time,
            "align_ms": 1e3 * m.align_time,
            "send_ms": 1e3 * (m.server_time - m.receive_time - m.align_time),
            "download_ms": 1e3 * m.download_time,
            "device_tracking_ms": 1e3 * m.tracking_time_device,
            "server_cpu_ms": 1e3 * m.server_cpu_time,
            "device_tracking_cpu_ms": 1e3 * m.tracking_cpu_time_device,
            "jpeg_quality": m.jpeg_quality, "upload_budget": m.upload_budget,
        }
        with self.lock:
            self.metrics.append(row)
            self.last_activity = time.time()

    def on_device_frame(self, m):
        """An ecar_msgs/DeviceFrame: the device's FrameRecord of that frame."""
        now = time.time()
        position, orientation = pose_tuples(m.pose)
        record = FrameRecord(m.status, position, orientation, m.uploaded, m.tracking_time, now,
                             dict(zip(m.object_ids, m.object_versions)),
                             {i: t.to_sec() for i, t in zip(m.object_ids, m.object_received)
                              if not t.is_zero()},
                             m.map_id)
        with self.lock:
            self.device_frames.setdefault(m.device_id, {})[m.frame_index] = record
            self.first_frame_wall.setdefault(m.device_id, now)
            self.last_frame_wall[m.device_id] = now
            self.last_activity = now

    def on_local_graph(self, graph, device):
        """An ecar_msgs/LocalGraph for `device`: counted, its planes kept, its pose kept as the
        server's when its status says it has one (SERVER_POSE_STATUSES)."""
        for plane in graph.planes:
            self.on_plane(plane, graph.map_id)
        with self.lock:
            for plane_id in graph.removed_planes:
                # Plane ids are never reused: a removed plane does not come back.
                self.removed_planes.add(plane_id)
                self.planes.pop(plane_id, None)
            self.graphs[device] += 1
            self.graph_walls[device].append(time.time())
            if graph.status in SERVER_POSE_STATUSES:
                self.server_poses[device][graph.frame_index] = pose_tuples(graph.pose)
                self.server_maps[device][graph.frame_index] = graph.map_id
            self.last_activity = time.time()

    def on_plane(self, plane, map_id=0):
        """An ecar_msgs/Plane of server map `map_id`: kept when newer than the version held (a
        merge moves a plane into the merged map with a new version)."""
        with self.lock:
            held = self.planes.get(plane.id)
            if plane.id in self.removed_planes or (held is not None and
                                                   held["version"] >= plane.version):
                return
        entry = plane_entry(plane, map_id)
        if entry is not None:
            with self.lock:
                self.planes[plane.id] = entry

    def on_object(self, m):
        """An ecar_msgs/VirtualObject accepted by the server, with its arrival time."""
        with self.lock:
            self.objects.append((time.time(), m))
            self.last_activity = time.time()

    def on_result(self, m, device):
        """An ecar_msgs/InteractionResult of `device`: counted as accepted or by reason."""
        with self.lock:
            r = self.results[device]
            if m.accepted:
                r["accepted"] += 1
            else:
                r["rejected"][m.reason] = r["rejected"].get(m.reason, 0) + 1

    def on_finished(self, msg, device):
        """The latched std_msgs/Bool of `device`'s player: true once it played everything."""
        if msg.data:
            with self.lock:
                self.finished[device] = True

    def on_ar_view(self, m, device):
        with self.lock:
            self.ar_views[device] = m

    def all_finished(self):
        """(every player has finished, seconds since the last message)."""
        with self.lock:
            return all(self.finished.values()), time.time() - self.last_activity

    def progress(self):
        """{device: DeviceProgress} in session order."""
        with self.lock:
            return {d: DeviceProgress(len(self.device_frames[d]),
                                      sum(1 for e in self.device_frames[d].values() if e.uploaded),
                                      self.graphs[d], self.first_frame_wall.get(d),
                                      self.last_frame_wall.get(d))
                    for d in self.devices}


class Collector(Records):
    """Records filled from the session's topics (rospy must be initialised)."""

    def __init__(self, devices, metrics_publishers=None, ar_views=False):
        """metrics_publishers: the nodes publishing /ecar/metrics (default one per device;
        light devices share one nodelet manager). ar_views: keep each device's latest ar_view
        image (self.ar_views {device: sensor_msgs/Image})."""
        super().__init__(devices)
        self.ar_views = {}
        sub = rospy.Subscriber
        self.subs = [sub("/ecar/metrics", RoundTripMetrics, self.on_metrics, queue_size=1000),
                     sub("/ecar/objects", VirtualObject, self.on_object, queue_size=1000)]
        for d in devices:
            self.subs += [
                sub("/%s/interaction_result" % d, InteractionResult, self.on_result,
                    callback_args=d, queue_size=1000),
                sub("/%s/device_frame" % d, DeviceFrame, self.on_device_frame, queue_size=1000),
                sub("/%s/local_graph" % d, LocalGraph, self.on_local_graph, callback_args=d,
                    queue_size=1000),
                sub("/%s/player/finished" % d, Bool, self.on_finished, callback_args=d,
                    queue_size=1)]
        if ar_views:
            self.subs += [sub("/%s/ar_view" % d, Image, self.on_ar_view, callback_args=d,
                              queue_size=1, buff_size=2 ** 22) for d in devices]
        # What the devices publish from their first frame on: the players start once these
        # subscriptions are connected, or those frames would be missing from the records.
        self.device_subs = [(s, 1) for s in self.subs
                            if s.name.endswith("/device_frame")]
        self.device_subs.append((self.subs[0], metrics_publishers or len(devices)))

    def unconnected(self):
        """Topics of the devices that this collector is not yet connected to, each with how
        many of its publishers are connected and how many are awaited."""
        return ["%s (%d of %d)" % (s.name, s.get_num_connections(), n)
                for s, n in self.device_subs if s.get_num_connections() < n]
