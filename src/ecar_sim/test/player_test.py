#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End-to-end test of dataset_player (started by player.test).

test_plays_first_frames_of_kitti07: receives the frames the player of
player.test publishes for one device, acknowledges each on /<device>/frame_done
(the player runs with ~pace_by_consumer), and checks: the number of images,
their size and encoding, camera_info intrinsics, the ground-truth tf
map -> <device>/camera_gt of the last frame against the dataset's
groundtruth.txt, and the latched /<device>/player/finished flag.

test_replays_scripted_touches: renders a short dataset of touch_scene.yaml
(whose device scripts touch events and a world stroke) with make_dataset,
plays it paced by this node's acks, and checks that every line of touches.txt
comes back as one ecar_msgs/Touch with its pixel, phase, colour and width,
stamped with its frame's image stamp, received after that image and before
the next one.

test_held_start: plays the same dataset with ~start_topic: the player reports
player/ready and publishes nothing until it receives a start time, then
publishes its first image no earlier than that time, and all of them.

Private params: ~dataset (folder, KITTI 07 layout), ~device, ~frames,
~touch_scene (scene file), ~player_launch.
"""

import os
import shutil
import subprocess
import sys
import tempfile
import threading
import unittest

import rospy
import rostest
from ecar_msgs.msg import Touch
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, Time, UInt32
from tf2_msgs.msg import TFMessage

PKG = "ecar_sim"
KITTI07_FX = 707.0912
KITTI07_CX = 601.8873
KITTI07_CY = 183.1104
KITTI07_SIZE = (1226, 370)  # width, height


def read_tum_list(path):
    """Non-comment lines of a TUM-style text file, split into fields."""
    with open(path) as f:
        return [line.split() for line in f if line.strip() and not line.startswith("#")]


class PlayerTest(unittest.TestCase):
    def setUp(self):
        self.dataset = rospy.get_param("~dataset")
        self.device = rospy.get_param("~device", "device_0")
        self.frames = rospy.get_param("~frames", 10)
        self.lock = threading.Lock()
        self.images = []
        self.infos = []
        self.finished = None
        self.gt_tfs = {}  # (secs, nsecs) -> TransformStamped map -> <device>/camera_gt

    def on_image(self, msg):
        with self.lock:
            self.images.append(msg)
        self.done_pub.publish(UInt32(data=msg.header.seq))

    def on_info(self, msg):
        with self.lock:
            self.infos.append(msg)

    def on_tf(self, msg):
        with self.lock:
            for tf in msg.transforms:
                if tf.header.frame_id == "map" and tf.child_frame_id == self.device + "/camera_gt":
                    self.gt_tfs[(tf.header.stamp.secs, tf.header.stamp.nsecs)] = tf

    def on_finished(self, msg):
        with self.lock:
            self.finished = msg

    def test_plays_first_frames_of_kitti07(self):
        if not os.path.isdir(self.dataset):
            msg = "dataset folder %s is absent: skipping the player test" % self.dataset
            sys.stderr.write(msg + "\n")
            rospy.logwarn(msg)
            self.skipTest(msg)

        ns = "/" + self.device
        self.done_pub = rospy.Publisher(ns + "/frame_done", UInt32, queue_size=100)
        rospy.Subscriber(ns + "/camera/camera_info", CameraInfo, self.on_info, queue_size=100)
        rospy.Subscriber("/tf", TFMessage, self.on_tf, queue_size=100)
        rospy.Subscriber(ns + "/player/finished", Bool, self.on_finished, queue_size=1)
        # Subscribe to the images last: the player starts when it sees this subscriber.
        rospy.Subscriber(ns + "/camera/image_raw", Image, self.on_image, queue_size=100)

        deadline = rospy.Time.now() + rospy.Duration(45.0)
        while not rospy.is_shutdown() and rospy.Time.now() < deadline:
            with self.lock:
                if self.finished is not None:
                    break
            rospy.sleep(0.05)
        rospy.sleep(0.5)  # the last camera_info and tf may arrive just after `finished`

        with self.lock:
            images, infos, finished = list(self.images), list(self.infos), self.finished
            gt_tfs = dict(self.gt_tfs)

        self.assertIsNotNone(finished, "no message on %s/player/finished" % ns)
        self.assertTrue(finished.data)

        # Images: one per frame, in order; seq counts the images (= frame index from frame 0).
        self.assertEqual(len(images), self.frames)
        self.assertEqual([m.header.seq for m in images], list(range(self.frames)))
        for m in images:
            self.assertEqual((m.width, m.height), KITTI07_SIZE)
            self.assertEqual(m.encoding, "mono8")
            self.assertEqual(m.header.frame_id, self.device + "/camera")
            self.assertEqual(len(m.data), m.step * m.height)
            self.assertGreaterEqual(m.step, m.width)

        # camera_info: same headers as the images, KITTI 07 intrinsics.
        self.assertEqual(len(infos), self.frames)
        for info, image in zip(infos, images):
            self.assertEqual(info.header.stamp, image.header.stamp)
            self.assertEqual(info.header.seq, image.header.seq)
            self.assertEqual((info.width, info.height), KITTI07_SIZE)
            self.assertAlmostEqual(info.K[0], KITTI07_FX, places=9)
            self.assertAlmostEqual(info.K[4], KITTI07_FX, places=9)
            self.assertAlmostEqual(info.K[2], KITTI07_CX, places=9)
            self.assertAlmostEqual(info.K[5], KITTI07_CY, places=9)
            self.assertEqual(info.distortion_model, "plumb_bob")

        # Ground truth of the last frame: tf at that image's stamp against the file.
        last = self.frames - 1
        t_last = float(read_tum_list(os.path.join(self.dataset, "rgb.txt"))[last][0])
        gt = [r for r in read_tum_list(os.path.join(self.dataset, "groundtruth.txt"))
              if abs(float(r[0]) - t_last) < 1e-6]
        self.assertEqual(len(gt), 1, "no ground-truth line at t=%f" % t_last)
        expected = [float(x) for x in gt[0][1:8]]
        self.assertEqual(len(gt_tfs), self.frames, "one ground-truth tf per frame")
        stamp = images[last].header.stamp
        tf = gt_tfs.get((stamp.secs, stamp.nsecs))
        self.assertIsNotNone(tf, "no tf map -> %s/camera_gt at the stamp of frame %d"
                             % (self.device, last))
        t, q = tf.transform.translation, tf.transform.rotation
        for got, want in zip((t.x, t.y, t.z), expected[0:3]):
            self.assertAlmostEqual(got, want, delta=1e-6)
        # q and -q are the same rotation.
        sign = 1.0 if q.w * expected[6] >= 0 else -1.0
        for got, want in zip((q.x, q.y, q.z, q.w), expected[3:7]):
            self.assertAlmostEqual(sign * got, want, delta=1e-6)


class TouchReplayTest(unittest.TestCase):
    DEVICE = "touch_dev"
    FRAMES = 12
    PHASES = {"begin": Touch.BEGIN, "move": Touch.MOVE, "end": Touch.END}

    def setUp(self):
        self.lock = threading.Lock()
        self.log = []  # ("image", msg) and ("touch", msg) in arrival order
        self.finished = False
        self.tmp = tempfile.mkdtemp(prefix="ecar_touch_replay_")
        self.player = None

    def tearDown(self):
        if self.player is not None and self.player.poll() is None:
            self.player.terminate()
            self.player.wait(timeout=20)
        shutil.rmtree(self.tmp, ignore_errors=True)

    def on_image(self, msg):
        with self.lock:
            self.log.append(("image", msg))
        self.done_pub.publish(UInt32(data=msg.header.seq))

    def on_touch(self, msg):
        with self.lock:
            self.log.append(("touch", msg))

    def on_finished(self, msg):
        with self.lock:
            self.finished = msg.data

    def test_replays_scripted_touches(self):
        dataset = os.path.join(self.tmp, "touch")
        subprocess.run(["rosrun", "ecar_sim", "make_dataset", "--scene",
                        rospy.get_param("~touch_scene"), "--device", self.DEVICE, "--out", dataset,
                        "--frames", str(self.FRAMES), "--quiet"],
                       check=True, stdout=subprocess.DEVNULL)
        expected = read_tum_list(os.path.join(dataset, "touches.txt"))
        # The script: begin/move/end events on frames 2, 3, 5, a stroke on frames 7..10.
        self.assertEqual([int(r[1]) for r in expected], [2, 3, 5, 7, 8, 9, 10])
        self.assertEqual([r[4] for r in expected],
                         ["begin", "move", "end", "begin", "move", "move", "end"])

        ns = "/" + self.DEVICE
        self.done_pub = rospy.Publisher(ns + "/frame_done", UInt32, queue_size=100)
        rospy.Subscriber(ns + "/touch", Touch, self.on_touch, queue_size=100)
        rospy.Subscriber(ns + "/player/finished", Bool, self.on_finished, queue_size=1)
        rospy.Subscriber(ns + "/camera/image_raw", Image, self.on_image, queue_size=100)
        self.player = subprocess.Popen(
            ["roslaunch", rospy.get_param("~player_launch"), "dataset:=" + dataset,
             "device:=" + self.DEVICE, "rate:=0", "pace_by_consumer:=true", "start_delay:=1.0",
             "wait_subscribers:=20.0", "output:=log"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        deadline = rospy.Time.now() + rospy.Duration(45.0)
        while not rospy.is_shutdown() and rospy.Time.now() < deadline:
            with self.lock:
                if self.finished:
                    break
            rospy.sleep(0.05)
        rospy.sleep(0.5)
        with self.lock:
            log, finished = list(self.log), self.finished
        self.assertTrue(finished, "no true on %s/player/finished" % ns)

        images = [m for kind, m in log if kind == "image"]
        touches = [m for kind, m in log if kind == "touch"]
        self.assertEqual(len(images), self.FRAMES)
        self.assertEqual(len(touches), len(expected))
        for msg, row in zip(touches, expected):
            frame = int(row[1])
            self.assertEqual(msg.header.frame_id, self.DEVICE + "/camera")
            self.assertEqual(msg.header.stamp, images[frame].header.stamp,
                             "touch of frame %d not stamped with its image" % frame)
            self.assertAlmostEqual(msg.u, float(row[2]), delta=1e-4)
            self.assertAlmostEqual(msg.v, float(row[3]), delta=1e-4)
            self.assertEqual(msg.phase, self.PHASES[row[4]])
            self.assertEqual((msg.r, msg.g, msg.b), tuple(int(x) for x in row[5:8]))
            self.assertAlmostEqual(msg.width, float(row[8]), delta=1e-6)
            # Published after this node acknowledged the frame's image, before the next image.
            position = next(k for k, (kind, m) in enumerate(log) if m is msg)
            seen = sum(1 for kind, _ in log[:position] if kind == "image")
            self.assertEqual(seen, frame + 1, "touch of frame %d arrived after %d images"
                             % (frame, seen))
        # The script's colours and pixels made it through.
        self.assertEqual((touches[0].r, touches[0].g, touches[0].b), (0, 255, 0))
        self.assertAlmostEqual(touches[0].width, 0.05, places=6)
        self.assertEqual((touches[1].u, touches[1].v), (50.0, 91.0))
        self.assertEqual((touches[2].r, touches[2].g, touches[2].b), (0, 255, 0))  # its begin's
        self.assertEqual((touches[3].r, touches[3].g, touches[3].b), (255, 64, 32))


class HeldStartTest(unittest.TestCase):
    DEVICE = "held_dev"
    FRAMES = 5
    START_IN = 1.0  # s: the start time sent lies this far ahead

    def setUp(self):
        self.lock = threading.Lock()
        self.images = []
        self.ready = False
        self.finished = False
        self.tmp = tempfile.mkdtemp(prefix="ecar_held_start_")
        self.player = None

    def tearDown(self):
        if self.player is not None and self.player.poll() is None:
            self.player.terminate()
            self.player.wait(timeout=20)
        shutil.rmtree(self.tmp, ignore_errors=True)

    def on_image(self, msg):
        with self.lock:
            self.images.append((rospy.Time.now(), msg))
        self.done_pub.publish(UInt32(data=msg.header.seq))

    def on_ready(self, msg):
        with self.lock:
            self.ready = msg.data

    def on_finished(self, msg):
        with self.lock:
            self.finished = msg.data

    def wait_for(self, what, timeout):
        deadline = rospy.Time.now() + rospy.Duration(timeout)
        while not rospy.is_shutdown() and rospy.Time.now() < deadline:
            with self.lock:
                if getattr(self, what):
                    return True
            rospy.sleep(0.05)
        return False

    def test_held_start(self):
        dataset = os.path.join(self.tmp, "touch")
        subprocess.run(["rosrun", "ecar_sim", "make_dataset", "--scene",
                        rospy.get_param("~touch_scene"), "--device", "touch_dev", "--out",
                        dataset, "--frames", str(self.FRAMES), "--quiet"],
                       check=True, stdout=subprocess.DEVNULL)
        ns = "/" + self.DEVICE
        start_topic = ns + "/player/start"
        self.done_pub = rospy.Publisher(ns + "/frame_done", UInt32, queue_size=100)
        starter = rospy.Publisher(start_topic, Time, queue_size=1, latch=True)
        rospy.Subscriber(ns + "/player/ready", Bool, self.on_ready, queue_size=1)
        rospy.Subscriber(ns + "/player/finished", Bool, self.on_finished, queue_size=1)
        rospy.Subscriber(ns + "/camera/image_raw", Image, self.on_image, queue_size=100)
        self.player = subprocess.Popen(
            ["roslaunch", rospy.get_param("~player_launch"), "dataset:=" + dataset,
             "device:=" + self.DEVICE, "rate:=0", "pace_by_consumer:=true", "start_delay:=0.2",
             "wait_subscribers:=20.0", "start_topic:=" + start_topic, "output:=log"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        self.assertTrue(self.wait_for("ready", 45.0), "no true on %s/player/ready" % ns)
        rospy.sleep(1.5)
        with self.lock:
            self.assertEqual(self.images, [], "the held player published before its start")
        start = rospy.Time.now() + rospy.Duration(self.START_IN)
        starter.publish(Time(data=start))
        self.assertTrue(self.wait_for("finished", 30.0), "no true on %s/player/finished" % ns)
        rospy.sleep(0.3)
        with self.lock:
            images = list(self.images)
        self.assertEqual(len(images), self.FRAMES)
        first_received, first = images[0]
        self.assertGreaterEqual(first.header.stamp, start, "first image stamped before the start")
        self.assertGreaterEqual(first_received, start)


def suite():
    loader = unittest.TestLoader()
    return unittest.TestSuite([loader.loadTestsFromTestCase(PlayerTest),
                               loader.loadTestsFromTestCase(TouchReplayTest),
                               loader.loadTestsFromTestCase(HeldStartTest)])


if __name__ == "__main__":
    rospy.init_node("player_test")
    rostest.rosrun(PKG, "player_test", "__main__.suite")
