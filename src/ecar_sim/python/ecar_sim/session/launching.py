"""The processes of a session: its own ROS master on a free port, the server, each device and
each player as a child process of its own, and their liveness.

Every child runs in its own process group with its output in DIR/logs/<name>.log (the
command line first). The server, a device and a player are each one `roslaunch` of the
repository's launch file (launch/server.launch, device.launch, player.launch) with the
session's args, so those files stay the one place that says how a node is started. A child
has died when its process exited or when roslaunch reported one of its nodes dead
("[<node>-<n>] process has died ..."): Processes.check() raises ChildDied naming it, and the
session ends at once.

    procs = Processes(log_dir)
    procs.start("roscore", "the ROS master", ["roscore", "-p", str(port)], env)
    procs.start("player_device_0", "the player of device_0",
                player_include(args, "device_0", folder).command(), env)
    procs.check()   # raises ChildDied: "the player of device_0 died: node ... exited with code 1"
    procs.stop_all()
"""

import collections
import os
import re
import shlex
import signal
import socket
import subprocess
import time
import xmlrpc.client
from xml.sax.saxutils import escape

from ecar_sim.session.options import REPO_ROOT

# roslaunch's report of a node that ended (roslaunch/pmon.py, nodeprocess.py).
_DEATH = re.compile(r"^=*(?:REQUIRED process )?\[(?P<process>[^\]\s]+)\]"
                    r"(?: has died!| process has died(?P<detail>.*)| process has finished cleanly)")
_EXIT_CODE = re.compile(r"exit code (-?\d+)")
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]|\x1b\][^\x07]*\x07")


def free_port():
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def strip_ansi(text):
    """text without terminal colour and title sequences."""
    return _ANSI.sub("", text)


def describe_exit(code):
    """'exited with code 1' or, for a negative code, 'was killed by signal 11 (SIGSEGV)'."""
    if code is not None and code < 0:
        try:
            name = " (%s)" % signal.Signals(-code).name
        except ValueError:
            name = ""
        return "was killed by signal %d%s" % (-code, name)
    return "exited with code %s" % code


def parse_death(line):
    """What a roslaunch output line says about a node that ended ("node device_0_player exited
    with code 1"), or None when the line is not such a report."""
    m = _DEATH.match(strip_ansi(line).strip())
    if not m:
        return None
    node = re.sub(r"-\d+$", "", m.group("process"))
    code = _EXIT_CODE.search(m.group("detail") or "")
    if code:
        return "node %s %s" % (node, describe_exit(int(code.group(1))))
    if "finished cleanly" in line:
        return "node %s %s" % (node, describe_exit(0))
    return "node %s died" % node


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Child:
    """One child process and its log file. `what` names it for the user ("the player of
    device_0")."""

    def __init__(self, name, what, cmd, env, log_path):
        self.name, self.what, self.log_path = name, what, log_path
        self._out = open(log_path, "w")
        self._out.write("# %s\n" % " ".join(shlex.quote(c) for c in cmd))
        self._out.flush()
        # SIGINT is how children are stopped (stop_all): restore its default action,
        # which a session started in the background of a shell (`run_session ... &`)
        # would otherwise pass on as ignored, leaving every child to be killed.
        self.proc = subprocess.Popen(cmd, env=env, stdout=self._out, stderr=subprocess.STDOUT,
                                     start_new_session=True, preexec_fn=_default_sigint)
        self._scanned = 0  # bytes of the log scanned for roslaunch's reports
        self._reported = None
        self._report_end = None  # where roslaunch's report ends in the log

    def death(self):
        """Why the child (or a node under its roslaunch) is dead, or None while all is well."""
        if self._reported:
            return self._reported
        code = self.proc.poll()  # first: once it has exited, its last lines are in the log
        for end, line in self._new_lines():
            reason = parse_death(line)
            if reason:
                self._reported, self._report_end = reason, end
                return reason
        if code is not None:
            self._reported = describe_exit(code)
        return self._reported

    def _new_lines(self):
        """(end offset, text) of each complete line written since the last call."""
        try:
            with open(self.log_path, "rb") as f:
                f.seek(self._scanned)
                data = f.read()
        except OSError:
            return []
        lines = []
        for raw in data.split(b"\n")[:-1]:  # the last piece is an unfinished line
            self._scanned += len(raw) + 1
            lines.append((self._scanned, raw.decode("utf-8", "replace")))
        return lines

    def tail(self, count=12, width=300):
        """The last `count` non-empty lines of the log (colours removed, cut at `width`), up to
        roslaunch's report of a dead node when there is one (what follows is its shutdown)."""
        try:
            end = self._report_end or os.path.getsize(self.log_path)
            with open(self.log_path, "rb") as f:
                f.seek(max(0, end - 64 * 1024))
                text = f.read(end - f.tell()).decode("utf-8", "replace")
        except OSError:
            return []
        lines = [strip_ansi(line).rstrip() for line in text.split("\n")]
        lines = [line if len(line) <= width else line[:width] + " ..." for line in lines if line]
        return lines[-count:]

    def signal(self, sig):
        """Sends sig to the child's process group while it runs."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                pass

    def close(self):
        """Closes the log file (once the process has ended)."""
        self._out.close()


class ChildDied(RuntimeError):
    """Children of the session ended while it ran: deaths = [(Child, reason)]."""

    def __init__(self, deaths):
        self.deaths = deaths
        super().__init__("; ".join("%s died: %s (log: %s)" % (c.what, why, c.log_path)
                                   for c, why in deaths))


class Processes:
    """The session's children in start order; the first (the ROS master) is stopped last."""

    def __init__(self, log_dir):
        self.log_dir = log_dir
        self.children = []

    def start(self, name, what, cmd, env):
        """Starts cmd as child `name` (log: <log_dir>/<name>.log) and returns the Child."""
        child = Child(name, what, cmd, env, os.path.join(self.log_dir, name + ".log"))
        self.children.append(child)
        return child

    def check(self):
        """Raises ChildDied naming every child that has died (or lost a node)."""
        deaths = [(c, c.death()) for c in self.children]
        deaths = [(c, why) for c, why in deaths if why]
        if deaths:
            raise ChildDied(deaths)

    def stop_all(self, timeout=15.0):
        """SIGINT to every child but the first at once, then to the first; SIGKILL to what
        still runs after `timeout` seconds."""
        for stage in (self.children[1:], self.children[:1]):
            for c in stage:
                c.signal(signal.SIGINT)
            deadline = time.time() + timeout
            for c in stage:
                while c.proc.poll() is None and time.time() < deadline:
                    time.sleep(0.1)
                if c.proc.poll() is None:
                    c.signal(signal.SIGKILL)
                    c.proc.wait()
                c.close()


