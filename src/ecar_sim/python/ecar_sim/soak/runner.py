"""One soak run from start to report.

Its own ROS master on a free port; the server (launch/server.launch, VO database and autosave on
OUT/db, map_dir OUT/maps); the scene's first N devices as light devices walking their routes back
and forth (launch/light_devices.launch loop:=true); the soak's VO editor; the hostile inputs in
turn; and on schedule the faults: kill -9 of the whole server (then, before it restarts, the
database must hold every acknowledged VO change; it restarts from its autosave and database as an
operator resumes after a crash), kill -9 of the light devices' process (started again at once),
and the database's disk full for a while. Every device must receive an aligned local graph within
--recover-timeout after each fault. Exit status: 0 when nothing crashed, no acknowledged change
was lost, every device recovered every time, every hostile input was refused and memory grew
within --max-growth; 1 otherwise; 2 on an error that stopped the run.
"""

import os
import random
import shutil
import sqlite3
import time
from concurrent.futures import ThreadPoolExecutor

import rospy
import yaml
from ecar_msgs.srv import SaveMap
from sensor_msgs.msg import CameraInfo

from ecar_sim.session import launching
from ecar_sim.session import report as session_report
from ecar_sim.session.datasets import ensure_datasets, scene_devices
from ecar_sim.session.report import log
from ecar_sim.session.runner import session_env
from ecar_sim.soak import faults, memory, options, report
from ecar_sim.soak.editor import VoEditor
from ecar_sim.soak.hostile import Context, Hostile
from ecar_sim.soak.ledger import VoLedger, read_database
from ecar_sim.soak.monitor import Monitor

SAMPLE_S = 2.0  # between memory samples
PROGRESS_S = 30.0
CONNECT_TIMEOUT_S = 60.0
DISK_MB = 512  # the database's tmpfs when not full
SETTLE_S = 15.0  # after a fault, hostile inputs are sent but not judged for this long
HANG_S = 30.0  # a service call of the soak without an answer this long: the server hangs
MAP_PROBE_S = 60.0  # between save_maps that count the map (keyframes, points, objects)


def main(argv, description=None):
    """soak's entry point: the exit status."""
    session_report.PREFIX = "[soak] "
    return run(options.parse_args(argv, description))


def camera_info(scene_file):
    """The scene's camera as a sensor_msgs/CameraInfo (for the editor's connect)."""
    with open(scene_file) as f:
        c = yaml.safe_load(f)["camera"]
    info = CameraInfo()
    info.width, info.height = int(c["width"]), int(c["height"])
    info.distortion_model = "plumb_bob"
    info.D = list(c.get("distortion", [0.0] * 4)) + [0.0]
    info.K = [c["fx"], 0.0, c["cx"], 0.0, c["fy"], c["cy"], 0.0, 0.0, 1.0]
    info.P = [c["fx"], 0.0, c["cx"], 0.0, 0.0, c["fy"], c["cy"], 0.0, 0.0, 0.0, 1.0, 0.0]
    info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    return info


def a_jpeg(dataset, quality, timeout=60.0):
    """The bytes of one of the dataset's cached uploads (the light device encodes them)."""
    folder = os.path.join(dataset, "jpeg_q%d" % quality)
    end = time.time() + timeout
    while time.time() < end:
        names = sorted(n for n in os.listdir(folder) if n.endswith(".jpg")) \
            if os.path.isdir(folder) else []
        if names:
            with open(os.path.join(folder, names[0]), "rb") as f:
                return f.read()
        time.sleep(0.5)
    raise RuntimeError("no cached JPEG in %s after %.0f s" % (folder, timeout))


def prepare(out):
    """Fresh OUT/logs and OUT/maps; returns the log folder."""
    os.makedirs(out, exist_ok=True)
    for sub in ("logs", "maps"):
        shutil.rmtree(os.path.join(out, sub), ignore_errors=True)
        os.makedirs(os.path.join(out, sub))
    return os.path.join(out, "logs")


