#!/usr/bin/python3
"""Tests of what a session records (python/ecar_sim/session/collecting.py: Records, fed with
real ecar_msgs messages through genpy, no ROS master) and of vo_raw.json.gz
(structure.py: save_raw and RawCollector for --reevaluate)."""

import io
import math
import os
import sys
import tempfile
import unittest

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_msgs.msg import (DeviceFrame, InteractionResult, LocalGraph, Plane,  # noqa: E402
                           RoundTripMetrics, VirtualObject)
from ecar_sim.session import structure  # noqa: E402
from ecar_sim.session.collecting import Records  # noqa: E402
from geometry_msgs.msg import Point  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402


def wire(msg):
    """msg serialised and deserialised by genpy, as a subscriber gets it."""
    buf = io.BytesIO()
    msg.serialize(buf)
    return type(msg)().deserialize(buf.getvalue())


def local_graph(device, frame, status, x, planes=(), removed_planes=()):
    g = LocalGraph(device_id=device, frame_index=frame, status=status)
    g.pose.position.x = x
    g.pose.orientation.w = 1.0
    g.planes = list(planes)
    g.removed_planes = list(removed_planes)
    return wire(g)


def plane(pid, version, label=Plane.FLOOR):
    return Plane(id=pid, version=version, label=label, normal=Point(0, 0, 1), offset=-0.5,
                 boundary=[Point(0, 0, 0.5), Point(2, 0, 0.5), Point(2, 4, 0.5)], num_points=40)


def device_frame(device, frame, status, uploaded, held=()):
    m = DeviceFrame(device_id=device, frame_index=frame, status=status, uploaded=uploaded,
                    tracking_time=0.004)
    m.pose.position.y = frame
    m.pose.orientation.w = 1.0
    m.object_ids = [i for i, _ in held]
    m.object_versions = [v for _, v in held]
    return wire(m)


class RecordsTest(unittest.TestCase):
    def setUp(self):
        self.r = Records(["device_0", "device_1"])

    def test_server_poses_only_from_graphs_with_a_pose(self):
        for frame, status in [(0, LocalGraph.NOT_INITIALISED), (4, LocalGraph.OK),
                              (8, LocalGraph.LOST), (12, LocalGraph.RELOCALISED)]:
            self.r.on_local_graph(local_graph("device_0", frame, status, 0.1 * frame), "device_0")
        self.assertEqual(self.r.graphs, {"device_0": 4, "device_1": 0})
        self.assertEqual(sorted(self.r.server_poses["device_0"]), [4, 12])
        self.assertEqual(self.r.server_maps["device_0"], {4: 0, 12: 0})  # and their map ids
        p, q = self.r.server_poses["device_0"][12]
        self.assertAlmostEqual(p[0], 1.2)
        self.assertEqual(q, (0.0, 0.0, 0.0, 1.0))
        self.assertEqual(len(self.r.graph_walls["device_0"]), 4)

    def test_newest_plane_version_is_kept(self):
        self.r.on_local_graph(local_graph("device_0", 0, LocalGraph.OK, 0, [plane(3, 2)]),
                              "device_0")
        self.r.on_local_graph(local_graph("device_1", 0, LocalGraph.OK, 0,
                                          [plane(3, 1, Plane.WALL), plane(4, 1)]), "device_1")
        no_boundary = plane(5, 1)
        no_boundary.boundary = []
        self.r.on_local_graph(local_graph("device_1", 4, LocalGraph.OK, 0, [no_boundary]),
                              "device_1")
        self.assertEqual(sorted(self.r.planes), [3, 4])
        p3 = self.r.planes[3]
        self.assertEqual((p3["version"], p3["label"], p3["points"]), (2, Plane.FLOOR, 40))
        np.testing.assert_allclose(p3["centroid"], (4 / 3, 4 / 3, 0.5))

    def test_planes_the_server_removed_are_dropped_and_stay_dropped(self):
        # A merged map's young floor (3) is fused into the floor it met (1): the device that
        # held it is told; a late graph of another device still carrying it does not bring
        # it back.
        self.r.on_local_graph(local_graph("device_0", 0, LocalGraph.OK, 0,
                                          [plane(1, 1), plane(3, 1)]), "device_0")
        self.r.on_local_graph(local_graph("device_0", 4, LocalGraph.OK, 0, [plane(1, 2)],
                                          removed_planes=[3]), "device_0")
        self.assertEqual(sorted(self.r.planes), [1])
        self.r.on_local_graph(local_graph("device_1", 0, LocalGraph.OK, 0, [plane(3, 2)]),
                              "device_1")
        self.assertEqual(sorted(self.r.planes), [1])
        self.assertEqual(self.r.removed_planes, {3})

    def test_device_frames_and_progress(self):
        progress = self.r.progress()
        self.assertEqual(list(progress), ["device_0", "device_1"])
        self.assertIsNone(progress["device_0"].first_wall)
        for f in range(6):
            self.r.on_device_frame(device_frame("device_0", f, DeviceFrame.OK, f % 4 == 0,
                                                [(7, 2)]))
        self.r.on_local_graph(local_graph("device_0", 0, LocalGraph.OK, 0), "device_0")
        e = self.r.device_frames["device_0"][5]
        self.assertEqual((e.status, e.position, e.uploaded, e.held),
                         (DeviceFrame.OK, (0.0, 5.0, 0.0), False, {7: 2}))
        self.assertAlmostEqual(e.tracking_time, 0.004)
        p = self.r.progress()["device_0"]
        self.assertEqual((p.frames, p.uploads, p.graphs), (6, 2, 1))
        self.assertLessEqual(p.first_wall, p.last_wall)

    def test_metrics_results_and_finished(self):
        self.r.on_metrics(wire(RoundTripMetrics(device_id="device_1", frame_index=8,
                                                bytes_down=5000, latency=0.0125)))
        self.assertAlmostEqual(self.r.metrics[0]["latency_ms"], 12.5, places=4)  # float32
        self.assertEqual(self.r.all_finished()[0], False)
        self.r.on_finished(Bool(True), "device_0")
        self.r.on_finished(Bool(False), "device_1")
        self.assertEqual(self.r.all_finished()[0], False)
        self.r.on_finished(Bool(True), "device_1")
        done, idle = self.r.all_finished()
        self.assertTrue(done)
        self.assertGreaterEqual(idle, 0.0)


