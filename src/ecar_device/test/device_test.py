#!/usr/bin/python3
# (The system interpreter: a python3 from pyenv or a venv first on PATH has no rospy.)
"""The device node alone, against a fake server (started by device.test).

1. Renders a short corridor dataset (make_dataset) and plays it in a loop.
2. Before any connect service exists the device tracks nothing and uploads nothing.
3. Offers /ecar/connect late: the device connects; uploads arrive every 4th frame with a valid
   JPEG of the camera's size, gravity (norm ~9.81), odometry, reset on the first one.
4. Answers uploads with NOT_INITIALISED local graphs: metrics arrive with the upload's bytes.
5. Sends bad graphs (another device, NaN pose, unknown frame): the device keeps running.
6. Stops answering: the device connects again within a few reconnect timeouts and sets reset.
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
from ecar_msgs.msg import DeviceFrame, LocalGraph, RoundTripMetrics, Upload
from ecar_msgs.srv import Connect, ConnectResponse

PKG = "ecar_device"
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
        ns = "/" + self.device
        self.graph_pub = rospy.Publisher(ns + "/local_graph", LocalGraph, queue_size=10)
        rospy.Subscriber(ns + "/upload", Upload, self.on_upload)
        rospy.Subscriber(ns + "/device_frame", DeviceFrame, self.on_frame)
        rospy.Subscriber(ns + "/metrics", RoundTripMetrics, self.on_metrics)

    def on_connect(self, req):
        with self.lock:
            self.connects.append((rospy.get_time(), req))
        ns = "/" + req.device_id
        return ConnectResponse(accepted=True, message="fake server", map_epoch=7,
                               upload_topic=ns + "/upload", local_graph_topic=ns + "/local_graph",
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
            g.map_epoch = 7
            g.upload_sent = msg.sent
            g.server_received = rospy.Time.now()
            g.server_sent = rospy.Time.now()
            self.graph_pub.publish(g)

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
        self.assertTrue(uploads[0].reset)
        for u in uploads:
            self.assertEqual(u.device_id, self.device)
            self.assertEqual(u.frame_index % 4, 0, "frame %d uploaded" % u.frame_index)
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


if __name__ == "__main__":
    rostest.rosrun(PKG, "device_test", DeviceTest)
