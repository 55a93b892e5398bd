#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End-to-end tests of the edge server (started by bad_input.test / edgeslam.test).

A python fake device renders a short corridor sequence (ecar_sim make_dataset),
connects on /ecar/connect and uploads every 4th frame as JPEG with gravity and
odometry, waiting for each local graph. It mirrors the contract's device
keyframe queue: every graph with a tracked pose is one keyframe holding all its
points; the last `keyframe_queue` are kept.

~scenario "bad_input": the good uploads are interleaved with a corrupt JPEG, a
wrong-size image, NaN gravity, an upload naming another device id, an oversized
upload and an upload from a device that never connected. Asserts: the server
keeps answering (every good upload gets its graph, most tracked after
initialisation), it warned naming the device and the field, every tracked
point's position is held or sent, and positions are not resent for points the
device holds unchanged.

~scenario "edgeslam": two fake devices upload the same images, device_0 in
edgeslam mode (the server default here) and device_1 in ecar mode. Asserts:
edgeslam graphs carry keyframes and map points with descriptors and no
points/positions, and are several times larger than the ecar graphs.

~scenario "vo": the test starts the server itself (roslaunch server.launch
with a temporary VO database) so that it can kill it. One fake device maps the
first part of the sequence; the server's local graphs carry planes, among them
a FLOOR. The device registers a line on that floor (REGISTER) in front of its
camera and gets an accepted InteractionResult; the next local graphs carry the
object. A NaN line, a MANIPULATE of an unknown id and a line far out of the map
are rejected with a reason (and warned naming the device). Then the server is
killed (SIGKILL) and restarted on the same database: the object is in the
database at its version and, after the device re-maps the same images, in the
new server's local graphs.

