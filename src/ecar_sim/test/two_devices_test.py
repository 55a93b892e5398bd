#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End to end (started by test/two_devices.test): the server and two devices.

Renders short datasets of two corridor devices, plays them (each player paced
by its device), and asserts that
- each device receives a local graph for at least 90% of its uploads;
- both devices end in one map (they start at the same time, so each may begin
  a map of its own; the server merges them): their server poses in it fit the
  ground truth with a single similarity transform within 3 cm;
- each device tracks at least 95% of its frames after its first local graph,
  within 1 cm (RMSE) of the server's pose on the frames both estimated in one
  map (the device's pose of the upload whose graph first names a new map was
  estimated in the old map's coordinates), after its first two compared frames.
  Those two are bounded by 10 cm each: the device tracks them on the points of
  a map a few uploads old, which the other device's keyframes are still moving.
  Measured against ground truth (one similarity for both devices' final server
  poses), a device that joined a map 3 uploads old had server poses 3.7, 3.2,
  1.1 and 0.8 cm off at its first four uploads, its own 4.2, 2.1, 0.9 and 0.6 cm:
  the map moved under both. A run where the other device initialised the map an
  upload before this one joined gave device-vs-server 5.7 and 5.0 cm at the
  first two, 1.4 cm and less after.

Private params: ~scene (scene file), ~player_launch, ~frames, ~devices
(comma-separated, default device_0,device_2).
"""

import os
import sys
import unittest

import numpy as np
import rospy
import rostest
from ecar_msgs.msg import DeviceFrame, LocalGraph
from ecar_sim.playback import Playback

PKG = "ecar_sim"


def read_tum(path):
    """{timestamp: position} of a TUM trajectory."""
    out = {}
    with open(path) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                v = [float(x) for x in line.split()]
                out[v[0]] = np.array(v[1:4])
    return out


def read_frame_times(folder):
    with open(os.path.join(folder, "rgb.txt")) as f:
        return [float(l.split()[0]) for l in f if l.strip() and not l.startswith("#")]


def similarity_fit_rmse(src, dst):
    """RMSE after the least-squares similarity (Umeyama: rotation, translation and
    scale) mapping src onto dst. One transform for both devices is what "one map"
    means; the scale is left free because the map's metric scale comes from the
    devices' drifting odometry."""
    src, dst = np.asarray(src), np.asarray(dst)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd(xd.T @ xs / len(src))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    scale = np.trace(np.diag(sig) @ d) / (xs ** 2).sum(1).mean()
    err = xd - scale * xs @ r.T
    return float(np.sqrt((err ** 2).sum(1).mean()))


class TwoDevicesTest(unittest.TestCase):
    def setUp(self):
        self.scene = rospy.get_param("~scene")
        self.player_launch = rospy.get_param("~player_launch")
        self.frames = int(rospy.get_param("~frames", 140))
        self.devices = rospy.get_param("~devices", "device_0,device_2").split(",")
        self.playback = Playback(self.scene, self.player_launch, self.frames, self.devices,
                                 prefix="ecar_two_devices_")
        self.lock = self.playback.lock
        self.device_frames = {d: {} for d in self.devices}
        self.server = {d: {} for d in self.devices}
        self.server_maps = {d: {} for d in self.devices}
        self.graphs = {d: 0 for d in self.devices}
        self.epochs = set()

    def tearDown(self):
        self.playback.close()

    def on_frame(self, m):
        with self.lock:
            self.device_frames[m.device_id][m.frame_index] = m
            self.playback.activity()

    def on_graph(self, m, device):
        with self.lock:
            self.graphs[device] += 1
            if m.status in (LocalGraph.OK, LocalGraph.RELOCALISED):
                p = m.pose.position
                self.server[device][m.frame_index] = np.array([p.x, p.y, p.z])
                self.server_maps[device][m.frame_index] = m.map_id
                self.epochs.add(m.map_epoch)
            self.playback.activity()

    def test_two_devices_share_one_map(self):
        datasets = self.playback.render_all()
        for d in self.devices:
            rospy.Subscriber("/%s/device_frame" % d, DeviceFrame, self.on_frame, queue_size=500)
            rospy.Subscriber("/%s/local_graph" % d, LocalGraph, self.on_graph, callback_args=d,
                             queue_size=500)
        try:
            self.playback.start(datasets)
        except rospy.ROSException:
            self.fail("the server's /ecar/connect did not appear")
        finished = self.playback.wait(300.0)
        self.assertTrue(all(finished.values()), "players did not finish: %s" % finished)

        src, dst = [], []
        final_maps = {d: self.server_maps[d][max(self.server_maps[d])]
                      for d in self.devices if self.server_maps[d]}
        self.assertEqual(len(set(final_maps.values())), 1, "maps at the end: %s" % final_maps)
        for d in self.devices:
            frames = self.device_frames[d]
            uploads = sum(1 for m in frames.values() if m.uploaded)
            self.assertGreater(uploads, 0, "%s uploaded nothing" % d)
            self.assertGreaterEqual(self.graphs[d], 0.9 * uploads,
                                    "%s: %d local graphs for %d uploads" %
                                    (d, self.graphs[d], uploads))
            server = self.server[d]
            self.assertGreaterEqual(len(server), 0.5 * uploads,
                                    "%s: only %d of %d uploads aligned" % (d, len(server), uploads))

            started = [m for m in frames.values() if m.status != DeviceFrame.NOT_INITIALISED]
            tracked = [m for m in started if m.status == DeviceFrame.OK]
            self.assertGreaterEqual(len(tracked), 0.95 * len(started),
                                    "%s tracked %d of %d frames after its first graph" %
                                    (d, len(tracked), len(started)))
            errors, compared = [], []
            maps = self.server_maps[d]
            held = None  # the map of the device's previous graph
            for f in sorted(server):
                p_server = server[f]
                same_map = held is None or maps[f] == held
                held = maps[f]
                m = frames.get(f)
                if same_map and m is not None and m.status == DeviceFrame.OK:
                    p = m.pose.position
                    errors.append(np.linalg.norm(np.array([p.x, p.y, p.z]) - p_server))
                    compared.append(f)
            self.assertGreater(len(errors), 5, "%s: no frames with both poses" % d)
            settling = 2  # compared frames tracked on a map still settling (docstring)
            for f, e in list(zip(compared, errors))[:settling]:
                self.assertLess(e, 0.10, "%s: compared frame %d is %.2f cm off" % (d, f, 100 * e))
            rmse = float(np.sqrt(np.mean(np.square(errors[settling:]))))
            rospy.loginfo("%s: %d uploads, %d graphs, %d aligned, device tracked %d/%d, "
                          "device-vs-server RMSE %.2f cm after the first two compared frames",
                          d, uploads, self.graphs[d], len(server), len(tracked), len(started),
                          100 * rmse)
            per_frame = ", ".join("%d: %.2f" % (f, 100 * e) for f, e in zip(compared, errors))
            rospy.loginfo("%s: device-vs-server per frame (cm): %s", d, per_frame)
            self.assertLess(rmse, 0.01, "%s: device-vs-server RMSE %.2f cm; per frame (cm): %s" % (
                d, 100 * rmse, per_frame))

            times = read_frame_times(datasets[d])
            gt = read_tum(os.path.join(datasets[d], "groundtruth.txt"))
            for f, p_server in server.items():
                if times[f] in gt and self.server_maps[d][f] == final_maps[d]:
                    src.append(p_server)
                    dst.append(gt[times[f]])
        self.assertEqual(len(self.epochs), 1, "map epoch changed: %s" % self.epochs)
        rmse = similarity_fit_rmse(src, dst)
        rospy.loginfo("both devices against ground truth with one transform: ATE %.2f cm",
                      100 * rmse)
        self.assertLess(rmse, 0.03, "one transform for both devices leaves %.2f cm" % (100 * rmse))


if __name__ == "__main__":
    rospy.init_node("two_devices_test")
    rostest.rosrun(PKG, "two_devices", TwoDevicesTest, sys.argv)
