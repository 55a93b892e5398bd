#!/usr/bin/python3
# (The system interpreter: a python3 from pyenv or a venv first on PATH has no rospy.)
"""The device node alone, against a fake server (started by device.test).

1. Renders a short corridor dataset (make_dataset) and plays it in a loop; the device reads the
   camera through the compressed transport (~image_transport: compressed, ecar_image_transport).
2. Before any connect service exists the device tracks nothing and uploads nothing.
3. Offers /ecar/connect late: the device connects; uploads arrive every 4th frame with a valid
   JPEG of the camera's size, gravity (norm ~9.81), odometry, reset on the first one.
4. Answers uploads with NOT_INITIALISED local graphs: metrics arrive with the upload's bytes.
   Then its graphs give the device an upload budget (LocalGraph.upload_budget) that quality 70
   does not fit: the uploads shrink to within it (metrics name the lower quality); without a
   budget they are at quality 70 again.
5. Sends bad graphs (another device, NaN pose, unknown frame): the device keeps running.
6. Stops answering: the device connects again within a few reconnect timeouts and sets reset.
7. Answers with OK graphs in map 3 (its device frames name map 3 from then on; the ground-truth pose, no points: the device does not track, so touch
   rays start at the graph's pose) holding the corridor's floor plane: a touch stroke produces
   REGISTER interactions whose lines lie on the floor, ahead of the device, chained, with the
   touch's colour and width; accepted ones come back in a graph and are drawn into ar_view in
   their colour; a touch on such a VO sends MANIPULATE with its id and base_version, moved along
   the floor.
   ar_view/compressed offers the same view as a JPEG.
8. vo_share direct: a VO published on /<device>/objects is held (a touch on it sends MANIPULATE);
   its tombstone removes it (a touch there sends nothing).
"""

import math
import os
import shutil
import struct
import subprocess
import tempfile
import threading
import time
import unittest

import rospy
import rostest
from sensor_msgs.msg import CompressedImage, Image
from ecar_msgs.msg import (DeviceFrame, Interaction, InteractionResult, LocalGraph, Plane,
                           RoundTripMetrics, Touch, Upload, VirtualObject)
from geometry_msgs.msg import Point
from ecar_msgs.srv import Connect, ConnectResponse

PKG = "ecar_device"
FAKE_SESSION = 0x5EC0DE5EC0DE  # the fake server's session token
REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.realpath(__file__)), "..", "..", ".."))


def jpeg_size(data):
    """(width, height) from a baseline/progressive JPEG's SOF marker, or None."""
    data = bytes(data)
    if len(data) < 4 or data[:2] != b"\xff\xd8" or data[-2:] != b"\xff\xd9":
        return None
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        length = struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return w, h
        i += 2 + length
    return None


def read_groundtruth(path):
    """T_w_c per frame index from a TUM groundtruth.txt: list of (t, q) with q = (x, y, z, w)."""
    poses = []
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            v = [float(x) for x in line.split()]
            poses.append((v[1:4], v[4:8]))
    return poses