def copy_database(src, dst):
    """The VO database at src copied consistently to dst (sqlite3's backup)."""
    if os.path.exists(dst):
        os.remove(dst)
    with sqlite3.connect(src) as a, sqlite3.connect(dst) as b:
        a.backup(b)


class Soak:
    """The state of one run (see the module's docstring)."""

    def __init__(self, args, procs, env, datasets, devices, db_dir):
        self.args, self.procs, self.env = args, procs, env
        self.devices, self.datasets = devices, datasets
        self.database = os.path.join(db_dir, "vo.sqlite")
        self.autosave = os.path.join(db_dir, "vo.autosave.ecarmap")
        self.map_dir = os.path.join(args.out, "maps")
        self.samples = []  # memory.Sample
        self.events = []  # {"t", "kind", ...}: kills, restarts, disk, crashes
        self.recoveries = []  # {"fault", "t", "device", "seconds" or None}
        self.checks = []  # {"t", "when", "acked", "lost": [...]}
        self.pending = []  # (fault label, t, {device: None or seconds})
        self.map_sizes = []  # {"t", "life", "keyframes", "map_points", "planes", "objects"}
        self.last_fault = 0.0  # wall time of the last kill of the server or the devices
        self.hangs = []  # run times at which the server stopped answering
        self.start_t = time.time()
        self.server = faults.NodeGroup(procs, "server", "the server", self.server_command, env,
                                       ["/edge_server"], "/edge_server")
        self.light = faults.NodeGroup(procs, "devices", "the light devices",
                                      self.devices_command, env,
                                      ["/light_devices"] + ["/%s" % d for d in devices],
                                      "/light_devices")

    def t(self):
        return time.time() - self.start_t

    def server_command(self, life):
        a = [("database", self.database), ("map_dir", self.map_dir),
             ("autosave_period", "%g" % self.args.autosave_period), ("output", "screen")]
        if self.args.server_prefix:
            a.append(("launch_prefix", self.args.server_prefix))
        if life > 1 and os.path.exists(self.autosave):
            a.append(("map", self.autosave))  # as an operator resumes after a crash
        return launching.Include(os.path.join(options.REPO_ROOT, "launch", "server.launch"),
                                 a).command()

    def devices_command(self, life):
        return launching.Include(os.path.join(options.REPO_ROOT, "launch",
                                              "light_devices.launch"), [
            ("devices", ",".join(self.devices)),
            ("datasets", ",".join(self.datasets[d] for d in self.devices)),
            ("every", "%d" % self.args.every), ("jpeg_quality", "%d" % self.args.jpeg_quality),
            ("loop", "true"), ("wait_subscribers", "0"), ("output", "screen")]).command()

    def event(self, kind, **fields):
        e = dict(t=round(self.t(), 1), kind=kind, **fields)
        self.events.append(e)
        log("%6.0f s: %s %s" % (e["t"], kind, " ".join(
            "%s=%s" % kv for kv in fields.items())))

    def expect_recovery(self, label, below=None):
        """Every device must receive an aligned graph after now (checked in poll_recoveries);
        below: {device: frame number} its graph's frame must be under (a restarted device)."""
        self.pending.append((label, time.time(), {d: None for d in self.devices}, below or {}))

    def poll_recoveries(self, monitor, final=False):
        """Moves recovered (or timed out, or at the end unfinished) devices to recoveries."""
        still = []
        for label, t0, waiting, below in self.pending:
            for d in list(waiting):
                got = monitor.first_aligned_after(d, t0, below.get(d))
                timed_out = time.time() - t0 > self.args.recover_timeout
                if got is not None or timed_out or final:
                    self.recoveries.append({"fault": label, "t": round(t0 - self.start_t, 1),
                                            "device": d,
                                            "seconds": None if got is None else
                                            round(got - t0, 2)})
                    del waiting[d]
            if waiting:
                still.append((label, t0, waiting, below))
        self.pending = still

    def check_database(self, ledger, when):
        """The acknowledged changes against the database now; logs and records the losses."""
        try:
            rows = read_database(self.database, copy_to=os.path.join(self.args.out, "check"))
        except RuntimeError as e:
            self.checks.append({"t": round(self.t(), 1), "when": when, "error": str(e)})
            log("" + str(e))
            return
        acked = ledger.acked()
        lost = ledger.check(rows)
        self.checks.append({"t": round(self.t(), 1), "when": when, "acked": len(acked),
                            "rows": len(rows), "lost": [l._asdict() for l in lost]})
        log("%6.0f s: database %s: %d acknowledged objects, %d rows, %d lost%s" % (
            self.t(), when, len(acked), len(rows), len(lost),
            "" if not lost else ": " + ", ".join("%d (v%d: %s)" % (l.object_id,
                                                                 l.acked_version, l.found)
                                                 for l in lost[:10])))

    def wait_connect_service(self, master):
        deadline = time.time() + CONNECT_TIMEOUT_S
        while not launching.service_exists(master, "/ecar/connect"):
            if self.server.crashed():
                raise RuntimeError("the server died while starting (see %s)" %
                                   self.server.child.log_path)
            if time.time() > deadline:
                raise RuntimeError("the server's /ecar/connect did not appear within %.0f s" %
                                   CONNECT_TIMEOUT_S)
            time.sleep(0.2)

    def probe_map(self):
        """Counts the server's map with a save_map into map_dir (what the memory holds)."""
        save = rospy.ServiceProxy("/ecar/save_map", SaveMap)
        try:
            res = save(path="soak_probe.ecarmap")
        except (rospy.ServiceException, rospy.ROSException, OSError):
            return
        if res.success:
            self.map_sizes.append({"t": round(self.t(), 1), "life": self.server.life,
                                   "keyframes": res.keyframes, "map_points": res.map_points,
                                   "planes": res.planes, "objects": res.objects})

    def sample(self, master):
        server = self.server.pid(master)
        anon, mapped = memory.rss_parts_kib(server)
        self.samples.append(memory.Sample(round(self.t(), 1), self.server.life,
                                          memory.rss_kib(server),
                                          memory.rss_kib(self.light.pid(master)),
                                          anon, mapped))


