#!/usr/bin/python3
"""Tests of run_session's command line (python/ecar_sim/session/options.py): every path flag
is resolved where the user stands, defaults and checks are as documented."""

import contextlib
import io
import os
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_sim.session import options  # noqa: E402


def parse(argv, cwd="/home/user/work"):
    return options.parse_args(argv, cwd=cwd)


class PathTest(unittest.TestCase):
    def test_relative_paths_are_resolved_against_the_given_directory(self):
        a = parse(["--scene", "config/scenes/corridor.yaml", "--datasets", "out/demo/datasets",
                   "--out", "../sessions/./s1", "--server-config", "cfg/server.yaml"])
        self.assertEqual(a.scene, "/home/user/work/config/scenes/corridor.yaml")
        self.assertEqual(a.datasets, "/home/user/work/out/demo/datasets")
        self.assertEqual(a.out, "/home/user/sessions/s1")
        self.assertEqual(a.server_config, "/home/user/work/cfg/server.yaml")

    def test_absolute_paths_stay(self):
        a = parse(["--scene", "/data/scene.yaml", "--out", "/tmp/s/"])
        self.assertEqual((a.scene, a.out), ("/data/scene.yaml", "/tmp/s"))

    def test_current_directory_by_default(self):
        here = os.getcwd()
        with tempfile.TemporaryDirectory() as tmp:
            try:
                os.chdir(tmp)
                a = options.parse_args(["--scene", "s.yaml", "--out", "o"])
                self.assertEqual(a.out, os.path.join(os.getcwd(), "o"))
                self.assertEqual(a.scene, os.path.join(os.getcwd(), "s.yaml"))
            finally:
                os.chdir(here)

    def test_every_path_flag_is_resolved(self):
        parser = options.build_parser()
        dests = {a.dest for a in parser._actions}
        for name in options.PATH_FLAGS:
            self.assertIn(name, dests)

    def test_defaults(self):
        a = parse(["--scene", "s.yaml", "--out", "o"])
        self.assertEqual(a.server_config, "")  # empty stays empty: config/server.yaml
        self.assertEqual(a.datasets, os.path.join(options.REPO_ROOT, "out", "datasets"))
        self.assertTrue(os.path.isfile(os.path.join(options.REPO_ROOT, "launch", "server.launch")))
        self.assertEqual((a.devices, a.every, a.jpeg_quality, a.rate, a.frames, a.in_flight,
                          a.workers, a.sync_mode, a.vo_attach, a.vo_share, a.vo_range),
                         (1, 4, 70, 1.0, 0, 1, 2, "ecar", "grid", "graph", 40.0))

    def test_reevaluate_needs_only_out(self):
        a = parse(["--reevaluate", "--out", "out/s"])
        self.assertTrue(a.reevaluate)
        self.assertEqual(a.out, "/home/user/work/out/s")


class CheckTest(unittest.TestCase):
    def assert_usage_error(self, argv, text):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), self.assertRaises(SystemExit) as cm:
            parse(argv)
        self.assertEqual(cm.exception.code, 2)
        self.assertIn(text, err.getvalue())

    def test_bad_values_name_the_flag(self):
        base = ["--scene", "s.yaml", "--out", "o"]
        self.assert_usage_error(["--out", "o"], "--scene is required")
        self.assert_usage_error(base + ["--devices", "0"], "--devices")
        self.assert_usage_error(base + ["--every", "0"], "--every")
        self.assert_usage_error(base + ["--jpeg-quality", "101"], "--jpeg-quality")
        self.assert_usage_error(base + ["--rate", "0"], "--rate")
        self.assert_usage_error(base + ["--frames", "-5"], "--frames")
        self.assert_usage_error(base + ["--sync-mode", "other"], "--sync-mode")
        self.assert_usage_error(["--scene", "s.yaml"], "--out")


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "session_options", "__main__")
