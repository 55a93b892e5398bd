"""Hosts on a shared, shaped link: the edge server and the devices as two network namespaces
joined by a veth pair, each end's egress shaped by a tc token bucket filter (config/links/).

    profile = LinkProfile.load("config/links/campus.yaml")
    with Hosts(profile) as hosts:       # needs root; removes leftovers of crashed runs first
        env = hosts.devices.env(hosts.master_uri(11311))
        subprocess.Popen(hosts.devices.wrap(["roslaunch", ...]), env=env)

ROS runs across the namespaces exactly as across two machines: ROS_MASTER_URI names the
server host's address and every node announces its own host's address (ROS_IP). A profile with
`shaped: false` (loopback) makes no namespaces: both hosts are this machine's loopback.
"""

import os
import re
import subprocess

import yaml

PREFIX = "ecar"  # namespaces ecar<pid>s / ecar<pid>d, veth ends ecar<pid>s / ecar<pid>d
SERVER_IP, DEVICES_IP, NETMASK = "10.77.0.1", "10.77.0.2", 30
# The observer link (this machine's own namespace <-> the server host, unshaped): the session
# runner measures from here; it reaches the devices through the server host.
OBSERVER_IP, OBSERVER_PEER_IP = "10.77.1.1", "10.77.1.2"
HOSTS_NET, OBSERVER_NET = "10.77.0.0", "10.77.1.0"
_KEYS = {"description", "shaped", "down_bytes_per_s", "up_bytes_per_s", "burst_bytes",
         "queue_ms"}


class LinkError(RuntimeError):
    """A profile that cannot be read, or hosts that cannot be set up (names what failed)."""


class LinkProfile:
    """One link profile (config/links/README.md documents the keys)."""

    def __init__(self, name, description="", shaped=True, down_bytes_per_s=None,
                 up_bytes_per_s=None, burst_bytes=32000, queue_ms=100):
        self.name, self.description, self.shaped = name, description, bool(shaped)
        self.down_bytes_per_s, self.up_bytes_per_s = down_bytes_per_s, up_bytes_per_s
        self.burst_bytes, self.queue_ms = burst_bytes, queue_ms
        if not self.shaped:
            return
        for key in ("down_bytes_per_s", "up_bytes_per_s", "burst_bytes", "queue_ms"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise LinkError("link profile %s: %s must be a positive number, not %r" %
                                (name, key, value))
        if self.burst_bytes < 1600:
            raise LinkError("link profile %s: burst_bytes %d is below one packet (1600)" %
                            (name, self.burst_bytes))

    def scaled(self, factor):
        """This profile in time scaled by `factor` (a session played at --rate factor): both
        rates times factor, the queue's time over it (so that it holds the same bytes), the
        bucket unchanged (bytes are bytes). Transfers then take 1 / factor as long, as every
        other interval of the session does."""
        if not self.shaped or factor == 1.0:
            return self
        return LinkProfile(self.name, self.description, True,
                           self.down_bytes_per_s * factor, self.up_bytes_per_s * factor,
                           self.burst_bytes, self.queue_ms / factor)

    @staticmethod
    def load(path):
        """The profile in a YAML file; raises LinkError naming the file and the key."""
        name = os.path.splitext(os.path.basename(path))[0]
        try:
            with open(path) as f:
                data = yaml.safe_load(f)
        except (OSError, yaml.YAMLError) as e:
            raise LinkError("link profile %s: %s" % (path, e))
        if not isinstance(data, dict):
            raise LinkError("link profile %s: not a mapping of keys" % path)
        unknown = sorted(set(data) - _KEYS)
        if unknown:
            raise LinkError("link profile %s: unknown key %s (known: %s)" %
                            (path, unknown[0], ", ".join(sorted(_KEYS))))
        return LinkProfile(name, **data)

    @staticmethod
    def find(name_or_path, links_dir):
        """A profile by name (a file in links_dir) or by path."""
        path = name_or_path
        if os.sep not in name_or_path and not name_or_path.endswith(".yaml"):
            path = os.path.join(links_dir, name_or_path + ".yaml")
        if not os.path.isfile(path):
            known = sorted(f[:-5] for f in os.listdir(links_dir) if f.endswith(".yaml"))
            raise LinkError("no link profile %s (known: %s)" % (name_or_path, ", ".join(known)))
        return LinkProfile.load(path)


class Host:
    """One side of the link: its namespace (None on loopback) and address."""

    def __init__(self, netns, ip):
        self.netns, self.ip = netns, ip

    def wrap(self, argv):
        """argv run inside this host's namespace."""
        return (["ip", "netns", "exec", self.netns] + list(argv)) if self.netns else list(argv)

    def env(self, master_uri, base=None):
        """The environment of a ROS process on this host."""
        env = dict(os.environ if base is None else base)
        env["ROS_MASTER_URI"] = master_uri
        env["ROS_IP"] = self.ip
        env.pop("ROS_HOSTNAME", None)  # ROS_HOSTNAME would win over ROS_IP
        return env


def _run(argv, what):
    try:
        r = subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           timeout=20)
    except FileNotFoundError:
        raise LinkError("%s: %s is not installed (iproute2)" % (what, argv[0]))
    except subprocess.TimeoutExpired:
        raise LinkError("%s: '%s' did not return within 20 s" % (what, " ".join(argv)))
    if r.returncode != 0:
        raise LinkError("%s: '%s' failed: %s" % (what, " ".join(argv), r.stderr.strip()))
    return r.stdout


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    return True


def leftover_namespaces():
    """Namespaces of earlier runs whose process is gone (a crashed or killed run)."""
    out = _run(["ip", "netns", "list"], "listing network namespaces")
    left = []
    for line in out.splitlines():
        name = line.split()[0] if line.split() else ""
        m = re.fullmatch(PREFIX + r"(\d+)[sd]", name)
        if m and not _alive(int(m.group(1))):
            left.append(name)
    return sorted(left)


