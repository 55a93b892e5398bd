"""Rendered datasets played through the real devices: the end-to-end rostests' common part.

    playback = Playback(scene, player_launch, frames, devices, prefix="ecar_vo_sharing_")
    datasets = playback.render_all()        # make_dataset per device, into a temporary folder
    # subscribe to what the test measures; its callbacks take playback.lock and call
    # playback.activity() so the wait below knows the system is still busy
    playback.start(datasets)                # once /ecar/connect is up (raises when it is not)
    finished = playback.wait(300.0)         # every player finished, then 3 s without activity
    playback.close()                        # tearDown: stops the players, removes the datasets

Or, to start devices at chosen moments whatever their players' preloading takes:

    playback.start(datasets, held=True)     # players preload, then wait
    playback.release(["walker"])            # walker's first frame goes now
    ...                                     # e.g. until walker's first graph is back
    playback.release(["walker_b"])

The players run `player_launch` (ecar_sim's player.launch) paced by their device's consumption, so
a slow machine slows the playback rather than dropping frames.
"""

import os
import shutil
import subprocess
import tempfile
import threading
import time

import rospy
from std_msgs.msg import Bool, Time


class Playback:
    def __init__(self, scene, player_launch, frames, devices, prefix="ecar_playback_"):
        self.scene = scene
        self.player_launch = player_launch
        self.frames = int(frames)
        self.devices = list(devices)
        self.tmp = tempfile.mkdtemp(prefix=prefix)
        self.lock = threading.Lock()
        self.finished = {d: False for d in self.devices}
        self.ready = {d: False for d in self.devices}
        self._starters = {}
        self.last_activity = time.time()
        self.players = []
        self._subscribers = [
            rospy.Subscriber("/%s/player/finished" % d, Bool, self._on_finished, callback_args=d)
            for d in self.devices] + [
            rospy.Subscriber("/%s/player/ready" % d, Bool, self._on_ready, callback_args=d)
            for d in self.devices]

    def _on_finished(self, m, device):
        with self.lock:
            self.finished[device] = self.finished[device] or m.data

    def _on_ready(self, m, device):
        with self.lock:
            self.ready[device] = self.ready[device] or m.data

    def activity(self):
        """Something arrived (call with `lock` held): the wait goes on for 3 s more."""
        self.last_activity = time.time()

    def render(self, device):
        """Renders one device's dataset (its first `frames` frames); returns its folder."""
        out = os.path.join(self.tmp, device)
        subprocess.run(["rosrun", "ecar_sim", "make_dataset", "--scene", self.scene, "--device",
                        device, "--frames", str(self.frames), "--out", out, "--quiet"],
                       check=True, stdout=subprocess.DEVNULL)
        return out

    def render_all(self):
        return {d: self.render(d) for d in self.devices}

    @staticmethod
    def start_topic(device):
        return "/%s/player/start" % device

    def start(self, datasets, connect_timeout=60.0, devices=None, held=False):
        """Starts a player per device (`devices`: these only, default all) once the server's
        /ecar/connect is up (devices connect when their camera_info arrives). `held`: each
        player preloads its frames and waits for `release`. Raises rospy.ROSException when the
        server never came up."""
        rospy.wait_for_service("/ecar/connect", connect_timeout)
        for d in devices or self.devices:
            args = ["roslaunch", self.player_launch, "dataset:=" + datasets[d], "device:=" + d,
                    "pace_by_consumer:=true", "ack_timeout:=5.0", "output:=log"]
            if held:
                self._starters[d] = rospy.Publisher(self.start_topic(d), Time, queue_size=1,
                                                    latch=True)
                args.append("start_topic:=" + self.start_topic(d))
            self.players.append(subprocess.Popen(args, stdout=subprocess.DEVNULL,
                                                 stderr=subprocess.DEVNULL))

    def release(self, devices, ready_timeout=180.0):
        """Starts the held players of `devices` now, once every one of them is ready (has
        preloaded). Raises rospy.ROSException when one is not ready within `ready_timeout` s."""
        deadline = time.time() + ready_timeout
        while not rospy.is_shutdown():
            with self.lock:
                waiting = [d for d in devices if not self.ready[d]]
            if not waiting:
                break
            if time.time() > deadline:
                raise rospy.ROSException("players not ready after %.0f s: %s"
                                         % (ready_timeout, waiting))
            time.sleep(0.05)
        now = rospy.Time.now()
        for d in devices:
            self._starters[d].publish(Time(data=now))

    def wait(self, timeout, quiet=3.0):
        """Waits until every player has finished and nothing arrived for `quiet` seconds, or
        `timeout`; returns which players finished."""
        deadline = time.time() + timeout
        while time.time() < deadline and not rospy.is_shutdown():
            with self.lock:
                if all(self.finished.values()) and time.time() - self.last_activity > quiet:
                    break
            time.sleep(0.5)
        with self.lock:
            return dict(self.finished)

    def close(self):
        for s in self._subscribers:
            s.unregister()
        for p in self.players:
            if p.poll() is None:
                p.terminate()
                p.wait()
        shutil.rmtree(self.tmp, ignore_errors=True)
