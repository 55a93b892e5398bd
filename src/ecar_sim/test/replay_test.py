#!/usr/bin/python3
# (The system interpreter: a python3 from pyenv or a venv first on PATH has no rospy.)
"""replay.launch end to end (started by replay.test): the server, the device and
`rosbag play --clock` of a recorded corridor bag.

Asserts that ROS time is the bag's (/use_sim_time set, the test's clock and every stamp inside
the recording), that the device tracks most of the frames it receives, that the server answers
most uploads with local graphs and aligns them, and that the round-trip metrics are measured on
that clock (non-negative, under a second of recording time).
"""

import threading
import time
import unittest

import rosbag
import rospy
import rostest
from ecar_msgs.msg import DeviceFrame, LocalGraph, RoundTripMetrics
from sensor_msgs.msg import CameraInfo

PKG = "ecar_sim"


class ReplayTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("replay_test")
        cls.device = rospy.get_param("~device", "device_0")
        with rosbag.Bag(rospy.get_param("~bag")) as bag:
            cls.start = bag.get_start_time()
            cls.end = bag.get_end_time()
            cls.images = bag.get_message_count("/%s/camera/image_raw" % cls.device)

    def setUp(self):
        self.lock = threading.Lock()
        self.frames = []
        self.graphs = []
        self.metrics = []
        self.clock_seen = []
        self.info_stamps = []  # camera_info stamps as played (one per image)
        ns = "/" + self.device
        rospy.Subscriber(ns + "/camera/camera_info", CameraInfo,
                         lambda m: self.info_stamps.append(m.header.stamp.to_sec()),
                         queue_size=500)
        rospy.Subscriber(ns + "/device_frame", DeviceFrame, self.on, callback_args=self.frames,
                         queue_size=500)
        rospy.Subscriber(ns + "/local_graph", LocalGraph, self.on, callback_args=self.graphs,
                         queue_size=500)
        rospy.Subscriber(ns + "/metrics", RoundTripMetrics, self.on, callback_args=self.metrics,
                         queue_size=500)

    def on(self, msg, into):
        with self.lock:
            into.append(msg)
            self.clock_seen.append(rospy.get_time())

    def in_recording(self, t, slack=1.0):
        return self.start - slack <= t <= self.end + slack

    def test_replay_with_the_bags_clock(self):
        self.assertTrue(rospy.get_param("/use_sim_time", False), "/use_sim_time is not set")
        self.assertGreaterEqual(self.images, 60, "the bag is too short for this test")
        # The bag plays after its delay: wait for its last frame (the camera_info beside its last
        # image), then for the last answers (graphs come back within a few frames). /clock itself
        # is no end marker: rosbag play publishes it on clock_hz ticks while it waits for the
        # next message, so its last value lies anywhere in the last frame interval (seen 20 ms
        # short of the end on a loaded machine).
        deadline = time.time() + 120.0
        while time.time() < deadline and not (self.info_stamps and
                                              max(self.info_stamps) >= self.end - 1e-3):
            time.sleep(0.2)
        self.assertTrue(self.info_stamps and max(self.info_stamps) >= self.end - 1e-3,
                        "the bag did not play to its end (%d frames, the last at %s of %.2f..%.2f)"
                        % (len(self.info_stamps), max(self.info_stamps or [None]), self.start,
                           self.end))
        # ROS time is the bag's and ran with it: past its last frame interval.
        self.assertGreaterEqual(rospy.get_time(), self.end - 0.1,
                                "the clock at %.3f of %.3f..%.3f" %
                                (rospy.get_time(), self.start, self.end))
        time.sleep(3.0)
        with self.lock:
            frames, graphs, metrics = list(self.frames), list(self.graphs), list(self.metrics)
            clocks = list(self.clock_seen)

        # Sim time everywhere: this node's clock and every stamp lie inside the recording.
        self.assertTrue(clocks and all(self.in_recording(t) for t in clocks),
                        "callbacks ran outside the bag's time: %s" % clocks[:5])
        for f in frames:
            self.assertTrue(self.in_recording(f.header.stamp.to_sec()), f.header.stamp)
        for g in graphs:
            self.assertTrue(self.in_recording(g.server_sent.to_sec()),
                            "server_sent %.3f is not the bag's time" % g.server_sent.to_sec())

        # Monocular initialisation takes the first uploads; from the first aligned one on, the
        # server keeps aligning and the device keeps tracking (a short queue may drop a frame
        # when it lags).
        frames.sort(key=lambda f: f.frame_index)
        graphs.sort(key=lambda g: g.frame_index)
        aligned = [g for g in graphs if g.status in (LocalGraph.OK, LocalGraph.RELOCALISED)]
        uploads = [f for f in frames if f.uploaded]
        self.assertTrue(aligned, "no upload was aligned (%d graphs)" % len(graphs))
        first = aligned[0].frame_index
        after = [f for f in frames if f.frame_index >= first]
        tracked = [f for f in after if f.status == DeviceFrame.OK]
        graphs_after = [g for g in graphs if g.frame_index >= first]
        print("replay: %d images, %d device frames, %d uploads, %d graphs; first aligned at "
              "frame %d; since then %d of %d frames tracked, %d of %d graphs aligned; %d metrics"
              % (self.images, len(frames), len(uploads), len(graphs), first, len(tracked),
                 len(after), len(aligned), len(graphs_after), len(metrics)))
        self.assertGreaterEqual(len(frames), 0.8 * self.images,
                                "%d device frames of %d images" % (len(frames), self.images))
        self.assertLessEqual(first, 0.5 * self.images, "initialised only at frame %d" % first)
        self.assertGreaterEqual(len(tracked), 0.9 * len(after),
                                "%d of %d device frames tracked" % (len(tracked), len(after)))
        self.assertGreaterEqual(len(graphs), 0.8 * len(uploads),
                                "%d local graphs for %d uploads" % (len(graphs), len(uploads)))
        self.assertGreaterEqual(len(aligned), 0.9 * len(graphs_after),
                                "%d of %d graphs aligned" % (len(aligned), len(graphs_after)))
        self.assertTrue(any(g.points for g in aligned), "no aligned graph holds map points")

        # Round trips on the bag's clock.
        self.assertGreaterEqual(len(metrics), 0.8 * len(graphs))
        for m in metrics:
            self.assertTrue(self.in_recording(m.header.stamp.to_sec()), m.header.stamp)
            self.assertTrue(0.0 <= m.latency < 1.0,
                            "round trip of %.3f s of recording time" % m.latency)


if __name__ == "__main__":
    rostest.rosrun(PKG, "replay", ReplayTest)
