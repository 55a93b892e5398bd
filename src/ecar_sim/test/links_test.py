#!/usr/bin/python3
"""Tests of the shared link (python/ecar_sim/links.py, config/links/): profiles and their errors;
with root, real hosts: each direction's rate through its tc bucket, ROS across the two hosts (a
master on the server host, publishers and subscribers on both, as on two machines), that no
namespace outlives a run, a failed one or a crashed one, and a short run_session --link campus
whose uploads and local graphs all cross the link. Without root the host tests skip."""

import csv
import json
import os
import subprocess
import sys
import tempfile
import time
import unittest
from unittest import mock

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_sim import links  # noqa: E402

LINKS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "config",
                         "links")

RECEIVE = r"""
import socket, sys, time
s = socket.socket()
s.bind((sys.argv[1], 5001))
s.listen(1)
print("ready", flush=True)
c, _ = s.accept()
n, t0 = 0, None
while True:
    b = c.recv(65536)
    if not b:
        break
    if t0 is None:
        t0 = time.monotonic()
    n += len(b)
print(n, time.monotonic() - t0, flush=True)
"""
SEND = r"""
import socket, sys
c = socket.create_connection((sys.argv[1], 5001), timeout=20)
c.sendall(b"x" * int(sys.argv[2]))
c.close()
"""


def namespaces():
    out = subprocess.run(["ip", "netns", "list"], stdout=subprocess.PIPE, text=True).stdout
    return {line.split()[0] for line in out.splitlines() if line.split()}


class ProfileTest(unittest.TestCase):
    def test_shipped_profiles(self):
        campus = links.LinkProfile.find("campus", LINKS_DIR)
        self.assertEqual((campus.down_bytes_per_s, campus.up_bytes_per_s), (3980000, 3500000))
        wifi = links.LinkProfile.find("wifi", LINKS_DIR)
        self.assertEqual((wifi.down_bytes_per_s * 8, wifi.up_bytes_per_s * 8), (600e6, 150e6))
        self.assertFalse(links.LinkProfile.find("loopback", LINKS_DIR).shaped)
        # Scaled time (run_session --rate 0.5): half the rates, a queue holding the same bytes.
        half = campus.scaled(0.5)
        self.assertEqual((half.down_bytes_per_s, half.up_bytes_per_s), (1990000, 1750000))
        self.assertEqual((half.burst_bytes, half.queue_ms), (campus.burst_bytes,
                                                              2 * campus.queue_ms))
        self.assertIs(campus.scaled(1.0), campus)

    def test_errors_name_the_file_and_the_key(self):
        with tempfile.TemporaryDirectory() as tmp:
            def load(text):
                path = os.path.join(tmp, "bad.yaml")
                with open(path, "w") as f:
                    f.write(text)
                with self.assertRaises(links.LinkError) as e:
                    links.LinkProfile.load(path)
                return str(e.exception)

            self.assertIn("unknown key down_mbit", load("down_mbit: 30\n"))
            self.assertIn("up_bytes_per_s must be a positive number, not -1",
                          load("down_bytes_per_s: 1000000\nup_bytes_per_s: -1\n"))
            self.assertIn("down_bytes_per_s must be a positive number, not None",
                          load("up_bytes_per_s: 1000000\n"))
            self.assertIn("burst_bytes 100 is below one packet",
                          load("down_bytes_per_s: 1000000\nup_bytes_per_s: 1000000\n"
                               "burst_bytes: 100\n"))
            self.assertIn("not a mapping", load("- 1\n"))
            self.assertIn("bad.yaml", load("down_bytes_per_s: [\n"))
        with self.assertRaises(links.LinkError) as e:
            links.LinkProfile.find("dialup", LINKS_DIR)
        self.assertIn("no link profile dialup (known: campus, loopback, wifi)", str(e.exception))

    def test_loopback_makes_no_hosts(self):
        with links.Hosts(links.LinkProfile.find("loopback", LINKS_DIR)) as hosts:
            self.assertIs(hosts.server, hosts.devices)
            self.assertEqual(hosts.server.wrap(["true"]), ["true"])
            self.assertEqual(hosts.master_uri(11311), "http://127.0.0.1:11311")
            self.assertIsNone(hosts.counters())

    def test_without_root_a_clear_error(self):
        profile = links.LinkProfile.find("campus", LINKS_DIR)
        with mock.patch.object(links.os, "geteuid", return_value=1000):
            with self.assertRaises(links.LinkError) as e:
                links.Hosts(profile).__enter__()
        self.assertIn("need root", str(e.exception))