def rotate(q, p):
    """Rotates p by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    ux = (y * p[2] - z * p[1], z * p[0] - x * p[2], x * p[1] - y * p[0])
    uux = (y * ux[2] - z * ux[1], z * ux[0] - x * ux[2], x * ux[1] - y * ux[0])
    return [p[i] + 2.0 * w * ux[i] + 2.0 * uux[i] for i in range(3)]


def project(pose, p_w, f=525.0, cx=319.5, cy=239.5):
    """Pixel of map point p_w seen from T_w_c = pose (t, q)."""
    t, (x, y, z, w) = pose
    p_c = rotate((-x, -y, -z, w), [p_w[i] - t[i] for i in range(3)])
    return cx + f * p_c[0] / p_c[2], cy + f * p_c[1] / p_c[2]


def floor_point(pose, u, v, f=525.0, cx=319.5, cy=239.5):
    """Where the ray of pixel (u, v) from T_w_c = pose (t, q) meets the floor z = 0."""
    t, q = pose
    d = rotate(q, [(u - cx) / f, (v - cy) / f, 1.0])
    s = -t[2] / d[2]
    return [t[i] + s * d[i] for i in range(3)]


def floor_plane():
    plane = Plane(id=3, label=Plane.FLOOR, offset=0.0, version=1, num_points=500)
    plane.normal.z = 1.0
    plane.boundary = [Point(0.0, 0.0, 0.0), Point(30.0, 0.0, 0.0), Point(30.0, 2.4, 0.0),
                      Point(0.0, 2.4, 0.0)]
    return plane


class DeviceTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("device_test")
        cls.device = rospy.get_param("~device", "device_0")
        cls.dir = tempfile.mkdtemp(prefix="ecar_device_test_")
        dataset = os.path.join(cls.dir, "corridor")
        subprocess.check_call(
            ["rosrun", "ecar_sim", "make_dataset", "--scene",
             os.path.join(REPO, "config", "scenes", "corridor.yaml"), "--device", cls.device,
             "--frames", str(rospy.get_param("~frames", 40)), "--out", dataset],
            stdout=subprocess.DEVNULL)
        cls.groundtruth = read_groundtruth(os.path.join(dataset, "groundtruth.txt"))
        cls.player = subprocess.Popen(
            ["rosrun", "ecar_sim", "dataset_player", "__name:=test_player", "_dataset:=" + dataset,
             "_device:=" + cls.device, "_rate:=1.0", "_loop:=true", "_start_delay:=0.0"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    @classmethod
    def tearDownClass(cls):
        cls.player.terminate()
        cls.player.wait()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def setUp(self):
        self.lock = threading.Lock()
        self.uploads = []
        self.frames = []
        self.metrics = []
        self.connects = []
        self.answer = True
        self.budget = 0         # step 4: LocalGraph.upload_budget, bytes/s
        self.ok_graphs = False  # step 7: OK graphs with the ground-truth pose and the floor
        self.objects = []       # VOs the fake server puts into its graphs
        self.last_pose = None   # ground-truth pose of the latest OK graph
        self.interactions = []
        ns = "/" + self.device
        self.touch_pub = rospy.Publisher(ns + "/touch", Touch, queue_size=50)
        self.direct_pub = rospy.Publisher(ns + "/objects", VirtualObject, queue_size=10)
        self.result_pub = rospy.Publisher(ns + "/interaction_result", InteractionResult,
                                          queue_size=50)
        rospy.Subscriber(ns + "/interaction", Interaction, self.on_interaction)
        self.graph_pub = rospy.Publisher(ns + "/local_graph", LocalGraph, queue_size=10)
        rospy.Subscriber(ns + "/upload", Upload, self.on_upload)
        rospy.Subscriber(ns + "/device_frame", DeviceFrame, self.on_frame)
        rospy.Subscriber(ns + "/metrics", RoundTripMetrics, self.on_metrics)

    def on_connect(self, req):
        with self.lock:
            self.connects.append((rospy.get_time(), req))
        ns = "/" + req.device_id
        return ConnectResponse(accepted=True, message="fake server", map_epoch=7,
                               session=FAKE_SESSION, upload_topic=ns + "/upload",
                               local_graph_topic=ns + "/local_graph",
                               interaction_topic=ns + "/interaction")

    def on_upload(self, msg):
        with self.lock:
            self.uploads.append((rospy.get_time(), msg))
            answer = self.answer
        if answer:
            g = LocalGraph()
            g.header = msg.header
            g.device_id = msg.device_id
            g.frame_index = msg.frame_index
            g.status = LocalGraph.NOT_INITIALISED
            g.pose.orientation.w = 1.0
            with self.lock:
                if self.ok_graphs:
                    # The player keeps counting header.seq when it loops.
                    pose = self.groundtruth[msg.frame_index % len(self.groundtruth)]
                    g.status = LocalGraph.OK
                    (g.pose.position.x, g.pose.position.y, g.pose.position.z) = pose[0]
                    (g.pose.orientation.x, g.pose.orientation.y, g.pose.orientation.z,
                     g.pose.orientation.w) = pose[1]
                    g.planes = [floor_plane()]
                    g.objects = list(self.objects)
                    g.map_id = 3
                    self.last_pose = pose
            g.map_epoch = 7
            with self.lock:
                g.upload_budget = self.budget
            g.upload_sent = msg.sent
            g.server_received = rospy.Time.now()
            g.server_sent = rospy.Time.now()
            self.graph_pub.publish(g)

    def on_interaction(self, msg):
        with self.lock:
            self.interactions.append(msg)

    def touch(self, u, v, phase, pause=0.03):
        self.touch_pub.publish(Touch(u=u, v=v, phase=phase, r=255, g=0, b=200, width=0.03))
        time.sleep(pause)

    def on_frame(self, msg):
        with self.lock:
            self.frames.append(msg)

    def on_metrics(self, msg):
        with self.lock:
            self.metrics.append(msg)

    def wait_for(self, condition, timeout, what):
        end = time.time() + timeout
        while time.time() < end and not rospy.is_shutdown():
            with self.lock:
                if condition():
                    return
            time.sleep(0.05)
        self.fail("timed out waiting for " + what)

    def test_device(self):
        # 2. No server yet: frames are tracked (NOT_INITIALISED), nothing is uploaded.
        self.wait_for(lambda: len(self.frames) >= 10, 40.0, "device_frame messages")
        with self.lock:
            self.assertEqual(len(self.uploads), 0)
            self.assertTrue(all(f.status == DeviceFrame.NOT_INITIALISED for f in self.frames))
            self.assertTrue(all(f.device_id == self.device for f in self.frames))

        # 3. The connect service appears late.
        rospy.Service("/ecar/connect", Connect, self.on_connect)
        self.wait_for(lambda: len(self.uploads) >= 6, 20.0, "uploads after connecting")
        with self.lock:
            connect_req = self.connects[0][1]
            uploads = [u for _, u in self.uploads]
        self.assertEqual(connect_req.device_id, self.device)
        self.assertEqual(connect_req.keyframe_queue, 10)
        self.assertEqual(connect_req.camera_info.width, 640)
        self.assertEqual(connect_req.session, 0)  # none yet
        self.assertTrue(uploads[0].reset)
        self.assertEqual({u.session for u in uploads}, {FAKE_SESSION})
        # One upload per slot of 4 frames: the first comes with the first frame after the
        # server joined the device's topics (any frame of its slot), the rest on time.
        slots = [u.frame_index // 4 for u in uploads]
        self.assertEqual(len(set(slots)), len(slots), [u.frame_index for u in uploads])
        for u in uploads[1:]:
            self.assertEqual(u.frame_index % 4, 0, "frame %d uploaded" % u.frame_index)
        for u in uploads:
            self.assertEqual(u.device_id, self.device)
            self.assertEqual(u.image.format, "jpeg")
            self.assertEqual(jpeg_size(u.image.data), (640, 480))
            self.assertTrue(u.has_gravity)
            g = u.gravity
            self.assertAlmostEqual(math.sqrt(g.x ** 2 + g.y ** 2 + g.z ** 2), 9.81, delta=0.3)
            self.assertTrue(u.has_odometry)
            self.assertEqual(u.header.stamp, u.image.header.stamp)
            self.assertGreaterEqual(u.sent, u.header.stamp)
        self.assertTrue(all(not u.reset for u in uploads[1:]))
        indices = [u.frame_index for u in uploads]
        self.assertEqual(indices, sorted(indices))

        # 4. Metrics for answered uploads, with the upload's serialized size.
        self.wait_for(lambda: len(self.metrics) >= 3, 10.0, "round-trip metrics")
        with self.lock:
            by_frame = {u.frame_index: u for _, u in self.uploads}
            m = self.metrics[0]
        self.assertIn(m.frame_index, by_frame)
        self.assertGreater(m.bytes_up, len(by_frame[m.frame_index].image.data))
        self.assertGreater(m.bytes_down, 0)
        self.assertGreaterEqual(m.latency, 0.0)
        with self.lock:
            uploaded = [f for f in self.frames if f.uploaded]
        self.assertGreater(len(uploaded), 0)
        self.assertEqual(m.jpeg_quality, 70)
        self.assertEqual(m.upload_budget, 0)

        # 4b. A budget of 180 kB/s, 24 kB per upload at 7.5 per second (quality 70 makes about
        # 50 kB of these frames, quality 10 about 16): the device lowers its quality to fit, and
        # restores it after.
        budget = 180000
        with self.lock:
            at70 = [len(u.image.data) for _, u in self.uploads[-5:]]
            self.budget = budget
            n = len(self.metrics)
        self.assertGreater(min(at70), 1.5 * budget / 7.5, at70)
        self.wait_for(lambda: len(self.metrics) >= n + 15, 10.0, "graphs with a budget")
        with self.lock:
            budgeted = [m for m in self.metrics[n:] if m.upload_budget == budget]
            by_frame = {u.frame_index: (t, len(u.image.data)) for t, u in self.uploads}
        self.assertGreaterEqual(len(budgeted), 10)
        late = budgeted[-8:]
        qualities = [m.jpeg_quality for m in late]
        self.assertTrue(all(10 < q < 70 for q in qualities), qualities)
        # Bytes per second at the rate the device uploads (7.5/s when it keeps up).
        times = [by_frame[m.frame_index][0] for m in late]
        sizes = [by_frame[m.frame_index][1] for m in late]
        rate = (len(late) - 1) / (times[-1] - times[0])
        sent = rate * sum(sizes) / len(sizes)
        print("[device_test] budget %d B/s: %.2f uploads/s of %s B at quality %s: %.0f B/s"
              % (budget, rate, sizes, qualities, sent))
        self.assertLessEqual(sent, 1.1 * budget, (rate, sizes, qualities))
        self.assertGreater(sent, 0.7 * budget, (rate, sizes, qualities))
        with self.lock:
            self.budget = 0
            n = len(self.metrics)
        self.wait_for(lambda: len(self.metrics) >= n + 4 and self.metrics[-1].jpeg_quality == 70,
                      10.0, "quality 70 again without a budget")

        # 5. Bad graphs are dropped; the device keeps going.
        bad = LocalGraph(device_id="device_99", frame_index=uploads[-1].frame_index)
        bad.pose.orientation.w = 1.0
        self.graph_pub.publish(bad)
        nan = LocalGraph(device_id=self.device, frame_index=uploads[-1].frame_index,
                         status=LocalGraph.OK, map_epoch=7)
        nan.pose.orientation.w = 1.0
        nan.pose.position.x = float("nan")
        self.graph_pub.publish(nan)
        unknown = LocalGraph(device_id=self.device, frame_index=3, map_epoch=7)
        unknown.pose.orientation.w = 1.0
        self.graph_pub.publish(unknown)
        with self.lock:
            n = len(self.frames)
        self.wait_for(lambda: len(self.frames) >= n + 10, 10.0, "frames after bad graphs")

        # 6. The server goes silent: the device connects again and asks for a reset.
        with self.lock:
            self.answer = False
            silent_from = len(self.uploads)
        self.wait_for(lambda: len(self.connects) >= 2, 15.0, "a second connection")
        with self.lock:
            self.answer = True
        self.wait_for(lambda: any(u.reset for _, u in self.uploads[silent_from:]), 10.0,
                      "an upload with reset after reconnecting")
        with self.lock:
            # It connects again with its token, so that a server holding it takes it back.
            self.assertEqual(self.connects[1][1].session, FAKE_SESSION)

        # 7. OK graphs with the floor: a stroke becomes REGISTERed lines on it.
        with self.lock:
            self.ok_graphs = True
        self.wait_for(lambda: self.last_pose is not None, 10.0, "an OK graph")
        # Its frames name the map of the graphs it took (0 before the first with a map).
        self.wait_for(lambda: any(f.map_id == 3 for f in self.frames), 5.0,
                      "a device frame in map 3")
        with self.lock:
            self.assertEqual({f.map_id for f in self.frames}, {0, 3})
        time.sleep(0.5)
        while self.touch_pub.get_num_connections() == 0:
            time.sleep(0.05)
        with self.lock:
            pose = self.last_pose
        self.touch(300.0, 400.0, Touch.BEGIN)
        for k in range(1, 11):
            self.touch(300.0 + 8.0 * k, 400.0, Touch.MOVE)
        self.touch(380.0, 400.0, Touch.END)
        self.wait_for(lambda: len(self.interactions) >= 2, 5.0, "REGISTER interactions")
        time.sleep(0.3)
        with self.lock:
            registers = list(self.interactions)
        self.assertGreaterEqual(len(registers), 2)
        camera_x = pose[0][0]
        for i, m in enumerate(registers):
            self.assertEqual(m.device_id, self.device)
            self.assertEqual(m.session, FAKE_SESSION)
            self.assertEqual(m.type, Interaction.REGISTER)
            self.assertEqual(m.object_id, 0)
            self.assertEqual(m.base_version, 0)
            self.assertEqual(m.header.frame_id, "map")
            o = m.object
            self.assertEqual(o.kind, VirtualObject.LINE)
            self.assertEqual((o.r, o.g, o.b), (255, 0, 200))
            self.assertAlmostEqual(o.width, 0.03, places=5)
            self.assertEqual(o.plane_id, 3)
            self.assertEqual(o.owner, self.device)
            self.assertAlmostEqual(o.normal.z, 1.0, places=9)
            for p in (o.start, o.end):
                self.assertAlmostEqual(p.z, 0.0, places=6)  # on the floor
                # Row 400 from 1.5 m at -5 deg pitch meets the floor ~3.7 m ahead.
                self.assertGreater(p.x, camera_x + 2.0)
                self.assertLess(p.x, camera_x + 6.0)
                self.assertTrue(0.0 < p.y < 2.4)
            if i > 0:
                self.assertEqual(m.request_id, registers[i - 1].request_id + 1)
                prev = registers[i - 1].object.end
                self.assertAlmostEqual(o.start.x, prev.x, places=9)
                self.assertAlmostEqual(o.start.y, prev.y, places=9)

        # The fake server accepts them (ids 100, 101, ...) and sends them back in its graphs.
        accepted = []
        for i, m in enumerate(registers):
            vo = m.object
            vo.id = 100 + i
            vo.version = 1
            accepted.append(vo)
            self.result_pub.publish(InteractionResult(
                device_id=self.device, request_id=m.request_id, accepted=True,
                object_id=vo.id, version=1))
        self.result_pub.publish(InteractionResult(
            device_id=self.device, request_id=9999, accepted=False, reason="unknown request"))
        with self.lock:
            self.objects = accepted
            self.last_pose = None
            self.interactions = []
        self.wait_for(lambda: self.last_pose is not None, 5.0, "an OK graph with the objects")
        time.sleep(0.3)

        # ar_view draws them in the touch's colour (BGR 200, 0, 255; the camera image is grey).
        self.stroke_pixels = []

        def on_view(img):
            if img.encoding != "bgr8":
                return
            data = bytes(img.data)
            n = sum(1 for i in range(0, len(data) - 2, 3)
                    if data[i] > 150 and data[i + 1] < 60 and data[i + 2] > 200)
            with self.lock:
                self.stroke_pixels.append(n)

        view_sub = rospy.Subscriber("/" + self.device + "/ar_view", Image, on_view, queue_size=1)
        self.wait_for(lambda: any(n >= 50 for n in self.stroke_pixels), 10.0,
                      "the stroke drawn in ar_view")
        view_sub.unregister()

        # ar_view is offered through image_transport's compressed transport too (ecar_image_
        # transport): a JPEG of the camera's size.
        sizes = []

        def on_compressed(img):
            with self.lock:
                sizes.append((img.format, jpeg_size(img.data)))

        view_sub = rospy.Subscriber("/" + self.device + "/ar_view/compressed", CompressedImage,
                                    on_compressed, queue_size=1)
        self.wait_for(lambda: len(sizes) >= 2, 10.0, "ar_view/compressed")
        view_sub.unregister()
        for fmt, size in sizes:
            self.assertIn("jpeg", fmt)
            self.assertEqual(size, (640, 480), "ar_view/compressed is a 640x480 JPEG")

        # 8. A touch on the first line grabs it: MANIPULATE with its id, moved along the floor.
        with self.lock:
            self.answer = False  # hold the pose still while touching
            pose = self.last_pose
        time.sleep(0.2)
        first = accepted[0]
        mid = [(first.start.x + first.end.x) / 2, (first.start.y + first.end.y) / 2, 0.0]
        u, v = project(pose, mid)
        self.touch(u, v, Touch.BEGIN)
        self.touch(u, v + 20.0, Touch.MOVE)
        self.touch(u, v + 20.0, Touch.END)
        with self.lock:
            self.answer = True
        self.wait_for(lambda: len(self.interactions) >= 3, 5.0, "MANIPULATE interactions")
        with self.lock:
            moves = list(self.interactions)
        # The first line, or its neighbour sharing an end point (as near to the ray).
        self.assertIn(moves[0].object_id, (100, 101))
        first = accepted[moves[0].object_id - 100]
        for m in moves:
            self.assertEqual(m.type, Interaction.MANIPULATE)
            self.assertEqual(m.object_id, first.id)
            self.assertEqual(m.base_version, 1)
            self.assertAlmostEqual(m.object.start.z, 0.0, places=6)
            self.assertAlmostEqual(m.object.end.z, 0.0, places=6)
        # Lower on the image = nearer the camera: the line moved towards the device.
        self.assertLess(moves[-1].object.position.x, moves[0].object.position.x - 0.05)
        length = math.hypot(first.end.x - first.start.x, first.end.y - first.start.y)
        moved = moves[-1].object
        self.assertAlmostEqual(math.hypot(moved.end.x - moved.start.x, moved.end.y - moved.start.y),
                               length, places=6)

        # 9. vo_share direct: a VO relayed on /<device>/objects is held; its tombstone removes it.
        while self.direct_pub.get_num_connections() == 0:
            time.sleep(0.05)
        with self.lock:
            self.answer = False
            pose = self.last_pose
            self.interactions = []
        time.sleep(0.2)
        a, b = floor_point(pose, 300.0, 380.0), floor_point(pose, 340.0, 380.0)
        relayed = VirtualObject(id=200, kind=VirtualObject.LINE, r=0, g=255, b=0, width=0.02,
                                plane_id=3, owner="device_1", version=4)
        relayed.start = Point(*a)
        relayed.end = Point(*b)
        relayed.position = Point(*[(a[i] + b[i]) / 2 for i in range(3)])
        relayed.normal.z = 1.0
        self.direct_pub.publish(relayed)
        time.sleep(0.2)
        u, v = project(pose, [relayed.position.x, relayed.position.y, 0.0])
        self.touch(u, v, Touch.BEGIN)
        self.touch(u, v, Touch.END)
        self.wait_for(lambda: len(self.interactions) >= 2, 5.0, "MANIPULATE of the relayed VO")
        with self.lock:
            self.assertTrue(all(m.type == Interaction.MANIPULATE and m.object_id == 200 and
                                m.base_version == 4 for m in self.interactions))
            self.interactions = []
        relayed.version = 5
        relayed.deleted = True
        self.direct_pub.publish(relayed)
        with self.lock:
            self.answer = True
            self.last_pose = None
        self.wait_for(lambda: self.last_pose is not None, 5.0, "an OK graph")
        with self.lock:
            self.answer = False
            pose = self.last_pose
        time.sleep(0.2)
        # The touch now meets the floor where the VO was: a stroke, no MANIPULATE.
        u, v = project(pose, [relayed.position.x, relayed.position.y, 0.0])
        self.touch(u, v, Touch.BEGIN)
        self.touch(u + 30.0, v, Touch.END)
        self.wait_for(lambda: len(self.interactions) >= 1, 5.0, "a stroke where the VO was")
        with self.lock:
            self.answer = True
            self.assertTrue(all(m.type == Interaction.REGISTER for m in self.interactions))


if __name__ == "__main__":
    rostest.rosrun(PKG, "device_test", DeviceTest)