class RawTest(unittest.TestCase):
    def test_round_trip_of_what_the_vo_metrics_read(self):
        r = Records(["device_0"])
        r.on_device_frame(device_frame("device_0", 3, DeviceFrame.LOST, True, [(1, 4)]))
        r.on_local_graph(local_graph("device_0", 4, LocalGraph.OK, 2.0, [plane(9, 1)]),
                         "device_0")
        vo = VirtualObject(id=1, version=4, owner="device_0", kind=VirtualObject.ANCHOR,
                           position=Point(1, 2, 3))
        r.on_object(wire(vo))
        r.on_result(wire(InteractionResult(accepted=False, reason="locked")), "device_0")
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "vo_raw.json.gz")
            structure.save_raw(path, r)
            back = structure.RawCollector(path)
        e, b = r.device_frames["device_0"][3], back.device_frames["device_0"][3]
        self.assertEqual((b.status, b.position, b.orientation, b.wall, b.held),
                         (e.status, e.position, e.orientation, e.wall, e.held))
        self.assertEqual((b.uploaded, b.tracking_time), (False, 0.0))  # not kept
        self.assertEqual(back.server_poses, r.server_poses)
        self.assertEqual(back.server_maps, r.server_maps)
        self.assertEqual(back.graph_walls, r.graph_walls)
        (wall, o), = back.objects
        self.assertEqual(wall, r.objects[0][0])
        self.assertEqual((o.id, o.version, o.kind, o.position.z), (1, 4, VirtualObject.ANCHOR, 3))
        self.assertEqual(back.results, {"device_0": {"accepted": 0, "rejected": {"locked": 1}}})
        self.assertEqual(back.planes[9]["centroid"], list(r.planes[9]["centroid"]))


class FitTest(unittest.TestCase):
    def test_map_to_world_drops_a_device_in_another_map(self):
        # Ground truth: frames walking a room; the server's map is the world scaled by 0.5 and
        # turned 90 degrees about z; device_1's first poses are still in its own map (2 m off).
        c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
        r_mw = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # world -> map rotation
        r = Records(["device_0", "device_1"])
        gt_rows = []
        walk = np.random.default_rng(5).uniform([0, 0, 1], [6, 4, 2], size=(12, 3))
        for f, p_w in enumerate(walk):
            gt_rows.append("%d %f %f %f 0 0 0 1" % ((f,) + tuple(p_w)))
            r.server_poses["device_0"][f] = (tuple(0.5 * r_mw @ p_w), (0, 0, 0, 1))
        for f in range(3):
            p_m = np.array(r.server_poses["device_0"][f][0]) + [1.0, 0.0, 0.0]
            r.server_poses["device_1"][f] = (tuple(p_m), (0, 0, 0, 1))
        with tempfile.TemporaryDirectory() as tmp:
            datasets = {}
            for d in ("device_0", "device_1"):
                datasets[d] = os.path.join(tmp, d)
                os.makedirs(datasets[d])
                with open(os.path.join(datasets[d], "groundtruth.txt"), "w") as f:
                    f.write("\n".join(gt_rows) + "\n")
            sim, info = structure.fit_map_to_world(["device_0", "device_1"], datasets, r)
        self.assertEqual((info["poses"], info["poses_dropped"]), (12, 3))
        self.assertAlmostEqual(info["scale"], 2.0)
        self.assertAlmostEqual(info["rmse_m"], 0.0, places=4)
        np.testing.assert_allclose(sim.r, r_mw.T, atol=1e-5)  # ground truth to 1 um

    def test_no_poses(self):
        r = Records(["device_0"])
        with tempfile.TemporaryDirectory() as tmp:
            with open(os.path.join(tmp, "groundtruth.txt"), "w") as f:
                f.write("0 0 0 0 0 0 0 1\n")
            with self.assertRaises(ValueError):
                structure.fit_map_to_world(["device_0"], {"device_0": tmp}, r)


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "session_records", "__main__")
