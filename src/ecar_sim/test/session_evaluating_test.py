#!/usr/bin/python3
"""Tests of a session's metrics and printed lines (python/ecar_sim/session/evaluating.py,
report.py) on synthetic records whose answers are known."""

import contextlib
import csv
import io
import math
import os
import sys
import tempfile
import types
import unittest
from unittest import mock

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_msgs.msg import DeviceFrame  # noqa: E402
from ecar_sim import links  # noqa: E402
from ecar_sim.session import evaluating as ev  # noqa: E402
from ecar_sim.session import maps  # noqa: E402
from ecar_sim.session import report  # noqa: E402
from ecar_sim.session import structure  # noqa: E402
from ecar_sim.session.collecting import FrameRecord  # noqa: E402

Q0 = (0.0, 0.0, 0.0, 1.0)
# 10 degrees about z.
Q10 = (0.0, 0.0, math.sin(math.radians(5.0)), math.cos(math.radians(5.0)))


def write_dataset(folder, frames):
    os.makedirs(folder)
    with open(os.path.join(folder, "rgb.txt"), "w") as f:
        f.write("# timestamp filename\n")
        for i in range(frames):
            f.write("%.6f rgb/%06d.png\n" % (100.0 + i / 30.0, i))
    with open(os.path.join(folder, "groundtruth.txt"), "w") as f:
        for i in range(frames):
            f.write("%.6f %d 0 0 0 0 0 1\n" % (100.0 + i / 30.0, i))


def metric_row(device, frame, latency, bytes_down=1000, points=50, server=5.0):
    return {"device": device, "frame": frame, "bytes_up": 20000, "bytes_down": bytes_down,
            "points": points, "positions": 3, "latency_ms": latency, "upload_ms": 1.0,
            "server_ms": server, "receive_ms": 0.2 * server, "align_ms": 0.5 * server,
            "send_ms": 0.3 * server, "download_ms": 0.5,
            "device_tracking_ms": 3.0}


def records():
    """device_0: 8 frames, not initialised on 0-1, OK on 2-5 and 7, LOST on 6; uploads on
    0 and 4; the server's poses of frames 2-5 are 3 cm off along x and 10 degrees turned."""
    frames = {}
    for f in range(8):
        status = (DeviceFrame.NOT_INITIALISED if f < 2 else
                  DeviceFrame.LOST if f == 6 else DeviceFrame.OK)
        frames[f] = FrameRecord(status, (float(f), 0.0, 0.0), Q0, f % 4 == 0, 0.002 * (f + 1),
                                10.0 + f, {})
    server = {f: ((f + 0.03, 0.0, 0.0), Q10) for f in range(2, 6)}
    return types.SimpleNamespace(
        device_frames={"device_0": frames}, server_poses={"device_0": server},
        graphs={"device_0": 5},
        metrics=[metric_row("device_0", 4, 30.0, 3000, 0), metric_row("device_0", 0, 10.0),
                 metric_row("device_1", 0, 20.0, 2000, 100, 7.0)])


class StatsTest(unittest.TestCase):
    def test_percentile_and_round(self):
        self.assertEqual(ev.percentile([4, 1, 3, 2], 50), 2.5)
        self.assertAlmostEqual(ev.percentile(list(range(101)), 95), 95.0)
        self.assertIsNone(ev.percentile([], 50))
        self.assertIsNone(ev.rnd(None))
        self.assertEqual(ev.rnd(1.23456, 2), 1.23)

    def test_rotation_angle(self):
        self.assertAlmostEqual(ev.rotation_angle_deg(Q0, Q10), 10.0, places=9)