def run(args):
    """A whole soak (args from options.parse_args); the exit status."""
    log_dir = prepare(args.out)
    scene_name, devices = scene_devices(args.scene, args.devices, args.device_names)
    port = launching.free_port()
    env = session_env(port, log_dir)["server"]
    try:
        datasets = ensure_datasets(args, env, scene_name, devices)
    except RuntimeError as e:
        log("error: " + str(e))
        return 2
    db_dir = os.path.join(args.out, "db")
    disk = None
    try:
        if args.disk_full_for > 0:
            disk = faults.TmpfsDisk(db_dir, DISK_MB)
            if disk.left_over:
                log("unmounted the tmpfs %s of a run that ended without cleaning up" % db_dir)
        else:
            shutil.rmtree(db_dir, ignore_errors=True)
            os.makedirs(db_dir)
    except faults.DiskError as e:
        log("error: " + str(e))
        return 2
    procs = launching.Processes(log_dir)
    soak = Soak(args, procs, env, datasets, devices, db_dir)
    try:
        status = _run(args, soak, procs, env, port, disk)
    finally:
        if rospy.core.is_initialized():
            rospy.signal_shutdown("soak over")
        procs.stop_all()
        if disk:
            try:
                if os.path.exists(soak.database):
                    copy_database(soak.database, os.path.join(args.out, "vo.sqlite"))
            finally:
                disk.unmount()
    return status