@unittest.skipUnless(os.geteuid() == 0, "network namespaces and tc need root")
class HostsTest(unittest.TestCase):
    def setUp(self):
        self.profile = links.LinkProfile.find("campus", LINKS_DIR)

    def transfer(self, src, dst, size):
        receiver = subprocess.Popen(dst.wrap(["/usr/bin/python3", "-c", RECEIVE, dst.ip]),
                                    stdout=subprocess.PIPE, text=True)
        try:
            self.assertEqual(receiver.stdout.readline().strip(), "ready")
            subprocess.run(src.wrap(["/usr/bin/python3", "-c", SEND, dst.ip, str(size)]),
                           check=True, timeout=30)
            n, seconds = receiver.stdout.readline().split()
        finally:
            receiver.kill()
            receiver.wait()
        self.assertEqual(int(n), size)
        return size / float(seconds)

    def test_each_direction_has_its_rate(self):
        with links.Hosts(self.profile) as hosts:
            names = {hosts.server.netns, hosts.devices.netns}
            self.assertTrue(names <= namespaces())
            up = self.transfer(hosts.devices, hosts.server, 3000000)
            down = self.transfer(hosts.server, hosts.devices, 3000000)
            sent = hosts.counters()
        # TCP over IPv4 on a 1500-byte MTU carries 1448 payload bytes per 1514-byte frame:
        # goodput is ~95.6% of the shaped rate; never more than the rate.
        for name, measured, rate in (("up", up, 3500000), ("down", down, 3980000)):
            self.assertGreater(measured, 0.90 * rate, "%s %.0f B/s" % (name, measured))
            self.assertLess(measured, 1.0 * rate, "%s %.0f B/s" % (name, measured))
        self.assertGreater(sent["up"], 3000000)
        self.assertGreater(sent["down"], 3000000)
        self.assertFalse(names & namespaces(), "namespaces left behind")

    def test_ros_across_the_hosts(self):
        with links.Hosts(self.profile) as hosts:
            uri = hosts.master_uri(11311)
            master = subprocess.Popen(hosts.server.wrap(["roscore", "-p", "11311"]),
                                      env=hosts.server.env(uri), stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL)
            pubs = []
            try:
                deadline = time.monotonic() + 30
                while subprocess.run(hosts.devices.wrap(["rostopic", "list"]),
                                     env=hosts.devices.env(uri), stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL).returncode != 0:
                    self.assertLess(time.monotonic(), deadline, "no master at %s" % uri)
                    time.sleep(0.5)
                for host, topic in ((hosts.devices, "/up"), (hosts.server, "/down")):
                    pubs.append(subprocess.Popen(
                        host.wrap(["rostopic", "pub", "-r", "5", topic, "std_msgs/String",
                                   "data: from " + host.ip]),
                        env=host.env(uri), stdout=subprocess.DEVNULL,
                        stderr=subprocess.DEVNULL))
                for host, topic, sender in ((hosts.server, "/up", hosts.devices.ip),
                                            (hosts.devices, "/down", hosts.server.ip)):
                    r = subprocess.run(host.wrap(["timeout", "30", "rostopic", "echo", "-n", "1",
                                                  topic]), env=host.env(uri),
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                    out = r.stdout
                    self.assertIn("from " + sender, out, "%s on %s: %s" % (topic, host.ip, out))
            finally:
                for p in pubs + [master]:
                    p.terminate()
                for p in pubs + [master]:
                    try:
                        p.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        p.wait()

    def test_nothing_outlives_a_failed_or_crashed_run(self):
        # A body that fails: the namespaces go with it.
        hosts = links.Hosts(self.profile)
        with self.assertRaises(ZeroDivisionError):
            with hosts:
                1 / 0
        self.assertFalse({hosts.server.netns, hosts.devices.netns} & namespaces())
        # A run killed before it could clean up (a pid that is not running): the next removes
        # its namespaces and says so; a live run's are left alone.
        dead = 4194000
        while links._alive(dead):
            dead += 1
        crashed = links.Hosts(self.profile, pid=dead)
        crashed._setup()
        with links.Hosts(self.profile) as hosts:
            self.assertEqual(hosts.removed_leftovers,
                             sorted([crashed.server.netns, crashed.devices.netns]))
        self.assertFalse({crashed.server.netns, crashed.devices.netns} & namespaces())
        # Another live run holds the addresses: a clear error, and its hosts stay.
        live = links.Hosts(self.profile, pid=os.getppid())
        live._setup()
        try:
            with self.assertRaises(links.LinkError) as e:
                with links.Hosts(self.profile):
                    pass
            self.assertIn("another shaped run (pid %d)" % os.getppid(), str(e.exception))
            self.assertTrue({live.server.netns, live.devices.netns} <= namespaces())
        finally:
            live._teardown()
            crashed._teardown()

    def test_the_observer_reaches_both_hosts_through_the_server(self):
        with links.Hosts(self.profile, observer=True) as hosts:
            self.assertEqual(hosts.observer.ip, links.OBSERVER_IP)
            self.assertIsNone(hosts.observer.netns)
            # The devices -> observer direction crosses the shaped uplink.
            rate = self.transfer(hosts.devices, hosts.observer, 2000000)
            self.assertGreater(rate, 0.90 * 3500000)
            self.assertLess(rate, 3500000)
            self.assertGreater(self.transfer(hosts.server, hosts.observer, 2000000), 20e6)
        out = subprocess.run(["ip", "route"], stdout=subprocess.PIPE, text=True).stdout
        self.assertNotIn("10.77.", out, "a route outlived the run")

    def test_a_session_on_the_campus_link(self):
        # run_session as users start it: the server on one host, device_0 and its player on the
        # other; every upload and local graph crosses the shaped link, and is counted there.
        root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "out")
            r = subprocess.run(
                ["rosrun", "ecar_sim", "run_session", "--scene",
                 os.path.join(root, "config", "scenes", "corridor.yaml"), "--device-names",
                 "device_0", "--frames", "60", "--datasets", os.path.join(tmp, "datasets"),
                 "--out", out, "--link", "campus"], stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, timeout=300)
            self.assertEqual(r.returncode, 0, r.stdout[-3000:])
            self.assertIn("link campus, master on http://10.77.0.1:", r.stdout)
            with open(os.path.join(out, "summary.json")) as f:
                summary = json.load(f)
            with open(os.path.join(out, "metrics.csv")) as f:
                rows = list(csv.DictReader(f))
        link = summary["link"]
        self.assertEqual((link["profile"], link["shaped"]), ("campus", True))
        self.assertGreaterEqual(summary["per_device"]["device_0"]["graphs_with_pose"], 5)
        up = sum(int(row["bytes_up"]) for row in rows)
        down = sum(int(row["bytes_down"]) for row in rows)
        self.assertGreater(up, 100000)
        self.assertGreaterEqual(link["up_bytes"], up)
        self.assertGreaterEqual(link["down_bytes"], down)
        # An upload (~50 kB) waits for the uplink's rate beyond the bucket: at least 90% of
        # (bytes - burst) / rate, median over the uploads (on loopback it takes ~0.5 ms).
        profile = links.LinkProfile.find("campus", LINKS_DIR)
        waits = sorted(float(row["upload_ms"]) - 0.9e3 * (int(row["bytes_up"]) -
                                                         profile.burst_bytes) /
                       profile.up_bytes_per_s for row in rows)
        self.assertGreater(waits[len(waits) // 2], 0.0, "upload times %s" %
                           [row["upload_ms"] for row in rows])
        self.assertFalse({n for n in namespaces() if n.startswith(links.PREFIX)},
                         "namespaces left behind")


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "links", "__main__")
