#!/usr/bin/python3
"""Tests of the VO sync metrics (python/ecar_sim/vo_metrics.py) and the plane check
(plane_metrics.py) on synthetic sessions whose answers are known: a corridor box, cameras on
known poses, VOs at known places."""

import math
import os
import sys
import unittest

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_msgs.msg import DeviceFrame, Plane, VirtualObject  # noqa: E402
from ecar_sim import ground_truth as truth  # noqa: E402
from ecar_sim import plane_metrics  # noqa: E402
from ecar_sim import vo_metrics as vm  # noqa: E402
from ecar_sim.alignment import Similarity, quat_to_rot  # noqa: E402

CORRIDOR = {"spaces": [{"min": [0, 0, 0], "max": [30, 2.4, 2.7]}],
            "solids": [{"min": [10, 0, 0], "max": [11, 2.4, 2.0]}]}
CAMERA = truth.Camera(525.0, 525.0, 319.5, 239.5, 640, 480)


def looking_along_x(x, y=1.2, z=1.5, sign=1.0):
    """T_world_camera of an optical camera at (x, y, z) looking along +x (sign 1) or -x,
    level (image x right, y down)."""
    T = np.eye(4)
    fwd = np.array([sign, 0.0, 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, fwd)
    T[:3, :3] = np.column_stack([right, down, fwd])
    T[:3, 3] = [x, y, z]
    return T


def rot_to_quat(r):
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    return ((r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w),
            (r[1, 0] - r[0, 1]) / (4 * w), w)


def line(oid, version, centre, wall, owner="device_0", deleted=False):
    c = np.array(centre, float)
    return vm.VoState(oid, version, deleted, owner, VirtualObject.LINE, c, c - [0.2, 0, 0],
                      c + [0.2, 0, 0], wall)


class Session:
    """Devices walking the corridor at 1 m per frame wall second, map == world."""

    def __init__(self, sim=None):
        self.sim = sim or Similarity()
        self.devices = []

    def device(self, name, xs, held, sign=1.0, wall0=0.0, pose_offset=(0, 0, 0), graphs=None,
               received=None):
        inv = np.linalg.inv(np.block([[self.sim.s * self.sim.r, self.sim.t[:, None]],
                                      [np.zeros((1, 3)), np.ones((1, 1))]]))
        frames, gt = {}, {}
        for f, x in enumerate(xs):
            T = looking_along_x(x, sign=sign)
            gt[f] = T
            # The device's estimate in the map: the ground truth mapped back, plus an offset.
            p_map = (inv @ np.append(T[:3, 3], 1.0))[:3] + np.asarray(pose_offset)
            r_map = self.sim.r.T @ T[:3, :3]
            frames[f] = (wall0 + f, DeviceFrame.OK, tuple(p_map), rot_to_quat(r_map), dict(held(f)))
            if received:
                frames[f] += (dict(received(f)),)
        walls = graphs if graphs is not None else [wall0 + 0.25 * k for k in range(4 * len(xs))]
        self.devices.append(vm.DeviceRecord(name, CAMERA, frames, gt, walls))

    def evaluate(self, states, max_range=40.0):
        return vm.VoEvaluator(vm.Timeline(states), self.devices, truth.FreeSpace(CORRIDOR),
                              self.sim, max_range).evaluate()


class VisibilityTest(unittest.TestCase):
    def test_frustum_range_and_walls(self):
        s = Session()
        s.device("device_1", [2.0], lambda f: {})
        ev = vm.VoEvaluator(vm.Timeline([]), s.devices, truth.FreeSpace(CORRIDOR), Similarity(),
                            max_range=40.0)
        dev = s.devices[0]
        self.assertTrue(ev.visible(dev, 0, line(1, 1, [8.0, 1.2, 0.0], 0.0)))   # ahead on the floor
        self.assertFalse(ev.visible(dev, 0, line(2, 1, [1.0, 1.2, 0.0], 0.0)))  # behind the camera
        self.assertFalse(ev.visible(dev, 0, line(3, 1, [20.0, 1.2, 0.0], 0.0)))  # behind the solid
        self.assertTrue(ev.visible(dev, 0, line(4, 1, [20.0, 1.2, 2.6], 0.0)))  # over it, ceiling
        short = vm.VoEvaluator(vm.Timeline([]), s.devices, truth.FreeSpace(CORRIDOR),
                               Similarity(), max_range=5.0)
        self.assertFalse(short.visible(dev, 0, line(1, 1, [8.0, 1.2, 0.0], 0.0)))  # out of range


class SuccessTest(unittest.TestCase):
    def test_bins_and_grace(self):
        s = Session()
        # device_0 registers a line at x = 1 (frame walls 0..), device_1 walks back from x = 9.5
        # (the solid at x = 10..11 would hide it from further; from nearer than 3.3 m the floor
        # under it leaves the image).
        s.device("device_0", [0.5] * 4, lambda f: {7: 1}, sign=1.0)
        # device_1 misses the VO on its first 2 frames after the grace, then holds it.
        xs = [9.5 - 0.5 * f for f in range(8)]
        s.device("device_1", xs, lambda f: {7: 1} if f >= 3 else {}, sign=-1.0)
        r = s.evaluate([line(7, 1, [1.0, 1.2, 0.0], wall=0.5)])
        # Grace = 2 round trips of 0.25 s: expected from wall 1.0 on, i.e. frames 1..7 of
        # device_1 (x = 9 .. 6), held from frame 3.
        d1 = r["by_device"]["device_1"]
        self.assertEqual(d1["expected"], 7)
        self.assertEqual(d1["held"], 5)
        self.assertAlmostEqual(d1["grace_s"], 0.5)
        bins = {b["bin"]: (b["held"], b["expected"]) for b in r["by_distance"]}
        # Camera 1.5 m above the floor: distance = hypot(x - 1, 1.5).
        expect = {}
        for f in range(1, 8):
            d = math.hypot(xs[f] - 1.0, 1.5)
            k = "%g-%g m" % (2 * int(d // 2), 2 * int(d // 2) + 2)
            ok, n = expect.get(k, (0, 0))
            expect[k] = (ok + (f >= 3), n + 1)
        self.assertEqual(bins, expect)
        self.assertAlmostEqual(r["success_other_devices"], round(5 / 7, 4))
        # Facing each other: the angle between the two views is near 180 degrees.
        self.assertEqual([b["bin"] for b in r["by_angle"]][-1], "165-180 deg")

    def test_deleted_and_newer_versions(self):
        s = Session()
        s.device("device_0", [0.5] * 2, lambda f: {})
        # Holds version 1 only: version 2 (accepted at wall 0) is expected from wall 0.5 on.
        s.device("device_1", [0.5, 0.6, 0.7], lambda f: {1: 1}, sign=1.0)
        r = s.evaluate([line(1, 1, [5.0, 1.2, 0.0], wall=-10.0),
                        line(1, 2, [6.0, 1.2, 0.0], wall=0.0),
                        line(1, 3, [6.0, 1.2, 0.0], wall=1.4, deleted=True)])
        d1 = r["by_device"]["device_1"]
        # Frame 0 (wall 0): version 1 visible and held, but there is no frame a grace (0.5 s)
        # earlier, so it counts only in the strict rate; frame 1 (wall 1): version 2 expected,
        # not held; frame 2 (wall 2): the tombstone from wall 1.4 is older than the grace.
        self.assertEqual((d1["held"], d1["expected"]), (0, 1))
        self.assertEqual(d1["success_strict"], 0.5)

    def test_what_just_came_into_view_is_not_yet_expected(self):
        s = Session()
        s.device("device_0", [0.5] * 2, lambda f: {})
        # device_1 turns round: the VO at x = 6 is behind it on frame 0, in view from frame 1;
        # it holds it from frame 2 (its first graph after seeing it).
        frames = [(5.0, -1.0), (0.5, 1.0), (0.6, 1.0), (0.7, 1.0)]
        held = lambda f: {1: 1} if f >= 2 else {}
        record = {}
        gt = {}
        for f, (x, sign) in enumerate(frames):
            T = looking_along_x(x, sign=sign)
            gt[f] = T
            record[f] = (float(f), DeviceFrame.OK, tuple(T[:3, 3]), rot_to_quat(T[:3, :3]), held(f))
        s.devices.append(vm.DeviceRecord("device_1", CAMERA, record, gt,
                                         [0.25 * k for k in range(16)]))
        r = s.evaluate([line(1, 1, [6.0, 1.2, 0.0], wall=-10.0)])
        d1 = r["by_device"]["device_1"]
        # Frame 1: in view, but not on frame 0 (0.5 s earlier): not expected; frames 2, 3: held.
        self.assertEqual((d1["held"], d1["expected"]), (2, 2))
        self.assertAlmostEqual(d1["success_strict"], round(2 / 3, 4))


class LatencyAndAgreementTest(unittest.TestCase):
    def test_latency_in_seconds_and_round_trips(self):
        s = Session()
        s.device("device_0", [0.5] * 6, lambda f: {3: 1})
        # Graphs every 0.5 s; device_1 holds version 1 from frame 2 (wall 2), accepted at 0.5.
        s.device("device_1", [1.0] * 6, lambda f: {3: 1} if f >= 2 else {},
                 graphs=[0.5 * k for k in range(12)])
        r = s.evaluate([line(3, 1, [6.0, 1.2, 0.0], wall=0.5)])
        lat = r["latency"]
        self.assertEqual(lat["changes_measured"], 1)
        self.assertAlmostEqual(lat["median_ms"], 1500.0)
        self.assertAlmostEqual(lat["median_round_trips"], 3.0)
        self.assertEqual(lat["within_two_round_trips"], 0.0)

    def test_latency_from_the_arrival_on_the_device(self):
        # As above, but the device says version 1 arrived at wall 1.2 (between frames 1 and 2):
        # the latency is 0.7 s, not the 1.5 s to the first frame that held it.
        s = Session()
        s.device("device_0", [0.5] * 6, lambda f: {3: 1})
        s.device("device_1", [1.0] * 6, lambda f: {3: 1} if f >= 2 else {},
                 graphs=[0.5 * k for k in range(12)],
                 received=lambda f: {3: 1.2} if f >= 2 else {})
        lat = s.evaluate([line(3, 1, [6.0, 1.2, 0.0], wall=0.5)])["latency"]
        self.assertAlmostEqual(lat["median_ms"], 700.0)
        # An arrival before the collector saw the change counts 0, never negative.
        s.devices[1].frames = {f: e[:5] + ({3: 0.2} if f >= 2 else {},)
                               for f, e in s.devices[1].frames.items()}
        lat = s.evaluate([line(3, 1, [6.0, 1.2, 0.0], wall=0.5)])["latency"]
        self.assertEqual(lat["median_ms"], 0.0)

    def test_agreement_reflects_pose_error(self):
        sim = Similarity(2.0, quat_to_rot((0.0, 0.0, 0.38268343, 0.92387953)),
                            np.array([3.0, -1.0, 0.2]))
        s = Session(sim)
        world = np.array([6.0, 1.2, 0.0])
        # The VO's map position is the world position mapped back.
        p_map = sim.r.T @ (world - sim.t) / sim.s
        s.device("device_0", [1.0] * 5, lambda f: {5: 1})
        # device_1's pose estimate is off by 0.005 map units (1 cm in the world) along map x.
        s.device("device_1", [1.5] * 5, lambda f: {5: 1}, pose_offset=(0.005, 0.0, 0.0))
        state = vm.VoState(5, 1, False, "device_0", VirtualObject.ANCHOR, p_map, p_map, p_map, -5.0)
        r = s.evaluate([state])
        self.assertEqual(r["success"], 1.0)
        self.assertEqual(r["position_agreement"]["pairs"], 1)
        self.assertAlmostEqual(r["position_agreement"]["max_m"], 0.01, places=4)
        # Both see it from about 5 m: the near-view agreement is the same pair.
        self.assertEqual(r["position_agreement"]["near_pairs"], 1)
        self.assertAlmostEqual(r["position_agreement"]["near_max_m"], 0.01, places=4)
        np.testing.assert_allclose(r["objects_detail"][0]["world_position"], world, atol=1e-3)


class PlanesTest(unittest.TestCase):
    def test_labels_checked_against_the_scene(self):
        sim = Similarity(0.5, quat_to_rot((0.0, 0.0, 0.38268343, 0.92387953)),
                            np.array([3.0, -1.0, 0.2]))

        def to_map(n_w, c_w):
            n = sim.r.T @ np.asarray(n_w, float)
            c = sim.r.T @ (np.asarray(c_w, float) - sim.t) / sim.s
            return {"normal": n, "offset": -float(n @ c), "centroid": c}

        planes = [dict(id=1, label=Plane.FLOOR, points=100, **to_map([0, 0, 1], [5.0, 1.2, 0.01])),
                  dict(id=2, label=Plane.WALL, points=80, **to_map([0, 1, 0], [6.0, 2.38, 1.0])),
                  dict(id=3, label=Plane.CEILING, points=50, **to_map([0, 0, -1], [7.0, 1.0, 2.7])),
                  dict(id=4, label=Plane.FLOOR, points=40, **to_map([0, 0, 1], [10.5, 1.0, 2.0])),
                  # A second floor 10 cm above the floor: labelled right, off its surface.
                  dict(id=6, label=Plane.FLOOR, points=45, **to_map([0, 0, 1], [8.0, 1.0, 0.1])),
                  # A wall labelled floor: wrong.
                  dict(id=5, label=Plane.FLOOR, points=30, **to_map([0, -1, 0], [12.0, 0.0, 1.0]))]
        r = plane_metrics.check_planes(planes, CORRIDOR, sim)
        rows = {d["id"]: d for d in r["detail"]}
        self.assertEqual(r["planes"], 6)
        self.assertEqual(r["labelled_right"], 5)
        self.assertEqual(r["on_surface"], 4)
        self.assertEqual(r["off_surface"], [6])
        self.assertAlmostEqual(rows[6]["distance_m"], 0.1, places=6)
        self.assertTrue(rows[6]["right"] and not rows[6]["on_surface"])
        self.assertTrue(rows[1]["on_surface"] and rows[4]["on_surface"])
        self.assertEqual(rows[1]["true_surface"], "floor")
        self.assertAlmostEqual(rows[1]["distance_m"], 0.01, places=6)
        self.assertEqual(rows[2]["true_surface"], "wall")
        self.assertAlmostEqual(rows[2]["distance_m"], 0.02, places=6)
        self.assertEqual(rows[3]["true_surface"], "ceiling")
        self.assertEqual(rows[4]["true_surface"], "object top")  # the solid's top, z = 2
        self.assertTrue(rows[4]["right"])
        self.assertFalse(rows[5]["right"])
        self.assertEqual(r["found"], ["ceiling", "floor", "object top", "wall"])


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "vo_metrics", "__main__")