class DeviceSummaryTest(unittest.TestCase):
    def test_known_records(self):
        calls = []

        def fake_ate(gt, est, env, sim3):
            calls.append((os.path.basename(est), sim3))
            return 0.012345 if sim3 else 0.5

        with tempfile.TemporaryDirectory() as tmp:
            dataset = os.path.join(tmp, "data")
            write_dataset(dataset, 8)
            traj = os.path.join(tmp, "traj")
            os.makedirs(traj)
            s = ev.device_summary("device_0", dataset, records(), traj, {}, ate_rmse=fake_ate)
            with open(os.path.join(traj, "device_0_server.txt")) as f:
                server_lines = f.read().splitlines()
            self.assertTrue(os.path.exists(os.path.join(traj, "device_0_groundtruth.txt")))
        self.assertEqual((s["frames"], s["uploads"], s["graphs_received"], s["graphs_with_pose"],
                          s["round_trips_measured"]), (8, 2, 5, 4, 2))
        self.assertEqual((s["frames_tracked_on_device"], s["frames_after_first_graph"]), (5, 6))
        self.assertEqual(s["tracked_after_first_graph"], round(5 / 6, 4))
        self.assertEqual(s["device_vs_server_frames"], 4)
        self.assertAlmostEqual(s["device_vs_server_rmse_m"], 0.03)
        self.assertAlmostEqual(s["device_vs_server_max_m"], 0.03)
        self.assertAlmostEqual(s["device_vs_server_rot_median_deg"], 10.0)
        self.assertEqual((s["device_ate_se3_m"], s["server_ate_sim3_m"]), (0.5, 0.0123))
        self.assertEqual(len(calls), 4)
        self.assertEqual(s["median_latency_ms"], 20.0)
        # This device's link: its parts of the latency and its bytes each way.
        self.assertEqual((s["upload_ms_median"], s["download_ms_median"]), (1.0, 0.5))
        self.assertEqual(s["upload_bytes"], 20000 * len([r for r in records().metrics
                                                          if r["device"] == "device_0"]))
        # TUM: a header, then frames 2..5 stamped with the dataset's times.
        self.assertEqual(len(server_lines), 5)
        self.assertEqual(server_lines[1].split()[:2], ["100.066667", "2.030000"])

    def test_no_poses_no_ate(self):
        r = records()
        r.server_poses["device_0"] = {}
        evaluated = []
        with tempfile.TemporaryDirectory() as tmp:
            write_dataset(os.path.join(tmp, "d"), 8)
            s = ev.device_summary("device_0", os.path.join(tmp, "d"), r, tmp, {},
                                  ate_rmse=lambda gt, est, env, sim3: evaluated.append(est))
        self.assertEqual([os.path.basename(e) for e in evaluated], ["device_0_device.txt"] * 2)
        self.assertIsNone(s["server_ate_se3_m"])
        self.assertIsNone(s["device_vs_server_rmse_m"])
        self.assertEqual(s["device_vs_server_frames"], 0)