def wait_for_master(uri, timeout, procs):
    """An XML-RPC proxy of the master at uri once it answers; raises RuntimeError after
    `timeout` seconds and ChildDied when a child dies meanwhile."""
    master = xmlrpc.client.ServerProxy(uri)
    deadline = time.time() + timeout
    while time.time() < deadline:
        procs.check()
        try:
            code, _, _ = master.getSystemState("/run_session")
            if code == 1:
                return master
        except OSError:
            pass
        time.sleep(0.2)
    raise RuntimeError("the ROS master at %s did not come up in %.0f s" % (uri, timeout))


def service_exists(master, name):
    """Whether the master knows the service `name`."""
    code, _, _ = master.lookupService("/run_session", name)
    return code == 1


class Include(collections.namedtuple("Include", "file args")):
    """One launch file of the repository with its args (an ordered list of (name, value))."""

    def command(self):
        """The roslaunch command line that starts it on its own."""
        return (["roslaunch", "--disable-title", "--skip-log-check", self.file] +
                ["%s:=%s" % (k, v) for k, v in self.args])

    def xml(self):
        """The <include> element of a launch file that starts it."""
        lines = ['  <include file="%s">' % escape(self.file, {'"': "&quot;"})]
        lines += ['    <arg name="%s" value="%s"/>' % (k, escape(str(v), {'"': "&quot;"}))
                  for k, v in self.args]
        return "\n".join(lines + ["  </include>"])


def server_include(args, uplink_capacity=None):
    """launch/server.launch with the session's server settings; its VO database in args.out.
    uplink_capacity: bytes/s of the devices' shared uplink (the server gives each device its
    share of it; None: the config file's)."""
    a = [("sync_mode", args.sync_mode), ("workers", "%d" % args.workers)]
    if uplink_capacity is not None:
        a.append(("uplink_capacity", "%.0f" % uplink_capacity))
    if args.server_config:
        a.append(("config", args.server_config))
    # Each session has its own map, so its own VO database (not the user's).
    a += [("vo_attach", args.vo_attach), ("vo_share", args.vo_share),
          ("database", os.path.join(args.out, "vo.sqlite")), ("output", "screen")]
    return Include(os.path.join(REPO_ROOT, "launch", "server.launch"), a)


def device_include(args, device):
    """launch/device.launch for one device of the session."""
    return Include(os.path.join(REPO_ROOT, "launch", "device.launch"), [
        ("device", device), ("every", "%d" % args.every),
        ("jpeg_quality", "%d" % args.jpeg_quality), ("sync_mode", args.sync_mode),
        ("pace_in_flight", "%d" % (args.in_flight if args.pacing == "lockstep" else 0)),
        ("output", "screen")])


# std_msgs/Time, latched: when the light devices of a session start playing, all together.
START_TOPIC = "/ecar/session_start"


def light_devices_include(args, devices, datasets):
    """launch/light_devices.launch: every device of the session as a light device in one
    nodelet manager, each on its dataset (datasets: {device: absolute folder})."""
    return Include(os.path.join(REPO_ROOT, "launch", "light_devices.launch"), [
        ("devices", ",".join(devices)), ("datasets", ",".join(datasets[d] for d in devices)),
        ("every", "%d" % args.every), ("jpeg_quality", "%d" % args.jpeg_quality),
        ("sync_mode", args.sync_mode), ("rate", "%g" % args.rate), ("wait_subscribers", "60"),
        ("start_topic", START_TOPIC), ("output", "screen")])


def player_include(args, device, dataset):
    """launch/player.launch playing `dataset` (an absolute folder) as `device`: at the rate,
    or, with --pacing lockstep, paced by the device's frame_done too."""
    lockstep = "true" if args.pacing == "lockstep" else "false"
    return Include(os.path.join(REPO_ROOT, "launch", "player.launch"), [
        ("dataset", dataset), ("device", device), ("rate", "%g" % args.rate),
        ("world_frame", "world"), ("pace_by_consumer", lockstep), ("ack_timeout", "5.0"),
        ("start_delay", "0.5"), ("wait_subscribers", "30.0"), ("output", "screen")])


def write_launch(path, includes):
    """A launch file of the includes (the session's nodes or players, to run it again by
    hand with roslaunch)."""
    with open(path, "w") as f:
        f.write("\n".join(["<launch>"] + [i.xml() for i in includes] + ["</launch>"]) + "\n")