def _run(args, soak, procs, env, port, disk):
    procs.start("roscore", "the ROS master", ["roscore", "-p", str(port)], env)
    try:
        master = launching.wait_for_master(env["ROS_MASTER_URI"], 30.0, procs)
        soak.server.start()
        soak.wait_connect_service(master)
        rospy.init_node("soak", disable_signals=True)
        ledger = VoLedger()
        monitor = Monitor(soak.devices, ledger)
        soak.light.start()
        editor = VoEditor(camera_info(args.scene), ledger, random.Random(7))
        jpeg = a_jpeg(soak.datasets[soak.devices[0]], args.jpeg_quality)
        hostile = Hostile(Context(editor, soak.devices, soak.map_dir, soak.database, jpeg,
                                  monitor.device_objects))
    except (RuntimeError, launching.ChildDied) as e:
        log("error: " + str(e))
        return 2
    log("%d light devices (%s), %.1f min, kill -9 every %s, devices restarted every %s, "
        "disk full %s, hostile input every %s, master %s" % (
            len(soak.devices), ",".join(soak.devices), args.minutes,
            "%g s" % args.kill_every if args.kill_every else "never",
            "%g s" % args.restart_devices_every if args.restart_devices_every else "never",
            "at %.0f s for %g s" % (args.disk_full_at * args.minutes * 60, args.disk_full_for)
            if disk else "never",
            "%g s" % args.hostile_every if args.hostile_every else "never",
            env["ROS_MASTER_URI"]))
    soak.expect_recovery("start")
    end = soak.start_t + 60.0 * args.minutes
    disk_at = soak.start_t + args.disk_full_at * 60.0 * args.minutes
    next_ = {"sample": 0.0, "editor": 0.0, "hostile": soak.start_t + 20.0,
             "kill": soak.start_t + (args.kill_every or 1e12),
             "devices": soak.start_t + (args.restart_devices_every or 1e12),
             "progress": soak.start_t + PROGRESS_S, "probe": soak.start_t + MAP_PROBE_S}
    disk_state = "waiting" if disk else "off"
    hostile_pool, hostile_job = ThreadPoolExecutor(max_workers=1), None
    probe_pool, probe_job = ThreadPoolExecutor(max_workers=1), None
    editor_pool, editor_job = ThreadPoolExecutor(max_workers=1), None
    while time.time() < end:
        now = time.time()
        if now >= next_["sample"]:
            soak.sample(master)
            next_["sample"] = now + SAMPLE_S
        if args.editor_rate and now >= next_["editor"]:
            # On a thread of its own: a server that stops answering (a deadlock) is
            # reported and restarted, as a watchdog would, instead of stopping the run.
            if editor_job is None or editor_job[0].done():
                if editor_job is not None and editor_job[0].exception() is not None:
                    log("%6.0f s: the VO editor failed: %s" % (soak.t(),
                                                              editor_job[0].exception()))
                editor_job = (editor_pool.submit(editor.step), now)
                next_["editor"] = now + 1.0 / args.editor_rate
            elif now - editor_job[1] > HANG_S:
                soak.hangs.append(round(soak.t(), 1))
                soak.event("SERVER UNRESPONSIVE", what="its connect service",
                           seconds=round(now - editor_job[1]))
                soak.last_fault = time.time()
                soak.server.kill9(master)
                soak.server.start()
                soak.expect_recovery("server restart after a hang")
                editor_pool.shutdown(wait=False)
                editor_pool, editor_job = ThreadPoolExecutor(max_workers=1), None
        if args.hostile_every and now >= next_["hostile"]:
            # On a thread of its own: a service that never answers must not stop the run.
            if hostile_job is None:
                hostile_job = (hostile_pool.submit(hostile.next), now)
            elif hostile_job[0].done():
                got = hostile_job[0].result()
                # An input sent while the server restarted says nothing (in the first
                # seconds after a restart an answer can stay away: see the README).
                if got and soak.last_fault < hostile_job[1] - SETTLE_S:
                    hostile.record(*got)
                    if not got[1]:
                        log("%6.0f s: hostile input %s NOT refused: %s" % (soak.t(), got[0],
                                                                               got[2]))
                hostile_job = None
                next_["hostile"] = now + args.hostile_every
            elif now - hostile_job[1] > HANG_S:
                kind = hostile.kinds[hostile.turn % len(hostile.kinds)][0]
                hostile.turn += 1
                hostile.record(kind, False, "no answer within %.0f s (a hang)" % HANG_S)
                log("%6.0f s: hostile input %s: no answer within %.0f s" % (
                    soak.t(), kind, HANG_S))
                hostile_pool.shutdown(wait=False)
                hostile_pool, hostile_job = ThreadPoolExecutor(max_workers=1), None
        if now >= next_["probe"] and (probe_job is None or probe_job.done()):
            probe_job = probe_pool.submit(soak.probe_map)
            next_["probe"] = now + MAP_PROBE_S
        if now >= next_["kill"]:
            soak.last_fault = time.time()
            killed = soak.server.kill9(master)
            soak.event("server killed", life=soak.server.life, nodes=len(killed))
            time.sleep(1.0)
            soak.check_database(ledger, "after kill %d" % soak.server.life)
            soak.server.start()
            soak.event("server restarted", life=soak.server.life,
                       resumed=os.path.exists(soak.autosave))
            soak.expect_recovery("server kill %d" % (soak.server.life - 1))
            next_["kill"] = time.time() + args.kill_every
        if now >= next_["devices"]:
            soak.last_fault = time.time()
            killed = soak.light.kill9(master)
            soak.event("devices killed", life=soak.light.life, nodes=len(killed))
            soak.light.start()
            soak.expect_recovery("devices restart %d" % (soak.light.life - 1),
                                 below={d: monitor.last_frame(d) for d in soak.devices})
            next_["devices"] = time.time() + args.restart_devices_every
        if disk_state == "waiting" and now >= disk_at:
            used = disk.fill()
            soak.event("disk full", bytes=used)
            disk_state = "full"
        elif disk_state == "full" and now >= disk_at + args.disk_full_for:
            disk.free()
            soak.event("disk space back")
            disk_state = "done"
        for group in (soak.server, soak.light):
            why = group.crashed()
            if why:
                soak.last_fault = time.time()
                soak.event("CRASH", what=group.what, why=why)
                group.start()
                soak.expect_recovery("crash of %s" % group.name)
        soak.poll_recoveries(monitor)
        if now >= next_["progress"]:
            log("%6.0f s: server %s MB, devices %s MB; %d acknowledged VO changes; "
                "graphs %s" % (soak.t(), _mb(soak.samples[-1].server_kib),
                               _mb(soak.samples[-1].devices_kib), ledger.accepted,
                               " ".join("%d" % n for n in monitor.graphs.values())))
            next_["progress"] = now + PROGRESS_S
        time.sleep(0.05)
    hostile_pool.shutdown(wait=False)
    probe_pool.shutdown(wait=False)
    editor_pool.shutdown(wait=False)
    if disk_state == "full":
        disk.free()
        soak.event("disk space back")
    # The last faults' devices get their time to recover, then a clean stop (the server
    # autosaves), then the database must hold everything acknowledged.
    deadline = time.time() + args.recover_timeout
    while soak.pending and time.time() < deadline:
        soak.poll_recoveries(monitor)
        time.sleep(0.2)
    soak.poll_recoveries(monitor, final=True)
    rospy.signal_shutdown("soak over")
    procs.stop_all()
    soak.check_database(ledger, "at the end")
    summary = report.build(args, soak, ledger, hostile, editor)
    report.write(args.out, summary, soak)
    report.print_summary(summary, args.out)
    return 0 if summary["passed"] else 1


def _mb(kib):
    return "-" if kib is None else "%.0f" % (kib / 1024.0)