~scenario "map": the test starts the server itself. One fake device maps the
first two thirds of the sequence and registers a line on the floor; the map is
saved with /ecar/save_map (an unwritable path fails with a message naming it).
The server is killed (SIGKILL) and a fresh one, on an empty VO database,
starts with map:=FILE: the device, re-uploading the same frames, is aligned in
the same coordinate system (each frame's pose within 2 cm of its pose before),
and its graphs carry the saved planes and the object (same id, version and
position). /ecar/load_map of a corrupt copy and of a missing file fail with a
message naming the file while the server keeps serving; a load of the good
file moves the map epoch on and the device is aligned the same again. After a
kill -9, the object is in the new server's database.

~scenario "share": the test starts server.launch with vo_share:=direct. Two
fake devices upload the same images; device_0 registers a line on the floor.
Asserts: device_1 receives its state on /device_1/objects and device_0 gets
nothing of its own change on /device_0/objects; a device_2 connecting late gets
the live object when it subscribes; no local graph carries objects;
/ecar/objects carries every accepted version in order (tombstone included). An
InteractiveMarkerFeedback (MOUSE_UP, a new pose) on /ecar/vo_markers/feedback
moves the object by the in-plane part of the marker's move (within 1 mm) at the
next version, relayed to both devices; feedback naming no marker is ignored
with a warning and the server keeps answering (a DELETE from device_1 then
reaches device_0 only).

Prints the measured figures (bytes, bytes per point, server time).
"""

import collections
import io
import math
import os
import shutil
import signal
import sqlite3
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import unittest
import xmlrpc.client

import cv2
import rospkg
import rospy
import rostest
import yaml
import rosgraph
from ecar_msgs.msg import Interaction, InteractionResult, LocalGraph, Plane, Upload, VirtualObject
from ecar_msgs.srv import Connect, ConnectRequest, Disconnect, LoadMap, SaveMap
from geometry_msgs.msg import PointStamped
from visualization_msgs.msg import InteractiveMarkerFeedback, InteractiveMarkerUpdate
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo

PKG = "ecar_server"
TRACKED = (LocalGraph.OK, LocalGraph.RELOCALISED)


def read_rows(path):
    """Non-comment lines of a TUM-style text file, split into fields."""
    with open(path) as f:
        return [l.split() for l in f if l.strip() and not l.startswith("#")]


class Dataset:
    """A make_dataset folder: images, gravity, odometry, camera."""

    def __init__(self, folder):
        self.folder = folder
        self.frames = read_rows(os.path.join(folder, "rgb.txt"))
        self.gravity = {r[0]: [float(x) for x in r[1:4]]
                        for r in read_rows(os.path.join(folder, "gravity.txt"))}
        self.odometry = {r[0]: [float(x) for x in r[1:8]]
                         for r in read_rows(os.path.join(folder, "odometry.txt"))}
        with open(os.path.join(folder, "camera.yaml")) as f:
            self.camera = yaml.safe_load(f)

    def camera_info(self):
        c = self.camera
        info = CameraInfo()
        info.width, info.height = c["width"], c["height"]
        info.distortion_model = "plumb_bob"
        info.D = list(c.get("distortion", [0.0] * 5))
        info.K = [c["fx"], 0, c["cx"], 0, c["fy"], c["cy"], 0, 0, 1]
        info.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
        info.P = [c["fx"], 0, c["cx"], 0, 0, c["fy"], c["cy"], 0, 0, 0, 1, 0]
        return info

    def jpeg(self, i, quality=70):
        image = cv2.imread(os.path.join(self.folder, self.frames[i][1]), cv2.IMREAD_GRAYSCALE)
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
        assert ok
        return data.tobytes()


def serialized_length(msg):
    buff = io.BytesIO()
    msg.serialize(buff)
    return len(buff.getvalue())


class FakeDevice:
    """Connects, uploads, receives local graphs and mirrors its keyframe queue."""

    def __init__(self, name, dataset, sync_mode="", keyframe_queue=10):
        self.name = name
        self.dataset = dataset
        self.sync_mode = sync_mode
        self.queue_length = keyframe_queue
        self.lock = threading.Condition()
        self.graphs = {}  # frame_index -> (LocalGraph, bytes)
        self.held = {}  # point id -> position
        self.queue = collections.deque()  # sets of point ids
        self.missing = 0  # tracked points without a held or sent position
        self.unchanged_resends = 0  # positions sent for points held at that position
        self.resends = 0  # positions sent for points held (moved)
        self.resend_moves = []  # metres
        self.resend_px = []  # image shift of the move seen from the graph's camera
        self.resend_dist = []
        self.pub = None
        self.results = {}  # request_id -> InteractionResult
        self.interaction_pub = None
        self.result_sub = None
        self.session = 0  # Connect's token

    def connect(self):
        rospy.wait_for_service("/ecar/connect", timeout=30.0)
        connect = rospy.ServiceProxy("/ecar/connect", Connect)
        req = ConnectRequest(device_id=self.name, camera_info=self.dataset.camera_info(),
                             sync_mode=self.sync_mode, keyframe_queue=self.queue_length,
                             session=self.session)
        res = connect(req)
        if res.accepted:
            self.session = res.session
            self.sub = rospy.Subscriber(res.local_graph_topic, LocalGraph, self.on_graph,
                                        queue_size=50, tcp_nodelay=True)
            self.pub = rospy.Publisher(res.upload_topic, Upload, queue_size=20)
            if self.interaction_pub is None:
                self.interaction_pub = rospy.Publisher(res.interaction_topic, Interaction,
                                                       queue_size=20)
                self.result_sub = rospy.Subscriber("/%s/interaction_result" % self.name,
                                                   InteractionResult, self.on_result,
                                                   queue_size=50)
        return res

    def on_result(self, msg):
        with self.lock:
            self.results[msg.request_id] = msg
            self.lock.notify_all()

    def interact(self, request_id, type_, obj, object_id=0, base_version=0, timeout=10.0,
                 session=None):
        """Sends an Interaction and waits for its InteractionResult (None on timeout)."""
        msg = Interaction()
        msg.header.stamp = rospy.Time.now()
        msg.header.frame_id = "map"
        msg.device_id = self.name
        msg.session = self.session if session is None else session
        msg.request_id = request_id
        msg.type = type_
        msg.object_id = object_id
        msg.object = obj
        msg.base_version = base_version
        self.interaction_pub.publish(msg)
        end = time.time() + timeout
        with self.lock:
            while request_id not in self.results and time.time() < end:
                self.lock.wait(0.05)
            return self.results.get(request_id)

    def on_graph(self, msg):
        size = serialized_length(msg)
        with self.lock:
            if msg.status in TRACKED and msg.sync_mode == LocalGraph.SYNC_ECAR:
                self.apply(msg)
            self.graphs[msg.frame_index] = (msg, size)
            self.lock.notify_all()

    def apply(self, msg):
        """The device's side of the contract: new positions, one keyframe, eviction."""
        for pos in msg.positions:
            p = msg.points[pos.index]  # a position names its point by index into points
            position = (pos.x, pos.y, pos.z)
            if self.held.get(p.id) == position:
                self.unchanged_resends += 1
            elif p.id in self.held:
                self.resends += 1
                self.resend_moves.append(math.dist(position, self.held[p.id]))
                c = msg.pose.position
                ray = [position[k] - (c.x, c.y, c.z)[k] for k in range(3)]
                dist = math.sqrt(sum(r * r for r in ray))
                move = [position[k] - self.held[p.id][k] for k in range(3)]
                along = sum(m * r for m, r in zip(move, ray)) / dist
                perp = math.sqrt(max(0.0, sum(m * m for m in move) - along * along))
                self.resend_px.append(525.0 * perp / dist)
                self.resend_dist.append(dist)
            self.held[p.id] = position
        ids = set(p.id for p in msg.points)
        self.missing += sum(1 for i in ids if i not in self.held)
        self.queue.append(ids)
        while len(self.queue) > self.queue_length:
            self.queue.popleft()
        alive = set().union(*self.queue) if self.queue else set()
        self.held = {i: v for i, v in self.held.items() if i in alive}

    def upload(self, i, data=None, device_id=None, gravity=None, reset=False, publisher=None,
               session=None):
        stamp_s, _ = self.dataset.frames[i]
        msg = Upload()
        msg.session = self.session if session is None else session
        msg.header.stamp = rospy.Time.from_sec(1000.0 + float(stamp_s))
        msg.header.frame_id = self.name + "/camera"
        msg.device_id = device_id if device_id is not None else self.name
        msg.frame_index = i
        msg.image.header = msg.header
        msg.image.format = "jpeg"
        msg.image.data = data if data is not None else self.dataset.jpeg(i)
        g = gravity if gravity is not None else self.dataset.gravity.get(stamp_s)
        if g is not None:
            msg.has_gravity = True
            msg.gravity.x, msg.gravity.y, msg.gravity.z = g
        o = self.dataset.odometry.get(stamp_s)
        if o is not None:
            msg.has_odometry = True
            p, q = msg.odometry.position, msg.odometry.orientation
            p.x, p.y, p.z, q.x, q.y, q.z, q.w = o
        msg.reset = reset
        msg.sent = rospy.Time.now()
        (publisher or self.pub).publish(msg)

    def wait_graph(self, i, timeout=15.0):
        end = time.time() + timeout
        with self.lock:
            while i not in self.graphs and time.time() < end and not rospy.is_shutdown():
                self.lock.wait(0.05)
            return self.graphs.get(i)


def wait_subscribed(pub, timeout=10.0):
    end = time.time() + timeout
    while pub.get_num_connections() == 0 and time.time() < end:
        time.sleep(0.05)
    return pub.get_num_connections() > 0


def render(frames):
    root = os.path.join(rospkg.RosPack().get_path("ecar_sim"), "..", "..")
    out = tempfile.mkdtemp(prefix="ecar_server_test_")
    subprocess.check_call(
        ["rosrun", "ecar_sim", "make_dataset", "--scene",
         os.path.join(root, "config", "scenes", "corridor.yaml"), "--device", "device_0",
         "--frames", str(frames), "--out", out], stdout=subprocess.DEVNULL)
    return out


def rotation(q):
    """3x3 rotation (rows) of a geometry_msgs/Quaternion."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def floor_line(graph, plane, camera, u, v, half_length=0.2):
    """A LINE VirtualObject on `plane` where pixel (u, v) of the graph's pose hits it."""
    R = rotation(graph.pose.orientation)
    t = [graph.pose.position.x, graph.pose.position.y, graph.pose.position.z]
    r_c = [(u - camera["cx"]) / camera["fx"], (v - camera["cy"]) / camera["fy"], 1.0]
    d = [dot(R[i], r_c) for i in range(3)]
    n = [plane.normal.x, plane.normal.y, plane.normal.z]
    s = -(dot(n, t) + plane.offset) / dot(n, d)
    if s <= 0:
        return None
    p = [t[i] + s * d[i] for i in range(3)]
    x = [R[i][0] for i in range(3)]  # camera x, projected into the plane
    k = dot(x, n)
    a = [x[i] - k * n[i] for i in range(3)]
    norm = math.sqrt(dot(a, a))
    a = [c / norm for c in a]
    obj = VirtualObject()
    obj.kind = VirtualObject.LINE
    obj.start.x, obj.start.y, obj.start.z = [p[i] - half_length * a[i] for i in range(3)]
    obj.end.x, obj.end.y, obj.end.z = [p[i] + half_length * a[i] for i in range(3)]
    obj.position.x, obj.position.y, obj.position.z = p
    obj.r, obj.g, obj.b = 255, 40, 40
    obj.width = 0.05
    obj.normal = plane.normal
    obj.plane_id = plane.id
    return obj


class Server:
    """server.launch run by the test (so that it can kill -9 it)."""

    def __init__(self, database, vo_attach="grid", map_file="", vo_share="graph",
                 autosave_period="", map_dir=""):
        root = os.path.join(rospkg.RosPack().get_path("ecar_server"), "..", "..")
        self.proc = subprocess.Popen(
            ["roslaunch", os.path.join(root, "launch", "server.launch"), "output:=log",
             "database:=" + database, "vo_attach:=" + vo_attach, "map:=" + map_file,
             "vo_share:=" + vo_share, "autosave_period:=" + autosave_period,
             "map_dir:=" + (map_dir or os.path.dirname(os.path.abspath(database)))],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)

    def manager_pid(self):
        uri = rosgraph.Master("/fake_device_test").lookupNode("/edge_server")
        return xmlrpc.client.ServerProxy(uri).getPid("/fake_device_test")[2]

    def kill9(self):
        os.kill(self.manager_pid(), signal.SIGKILL)
        time.sleep(0.5)
        self.stop()

    def stop(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


def saved_planes(path):
    """plane id -> (label, offset, version) from the "planes" section of a map file
    (layout: ecar_core/map_io.h)."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"ECARMAP\0"
    count = struct.unpack_from("<I", data, 12)[0]
    at, sections = 16, {}
    for _ in range(count):
        n = data[at]
        name = data[at + 1:at + 1 + n].decode()
        offset, length, _ = struct.unpack_from("<QQI", data, at + 1 + n)
        sections[name] = (offset, length)
        at += 1 + n + 20
    at = sections["planes"][0]
    section_version, _, planes = struct.unpack_from("<III", data, at)
    at += 12
    out = {}
    for _ in range(planes):
        pid = struct.unpack_from("<I", data, at)[0]
        if section_version >= 2:  # the plane's atlas map id follows its id
            at += 4
        label = struct.unpack_from("<B", data, at + 4)[0]
        offset, version = struct.unpack_from("<dI", data, at + 5 + 24)
        at += 5 + 24 + 8 + 8
        boundary = struct.unpack_from("<I", data, at)[0]
        at += 4 + 24 * boundary
        points = struct.unpack_from("<I", data, at)[0]
        at += 4 + 28 * points
        keyframes = struct.unpack_from("<I", data, at)[0]
        at += 4 + 4 * keyframes
        out[pid] = (label, offset, version)
    return out


def wait_service_gone(name, timeout=10.0):
    end = time.time() + timeout
    while time.time() < end:
        try:
            rospy.wait_for_service(name, timeout=0.2)
        except rospy.ROSException:
            return True
        time.sleep(0.2)
    return False


def summary(label, graphs):
    tracked = [(m, b) for m, b in graphs if m.status in TRACKED]
    if not tracked:
        return
    sizes = [b for _, b in tracked]
    points = [max(1, len(m.points) or len(m.map_points)) for m, _ in tracked]
    server_ms = [1000.0 * m.server_time for m, _ in tracked]
    track_ms = [1000.0 * m.tracking_time for m, _ in tracked]
    print("[%s] graphs %d tracked %d | bytes median %.0f | bytes/point median %.1f | "
          "positions/points %.3f | server time median %.1f ms (tracking %.1f ms)"
          % (label, len(graphs), len(tracked), statistics.median(sizes),
             statistics.median([b / p for b, p in zip(sizes, points)]),
             sum(len(m.positions) for m, _ in tracked) / float(sum(points)),
             statistics.median(server_ms), statistics.median(track_ms)))
    sys.stdout.flush()


class ServerTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.frames = rospy.get_param("~frames", 120)
        cls.every = rospy.get_param("~every", 4)
        cls.folder = render(cls.frames)
        cls.dataset = Dataset(cls.folder)
        cls.warnings = []
        cls.infos = []
        cls.log_sub = rospy.Subscriber("/rosout", Log, cls.on_log, queue_size=500)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.folder, ignore_errors=True)

    @classmethod
    def on_log(cls, msg):
        if msg.level >= Log.WARN:
            cls.warnings.append(msg.msg)
        elif msg.level == Log.INFO:
            cls.infos.append(msg.msg)

    def warned(self, *words):
        return any(all(w in text for w in words) for text in list(self.warnings))

    def tracked_share(self, graphs):
        statuses = [graphs[i][0].status for i in sorted(graphs)]
        first = next((k for k, s in enumerate(statuses) if s in TRACKED), None)
        self.assertIsNotNone(first, "never initialised")
        after = statuses[first:]
        return sum(1 for s in after if s in TRACKED) / float(len(after)), len(after)

    def test_server(self):
        scenario = rospy.get_param("~scenario", "bad_input")
        if scenario == "edgeslam":
            self.run_edgeslam()
        elif scenario == "vo":
            self.run_vo()
        elif scenario == "map":
            self.run_map()
        elif scenario == "share":
            self.run_share()
        else:
            self.run_bad_input()

    def run_bad_input(self):
        max_bytes = rospy.get_param("~max_upload_bytes", 300000)
        device = FakeDevice("device_0", self.dataset)
        res = device.connect()
        self.assertTrue(res.accepted, res.message)
        self.assertNotEqual(res.session, 0)
        # The uplink_capacity's share of the one device connected (uplink_utilisation 0.5).
        budget = rospy.get_param("~upload_budget", 0)
        self.assertEqual(res.upload_budget, budget)
        self.assertTrue(wait_subscribed(device.pub), "the server did not subscribe the upload topic")
        # Sessions: another node cannot take the live name, disconnect it, or speak as a
        # reserved user; the device itself reconnects with its token.
        rogue = FakeDevice("device_0", self.dataset)
        r = rogue.connect()
        self.assertFalse(r.accepted)
        self.assertIn("another session", r.message)
        disconnect = rospy.ServiceProxy("/ecar/disconnect", Disconnect)
        d = disconnect(device_id="device_0", session=res.session ^ 1)
        self.assertFalse(d.ok)
        self.assertIn("wrong session token", d.message)
        for name in ("ecar", "rviz"):
            r = FakeDevice(name, self.dataset).connect()
            self.assertFalse(r.accepted, name)
            self.assertIn("reserved", r.message)
        connect = rospy.ServiceProxy("/ecar/connect", Connect)
        again = connect(ConnectRequest(device_id="device_0", camera_info=self.dataset.camera_info(),
                                       keyframe_queue=device.queue_length, session=res.session))
        self.assertTrue(again.accepted, again.message)
        self.assertEqual(again.session, res.session)
        ghost = rospy.Publisher("/ghost/upload", Upload, queue_size=5)
        bad = [
            ("corrupt jpeg", lambda i: device.upload(i, data=b"not a jpeg" * 300)),
            ("wrong size", lambda i: device.upload(i, data=cv2.imencode(
                ".jpg", cv2.resize(cv2.imread(os.path.join(self.folder, self.dataset.frames[i][1]),
                                              cv2.IMREAD_GRAYSCALE), (320, 240)))[1].tobytes())),
            ("nan gravity", lambda i: device.upload(i, gravity=[float("nan"), -9.8, 0.0])),
            ("unknown device id", lambda i: device.upload(i, device_id="intruder")),
            ("oversized", lambda i: device.upload(i, data=b"\xff" * (max_bytes + 1000))),
            ("never connected", lambda i: device.upload(i, device_id="ghost", publisher=ghost)),
            ("wrong session token", lambda i: device.upload(i, session=device.session ^ 1)),
        ]
        good = list(range(0, len(self.dataset.frames), self.every))
        answered = {}
        for k, i in enumerate(good):
            device.upload(i, reset=(k == 0))
            got = device.wait_graph(i)
            self.assertIsNotNone(got, "no local graph for good upload %d" % i)
            answered[i] = got
            # A bad upload (with the next frame's index) between good ones.
            name, send = bad[k % len(bad)]
            send(min(i + 1, len(self.dataset.frames) - 1))
            time.sleep(0.05)
        time.sleep(0.5)
        # Bad uploads got no graph (frame i + 1 was never uploaded well).
        for i in good:
            self.assertNotIn(i + 1, device.graphs, "a bad upload was answered")
        self.assertEqual({m.upload_budget for m, _ in answered.values()}, {budget})
        share, n = self.tracked_share(answered)
        self.assertGreaterEqual(share, 0.9, "tracked %.0f%% of %d uploads after init"
                                % (100 * share, n))
        for words in [("device_0", "image"), ("device_0", "320x240"), ("device_0", "gravity"),
                      ("device_0", "device_id", "intruder"), ("device_0", "max_upload_bytes"),
                      ("device_0", "wrong session token")]:
            self.assertTrue(self.warned(*words), "no warning with %s in %s"
                            % (words, self.warnings))
        # Still alive: a new connect is answered.
        self.assertTrue(device.connect().accepted)
        # The mirror: every tracked point held or sent, nothing resent unchanged.
        positions = sum(len(m.positions) for m, _ in answered.values())
        points = sum(len(m.points) for m, _ in answered.values())
        self.assertEqual(device.missing, 0, "tracked points without a position")
        self.assertLessEqual(device.unchanged_resends, 0.02 * positions)
        tolerance = rospy.get_param("/edge_server/position_tolerance", 0.0)
        small = sum(1 for d in device.resend_moves if d < 0.9 * tolerance)
        self.assertLessEqual(small, 0.02 * max(1, positions),
                             "%d positions resent that moved less than position_tolerance" % small)
        # Positions go only to points the device lacks or holds at a moved
        # position (position_tolerance); a young map moves most held points by
        # centimetres at each local BA, so no ratio is asserted here.
        self.assertLess(positions, points, "positions %d for %d tracked points"
                        % (positions, points))
        self.assertGreater(device.resends, 0)
        summary("ecar", list(answered.values()))
        print("[ecar] positions %d: for held points %d (moved median %.4f m), unchanged %d"
              % (positions, device.resends,
                 statistics.median(device.resend_moves) if device.resend_moves else 0.0,
                 device.unchanged_resends))
        if device.resend_px:
            q = sorted(device.resend_px)
            print("[ecar] resent moves seen from the camera: px median %.2f p90 %.2f; distance median %.1f m"
                  % (q[len(q) // 2], q[int(0.9 * len(q))], statistics.median(device.resend_dist)))

    def run_edgeslam(self):
        edge = FakeDevice("device_0", self.dataset)  # server default: edgeslam
        ecar = FakeDevice("device_1", self.dataset, sync_mode="ecar")
        for d in (edge, ecar):
            res = d.connect()
            self.assertTrue(res.accepted, res.message)
            self.assertTrue(wait_subscribed(d.pub))
        good = list(range(0, len(self.dataset.frames), self.every))
        for k, i in enumerate(good):
            edge.upload(i, reset=(k == 0))
            self.assertIsNotNone(edge.wait_graph(i), "no edgeslam graph for %d" % i)
            ecar.upload(i, reset=(k == 0))
            self.assertIsNotNone(ecar.wait_graph(i), "no ecar graph for %d" % i)
        share, n = self.tracked_share(edge.graphs)
        self.assertGreaterEqual(share, 0.9)
        both = [i for i in good if edge.graphs[i][0].status in TRACKED
                and ecar.graphs[i][0].status in TRACKED]
        self.assertGreaterEqual(len(both), 5, "too few frames tracked for both devices")
        for i in both:
            m = edge.graphs[i][0]
            self.assertEqual(m.sync_mode, LocalGraph.SYNC_EDGESLAM)
            self.assertFalse(m.points or m.positions)
            self.assertTrue(m.keyframes and m.map_points)
            ids = set(p.id for p in m.map_points)
            for kf in m.keyframes:
                self.assertTrue(set(kf.point_ids) <= ids)
                self.assertTrue(kf.device_id in ("device_0", "device_1"))
            self.assertTrue(all(any(bytearray(p.descriptor)) for p in m.map_points))
            self.assertTrue(all(p.max_distance > p.min_distance for p in m.map_points))
        edge_bytes = statistics.median([edge.graphs[i][1] for i in both])
        ecar_bytes = statistics.median([ecar.graphs[i][1] for i in both])
        summary("edgeslam", [edge.graphs[i] for i in both])
        summary("ecar", [ecar.graphs[i] for i in both])
        print("[edgeslam vs ecar] median bytes %.0f vs %.0f (ratio %.1f)"
              % (edge_bytes, ecar_bytes, edge_bytes / ecar_bytes))
        self.assertGreaterEqual(edge_bytes, 3 * ecar_bytes)


    def upload_all(self, device, frames, first_reset):
        for k, i in enumerate(frames):
            # The first upload to a restarted server may go to the killed one's
            # stale connection: send it again until answered.
            for attempt in range(6 if k == 0 else 1):
                device.upload(i, reset=(first_reset and k == 0))
                if device.wait_graph(i, timeout=3.0 if k == 0 else 15.0):
                    break
            self.assertIsNotNone(device.wait_graph(i, timeout=0.0),
                                 "no local graph for upload %d" % i)

    def run_vo(self):
        folder = tempfile.mkdtemp(prefix="ecar_vo_test_")
        database = os.path.join(folder, "vo.sqlite")
        server = Server(database)
        try:
            self.vo_session(server, database)
        finally:
            server.stop()
            shutil.rmtree(folder, ignore_errors=True)

    def vo_session(self, server, database):
        device = FakeDevice("device_0", self.dataset)
        self.assertTrue(device.connect().accepted)
        self.assertTrue(wait_subscribed(device.pub))
        good = list(range(0, len(self.dataset.frames), self.every))
        first, second = good[:len(good) * 2 // 3], good[len(good) * 2 // 3:]
        self.upload_all(device, first, True)
        # Planes: the graphs carry each plane when it is new or changed visibly (and now and
        # then again); the device holds the latest of each, a FLOOR among them.
        tracked = [device.graphs[i][0] for i in first if device.graphs[i][0].status in TRACKED]
        self.assertTrue(tracked, "never tracked")
        graph = tracked[-1]
        held = {}
        for g in tracked:
            for p in g.planes:
                if p.id not in held or held[p.id].version <= p.version:
                    held[p.id] = p
        planes = list(held.values())
        sent = sum(len(g.planes) for g in tracked)
        labels = collections.Counter(p.label for p in planes)
        print("[vo] planes held: %d (floor %d, wall %d, ceiling %d, other %d), %.2f sent per graph"
              % (len(planes), labels[Plane.FLOOR], labels[Plane.WALL], labels[Plane.CEILING],
                 labels[Plane.OTHER], sent / float(len(tracked))))
        floors = [p for p in planes if p.label == Plane.FLOOR]
        self.assertTrue(floors, "no FLOOR plane in the local graphs: %s" % labels)
        floor = max(floors, key=lambda p: p.num_points)
        self.assertTrue(all(p.version >= 1 for p in planes))
        obj = floor_line(graph, floor, self.dataset.camera, 319.5, 400.0)
        self.assertIsNotNone(obj, "the floor is not below the camera")

        # Register: accepted, with an id and version 1.
        res = device.interact(1, Interaction.REGISTER, obj)
        self.assertIsNotNone(res, "no InteractionResult for the REGISTER")
        self.assertTrue(res.accepted, res.reason)
        self.assertGreater(res.object_id, 0)
        self.assertEqual(res.version, 1)
        vo_id = res.object_id

        # rviz's Publish Point tool: an ANCHOR owned by "rviz" at the same place.
        clicked = rospy.Publisher("/clicked_point", PointStamped, queue_size=1, latch=True)
        self.assertTrue(wait_subscribed(clicked))
        point = PointStamped()
        point.header.frame_id = "map"
        point.point = obj.position
        clicked.publish(point)

        # Bad interactions: rejected with a reason.
        nan = floor_line(graph, floor, self.dataset.camera, 319.5, 400.0)
        nan.start.x = float("nan")
        far = floor_line(graph, floor, self.dataset.camera, 319.5, 400.0)
        far.start.x += 1e5
        far.end.x += 1e5
        far.position.x += 1e5
        for request_id, type_, o, oid, base, word, session in [
                (2, Interaction.REGISTER, nan, 0, 0, "finite", None),
                (3, Interaction.MANIPULATE, obj, 9999, 1, "9999", None),
                (4, Interaction.REGISTER, far, 0, 0, "map", None),
                # Another node on the device's topic, without its token: the object stays.
                (6, Interaction.DELETE, VirtualObject(), vo_id, 1, "session", 0)]:
            r = device.interact(request_id, type_, o, object_id=oid, base_version=base,
                                session=session)
            self.assertIsNotNone(r, "no InteractionResult for request %d" % request_id)
            self.assertFalse(r.accepted, "request %d accepted" % request_id)
            self.assertIn(word, r.reason)
            print("[vo] request %d rejected: %s" % (request_id, r.reason))
        time.sleep(0.5)
        self.assertTrue(self.warned("device_0", "rejected"), "no warning naming the device")

        # The next local graphs carry the object at version 1.
        self.upload_all(device, second, False)
        carried = [i for i in second if device.graphs[i][0].status in TRACKED
                   and any(o.id == vo_id and o.version == 1 and not o.deleted
                           for o in device.graphs[i][0].objects)]
        print("[vo] graphs after the registration: %d, carrying the object: %d"
              % (len(second), len(carried)))
        self.assertTrue(carried, "no local graph carried the registered object")
        self.assertEqual(carried[0], second[0], "the first graph after registration lacks it")
        got = next(o for o in device.graphs[carried[0]][0].objects if o.id == vo_id)
        self.assertLess(math.dist((got.start.x, got.start.y, got.start.z),
                                  (obj.start.x, obj.start.y, obj.start.z)), 1e-6)
        self.assertEqual(got.owner, "device_0")
        self.assertTrue(any(o.owner == "rviz" and o.kind == VirtualObject.ANCHOR
                            for o in device.graphs[carried[0]][0].objects),
                        "the rviz clicked point is not in the local graph")

        # kill -9 and restart on the same database.
        server.kill9()
        self.assertTrue(wait_service_gone("/ecar/connect"), "the killed server's service stays")
        # Closed before the restart: the store refuses a database another process has open.
        db = sqlite3.connect(database)
        try:
            rows = db.execute("SELECT version, deleted FROM objects WHERE id = ?",
                              (vo_id,)).fetchall()
        finally:
            db.close()
        self.assertEqual(rows, [(1, 0)], "the acknowledged object is not in the database")
        restarted = Server(database)
        try:
            device.graphs.clear()
            self.assertTrue(device.connect().accepted)
            self.assertTrue(wait_subscribed(device.pub))
            self.upload_all(device, good, True)
            carried = [i for i in good if device.graphs[i][0].status in TRACKED
                       and any(o.id == vo_id and o.version == 1 for o in device.graphs[i][0].objects)]
            print("[vo] after kill -9 and restart: %d of %d graphs carry the object"
                  % (len(carried), len(good)))
            self.assertTrue(carried, "the restarted server never sent the acknowledged object "
                            "(warnings: %s)" % sorted(set(self.warnings)))
            for text in [t for t in self.infos if "per upload" in t or "planes:" in t]:
                print("[vo] server: %s" % text)
            # The store continues after the id: a new registration gets a new id.
            res = device.interact(5, Interaction.REGISTER, obj)
            self.assertTrue(res is not None and res.accepted)
            self.assertGreater(res.object_id, vo_id)
        finally:
            restarted.stop()

    def run_map(self):
        folder = tempfile.mkdtemp(prefix="ecar_map_test_")
        servers = []
        try:
            self.map_session(folder, servers)
        finally:
            for server in servers:
                server.stop()
            shutil.rmtree(folder, ignore_errors=True)

    @staticmethod
    def poses(device, frames):
        """frame -> (x, y, z) of the tracked graphs among `frames`."""
        out = {}
        for i in frames:
            got = device.graphs.get(i)
            if got and got[0].status in TRACKED:
                p = got[0].pose.position
                out[i] = (p.x, p.y, p.z)
        return out

    def realign(self, device, frames, before, label):
        """Uploads `frames` (the first with reset) until tracked; asserts the poses."""
        device.graphs.clear()
        self.upload_all(device, frames, True)
        after = self.poses(device, frames)
        self.assertTrue(after, "%s: no upload was aligned in the loaded map" % label)
        errors = {i: math.dist(after[i], before[i]) for i in after if i in before}
        self.assertTrue(errors, "%s: no frame tracked in both sessions" % label)
        print("[map] %s: %d of %d uploads aligned, pose difference to the saved map's: "
              "max %.2f cm, median %.2f cm" % (label, len(after), len(frames),
                                               100 * max(errors.values()),
                                               100 * statistics.median(errors.values())))
        self.assertLess(max(errors.values()), 0.02, "%s: poses moved: %s" % (label, errors))
        return [device.graphs[i][0] for i in frames if i in after]

    def check_structure(self, graphs, saved, floor, obj, vo_id, label, as_saved):
        """The graphs carry the saved planes (`saved`: saved_planes()), the floor
        among them, and the object at version 1, in place. A plane is compared
        as first sent: the re-uploaded frames may re-estimate it later, or find
        a new one (with a new id)."""
        planes = {}
        for g in graphs:
            for p in g.planes:
                planes.setdefault(p.id, p)
        self.assertIn(floor.id, planes, "%s: the floor plane %d is not back (got %s)"
                      % (label, floor.id, sorted(planes)))
        same = 0
        for p in planes.values():
            if p.id not in saved:
                # Found since the load (re-uploaded frames map new keyframes): its id comes
                # after the file's, never one of them reused.
                self.assertGreater(p.id, max(saved), "%s: new plane %d reuses a saved id"
                                   % (label, p.id))
                continue
            self.assertEqual(p.label, saved[p.id][0])
            self.assertGreaterEqual(p.version, saved[p.id][2])
            if p.version == saved[p.id][2]:
                self.assertEqual(p.offset, saved[p.id][1])
                same += 1
        print("[map] %s: %d planes back, %d of them as saved (the others re-estimated since)"
              % (label, len(planes), same))
        # A fresh server has mapped nothing before its first graph: planes as loaded.
        if as_saved:
            self.assertGreater(same, 0, "%s: no plane as saved" % label)
        self.assertEqual(planes[floor.id].label, Plane.FLOOR)
        self.assertLess(abs(planes[floor.id].offset - saved[floor.id][1]), 0.02)
        objects = [o for g in graphs for o in g.objects if o.id == vo_id]
        self.assertTrue(objects, "%s: the object %d is not back" % (label, vo_id))
        got = objects[-1]
        self.assertEqual(got.version, 1)
        self.assertFalse(got.deleted)
        self.assertLess(math.dist((got.position.x, got.position.y, got.position.z),
                                  (obj.position.x, obj.position.y, obj.position.z)), 1e-6)

    def map_session(self, folder, servers):
        map_file = os.path.join(folder, "session.ecarmap")
        # Autosaves every 2 s beside its database (first.autosave.ecarmap).
        servers.append(Server(os.path.join(folder, "first.sqlite"), autosave_period="2"))
        device = FakeDevice("device_0", self.dataset)
        self.assertTrue(device.connect().accepted)
        self.assertTrue(wait_subscribed(device.pub))
        good = list(range(0, len(self.dataset.frames), self.every))
        first = good[:len(good) * 2 // 3]
        self.upload_all(device, first, True)
        before = self.poses(device, first)
        tracked = [device.graphs[i][0] for i in first if i in before]
        self.assertGreaterEqual(len(tracked), 5, "the first session hardly tracked")
        held = {}
        for g in tracked:
            for p in g.planes:
                if p.id not in held or held[p.id].version <= p.version:
                    held[p.id] = p
        floors = [p for p in held.values() if p.label == Plane.FLOOR]
        self.assertTrue(floors, "no FLOOR plane in the first session")
        floor = max(floors, key=lambda p: p.num_points)
        obj = floor_line(tracked[-1], floor, self.dataset.camera, 319.5, 400.0)
        self.assertIsNotNone(obj)
        res = device.interact(1, Interaction.REGISTER, obj)
        self.assertTrue(res is not None and res.accepted, res and res.reason)
        vo_id = res.object_id

        rospy.wait_for_service("/ecar/save_map", timeout=10.0)
        save = rospy.ServiceProxy("/ecar/save_map", SaveMap)
        # Paths outside the map folder (map_dir: the test's folder), or naming other files in it
        # (the VO database), are refused with the reason; nothing is written.
        for bad_path, why in [(os.path.join(folder, "no_such_dir", "x.ecarmap"), "outside"),
                              ("../escape.ecarmap", "subfolder or '..'"),
                              ("/tmp/elsewhere.ecarmap", "outside"),
                              ("first.sqlite", "must end in .ecarmap")]:
            r = save(bad_path)
            self.assertFalse(r.success, bad_path)
            self.assertIn(bad_path, r.message)
            self.assertIn(why, r.message)
            print("[map] save to %s: %s" % (bad_path, r.message))
        self.assertFalse(os.path.exists(os.path.join(os.path.dirname(folder), "escape.ecarmap")))
        start = time.time()
        r = save(map_file)
        print("[map] save_map: %s (call %.0f ms)" % (r.message, 1000 * (time.time() - start)))
        self.assertTrue(r.success, r.message)
        self.assertGreater(r.keyframes, 0)
        self.assertGreater(r.map_points, 0)
        self.assertGreater(r.planes, 0)
        self.assertEqual(r.objects, 1)
        saved = r
        planes = saved_planes(map_file)
        self.assertEqual(len(planes), saved.planes)
        # The floor the device held, maybe re-estimated since its last graph.
        self.assertIn(floor.id, planes)
        self.assertEqual(planes[floor.id][0], Plane.FLOOR)
        self.assertLess(abs(planes[floor.id][1] - floor.offset), 0.1)
        # The poses the saved map gives the last frames: aligned once more by the
        # first server after the save. Local BA refined the map after each frame
        # was first tracked (odometry holds its scale, gravity its tilt), so a
        # frame's first pose and its pose in the saved map differ by that
        # refinement (about 2 cm here); save and load must add nothing to it.
        check = first[-6:]
        for i in check:
            device.graphs.pop(i, None)
        self.upload_all(device, check, True)
        refined = self.poses(device, check)
        moved = [math.dist(refined[i], before[i]) for i in refined if i in before]
        if moved:
            print("[map] refinement since first tracked: max %.2f cm" % (100 * max(moved)))
        before = refined
        time.sleep(2.5)  # one more autosave, with the object
        servers[0].kill9()
        self.assertTrue(wait_service_gone("/ecar/connect"))
        # What the killed server autosaved: a whole map file with the planes and the object.
        autosaved = os.path.join(folder, "first.autosave.ecarmap")
        self.assertTrue(os.path.exists(autosaved), "no autosave after kill -9")
        # The re-uploads since the save may have added or merged planes: the autosave (later)
        # holds the floor the object lies on.
        autosaved_planes = saved_planes(autosaved)
        self.assertIn(floor.id, autosaved_planes)
        print("[map] autosave after kill -9: %d bytes, %d planes (%d saved before)" %
              (os.path.getsize(autosaved), len(autosaved_planes), saved.planes))

        # A fresh server on an empty database, resuming the saved map.
        servers.append(Server(os.path.join(folder, "second.sqlite"), map_file=map_file))
        rospy.wait_for_service("/ecar/load_map", timeout=30.0)
        self.assertTrue(device.connect().accepted)
        self.assertTrue(wait_subscribed(device.pub))
        graphs = self.realign(device, check, before, "restart with map:=FILE")
        self.check_structure(graphs, planes, floor, obj, vo_id, "restart with map:=FILE",
                             True)

        # Bad files: refused with a message naming the file; the server goes on.
        load = rospy.ServiceProxy("/ecar/load_map", LoadMap)
        with open(map_file, "rb") as f:
            data = bytearray(f.read())
        corrupt = os.path.join(folder, "corrupt.ecarmap")
        data[len(data) // 2] ^= 0x5A
        with open(corrupt, "wb") as f:
            f.write(bytes(data))
        # A FIFO is refused at once (opening it for reading had blocked a manager thread forever),
        # and a link is not followed (it could lead anywhere).
        fifo = os.path.join(folder, "fifo.ecarmap")
        os.mkfifo(fifo)
        link = os.path.join(folder, "link.ecarmap")
        os.symlink(map_file, link)
        for path, word in [(corrupt, "CRC"), (os.path.join(folder, "missing.ecarmap"), ""),
                           (fifo, "FIFO"), (link, "symbolic link")]:
            r = load(path)
            print("[map] load_map %s: success %s, %s" % (os.path.basename(path), r.success,
                                                          r.message))
            self.assertFalse(r.success)
            self.assertIn(path, r.message)
            self.assertIn(word, r.message)
        epoch = device.graphs[check[-1]][0].map_epoch
        device.upload(check[-1])
        got = device.wait_graph(check[-1])
        self.assertTrue(got and got[0].status in TRACKED, "the server stopped tracking")
        self.assertEqual(got[0].map_epoch, epoch, "a failed load changed the map epoch")

        # A live load of the good file: a new epoch, the same coordinate system.
        start = time.time()
        r = load(map_file)
        print("[map] load_map: %s (call %.0f ms)" % (r.message, 1000 * (time.time() - start)))
        self.assertTrue(r.success, r.message)
        self.assertEqual((r.keyframes, r.map_points, r.planes, r.objects),
                         (saved.keyframes, saved.map_points, saved.planes, saved.objects))
        graphs = self.realign(device, check, before, "load_map while running")
        self.assertTrue(all(g.map_epoch != epoch for g in graphs), "the map epoch did not change")
        self.check_structure(graphs, planes, floor, obj, vo_id, "load_map while running",
                             False)

        # A clean shutdown autosaves the map (the period, 60 s, has not come
        # yet), and the loaded object is in the new server's database.
        servers[1].stop()
        self.assertTrue(wait_service_gone("/ecar/connect"))
        autosaved = os.path.join(folder, "second.autosave.ecarmap")
        self.assertTrue(os.path.exists(autosaved), "no autosave on shutdown")
        self.assertEqual(len(saved_planes(autosaved)), len(planes))
        db = sqlite3.connect(os.path.join(folder, "second.sqlite"))
        try:
            rows = db.execute("SELECT version, deleted FROM objects WHERE id = ?",
                              (vo_id,)).fetchall()
        finally:
            db.close()
        self.assertEqual(rows, [(1, 0)], "the loaded object is not in the database")

    def run_share(self):
        folder = tempfile.mkdtemp(prefix="ecar_share_test_")
        server = Server(os.path.join(folder, "vo.sqlite"), vo_share="direct")
        try:
            self.share_session()
        finally:
            server.stop()
            shutil.rmtree(folder, ignore_errors=True)

    def share_session(self):
        received = collections.defaultdict(list)  # topic -> [VirtualObject]
        markers = {}  # interactive marker name -> pose
        cond = threading.Condition()

        def keep(topic):
            def cb(msg):
                with cond:
                    received[topic].append(msg)
                    cond.notify_all()
            return cb

        def on_markers(msg):
            with cond:
                for m in getattr(msg, "markers", []):
                    markers[m.name] = m.pose
                for p in getattr(msg, "poses", []):
                    markers[p.name] = p.pose
                for name in getattr(msg, "erases", []):
                    markers.pop(name, None)
                cond.notify_all()

        def wait_for(predicate, timeout=10.0):
            end = time.time() + timeout
            with cond:
                while not predicate() and time.time() < end:
                    cond.wait(0.05)
                return predicate()

        def versions(topic, vo_id):
            return [(o.version, o.deleted) for o in received[topic] if o.id == vo_id]

        subs = [rospy.Subscriber(t, VirtualObject, keep(t), queue_size=100)
                for t in ("/ecar/objects", "/device_0/objects", "/device_1/objects")]
        subs.append(rospy.Subscriber("/ecar/vo_markers/update", InteractiveMarkerUpdate,
                                     on_markers, queue_size=100))
        a = FakeDevice("device_0", self.dataset)
        b = FakeDevice("device_1", self.dataset)
        for d in (a, b):
            self.assertTrue(d.connect().accepted)
            self.assertTrue(wait_subscribed(d.pub))
        good = list(range(0, len(self.dataset.frames), self.every))
        first, second = good[:len(good) * 2 // 3], good[len(good) * 2 // 3:]
        for k, i in enumerate(first):
            for d in (a, b):
                d.upload(i, reset=(k == 0))
                self.assertIsNotNone(d.wait_graph(i), "%s: no local graph for %d" % (d.name, i))
        tracked = [a.graphs[i][0] for i in first if a.graphs[i][0].status in TRACKED]
        self.assertTrue(tracked, "never tracked")
        floors = {}
        for g in tracked:
            for p in g.planes:
                if p.label == Plane.FLOOR:
                    floors[p.id] = p
        self.assertTrue(floors, "no FLOOR plane in the local graphs")
        floor = max(floors.values(), key=lambda p: p.num_points)
        obj = floor_line(tracked[-1], floor, self.dataset.camera, 319.5, 400.0)
        self.assertIsNotNone(obj)

        # Direct: device_1 gets the state, device_0 (the author) does not.
        res = a.interact(1, Interaction.REGISTER, obj)
        self.assertTrue(res is not None and res.accepted, res and res.reason)
        vo_id = res.object_id
        self.assertTrue(wait_for(lambda: versions("/device_1/objects", vo_id) == [(1, False)]),
                        "device_1 did not receive the registration: %s"
                        % versions("/device_1/objects", vo_id))
        self.assertTrue(wait_for(lambda: versions("/ecar/objects", vo_id) == [(1, False)]))
        got = next(o for o in received["/device_1/objects"] if o.id == vo_id)
        self.assertEqual(got.owner, "device_0")
        self.assertLess(math.dist((got.start.x, got.start.y, got.start.z),
                                  (obj.start.x, obj.start.y, obj.start.z)), 1e-6)

        # Local graphs carry no objects in direct mode.
        for k, i in enumerate(second):
            for d in (a, b):
                d.upload(i)
                self.assertIsNotNone(d.wait_graph(i), "%s: no local graph for %d" % (d.name, i))
        for d in (a, b):
            with_objects = [i for i, (m, _) in d.graphs.items() if m.objects]
            self.assertEqual(with_objects, [], "%s: graphs with objects" % d.name)
            self.assertTrue(any(d.graphs[i][0].status in TRACKED for i in second),
                            "%s never tracked after the registration" % d.name)
        self.assertEqual(versions("/device_0/objects", vo_id), [])

        # rviz: the object's interactive marker, moved by a MOUSE_UP feedback.
        name = "vo_%d" % vo_id
        self.assertTrue(wait_for(lambda: name in markers), "no interactive marker %s" % name)
        pose = markers[name]
        self.assertLess(math.dist((pose.position.x, pose.position.y, pose.position.z),
                                  (got.position.x, got.position.y, got.position.z)), 1e-6)
        feedback_pub = rospy.Publisher("/ecar/vo_markers/feedback", InteractiveMarkerFeedback,
                                       queue_size=10)
        # (The marker server and the name check share the manager's one connection.)
        self.assertTrue(wait_subscribed(feedback_pub))
        time.sleep(0.3)
        n = (got.normal.x, got.normal.y, got.normal.z)
        along = [got.end.x - got.start.x, got.end.y - got.start.y, got.end.z - got.start.z]
        along = [c / math.sqrt(dot(along, along)) for c in along]
        across = [n[1] * along[2] - n[2] * along[1], n[2] * along[0] - n[0] * along[2],
                  n[0] * along[1] - n[1] * along[0]]
        move = [0.3 * along[k] + 0.2 * across[k] for k in range(3)]  # in the floor plane
        off = 0.05  # and 5 cm off it, which the server drops
        fb = InteractiveMarkerFeedback()
        fb.header.frame_id = "map"
        fb.header.stamp = rospy.Time.now()
        fb.client_id = "/fake_device_test"
        fb.marker_name = name
        fb.control_name = "move_in_plane"
        fb.event_type = InteractiveMarkerFeedback.MOUSE_UP
        fb.pose.position.x = got.position.x + move[0] + off * n[0]
        fb.pose.position.y = got.position.y + move[1] + off * n[1]
        fb.pose.position.z = got.position.z + move[2] + off * n[2]
        fb.pose.orientation.w = 1.0
        feedback_pub.publish(fb)
        self.assertTrue(wait_for(lambda: [v for v, _ in versions("/ecar/objects", vo_id)] == [1, 2]),
                        "no version 2 from the marker: %s" % versions("/ecar/objects", vo_id))
        moved = [o for o in received["/ecar/objects"] if o.id == vo_id][-1]
        for field in ("position", "start", "end"):
            before, after = getattr(got, field), getattr(moved, field)
            delta = (after.x - before.x, after.y - before.y, after.z - before.z)
            self.assertLess(math.dist(delta, move), 1e-3, "%s moved by %s, not %s"
                            % (field, delta, move))
        self.assertEqual(moved.owner, "device_0")
        for topic in ("/device_0/objects", "/device_1/objects"):
            self.assertTrue(wait_for(lambda: (2, False) in versions(topic, vo_id)),
                            "%s did not receive the rviz move" % topic)
        self.assertTrue(wait_for(lambda: math.dist(
            (markers[name].position.x, markers[name].position.y, markers[name].position.z),
            (moved.position.x, moved.position.y, moved.position.z)) < 1e-6),
            "the marker did not follow the object")
        print("[share] marker move: %.3f m asked in the plane (+%.2f m off it), moved %.4f m"
              % (math.sqrt(dot(move, move)), off,
                 math.dist((moved.position.x, moved.position.y, moved.position.z),
                           (got.position.x, got.position.y, got.position.z))))

        # Feedback naming no marker: a warning, nothing changes, the server still answers.
        for bogus in ("vo_9999", "not_a_vo"):
            fb.marker_name = bogus
            fb.header.stamp = rospy.Time.now()
            feedback_pub.publish(fb)
        self.assertTrue(wait_for(lambda: self.warned("unknown interactive marker", "vo_9999")),
                        "no warning for the unknown marker")
        # A late joiner gets the live objects when it subscribes, then the changes (checked
        # with the delete below, well within the device timeout: it uploads nothing).
        late = FakeDevice("device_2", self.dataset)
        subs.append(rospy.Subscriber("/device_2/objects", VirtualObject,
                                     keep("/device_2/objects"), queue_size=100))
        self.assertTrue(late.connect().accepted)
        self.assertTrue(wait_for(lambda: versions("/device_2/objects", vo_id) == [(2, False)]),
                        "the late joiner did not get the live object: %s"
                        % versions("/device_2/objects", vo_id))

        # vo.policy owner_delete (the default): device_1 may move device_0's line but not
        # delete it; device_0 may, and the tombstone goes to the others.
        res = b.interact(1, Interaction.DELETE, VirtualObject(), object_id=vo_id, base_version=2)
        self.assertTrue(res is not None and not res.accepted, "device_1 deleted device_0's VO")
        self.assertIn("owner device_0 only", res.reason)
        res = a.interact(7, Interaction.DELETE, VirtualObject(), object_id=vo_id, base_version=2)
        self.assertTrue(res is not None and res.accepted, res and res.reason)
        self.assertEqual(res.version, 3)
        for topic in ("/device_1/objects", "/device_2/objects"):
            self.assertTrue(wait_for(lambda: (3, True) in versions(topic, vo_id)),
                            "%s did not receive the tombstone" % topic)
        self.assertTrue(wait_for(lambda: versions("/ecar/objects", vo_id)
                                 == [(1, False), (2, False), (3, True)]),
                        "/ecar/objects: %s" % versions("/ecar/objects", vo_id))
        self.assertTrue(wait_for(lambda: name not in markers), "the marker of a tombstone stays")
        time.sleep(0.3)
        self.assertNotIn((3, True), versions("/device_0/objects", vo_id))
        self.assertEqual(len(received["/ecar/objects"]), 3, "changes from the bogus feedback")
        print("[share] /ecar/objects: %s; device_0 got %s, device_1 got %s"
              % (versions("/ecar/objects", vo_id), versions("/device_0/objects", vo_id),
                 versions("/device_1/objects", vo_id)))
        for s in subs:
            s.unregister()


if __name__ == "__main__":
    rospy.init_node("fake_device_test")
    rostest.rosrun(PKG, "fake_device_test", ServerTest, sys.argv)