class FinalMapTest(unittest.TestCase):
    """A device whose map merged into another: its poses before the merge (another map's
    coordinates) are left out of the pose metrics."""

    def test_poses_before_the_merge_are_left_out(self):
        r = records()
        # Graphs of frames 2-3 in map 2; the merge: frames 4-5 in map 1, which device_1 ends in.
        r.server_maps = {"device_0": {2: 2, 3: 2, 4: 1, 5: 1}, "device_1": {0: 1}}
        # Before the merge the device's own poses are in map 2 too, 5 m away.
        for f in (2, 3, 4):
            e = r.device_frames["device_0"][f]
            r.device_frames["device_0"][f] = e._replace(position=(f + 5.0, 0.0, 0.0))
        final = maps.final_map(r, ["device_0", "device_1"])
        self.assertEqual(final, 1)
        with tempfile.TemporaryDirectory() as tmp:
            write_dataset(os.path.join(tmp, "d"), 8)
            s = ev.device_summary("device_0", os.path.join(tmp, "d"), r, tmp, {},
                                  ate_rmse=lambda gt, est, env, sim3: 0.0, final=final)
        self.assertEqual((s["maps"], s["final_map"], s["final_map_from_frame"]), ([1, 2], 1, 4))
        self.assertEqual(s["server_poses_other_maps"], 2)
        # Frame 4's own pose was tracked before its graph named map 1: only frame 5 compares.
        self.assertEqual(s["device_vs_server_frames"], 1)
        self.assertAlmostEqual(s["device_vs_server_rmse_m"], 0.03)

    def test_poses_after_leaving_the_final_map_are_left_out(self):
        # device_0 starts in map 1 (the final map, where device_1 ends), is lost and
        # relocalised into map 2 at frame 4, which had not merged by the end: its own poses
        # from frame 5 on are in map 2's coordinates, 5 m away.
        r = records()
        r.server_maps = {"device_0": {2: 1, 3: 1, 4: 2, 5: 2}, "device_1": {0: 1}}
        for f in (5, 7):
            e = r.device_frames["device_0"][f]
            r.device_frames["device_0"][f] = e._replace(position=(f + 5.0, 0.0, 0.0))
        in_final = maps.frames_of(r, "device_0", 1)
        self.assertEqual([f for f in range(8) if in_final.device(f)], [0, 1, 2, 3, 4])
        self.assertEqual([f for f in range(8) if in_final.server(f)], [2, 3])
        estimates = {}
        with tempfile.TemporaryDirectory() as tmp:
            write_dataset(os.path.join(tmp, "d"), 8)

            def ate(gt, est, env, sim3):
                with open(est) as f:
                    estimates[os.path.basename(est)] = [l.split()[1] for l in f
                                                        if not l.startswith("#")]
                return 0.0

            s = ev.device_summary("device_0", os.path.join(tmp, "d"), r, tmp, {},
                                  ate_rmse=ate, final=1)
        # The device's own trajectory keeps its tracked frames in map 1 only (2, 3 and 4).
        self.assertEqual([float(x) for x in estimates["device_0_device.txt"]], [2.0, 3.0, 4.0])
        self.assertEqual(s["server_poses_other_maps"], 2)
        self.assertEqual(s["device_vs_server_frames"], 2)

    def test_a_device_never_in_the_final_map_is_measured_in_its_own(self):
        # device_0 tracks in map 2 all along (never merged); device_1 and device_2 end in
        # map 1, the session's final map.
        r = records()
        r.server_maps = {"device_0": {f: 2 for f in range(2, 6)}, "device_1": {0: 1},
                         "device_2": {0: 1}}
        final = maps.final_map(r, ["device_0", "device_1", "device_2"])
        self.assertEqual(final, 1)
        with tempfile.TemporaryDirectory() as tmp:
            write_dataset(os.path.join(tmp, "d"), 8)
            s = ev.device_summary("device_0", os.path.join(tmp, "d"), r, tmp, {},
                                  ate_rmse=lambda gt, est, env, sim3: 0.0, final=final)
        self.assertEqual((s["final_map"], s["session_final_map"]), (2, 1))
        self.assertEqual(s["graphs_with_pose"], 4)
        self.assertEqual(s["server_poses_other_maps"], 0)
        self.assertEqual(s["device_vs_server_frames"], 4)  # frames 2-5, all in map 2
        full = summary()
        full["per_device"] = {"device_0": s}
        lines = io.StringIO()
        with contextlib.redirect_stdout(lines):
            report.print_summary(full, "/o")
        self.assertIn("device_0: never in the session's final map 1: measured in its own map 2",
                      lines.getvalue())

    def test_the_map_the_device_names_decides(self):
        # The merge's graph (frame 4, map 1) reached the device only after it had tracked
        # frame 5 in map 2's coordinates: the device says so (DeviceFrame.map_id).
        r = records()
        r.server_maps = {"device_0": {2: 2, 3: 2, 4: 1, 5: 1}, "device_1": {0: 1}}
        for f, m in ((2, 2), (3, 2), (4, 2), (5, 2), (6, 1), (7, 1)):
            r.device_frames["device_0"][f] = r.device_frames["device_0"][f]._replace(map_id=m)
        in_final = maps.frames_of(r, "device_0", 1)
        self.assertEqual([f for f in range(8) if in_final.device(f)], [6, 7])
        # Without the device's word, the last graph before frame 5 (frame 4's, map 1) decides.
        r = records()
        r.server_maps = {"device_0": {2: 2, 3: 2, 4: 1, 5: 1}, "device_1": {0: 1}}
        in_final = maps.frames_of(r, "device_0", 1)
        self.assertEqual([f for f in range(8) if in_final.device(f)], [5, 6, 7])

    def test_planes_of_merged_maps_are_counted_apart(self):
        # device_0 held planes 3 and 5 in its map 2 before the merge (and dropped them with
        # it); plane 4 came with a new version in map 1; plane 6 predates map ids.
        r = records()
        r.server_maps = {"device_0": {2: 2, 4: 1}, "device_1": {0: 1}}
        r.planes = {3: {"id": 3, "map": 2}, 4: {"id": 4, "map": 1}, 5: {"id": 5, "map": 2},
                    6: {"id": 6}}
        r.removed_planes = {7}
        with mock.patch.object(structure.plane_metrics, "check_planes",
                               side_effect=lambda planes, scene, sim: {"checked": planes}), \
                mock.patch.object(structure, "_read_scene", return_value={}):
            result = structure.evaluate_planes(types.SimpleNamespace(scene="s.yaml"),
                                               ["device_0", "device_1"], r, ("sim", {}))
        self.assertEqual([p["id"] for p in result["checked"]], [4, 6])
        self.assertEqual((result["other_maps"], result["removed"]), (2, 1))

    def test_records_without_map_ids_are_one_map(self):
        r = records()
        self.assertIsNone(maps.final_map(r, ["device_0"]))
        in_final = maps.frames_of(r, "device_0", None)
        self.assertTrue(in_final.server(3) and in_final.device(3))


