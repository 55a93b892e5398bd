#!/usr/bin/python3
"""End to end: `scripts/reproduce.sh --quick` (all eight experiments, real sessions on network
namespaces and the SLAM core offline) into a temporary folder, so the reproduction cannot rot.

Checks what each experiment must show, not only that files exist:
- E1: eCAR's local graph is smaller than edgeSLAM's; E2/E3: every point has a latency and
  its five parts; the campus uplink carried bytes.
- E4: every quality has a finite ATE, and quality 100 tracks at least as many uploads as 10.
- E5: the device tracked frames and has a device-vs-server error in both modes.
- E6: VOs drawn by light devices reached the other devices, through the graph and direct.
- E7: the half circle's bins for both attachments.
- E8: every artist holds every accepted VO at the end, the montage is a real PNG, the
  devices draw the VOs within 2 cm of each other, and every plane lies within 5 cm of its
  surface.
Needs root (network namespaces); about 10 minutes on 2 cores. Results:
build/test_results/e2e/python-reproduce_quick.xml (counted by scripts/test.sh).
"""

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src", "ecar_sim", "python"))
from ecar_sim.reproduce.table import parse_rows  # noqa: E402


class ReproduceQuickTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.out = tempfile.mkdtemp(prefix="reproduce_quick_")
        started = time.time()
        r = subprocess.run(["bash", os.path.join(ROOT, "scripts", "reproduce.sh"), "--quick",
                            "--out", cls.out], stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, timeout=1500)
        cls.seconds = time.time() - started
        cls.code, cls.output = r.returncode, r.stdout
        sys.stdout.write(r.stdout)
        print("reproduce.sh --quick: exit %d after %.0f s" % (cls.code, cls.seconds))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.out, ignore_errors=True)

    def rows(self, name):
        self.assertEqual(self.code, 0, self.output[-3000:])
        return parse_rows(os.path.join(self.out, name))

    def test_report_has_every_experiment(self):
        self.assertEqual(self.code, 0, self.output[-3000:])
        with open(os.path.join(self.out, "REPORT.md")) as f:
            report = f.read()
        for n in range(1, 9):
            self.assertIn("## E%d:" % n, report)
        self.assertNotIn("Not in this folder", report)
        for png in ("e2_latency", "e3_parts", "e4_quality", "e5_device_vs_server",
                    "e6_vo_latency", "e7_success", "e8_montage"):
            with open(os.path.join(self.out, png + ".png"), "rb") as f:
                self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n", png)

    def test_traffic_and_latency(self):
        rows = self.rows("e2_e3.csv")
        one = {r["mode"]: r for r in rows if r["devices"] == 1}
        self.assertLess(one["ecar"]["local_graph_bytes_median"],
                        one["edgeslam"]["local_graph_bytes_median"])
        for r in rows:
            for key in ("latency_scaled_ms_median", "upload_ms_median", "receive_ms_median",
                        "align_ms_median", "send_ms_median", "download_ms_median"):
                self.assertIsNotNone(r[key], (r["mode"], r["devices"], key))
            self.assertGreater(r["up_utilisation"], 0.0)

    def test_quality(self):
        rows = self.rows("e4_quality.csv")
        for r in rows:
            self.assertTrue(r["ate_rmse_m"] is not None and math.isfinite(r["ate_rmse_m"]), r)
        for seq in {r["sequence"] for r in rows}:
            by_q = {r["quality"]: r for r in rows if r["sequence"] == seq}
            self.assertGreaterEqual(by_q[100]["tracked"], by_q[10]["tracked"], seq)
            self.assertGreater(by_q[100]["jpeg_bytes_median"], by_q[10]["jpeg_bytes_median"])

    def test_device_accuracy(self):
        rows = self.rows("e5_device_vs_server.csv")
        self.assertEqual({r["mode"] for r in rows}, {"ecar", "edgeslam"})
        for r in rows:
            self.assertGreater(r["frames_tracked_on_device"], 0, r)
            self.assertIsNotNone(r["device_vs_server_rmse_m"], r)

    def test_vo_latency(self):
        rows = self.rows("e6_vo_latency.csv")
        self.assertEqual({r["share"] for r in rows}, {"graph", "direct"})
        for r in rows:
            self.assertGreater(r["vo_changes_measured"] or 0, 0, r)
            self.assertIsNotNone(r["vo_latency_ms_median"], r)

    def test_vo_success(self):
        rows = self.rows("e7_success.csv")
        self.assertEqual({r["attach"] for r in rows}, {"grid", "keyframe"})
        self.assertTrue(all(r["by"] == "by_angle" for r in rows))

    def test_drawing(self):
        rows = self.rows("e8_drawing.csv")
        self.assertEqual(len(rows), 4)
        accepted = rows[0]["objects_accepted"]
        self.assertGreaterEqual(accepted, 30)
        for r in rows:
            self.assertEqual(r["objects_held_at_end"], accepted, r["device"])
        self.assertLess(rows[0]["agreement_max_m"], 0.02)
        # The strokes lie on the floor: no plane 5-16 cm above it ("a second floor" from the
        # depth noise took them in 4 of 10 runs, and the next artist's touch dragged them).
        with open(os.path.join(self.out, "runs", "e8_artists", "summary.json")) as f:
            planes = json.load(f)["planes"]["detail"]
        self.assertTrue(planes)
        for p in planes:
            self.assertLess(p["distance_m"], 0.05, p)


if __name__ == "__main__":
    import rosunit
    if os.geteuid() != 0:
        print("reproduce_quick_test: skipped: needs root for the network namespaces")
        sys.exit(0)
    argv = sys.argv
    if not any(a.startswith("--gtest_output=") for a in argv):
        argv = argv + ["--gtest_output=xml:" + os.path.join(
            ROOT, "build", "test_results", "e2e", "python-reproduce_quick.xml")]
    rosunit.unitrun("ecar_sim", "reproduce_quick", ReproduceQuickTest, sysargs=argv)
