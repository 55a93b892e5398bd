"""The faults a soak injects: a roslaunch of its nodes killed with SIGKILL and started again
(NodeGroup: the server, or all light devices), and a full disk under the VO database
(TmpfsDisk: a tmpfs resized to what it holds, then grown back).

    server = NodeGroup(procs, "server", "the server", make_command, env, "/edge_server")
    server.start()          # a new life: logs/server_<life>.log
    server.kill9(master)    # every node of the group, then its roslaunch
    disk = TmpfsDisk("out/soak/db", 256)
    disk.fill(); disk.free(); disk.unmount()
"""

import os
import signal
import subprocess
import time
import xmlrpc.client

CALLER = "/soak"
XMLRPC_TIMEOUT_S = 3.0


class _TimeoutTransport(xmlrpc.client.Transport):
    """An XML-RPC transport that gives up after XMLRPC_TIMEOUT_S: a node that does not answer
    (hung, or a stale URI whose port another socket took) must not stop the run."""

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = XMLRPC_TIMEOUT_S
        return conn


def node_names(master, prefix):
    """Every node the master knows whose name is prefix or under it."""
    code, _, state = master.getSystemState(CALLER)
    names = set()
    if code == 1:
        for group in state:
            for _, providers in group:
                names.update(n for n in providers if n == prefix or n.startswith(prefix + "/"))
    return sorted(names)


def node_pid(master, name):
    """The pid of node `name` (its getPid), or None when it does not answer."""
    try:
        code, _, uri = master.lookupNode(CALLER, name)
        if code != 1:
            return None
        proxy = xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport())
        code, _, pid = proxy.getPid(CALLER)
        return pid if code == 1 else None
    except (OSError, xmlrpc.client.Error):
        return None


class NodeGroup:
    """One roslaunch of the run that a fault kills and the run starts again. Its nodes are
    found on the master: `prefixes` (e.g. ["/edge_server"]); `manager` is the node whose memory
    is sampled."""

    def __init__(self, procs, name, what, command, env, prefixes, manager):
        self.procs, self.name, self.what = procs, name, what
        self.command, self.env = command, env  # command(life) -> argv
        self.prefixes, self.manager = prefixes, manager
        self.life = 0
        self.child = None
        self.killed = False  # the current child was killed on purpose
        self.crashes = []  # (life, reason, log tail) of lives that ended by themselves

    def start(self):
        """Starts the next life (log: <log_dir>/<name>_<life>.log)."""
        self.life += 1
        self.killed = False
        self.child = self.procs.start("%s_%d" % (self.name, self.life),
                                      "%s (life %d)" % (self.what, self.life),
                                      self.command(self.life), self.env)
        return self.child

    def pid(self, master):
        """The manager node's pid, or None."""
        return node_pid(master, self.manager)

    def kill9(self, master):
        """SIGKILL to every node of the group (each runs in its own process group) and to its
        roslaunch; returns the nodes killed."""
        pids = {}
        for prefix in self.prefixes:
            for name in node_names(master, prefix):
                pid = node_pid(master, name)
                if pid:
                    pids[name] = pid
        self.killed = True
        for pid in pids.values():
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.child:
            self.child.signal(signal.SIGKILL)
            self.child.proc.wait()
            self.child.close()
        return sorted(pids)

    def crashed(self):
        """Why the current life ended by itself (recorded in crashes), or None."""
        if self.child is None or self.killed:
            return None
        why = self.child.death()
        if why:
            self.crashes.append((self.life, why, self.child.tail()))
            self.killed = True  # recorded once
        return why


class DiskError(RuntimeError):
    """The tmpfs could not be made or changed (names the command and why)."""


def _run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        raise DiskError("%s: %s" % (" ".join(cmd), r.stdout.strip() or "exit %d" % r.returncode))


class TmpfsDisk:
    """A tmpfs of size_mb at path for the VO database; fill() resizes it to what it holds (the
    next write that needs a new page fails with ENOSPC, as on a full disk), free() gives the
    space back. Needs root (mount); a tmpfs left by a crashed run is unmounted first."""

    def __init__(self, path, size_mb):
        if os.geteuid() != 0:
            raise DiskError("the disk-full fault mounts a tmpfs and needs root (run as root, "
                            "or --disk-full-for 0)")
        self.path, self.size_mb = path, size_mb
        os.makedirs(path, exist_ok=True)
        self.left_over = os.path.ismount(path)
        if self.left_over:
            _run(["umount", "-l", path])
        _run(["mount", "-t", "tmpfs", "-o", "size=%dm,mode=0700" % size_mb, "tmpfs", path])
        self.full_since = None

    def used_bytes(self):
        st = os.statvfs(self.path)
        return (st.f_blocks - st.f_bfree) * st.f_frsize

    def fill(self):
        """Resizes the tmpfs to the pages in use; returns them in bytes. The server may write
        between the count and the remount, and a tmpfs refuses a size below what it holds
        ("bad option"): then counted again, a few times."""
        for attempt in range(5):
            used = max(self.used_bytes(), 4096)
            try:
                _run(["mount", "-o", "remount,size=%d" % used, self.path])
                break
            except DiskError:
                if attempt == 4:
                    raise
                time.sleep(0.05)
        self.full_since = time.time()
        return used

    def free(self):
        """Gives the space back (size_mb)."""
        _run(["mount", "-o", "remount,size=%dm" % self.size_mb, self.path])
        self.full_since = None

    def unmount(self):
        """Unmounts it (what it held is gone: copy it first)."""
        if os.path.ismount(self.path):
            _run(["umount", "-l", self.path])
