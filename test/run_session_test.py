#!/usr/bin/python3
"""End to end: `rosrun ecar_sim run_session` with real processes on tiny sessions.

- Relative paths (--scene, --datasets, --out) from another directory than the repository:
  the 40-frame session of device_0 renders its dataset where the user stands, completes, and
  the device gets local graphs (the players used to die at once on a relative --datasets).
- Two light devices (--light) play their uploads from the JPEG cache and get every graph.
- A dataset folder the player cannot read (camera.yaml broken, the rest as run_session
  reuses it): the session ends within 30 s with exit status 2 and an error naming the player
  and quoting its log (it used to wait ~3 minutes and report "could not keep up").

Each case takes about 20 s (2 cores). Results: build/test_results/e2e/python-run_session.xml
(counted by scripts/test.sh) unless --gtest_output=xml:FILE is given.
"""

import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src", "ecar_sim", "python"))
from ecar_sim.session.datasets import dataset_folder, scene_digest  # noqa: E402

SCENE = os.path.join(ROOT, "config", "scenes", "corridor.yaml")
FRAMES = 40


def run_session(cwd, args, timeout):
    """(exit status, output lines, seconds) of run_session started in cwd."""
    started = time.time()
    r = subprocess.run(["rosrun", "ecar_sim", "run_session"] + args, cwd=cwd,
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                       timeout=timeout)
    sys.stdout.write(r.stdout)
    return r.returncode, r.stdout.splitlines(), time.time() - started


