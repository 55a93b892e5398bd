#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End-to-end test of dataset_player (started by player.test).

Receives the frames the player publishes for one device, acknowledges each on
/<device>/frame_done (the player runs with ~pace_by_consumer), and checks:
the number of images, their size and encoding, camera_info intrinsics, the
ground-truth tf map -> <device>/camera_gt of the last frame against the
dataset's groundtruth.txt, and the latched /<device>/player/finished flag.

Private params: ~dataset (folder, KITTI 07 layout), ~device, ~frames.
"""

import os
import sys
import threading
import unittest

import rospy
import rostest
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, UInt32
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


if __name__ == "__main__":
    rospy.init_node("player_test")
    rostest.rosrun(PKG, "player_test", PlayerTest)
