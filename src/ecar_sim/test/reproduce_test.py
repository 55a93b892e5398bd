#!/usr/bin/python3
"""ecar_sim.reproduce without running sessions: the E2/E3 report section and plots from rows
as scaling.run_point makes them from summary.json."""

import os
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "python"))
from ecar_sim.reproduce import __main__ as cli  # noqa: E402
from ecar_sim.reproduce import accuracy, drawing, objects, plots, scaling  # noqa: E402
from ecar_sim.reproduce.table import parse_rows, write_rows  # noqa: E402


def row(mode, devices, latency):
    r = {k: 1.0 for k in scaling.FIELDS}
    r.update(mode=mode, devices=devices, latency_scaled_ms_median=latency,
             latency_ms_median=4 * latency, latency_ms_p95=8 * latency, up_utilisation=0.25,
             upload_bytes_median=49000, upload_quality_median=70, server_ate_cm_median=1.5)
    return r


class ReproduceTest(unittest.TestCase):
    def test_section_has_every_point_and_the_papers(self):
        rows = [row("ecar", 1, 23.2), row("ecar", 20, 393.8), row("edgeslam", 1, 42.5)]
        text = scaling.section(rows, 200, 0.25, 70)
        self.assertIn("| ecar | 1 | 23.2 | 92.8 | 185.6 | 25% | 49000 | 70 | 1.50 | 53 |", text)
        self.assertIn("| ecar | 20 | 393.8 |", text)
        self.assertIn("| 69 |", text)
        self.assertIn("| edgeslam | 1 | 42.5 |", text)
        self.assertIn("scaled time at rate 0.25", text)
        self.assertIn("![E2](e2_latency.png)", text)

    def test_traffic_of_one_device_in_each_mode(self):
        rows = [row("ecar", 1, 23.2), row("edgeslam", 1, 42.5), row("ecar", 5, 40.0)]
        rows[0]["local_graph_bytes_median"] = 5835
        rows[1]["local_graph_bytes_median"] = 97780
        text = scaling.traffic_section(rows)
        self.assertIn("| eCAR | 5835 | 49000 |", text)
        self.assertIn("| edgeSLAM | 97780 | 49000 |", text)
        self.assertIn("edgeSLAM's local graph is 16.8x eCAR's", text)
        self.assertEqual(scaling.traffic_section(rows[:1]), "")

    def test_report_again_from_the_csv(self):
        rows = [row(m, n, 10.0 * n) for m in ("ecar", "edgeslam") for n in (1, 20)]
        for r in rows:
            r.update(frames=200, jpeg_quality=70, time_scale=0.25)
        with tempfile.TemporaryDirectory() as tmp:
            import csv
            with open(os.path.join(tmp, "e2_e3.csv"), "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=scaling.FIELDS)
                w.writeheader()
                w.writerows(rows)
            text = scaling.report(tmp)
            self.assertTrue(os.path.exists(os.path.join(tmp, "e2_latency.png")))
        self.assertIn("| edgeslam | 20 | 200.0 | 800.0 | 1600.0 | 25% | 49000 | 70 | 1.50 | 111 |",
                      text)
        self.assertIn("200 frames each (every 4th uploaded at JPEG 70)", text)

    def test_plots_are_written(self):
        rows = [row(m, n, 10.0 * n) for m in ("ecar", "edgeslam") for n in (1, 5, 20)]
        with tempfile.TemporaryDirectory() as tmp:
            for name, draw in (("e2.png", lambda p: plots.latency_vs_devices(
                    rows, scaling.PAPER_LATENCY, p)), ("e3.png", lambda p: plots.parts_vs_devices(
                    rows, p))):
                path = os.path.join(tmp, name)
                draw(path)
                with open(path, "rb") as f:
                    self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
                self.assertGreater(os.path.getsize(path), 10000)


    def test_quality_section_and_csv_round_trip(self):
        rows = [{"sequence": "kitti07", "quality": q, "jpeg_bytes_median": 1000.0 * q,
                 "uploads": 80, "tracked": 78 if q > 10 else 60, "ate_rmse_m": 0.0025 * (110 - q),
                 "alignment": "sim3", "frames": 80, "every": 1} for q in (100, 50, 10)]
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "e4.csv")
            write_rows(path, accuracy.E4_FIELDS, rows)
            back = parse_rows(path)
        self.assertEqual(back[1]["quality"], 50)
        self.assertAlmostEqual(back[2]["ate_rmse_m"], 0.25)
        text = accuracy.quality_section(back)
        self.assertIn("| kitti07 | 100 | 100.0 | 78 / 80 | 2.50 |", text)
        self.assertIn("| kitti07 | 10 | 10.0 | 60 / 80 | 25.00 |", text)

    def test_device_section_has_both_modes(self):
        rows = [{"sequence": "corridor", "mode": m, "frames": 200, "frames_tracked_on_device": 160,
                 "device_vs_server_rmse_m": 0.0044 if m == "ecar" else 0.0051,
                 "device_vs_server_max_m": 0.02, "device_ate_sim3_m": None,
                 "server_ate_sim3_m": 0.01, "local_graph_bytes_median": 5800.0,
                 "latency_ms_median": 12.0} for m in ("ecar", "edgeslam")]
        text = accuracy.device_section(rows)
        self.assertIn("| corridor | ecar | 160 / 200 | 0.44 | 2.00 | - | 1.00 | 5800 |", text)
        self.assertIn("| corridor | edgeslam | 160 / 200 | 0.51 |", text)

    def test_vo_latency_rows_scale_back_and_name_the_paper(self):
        r = row("ecar", 20, 100.0)
        r.update(vo_latency_ms_median=240.0, vo_latency_ms_p95=400.0, vo_changes_measured=50,
                 vo_never_received=1, time_scale=0.25, frames=160)
        graph = objects.vo_row("graph", r)
        self.assertEqual(graph["vo_latency_scaled_ms_median"], 60.0)
        text = objects.latency_section([graph, objects.vo_row("direct", r)])
        self.assertIn("| graph | 20 | 60.0 | 240.0 | 400.0 | 50 | 1 | 69 |", text)
        self.assertIn("| direct | 20 | 60.0 | 240.0 | 400.0 | 50 | 1 | 494 |", text)
        # A session in which no VO reached another device has no latency, not a crash.
        r.update(vo_latency_ms_median=None)
        self.assertIn("| graph | 20 | - | - |", objects.latency_section([objects.vo_row("graph", r)]))

    def test_success_section_and_plot(self):
        rows = [{"scenario": "half_circle", "attach": a, "by": "by_angle", "bin": b,
                 "bin_start": float(b.split("-")[0]), "success": s, "expected": 40,
                 "overall_success": 0.9, "playback_rate": 0.5}
                for a, s0 in (("grid", 1.0), ("keyframe", 0.5))
                for b, s in (("0-15 deg", s0), ("90-105 deg", s0 - 0.4))]
        text = objects.success_section(rows)
        self.assertIn("| half_circle | keyframe | 90-105 deg | 10% | 40 | 90% |", text)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "e7.png")
            plots.vo_success(rows, path)
            self.assertGreater(os.path.getsize(path), 10000)

    def test_drawing_section_without_views(self):
        rows = [{"device": "artist_%d" % k, "objects_held_at_end": 40, "objects_accepted": 40,
                 "tracked_after_first_graph": 1.0, "device_vs_server_rmse_m": 0.0016,
                 "agreement_max_m": 0.001, "agreement_near_max_m": 0.001,
                 "success_other_devices": 1.0, "vo_latency_ms_median": 85.0,
                 "playback_rate": 0.5, "view": None} for k in range(4)]
        with tempfile.TemporaryDirectory() as tmp:
            write_rows(os.path.join(tmp, "e8_drawing.csv"), drawing.FIELDS, rows)
            text = drawing.report(tmp)
            self.assertFalse(os.path.exists(os.path.join(tmp, "e8_montage.png")))
        self.assertIn("(no ar_view frame was recorded)", text)
        self.assertIn("| artist_3 | 40 | 100.0% | 0.16 |", text)
        self.assertIn("0.10 cm at most over all frames", text)

    def test_only_selects_groups_and_refuses_unknown_names(self):
        self.assertEqual([g[0] for g in cli.selected("e4")], [("E4", "E5")])
        self.assertEqual(len(cli.selected("")), 4)
        self.assertEqual([g[0][0] for g in cli.selected("E8,E2")], ["E1", "E8"])
        with self.assertRaises(SystemExit) as e:
            cli.selected("E9")
        self.assertIn("unknown experiment(s) E9", str(e.exception))


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "reproduce", ReproduceTest)