class RunSessionTest(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="run_session_test_")
        self.cwd = os.path.join(self.tmp, "here")
        os.makedirs(self.cwd)

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_relative_paths(self):
        scene = os.path.relpath(SCENE, self.cwd)
        self.assertTrue(scene.startswith(".."), scene)
        code, lines, seconds = run_session(self.cwd, [
            "--scene", scene, "--device-names", "device_0", "--frames", str(FRAMES),
            "--datasets", "datasets", "--out", "session"], timeout=120)
        self.assertEqual(code, 0, "run_session failed after %.0f s" % seconds)
        out = os.path.join(self.cwd, "session")
        dataset = dataset_folder(os.path.join(self.cwd, "datasets"), "corridor", "device_0",
                                 FRAMES)
        self.assertTrue(os.path.isfile(os.path.join(dataset, "groundtruth.txt")))
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
        d0 = summary["per_device"]["device_0"]
        self.assertEqual(d0["dataset"], dataset)
        self.assertEqual(summary["scene"], SCENE)
        self.assertGreater(d0["frames"], FRAMES // 2)
        self.assertGreater(d0["uploads"], 0)
        self.assertGreater(d0["graphs_received"], 0)
        for name in ("metrics.csv", "vo_raw.json.gz", "traj/device_0_server.txt",
                     "logs/device_0_player.log", "logs/server.log", "session_players.launch"):
            self.assertTrue(os.path.exists(os.path.join(out, name)), name)
        self.assertIn("[run_session] wrote %s/summary.json and %s/metrics.csv" % (out, out), lines)
        self.assertFalse(any("error" in line for line in lines), lines)
        # CPU times, on each thread's own clock: every upload costs the server and the device
        # some, and the server's stages run one after another within its wall time.
        with open(os.path.join(out, "metrics.csv")) as f:
            rows = list(csv.DictReader(f))
        self.assertGreater(len(rows), 0)
        for r in rows:
            server_cpu, server = float(r["server_cpu_ms"]), float(r["server_ms"])
            self.assertGreater(server_cpu, 0.0, r)
            self.assertLessEqual(server_cpu, server + 0.5, r)
            self.assertGreater(float(r["device_tracking_cpu_ms"]), 0.0, r)
        self.assertGreater(summary["overall"]["server_cpu_ms_median"], 0.0)
        self.assertTrue(any(line.startswith("[run_session] CPU time") for line in lines), lines)

    def test_light_devices(self):
        # Two light devices in one nodelet manager, no players: each plays its dataset's
        # uploads (encoded into <dataset>/jpeg_q70 on first use) and tracks those frames.
        code, lines, seconds = run_session(self.cwd, [
            "--scene", SCENE, "--device-names", "device_0,device_1", "--frames", str(FRAMES),
            "--datasets", "datasets", "--out", "session", "--light"], timeout=150)
        self.assertEqual(code, 0, "run_session failed after %.0f s" % seconds)
        with open(os.path.join(self.cwd, "session", "summary.json")) as f:
            summary = json.load(f)
        self.assertTrue(summary["light"])
        for name in ("device_0", "device_1"):
            d = summary["per_device"][name]
            # Every 4th frame of 40, each uploaded and answered (the session starts once
            # the devices are joined to the server).
            self.assertEqual(d["uploads"], FRAMES // 4, name)
            self.assertEqual(d["frames"], FRAMES // 4, name)
            self.assertIsNone(d["frames_skipped"])
            self.assertEqual(d["graphs_received"], FRAMES // 4, name)
            cache = os.path.join(d["dataset"], "jpeg_q70")
            self.assertEqual(len(os.listdir(cache)), FRAMES // 4, cache)
        self.assertFalse(os.path.exists(os.path.join(self.cwd, "session",
                                                     "session_players.launch")))
        self.assertIn("[run_session] server up; playing 2 light device(s)", lines)

    def test_a_player_that_dies_ends_the_session(self):
        # A dataset as run_session reuses it (frames, ground truth, scene digest) whose camera
        # file the player cannot read: it dies on start.
        datasets = os.path.join(self.tmp, "broken")
        folder = dataset_folder(datasets, "corridor", "device_0", FRAMES)
        os.makedirs(folder)
        with open(os.path.join(folder, "rgb.txt"), "w") as f:
            f.writelines("%.6f rgb/%06d.png\n" % (i / 30.0, i) for i in range(FRAMES))
        with open(os.path.join(folder, "groundtruth.txt"), "w") as f:
            f.writelines("%.6f 0 0 0 0 0 0 1\n" % (i / 30.0) for i in range(FRAMES))
        with open(os.path.join(folder, "camera.yaml"), "w") as f:
            f.write("this is not a camera file\n")
        with open(os.path.join(folder, "scene.sha256"), "w") as f:
            f.write(scene_digest(SCENE, "device_0") + "\n")

        code, lines, seconds = run_session(self.cwd, [
            "--scene", SCENE, "--device-names", "device_0", "--frames", str(FRAMES),
            "--datasets", datasets, "--out", "session"], timeout=90)
        self.assertEqual(code, 2)
        self.assertLess(seconds, 30.0)
        log = os.path.join(self.cwd, "session", "logs", "device_0_player.log")
        errors = [line for line in lines if line.startswith("[run_session] error: ")]
        self.assertEqual(len(errors), 1, lines)
        self.assertIn("the player of device_0 died (node device_0_player exited with code 1)",
                      errors[0])
        self.assertIn(log, errors[0])
        # The end of its log is quoted: the player's own fatal error about its dataset.
        quoted = lines[lines.index(errors[0]) + 1:]
        self.assertTrue(any("FATAL" in line and "device_0_player" in line and folder in line
                            for line in quoted), quoted)
        self.assertIn("[device_0_player-1] process has died", quoted[-1])
        self.assertFalse(any("could not keep up" in line for line in lines))
        self.assertFalse(os.path.exists(os.path.join(self.cwd, "session", "summary.json")))


if __name__ == "__main__":
    import rosunit
    argv = sys.argv
    if not any(a.startswith("--gtest_output=") for a in argv):
        argv = argv + ["--gtest_output=xml:" + os.path.join(
            ROOT, "build", "test_results", "e2e", "python-run_session.xml")]
    rosunit.unitrun("ecar_sim", "run_session_e2e", RunSessionTest, sysargs=argv)
