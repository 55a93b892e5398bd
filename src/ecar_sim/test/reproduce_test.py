#!/usr/bin/python3
"""ecar_sim.reproduce without running sessions: the E2/E3 report section and plots from rows
as scaling.run_point makes them from summary.json."""

import os
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "python"))
from ecar_sim.reproduce import plots, scaling  # noqa: E402


def row(mode, devices, latency):
    r = {k: 1.0 for k in scaling.FIELDS}
    r.update(mode=mode, devices=devices, latency_scaled_ms_median=latency,
             latency_ms_median=4 * latency, latency_ms_p95=8 * latency, up_utilisation=0.25,
             upload_bytes_median=49000)
    return r


class ReproduceTest(unittest.TestCase):
    def test_section_has_every_point_and_the_papers(self):
        rows = [row("ecar", 1, 23.2), row("ecar", 20, 393.8), row("edgeslam", 1, 42.5)]
        text = scaling.section(rows, 200, 0.25, 70)
        self.assertIn("| ecar | 1 | 23.2 | 92.8 | 185.6 | 25% | 49000 | 53 |", text)
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
        self.assertIn("| edgeslam | 20 | 200.0 | 800.0 | 1600.0 | 25% | 49000 | 111 |", text)
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


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "reproduce", ReproduceTest)