class Hosts:
    """The server and devices hosts of a profile, set up on enter and removed on exit (also
    when the body raises). The namespaces are named after this process's pid, so that a later
    run can tell a crashed run's leftovers (removed on enter) from a live run's; the
    addresses are fixed, so one shaped run at a time per machine (another live one is an
    error). With observer=True this machine's own namespace is a third host (`observer`),
    joined to the server host by an unshaped link and routed through it to the devices: what
    it sends to or gets from the devices crosses the shaped link like the server's traffic."""

    def __init__(self, profile, pid=None, observer=False):
        self.profile = profile
        self.pid = os.getpid() if pid is None else pid
        self._names = ("%s%ds" % (PREFIX, self.pid), "%s%dd" % (PREFIX, self.pid))
        self._observer = observer
        self.removed_leftovers = []
        if profile.shaped:
            self.server, self.devices = Host(self._names[0], SERVER_IP), Host(self._names[1],
                                                                              DEVICES_IP)
            self.observer = Host(None, OBSERVER_IP) if observer else None
        else:
            self.server = self.devices = Host(None, "127.0.0.1")
            self.observer = self.server if observer else None

    def master_uri(self, port):
        return "http://%s:%d" % (self.server.ip, port)

    def __enter__(self):
        if not self.profile.shaped:
            return self
        if os.geteuid() != 0:
            raise LinkError("link %s: network namespaces and tc need root; run as root, or use "
                            "the loopback link" % self.profile.name)
        for name in leftover_namespaces():
            _run(["ip", "netns", "delete", name], "removing a crashed run's namespace")
            self.removed_leftovers.append(name)
        present = _run(["ip", "netns", "list"], "listing network namespaces")
        live = sorted(set(re.findall(PREFIX + r"(\d+)[sd]", present)) - {str(self.pid)})
        if live:
            raise LinkError("link %s: another shaped run (pid %s) holds the link's addresses; "
                            "wait for it to end" % (self.profile.name, live[0]))
        try:
            self._setup()
        except BaseException:
            self._teardown()
            raise
        return self

    def __exit__(self, *exc):
        if self.profile.shaped:
            self._teardown()
        return False

    def _setup(self):
        server, devices = self._names
        for ns in (server, devices):
            _run(["ip", "netns", "add", ns], "creating the host namespace")
        _run(["ip", "link", "add", server, "netns", server, "type", "veth", "peer", "name",
              devices, "netns", devices], "creating the link")
        p = self.profile
        for ns, ip, rate in ((server, SERVER_IP, p.down_bytes_per_s),
                             (devices, DEVICES_IP, p.up_bytes_per_s)):
            inside = ["ip", "netns", "exec", ns]
            _run(inside + ["ip", "link", "set", "lo", "up"], "bringing up loopback in " + ns)
            _run(inside + ["ip", "addr", "add", "%s/%d" % (ip, NETMASK), "dev", ns],
                 "addressing " + ns)
            _run(inside + ["ip", "link", "set", ns, "up"], "bringing up " + ns)
            # The end's egress is the direction's bottleneck: the server sends down, the
            # devices up. tc takes the rate in bits per second.
            _run(inside + ["tc", "qdisc", "add", "dev", ns, "root", "tbf", "rate",
                           "%dbit" % int(rate * 8), "burst", str(int(p.burst_bytes)),
                           "latency", "%dms" % int(p.queue_ms)], "shaping " + ns)
        if self._observer:
            self._setup_observer()

    def _setup_observer(self):
        server, devices = self._names
        mine, peer = "%s%do" % (PREFIX, self.pid), "%s%dm" % (PREFIX, self.pid)
        _run(["ip", "link", "add", mine, "type", "veth", "peer", "name", peer, "netns", server],
             "creating the observer's link")
        _run(["ip", "addr", "add", "%s/%d" % (OBSERVER_IP, NETMASK), "dev", mine],
             "addressing the observer's link")
        _run(["ip", "link", "set", mine, "up"], "bringing up the observer's link")
        inside = ["ip", "netns", "exec", server]
        _run(inside + ["ip", "addr", "add", "%s/%d" % (OBSERVER_PEER_IP, NETMASK), "dev", peer],
             "addressing the observer's link")
        _run(inside + ["ip", "link", "set", peer, "up"], "bringing up the observer's link")
        _run(inside + ["sysctl", "-q", "-w", "net.ipv4.ip_forward=1"],
             "routing through the server host")
        _run(["ip", "route", "add", "%s/%d" % (HOSTS_NET, NETMASK), "via", OBSERVER_PEER_IP],
             "routing the observer to the hosts")
        _run(["ip", "netns", "exec", devices, "ip", "route", "add",
              "%s/%d" % (OBSERVER_NET, NETMASK), "via", SERVER_IP],
             "routing the devices to the observer")

    def _teardown(self):
        present = _run(["ip", "netns", "list"], "listing network namespaces").split()
        for ns in self._names:
            if ns in present:
                _run(["ip", "netns", "delete", ns], "removing the host namespace")

    def counters(self):
        """Bytes sent {"down": server end, "up": devices end} so far (tc's qdisc counters);
        None on loopback."""
        if not self.profile.shaped:
            return None
        out = {}
        for direction, host in (("down", self.server), ("up", self.devices)):
            text = _run(host.wrap(["tc", "-s", "qdisc", "show", "dev", host.netns]),
                        "reading the link's counters")
            m = re.search(r"Sent (\d+) bytes", text)
            out[direction] = int(m.group(1)) if m else 0
        return out
