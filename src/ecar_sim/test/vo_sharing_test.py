#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End to end (started by test/vo_sharing.test): one device draws, another far away receives.

Renders test/vo_far_scene.yaml: `drawer` walks 11 m down the corridor and draws, by its scripted
touches, a line across the floor at x = 15 and one on the left wall at x = 16.5; `receiver` stays
near the start, 12-15 m from them. Plays both through the real server and devices and asserts
that
- the drawer's touches became accepted REGISTERs (no rejections);
- the VOs lie where the user touched, on the floor and on the wall, in the world (map -> world
  by the similarity fit of the server's poses to the ground truth), within 10 cm;
- the receiver held every VO its ground-truth view showed (at the version accepted two of its
  round trips before; ecar_sim.vo_metrics, as run_session measures it), from 10 m and more away,
  and where the two devices draw them agrees within 8 cm (0.35 degrees at 13 m).

Private params: ~scene, ~player_launch, ~frames.
"""

import os
import sys
import time
import unittest

import numpy as np
import rospy
import rostest
import yaml
from ecar_msgs.msg import DeviceFrame, InteractionResult, LocalGraph, Plane, VirtualObject
from rosgraph_msgs.msg import Log
from ecar_sim import ground_truth
from ecar_sim import vo_metrics as vm
from ecar_sim.alignment import Similarity, umeyama
from ecar_sim.playback import Playback

PKG = "ecar_sim"
DEVICES = ["drawer", "receiver"]
# The first frame of the drawer's wall stroke (vo_far_scene.yaml).
WALL_TOUCH_FRAME = 316


class VoSharingTest(unittest.TestCase):
    def setUp(self):
        self.scene = rospy.get_param("~scene")
        self.player_launch = rospy.get_param("~player_launch")
        self.frames = int(rospy.get_param("~frames", 150))
        self.playback = Playback(self.scene, self.player_launch, self.frames, DEVICES,
                                 prefix="ecar_vo_sharing_")
        self.lock = self.playback.lock
        self.device_frames = {d: {} for d in DEVICES}
        self.server = {d: {} for d in DEVICES}
        self.graph_walls = {d: [] for d in DEVICES}
        self.objects = []
        self.results = []
        # What the drawer held of the walls when it touched them, for the failure message:
        # its planes by id (applied from its graphs as the device applies them), and per graph
        # frame the walls' boundaries in the map.
        self.drawer_planes = {}
        self.drawer_walls = []  # (frame_index, [boundary as an Nx3 array])
        self.drawer_log = []  # the drawer device's warnings and errors (/rosout)

    def tearDown(self):
        self.playback.close()

    def on_frame(self, m):
        now = time.time()
        with self.lock:
            p, q = m.pose.position, m.pose.orientation
            self.device_frames[m.device_id][m.frame_index] = (
                now, m.status, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w),
                dict(zip(m.object_ids, m.object_versions)))
            self.playback.activity()

    def on_graph(self, m, device):
        with self.lock:
            self.graph_walls[device].append(time.time())
            if device == "drawer":
                self.note_drawer_planes(m)
            if m.status in (LocalGraph.OK, LocalGraph.RELOCALISED):
                p = m.pose.position
                self.server[device][m.frame_index] = np.array([p.x, p.y, p.z])
            self.playback.activity()

    def note_drawer_planes(self, m):
        for plane_id in m.removed_planes:
            self.drawer_planes.pop(plane_id, None)
        for p in m.planes:
            held = self.drawer_planes.get(p.id)
            if held is None or p.version > held.version:
                self.drawer_planes[p.id] = p
        walls = [np.array([(b.x, b.y, b.z) for b in p.boundary])
                 for p in self.drawer_planes.values() if p.label == Plane.WALL and p.boundary]
        self.drawer_walls.append((m.frame_index, walls))

    def on_log(self, m):
        if "drawer" in m.name and m.level >= Log.WARN:
            with self.lock:
                self.drawer_log.append(m.msg)

    def why_no_wall_vo(self, sim):
        """What the drawer held and said around its wall stroke: the walls' extent along the
        corridor (world x; the stroke is at x = 16.5 on the y = 2.4 wall) in its last graph
        before the stroke, its status on the stroke's frames, and its warnings."""
        before = [w for f, w in self.drawer_walls if f <= WALL_TOUCH_FRAME]
        walls = []
        for boundary in (before[-1] if before else []):
            world = np.array([sim.apply(b) for b in boundary])
            walls.append("y %.2f: x %.2f..%.2f" % (np.median(world[:, 1]), world[:, 0].min(),
                                                   world[:, 0].max()))
        frames = self.device_frames["drawer"]
        statuses = [frames[f][1] if f in frames else None
                    for f in range(WALL_TOUCH_FRAME, WALL_TOUCH_FRAME + 9)]
        return ("the drawer's walls before frame %d: %s; its statuses on frames %d+: %s; "
                "its warnings: %s" % (WALL_TOUCH_FRAME, walls or "none", WALL_TOUCH_FRAME,
                                      statuses, self.drawer_log[-10:] or "none"))

    def on_object(self, m):
        with self.lock:
            self.objects.append((time.time(), m))

    def on_result(self, m):
        with self.lock:
            self.results.append(m)

    def test_stroke_reaches_a_device_far_along_the_corridor(self):
        datasets = self.playback.render_all()
        self.assertTrue(os.path.exists(os.path.join(datasets["drawer"], "touches.txt")),
                        "the drawer's dataset has no touches.txt")
        rospy.Subscriber("/ecar/objects", VirtualObject, self.on_object, queue_size=1000)
        rospy.Subscriber("/drawer/interaction_result", InteractionResult, self.on_result,
                         queue_size=1000)
        rospy.Subscriber("/rosout_agg", Log, self.on_log, queue_size=1000)
        for d in DEVICES:
            rospy.Subscriber("/%s/device_frame" % d, DeviceFrame, self.on_frame, queue_size=500)
            rospy.Subscriber("/%s/local_graph" % d, LocalGraph, self.on_graph, callback_args=d,
                             queue_size=500)
        self.playback.start(datasets)
        finished = self.playback.wait(300.0)
        self.assertTrue(all(finished.values()), "players did not finish: %s" % finished)

        # The touches became VOs, all accepted.
        rejected = [(r.request_id, r.reason) for r in self.results if not r.accepted]
        accepted = [r for r in self.results if r.accepted]
        self.assertEqual(rejected, [], "rejected interactions")
        self.assertGreaterEqual(len(accepted), 10, "only %d accepted interactions" % len(accepted))

        # Map -> world from the server's poses of both devices.
        src, dst, records = [], [], []
        for d in DEVICES:
            gt = ground_truth.read_groundtruth(datasets[d])
            for f, p in self.server[d].items():
                src.append(p)
                dst.append(gt[f][:3, 3])
            with open(os.path.join(datasets[d], "camera.yaml")) as f:
                camera = ground_truth.Camera.from_yaml(yaml.safe_load(f))
            records.append(vm.DeviceRecord(d, camera, self.device_frames[d], gt,
                                           self.graph_walls[d]))
        self.assertGreater(len(self.server["receiver"]), 5, "the receiver never joined the map")
        sim = Similarity(*umeyama(src, dst))

        # Each VO where it was drawn: floor line at x = 15, wall line at y = 2.4, x = 16.5. Along
        # the corridor the tolerance is wider on the wall: the touch ray meets it at about 15
        # degrees, so a 4 cm error of the wall plane moves the hit 15 cm along it.
        latest = {}
        for _, m in self.objects:
            latest[m.id] = m
        floor, wall = 0, 0
        for m in latest.values():
            p = sim.apply((m.position.x, m.position.y, m.position.z))
            if abs(p[2]) < 0.1:
                floor += 1
                self.assertLess(abs(p[0] - 15.0), 0.1, "floor VO %d at %s" % (m.id, p))
            else:
                wall += 1
                self.assertLess(abs(p[1] - 2.4), 0.05, "wall VO %d at %s" % (m.id, p))
                self.assertLess(abs(p[0] - 16.5), 0.25, "wall VO %d at %s" % (m.id, p))
                self.assertTrue(0.8 < p[2] < 1.6, "wall VO %d at %s" % (m.id, p))
        rospy.loginfo("VOs: %d on the floor, %d on the wall; %s", floor, wall,
                      self.why_no_wall_vo(sim))
        self.assertGreater(floor, 5, "VOs on the floor: %d" % floor)
        self.assertGreater(wall, 3, "VOs on the wall: %d (%s)" % (wall, self.why_no_wall_vo(sim)))

        # The receiver held them while far away.
        states = [vm.VoState(m.id, m.version, m.deleted, m.owner, m.kind,
                             (m.position.x, m.position.y, m.position.z),
                             (m.start.x, m.start.y, m.start.z), (m.end.x, m.end.y, m.end.z), w)
                  for w, m in self.objects]
        with open(self.scene) as f:
            space = ground_truth.FreeSpace(yaml.safe_load(f))
        result = vm.VoEvaluator(vm.Timeline(states), records, space, sim).evaluate()
        rospy.loginfo("VO metrics: %s", {k: result[k] for k in (
            "objects", "success", "success_other_devices", "by_distance", "latency",
            "position_agreement")})
        d1 = result["by_device"]["receiver"]
        self.assertGreater(d1["expected"], 50, "the receiver was expected to see VOs on %d frames"
                           % d1["expected"])
        self.assertGreaterEqual(d1["success"], 0.95, "the receiver held the VOs on %s of frames" %
                                d1["success"])
        far = [b for b in result["by_distance"] if float(b["bin"].split("-")[0]) >= 10.0]
        self.assertTrue(far, "no frames of the receiver 10 m or more from a VO: %s" %
                        result["by_distance"])
        for b in far:
            self.assertGreaterEqual(b["success"], 0.95, "bin %s" % b)
        # Where the two devices draw each VO: the receiver, 12-14 m away, sees it through the
        # map between them. Monocular mapping bends that span by 0.1-0.3 degrees (the corridor
        # runs of scripts/bench_vo.sh), which moves the drawn VO by 2-7 cm at 13 m; measured
        # here 4-5 cm. Beyond 8 cm (0.35 degrees) the map or the receiver's pose is wrong.
        agreement = result["position_agreement"]
        self.assertIsNotNone(agreement["max_m"])
        self.assertGreaterEqual(agreement["pairs"], 10, "VOs both devices drew: %s" % agreement)
        self.assertLess(agreement["max_m"], 0.08, "drawn positions disagree: %s" % agreement)


if __name__ == "__main__":
    rospy.init_node("vo_sharing_test")
    rostest.rosrun(PKG, "vo_sharing", VoSharingTest, sys.argv)