class OverallTest(unittest.TestCase):
    def test_medians_and_bytes_per_point(self):
        o = ev.overall_summary(["device_0"], records())
        self.assertEqual(o["round_trips"], 3)
        self.assertEqual(o["local_graph_bytes_median"], 2000)
        self.assertEqual(o["latency_ms_median"], 20.0)
        self.assertEqual(o["server_ms_median"], 5.0)
        self.assertEqual((o["upload_ms_median"], o["align_ms_median"],
                          o["server_other_ms_median"], o["download_ms_median"]),
                         (1.0, 2.5, 2.5, 0.5))
        # server_other splits into receive (worker queue, JPEG decoding) and send.
        self.assertEqual((o["receive_ms_median"], o["send_ms_median"]), (1.0, 1.5))
        # The graph without points is left out: 1000/50 and 2000/100.
        self.assertEqual(o["bytes_per_point_median"], 20.0)
        self.assertEqual(o["device_tracking_ms_median"], 9.0)

    def test_scaled_back(self):
        # At time scale 0.25 the link's parts (upload 1 ms, download 0.5 ms) are 4x what
        # they are at real time; the server's 5 ms are not.
        o = ev.overall_summary(["device_0"], records(), time_scale=0.25)
        self.assertEqual(o["latency_ms_median"], 20.0)
        self.assertEqual(o["scaled_back"], {
            "time_scale": 0.25, "latency_ms_median": 5.38, "latency_ms_p95": 7.17,
            "upload_ms_median": 0.25, "download_ms_median": 0.12})
        self.assertNotIn("scaled_back", ev.overall_summary(["device_0"], records()))

    def test_empty_session(self):
        empty = types.SimpleNamespace(device_frames={"a": {}}, metrics=[])
        o = ev.overall_summary(["a"], empty)
        self.assertEqual(o["round_trips"], 0)
        self.assertIsNone(o["latency_ms_median"])


class PacingTest(unittest.TestCase):
    def test_rate_of_the_slowest_device(self):
        # 31 frames at 30 fps = 1 s of data: device a in 2 s, b in 4 s.
        spans = {"a": (31, 10.0, 12.0), "b": (31, 10.0, 14.0), "c": (31, None, None)}
        self.assertAlmostEqual(ev.playback_rate(spans, 30.0), 0.25)
        self.assertIsNone(ev.playback_rate({"a": (5, 3.0, 3.0)}, 30.0))

    def test_note(self):
        p = ev.pacing_summary(1.0, 0.4321, 20.04)
        self.assertEqual(p, {"pacing": "lockstep", "requested_rate": 1.0, "achieved_rate": 0.432,
                             "kept_up": False, "frames_skipped": 0, "wall_seconds": 20.0,
                             "note": "the machine could not keep up at rate 1: the round trips "
                                     "paced playback to 0.43x real time"})
        self.assertEqual(ev.pacing_summary(1.0, 0.97, 20.0, "camera", 31)["note"],
                         "playback kept the requested rate; the devices skipped 31 frames they "
                         "were too busy for")
        self.assertIn("the players paced playback to 0.50x",
                      ev.pacing_summary(1.0, 0.5, 20.0, "camera", 0)["note"])
        self.assertTrue(ev.pacing_summary(0.5, 0.46, 1.0)["kept_up"])
        self.assertEqual(ev.pacing_summary(0.5, 0.46, 1.0)["note"],
                         "playback kept the requested rate")
        self.assertEqual(ev.pacing_summary(1.0, None, 1.0)["achieved_rate"], 0.0)


class FilesTest(unittest.TestCase):
    def test_metrics_csv(self):
        with tempfile.TemporaryDirectory() as tmp:
            ev.write_metrics_csv(tmp, records().metrics)
            with open(os.path.join(tmp, "metrics.csv")) as f:
                rows = list(csv.DictReader(f))
        self.assertEqual(list(rows[0]), ev.METRICS_FIELDS)
        self.assertEqual([(r["device"], r["frame"]) for r in rows],
                         [("device_0", "0"), ("device_0", "4"), ("device_1", "0")])


