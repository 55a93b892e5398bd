#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End to end (started by server_restart.test): the server dies and comes back.

The device (started by the launch file) runs throughout. The test node renders
a short corridor sequence, plays it in a loop, starts the server, waits for
aligned local graphs, kills the whole server with SIGKILL (a crash, not a clean
shutdown), starts it again, and asserts that the same device process
reconnects by itself, receives aligned local graphs of the new map (a new map
epoch) and tracks on the device again.

Private params: ~scene, ~server_launch, ~player_launch, ~frames.
"""

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest
from xmlrpc.client import ServerProxy

import rospy
import rostest
from ecar_msgs.msg import DeviceFrame, LocalGraph

PKG = "ecar_sim"
DEVICE = "device_0"


class ServerRestartTest(unittest.TestCase):
    def setUp(self):
        self.scene = rospy.get_param("~scene")
        self.server_launch = rospy.get_param("~server_launch")
        self.player_launch = rospy.get_param("~player_launch")
        self.frames = int(rospy.get_param("~frames", 120))
        self.tmp = tempfile.mkdtemp(prefix="ecar_server_restart_")
        self.lock = threading.Lock()
        self.aligned = {}       # map epoch -> aligned graphs received
        self.tracked_after = 0  # device frames tracked since the mark
        self.mark = None
        self.children = []

    def tearDown(self):
        for p in self.children:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def on_graph(self, m):
        if m.status in (LocalGraph.OK, LocalGraph.RELOCALISED):
            with self.lock:
                self.aligned[m.map_epoch] = self.aligned.get(m.map_epoch, 0) + 1

    def on_frame(self, m):
        with self.lock:
            if self.mark is not None and m.status == DeviceFrame.OK:
                self.tracked_after += 1

    def start(self, args):
        p = subprocess.Popen(["roslaunch"] + args, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
        self.children.append(p)
        return p

    def kill_server_nodes(self):
        """SIGKILLs /edge_server and its nodelet loaders; returns the node names killed."""
        master = rospy.get_master()
        _, _, state = master.getSystemState()
        names = set()
        for group in state:
            for _, providers in group:
                names.update(n for n in providers if n == "/edge_server" or
                             n.startswith("/edge_server/"))
        killed = []
        for name in sorted(names):
            code, _, uri = master.lookupNode(name)
            if code != 1:
                continue
            try:
                _, _, pid = ServerProxy(uri).getPid("/server_restart_test")
                os.kill(pid, signal.SIGKILL)
                killed.append(name)
            except (OSError, ProcessLookupError):
                pass
        return killed

    def wait_for(self, predicate, timeout):
        deadline = time.time() + timeout
        while time.time() < deadline and not rospy.is_shutdown():
            with self.lock:
                if predicate():
                    return True
            time.sleep(0.2)
        return False

    def test_device_realigns_after_server_crash(self):
        data = os.path.join(self.tmp, DEVICE)
        subprocess.run(["rosrun", "ecar_sim", "make_dataset", "--scene", self.scene, "--device",
                        DEVICE, "--frames", str(self.frames), "--out", data, "--quiet"],
                       check=True, stdout=subprocess.DEVNULL)
        rospy.Subscriber("/%s/local_graph" % DEVICE, LocalGraph, self.on_graph, queue_size=100)
        rospy.Subscriber("/%s/device_frame" % DEVICE, DeviceFrame, self.on_frame, queue_size=100)

        server = self.start([self.server_launch, "output:=log", "database:=:memory:"])
        self.start([self.player_launch, "dataset:=" + data, "device:=" + DEVICE, "loop:=true",
                    "pace_by_consumer:=true", "ack_timeout:=1.0", "output:=log"])
        self.assertTrue(self.wait_for(lambda: sum(self.aligned.values()) >= 5, 120.0),
                        "no aligned local graphs before the crash: %s" % self.aligned)
        with self.lock:
            first_epochs = set(self.aligned)

        # A crash: SIGKILL to every server process (roslaunch starts each node in its own
        # process group, so the manager and the nodelet loaders are killed one by one).
        killed = self.kill_server_nodes()
        self.assertIn("/edge_server", killed, "no /edge_server node to kill")
        os.killpg(server.pid, signal.SIGKILL)
        server.wait()
        time.sleep(2.0)
        with self.lock:
            self.mark = time.time()
            self.tracked_after = 0
        self.start([self.server_launch, "output:=log", "database:=:memory:"])

        new_epoch = lambda: any(e not in first_epochs and n >= 5 for e, n in self.aligned.items())
        self.assertTrue(self.wait_for(new_epoch, 120.0),
                        "the device did not re-align with the restarted server: graphs per "
                        "epoch %s (before the crash: %s)" % (self.aligned, first_epochs))
        self.assertTrue(self.wait_for(lambda: self.tracked_after >= 10, 60.0),
                        "the device did not track again after the restart (%d frames)" %
                        self.tracked_after)
        rospy.loginfo("graphs per map epoch: %s; device frames tracked since the restart: %d",
                      self.aligned, self.tracked_after)


if __name__ == "__main__":
    rospy.init_node("server_restart_test")
    rostest.rosrun(PKG, "server_restart", ServerRestartTest, sys.argv)
