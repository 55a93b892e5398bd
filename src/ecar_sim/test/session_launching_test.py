#!/usr/bin/python3
"""Tests of the session's child processes (python/ecar_sim/session/launching.py) with fake
children: one that exits, one that is killed, one that reports a dead node the way roslaunch
does and stays up, one that runs until stopped. No ROS master is needed."""

import os
import sys
import tempfile
import time
import types
import unittest
import xml.etree.ElementTree as ET

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_sim.session import launching  # noqa: E402
from ecar_sim.session.options import REPO_ROOT  # noqa: E402

PY = sys.executable
# roslaunch's report when a node of a launch file dies (red, as it prints it).
ROSLAUNCH_DEATH = ("\x1b[31m[device_0_player-1] process has died [pid 27407, exit code 1, cmd "
                   "/ws/devel/lib/ecar_sim/dataset_player __name:=device_0_player].\n"
                   "log file: /ws/logs/x/device_0_player-1*.log\x1b[0m")


def wait_for(predicate, timeout=5.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    return predicate()


class ParseTest(unittest.TestCase):
    def test_roslaunch_reports(self):
        self.assertEqual(launching.parse_death(ROSLAUNCH_DEATH.split("\n")[0]),
                         "node device_0_player exited with code 1")
        self.assertEqual(launching.parse_death(
            "[device_0/device-3] process has died [pid 5, exit code -11, cmd a b]."),
            "node device_0/device was killed by signal 11 (SIGSEGV)")
        self.assertEqual(launching.parse_death("[edge_server-1] process has finished cleanly"),
                         "node edge_server exited with code 0")
        self.assertEqual(launching.parse_death(
            "=" * 80 + "REQUIRED process [edge_server/tracking-4] has died!"),
            "node edge_server/tracking died")

    def test_other_lines(self):
        for line in ["[ INFO] [1796143282.1]: device_0: playing", "",
                     "\x1b[1mprocess[device_0_player-1]: started with pid [27407]\x1b[0m",
                     "all processes on machine have died, roslaunch will exit",
                     "[FATAL] [1796143282.129510235]: /device_0_player: no such folder"]:
            self.assertIsNone(launching.parse_death(line), line)

    def test_describe_exit(self):
        self.assertEqual(launching.describe_exit(3), "exited with code 3")
        self.assertEqual(launching.describe_exit(-9), "was killed by signal 9 (SIGKILL)")


class ChildTest(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.procs = launching.Processes(self.tmp.name)

    def tearDown(self):
        self.procs.stop_all(timeout=5.0)
        self.tmp.cleanup()

    def start(self, name, what, code):
        return self.procs.start(name, what, [PY, "-c", code], dict(os.environ))

    def test_a_child_that_exits_is_named_with_its_log(self):
        self.start("healthy", "a healthy child", "import time; time.sleep(30)")
        child = self.start("player_x", "the player of x",
                           "import sys\nfor i in range(30): print('line %d' % i)\n"
                           "print('FATAL: dataset folder does not exist')\nsys.exit(3)")
        wait_for(lambda: child.proc.poll() is not None)
        with self.assertRaises(launching.ChildDied) as cm:
            self.procs.check()
        self.assertEqual([(c.name, why) for c, why in cm.exception.deaths],
                         [("player_x", "exited with code 3")])
        self.assertIn("the player of x died: exited with code 3", str(cm.exception))
        self.assertIn(child.log_path, str(cm.exception))
        tail = child.tail(5)
        self.assertEqual(tail, ["line 26", "line 27", "line 28", "line 29",
                                "FATAL: dataset folder does not exist"])
        # The log starts with the command line.
        with open(child.log_path) as f:
            self.assertTrue(f.readline().startswith("# %s -c " % PY))

    def test_a_killed_child(self):
        child = self.start("device_y", "device y", "import os, signal\n"
                           "os.kill(os.getpid(), signal.SIGKILL)")
        self.assertEqual(wait_for(child.death), "was killed by signal 9 (SIGKILL)")

    def test_a_node_reported_dead_by_roslaunch(self):
        # roslaunch stays up when one of several nodes dies: the report in its output counts.
        child = self.start("server", "the server",
                           "import sys, time\nprint('started')\nprint(%r, flush=True)\n"
                           "print('shutting down', flush=True)\ntime.sleep(30)" % ROSLAUNCH_DEATH)
        self.assertEqual(wait_for(child.death), "node device_0_player exited with code 1")
        self.assertIsNone(child.proc.poll())
        # The quoted end of the log stops at the report (what follows is roslaunch's shutdown).
        self.assertEqual(child.tail(2), ["started", ROSLAUNCH_DEATH.split("\n")[0][5:]])

    def test_healthy_children_pass_and_stop_at_once(self):
        shell = self.procs.start("shell", "a shell with a child",
                                 ["bash", "-c", "sleep 30; echo not reached"], dict(os.environ))
        self.start("python", "a python child", "import time; time.sleep(30)")
        time.sleep(0.3)
        self.procs.check()
        started = time.time()
        self.procs.stop_all(timeout=5.0)
        self.assertLess(time.time() - started, 3.0)
        for c in self.procs.children:
            self.assertIsNotNone(c.proc.poll(), c.name)
        with self.assertRaises(ProcessLookupError):  # the shell's sleep went with it
            os.killpg(shell.proc.pid, 0)

    def test_every_dead_child_is_reported(self):
        a = self.start("a", "child a", "import sys; sys.exit(1)")
        b = self.start("b", "child b", "import sys; sys.exit(2)")
        wait_for(lambda: a.proc.poll() is not None and b.proc.poll() is not None)
        with self.assertRaises(launching.ChildDied) as cm:
            self.procs.check()
        self.assertEqual([why for _, why in cm.exception.deaths],
                         ["exited with code 1", "exited with code 2"])


class LaunchTest(unittest.TestCase):
    ARGS = types.SimpleNamespace(sync_mode="ecar", workers=2, server_config="", vo_attach="grid",
                                 vo_share="graph", out="/o", every=4, jpeg_quality=70,
                                 in_flight=1, rate=0.5, pacing="lockstep", light=False)
    CAMERA = types.SimpleNamespace(**dict(vars(ARGS), pacing="camera"))

    def test_player_command(self):
        inc = launching.player_include(self.ARGS, "device_0", "/data/corridor_device_0")
        cmd = inc.command()
        self.assertEqual(cmd[0], "roslaunch")
        self.assertIn(os.path.join(REPO_ROOT, "launch", "player.launch"), cmd)
        for arg in ("dataset:=/data/corridor_device_0", "device:=device_0", "rate:=0.5",
                    "pace_by_consumer:=true", "output:=screen"):
            self.assertIn(arg, cmd)

    def test_camera_pacing(self):
        # The player keeps its rate, the device never holds a frame_done.
        player = launching.player_include(self.CAMERA, "device_0", "/d").command()
        self.assertIn("pace_by_consumer:=false", player)
        self.assertIn("rate:=0.5", player)
        self.assertIn("pace_in_flight:=0", launching.device_include(self.CAMERA, "d").command())

    def test_light_devices(self):
        inc = launching.light_devices_include(self.CAMERA, ["device_0", "device_3"],
                                              {"device_0": "/d/0", "device_3": "/d/3"})
        cmd = inc.command()
        self.assertIn(os.path.join(REPO_ROOT, "launch", "light_devices.launch"), cmd)
        for arg in ("devices:=device_0,device_3", "datasets:=/d/0,/d/3", "rate:=0.5",
                    "every:=4", "jpeg_quality:=70", "sync_mode:=ecar"):
            self.assertIn(arg, cmd)

    def test_server_and_device(self):
        server = launching.server_include(self.ARGS)
        self.assertIn("database:=/o/vo.sqlite", server.command())
        self.assertFalse(any(a.startswith("config:=") for a in server.command()))
        cfg = types.SimpleNamespace(**dict(vars(self.ARGS), server_config="/c/s.yaml"))
        self.assertIn("config:=/c/s.yaml", launching.server_include(cfg).command())
        self.assertFalse(any(a.startswith("uplink_capacity:=") for a in server.command()))
        self.assertIn("uplink_capacity:=875000",
                      launching.server_include(self.ARGS, 875000.0).command())
        dev = launching.device_include(self.ARGS, "device_2").command()
        self.assertIn("device:=device_2", dev)
        self.assertIn("pace_in_flight:=1", dev)

    def test_launch_file(self):
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "session_players.launch")
            launching.write_launch(path, [
                launching.player_include(self.ARGS, d, '/data/"odd" & <name>')
                for d in ("a", "b")])
            root = ET.parse(path).getroot()
        includes = root.findall("include")
        self.assertEqual(len(includes), 2)
        args = {a.get("name"): a.get("value") for a in includes[1].findall("arg")}
        self.assertEqual(args["device"], "b")
        self.assertEqual(args["dataset"], '/data/"odd" & <name>')


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "session_launching", "__main__")