def summary():
    per = {"uploads": 98, "graphs_received": 97, "graphs_with_pose": 92,
           "tracked_after_first_graph": 1.0, "device_vs_server_rmse_m": 0.00531,
           "device_vs_server_frames": 91, "device_ate_se3_m": 0.0123, "server_ate_se3_m": None}
    return {
        "vo_attach": "grid", "vo_share": "graph",
        "pacing": ev.pacing_summary(1.0, 0.44, 20.0), "per_device": {"device_0": per},
        "overall": {"local_graph_bytes_median": 5772.0, "local_graph_bytes_p95": 7630.4,
                    "bytes_per_point_median": 19.23, "latency_ms_median": 21.8,
                    "latency_ms_p95": 46.44, "server_ms_median": 19.6, "upload_ms_median": 1.2,
                    "receive_ms_median": 4.0, "align_ms_median": 12.5,
                    "send_ms_median": 3.1, "server_other_ms_median": 7.1,
                    "download_ms_median": 0.4},
        "planes": {"planes": 1, "labelled_right": 1, "found": ["floor"], "removed": 2,
                   "other_maps": 1,
                   "detail": [{"id": 1, "label": "floor", "true_surface": "floor",
                               "distance_m": 0.014, "angle_deg": 0.5}]},
        "vo": {"objects": 18, "changes": 293, "success": 1.0, "success_other_devices": 0.5,
               "latency": {"median_ms": 173.3, "median_round_trips": 0.734,
                           "max_round_trips": 1.13},
               "position_agreement": {"max_m": 0.0044, "near_max_m": None, "near_limit_m": 10.0},
               "by_distance": [{"bin": "2-4 m", "success": 1.0, "expected": 58}],
               "by_angle": [{"bin": "0-15 deg", "success": None, "expected": 0}]},
    }


class ReportTest(unittest.TestCase):
    def test_summary_lines(self):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            report.print_summary(summary(), "/o")
        p = "[run_session] "
        self.assertEqual(out.getvalue().splitlines(), [
            p + "the machine could not keep up at rate 1: the round trips paced playback to "
                "0.44x real time",
            p + "device_0: uploads 98, graphs 97 (92 with a pose), device tracked 100.0% after its "
                "first graph, device-vs-server 0.53 cm over 91 frames, ATE device 1.23 cm / "
                "server n/a",
            p + "local graph 5772 B median (p95 7630 B), 19.2 B per tracked point; latency 21.8 ms "
                "median (p95 46.4); server 19.6 ms median",
            p + "latency's parts, medians: upload 1.2 ms, on the server 19.6 ms (receive 4.0: "
                "worker queue and JPEG decoding; align 12.5; send 3.1: composing and "
                "publishing), download 0.4 ms",
            p + "planes: 1, labelled right 1 (floor), 2 removed by the server (fused), 1 left in "
                "merged maps; 1 floor on floor 1.4 cm 0.5 deg",
            p + "VOs (grid attach, graph share): 18 objects, 293 changes; success 100.0% overall, "
                "50.0% on other devices; change -> held on another device 173.3 ms median (0.73 "
                "round trips, max 1.13); position agreement 0.44 cm max (n/a max from within "
                "10 m)",
            p + "  by_distance: 2-4 m 100.0% (58)",
            p + "  by_angle: 0-15 deg n/a (0)",
            p + "wrote /o/summary.json and /o/metrics.csv"])

    def test_link_line(self):
        profile = links.LinkProfile("campus", down_bytes_per_s=4e6, up_bytes_per_s=2e6)
        s = summary()
        s["link"] = ev.link_summary(profile, {"down": 3000000, "up": 8000000}, 10.0)
        self.assertEqual((s["link"]["down_utilisation"], s["link"]["up_utilisation"]),
                         (0.075, 0.4))
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            report.print_summary(s, "/o")
        self.assertEqual(out.getvalue().splitlines()[1],
                         "[run_session] link campus: down 3.00 MB (7.5% of 4.00 MB/s), up 8.00 "
                         "MB (40.0% of 2.00 MB/s) over the session")
        # Loopback: the profile only, no line.
        loop = ev.link_summary(links.LinkProfile("loopback", shaped=False), None, 10.0)
        self.assertEqual(loop, {"profile": "loopback", "description": "", "shaped": False,
                                "time_scale": 1.0})
        # Scaled time: the scaled rates, the utilisation as at real time.
        half = ev.link_summary(profile.scaled(0.5), {"down": 1500000, "up": 4000000}, 20.0,
                               time_scale=0.5)
        self.assertEqual((half["time_scale"], half["up_bytes_per_s"], half["up_utilisation"]),
                         (0.5, 1e6, 0.2))

    def test_progress_line(self):
        line = report.progress_line(20.4, {"device_0": 64, "device_2": 60},
                                    {"device_0": 120, "device_2": 120},
                                    {"device_0": 16, "device_2": 15},
                                    {"device_0": 15, "device_2": 14}, 0.4512)
        self.assertEqual(line, "20 s: frames 124/240, uploads 31 (device_0 16, device_2 15), "
                               "local graphs 29, playback 0.45x real time")
        line = report.progress_line(5.0, {"a": 0}, {"a": 40}, {"a": 0}, {"a": 0}, None)
        self.assertEqual(line, "5 s: frames 0/40, uploads 0 (a 0), local graphs 0, "
                               "playback n/a real time")


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "session_evaluating", "__main__")
