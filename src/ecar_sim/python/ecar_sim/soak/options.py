"""soak's command line: every flag, its checks, and paths made absolute.

    args = parse_args(["--devices", "8", "--minutes", "10", "--out", "out/soak"])
"""

import argparse
import os

from ecar_sim.session.options import REPO_ROOT


DEFAULT_SCENE = os.path.join(REPO_ROOT, "config", "scenes", "corridor.yaml")
# The corridor's devices that walk from its x = 0 end within a second or so of the start: on
# short routes walked back and forth each makes or joins the map at once. (device_1 starts at
# the far end and stands for 2.5 s: on a route of a few hundred frames it may never initialise,
# which a soak would report as a device that never recovered.)
DEFAULT_DEVICES = ["device_0", "device_3", "device_4", "device_5", "device_6", "device_7",
                   "device_2", "phone_800", "device_8", "device_9", "device_13", "device_14",
                   "device_15", "device_16", "device_17"]


def build_parser(description=None):
    """The argparse parser of soak (defaults as documented in the README)."""
    p = argparse.ArgumentParser(prog="soak", description=description,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default=DEFAULT_SCENE,
                   help="scene whose first N device routes the light devices walk")
    p.add_argument("--devices", type=int, default=8,
                   help="light devices: the scene's first N (of the default corridor: the N "
                        "first that start at its x = 0 end, see DEFAULT_DEVICES)")
    p.add_argument("--device-names", default="",
                   help="comma-separated devices of the scene to use instead")
    p.add_argument("--minutes", type=float, default=10.0, help="length of the run")
    p.add_argument("--frames", type=int, default=300,
                   help="frames of each device's route; the devices walk it back and forth")
    p.add_argument("--every", type=int, default=4, help="upload every Nth frame")
    p.add_argument("--jpeg-quality", type=int, default=70)
    p.add_argument("--kill-every", type=float, default=120.0,
                   help="s between kill -9s of the whole server (restarted at once from its "
                        "autosave and database, as an operator resumes after a crash); 0 = never")
    p.add_argument("--restart-devices-every", type=float, default=300.0,
                   help="s between kill -9s of the light devices' process (started again at "
                        "once: each must get its name back and realign); 0 = never")
    p.add_argument("--disk-full-at", type=float, default=0.4,
                   help="when the VO database's disk fills up, as a fraction of the run (the "
                        "database lives on a tmpfs resized to what it holds; needs root)")
    p.add_argument("--disk-full-for", type=float, default=45.0,
                   help="s the disk stays full before space comes back; 0 = no disk-full fault")
    p.add_argument("--hostile-every", type=float, default=4.0,
                   help="s between hostile or malformed inputs (each kind in turn); 0 = none")
    p.add_argument("--editor-rate", type=float, default=2.0,
                   help="VO changes a second of the soak's own VO client (register, move, "
                        "delete its objects); 0 = none")
    p.add_argument("--autosave-period", type=float, default=30.0,
                   help="s between the server's autosaves of the map")
    p.add_argument("--warmup", type=float, default=120.0,
                   help="s of a server life before its memory is the baseline of the growth")
    p.add_argument("--max-growth", type=float, default=10.0,
                   help="%% server memory growth after warm-up allowed (lives long enough to "
                        "judge); 0 = report only")
    p.add_argument("--recover-timeout", type=float, default=90.0,
                   help="s every device has after a fault to receive an aligned local graph")
    p.add_argument("--server-prefix", default="",
                   help="command the server's nodelet manager runs under (launch_prefix), e.g. "
                   "'heaptrack -o OUT/heaptrack' to attribute its memory")
    p.add_argument("--datasets", default=os.path.join(REPO_ROOT, "out", "datasets"),
                   help="where generated datasets are kept and reused")
    p.add_argument("--out", default=os.path.join(REPO_ROOT, "out", "soak"), help="output folder")
    return p


def parse_args(argv, description=None, cwd=None):
    """The checked arguments, paths absolute. Exits with a usage error naming the flag."""
    p = build_parser(description)
    a = p.parse_args(argv)
    cwd = cwd or os.getcwd()
    for name in ("scene", "datasets", "out"):
        setattr(a, name, os.path.normpath(os.path.join(cwd, os.path.expanduser(getattr(a, name)))))
    if a.devices < 1:
        p.error("--devices must be >= 1")
    if a.minutes <= 0:
        p.error("--minutes must be > 0")
    if a.frames < 8:
        p.error("--frames must be >= 8")
    if a.every < 1:
        p.error("--every must be >= 1")
    if not 1 <= a.jpeg_quality <= 100:
        p.error("--jpeg-quality must be in 1..100")
    for flag in ("kill_every", "restart_devices_every", "disk_full_for", "hostile_every",
                 "editor_rate", "warmup", "max_growth"):
        if getattr(a, flag) < 0:
            p.error("--%s must be >= 0" % flag.replace("_", "-"))
    if a.autosave_period <= 0:
        p.error("--autosave-period must be > 0")
    if not 0.0 <= a.disk_full_at < 1.0:
        p.error("--disk-full-at must be a fraction of the run in [0, 1)")
    if a.recover_timeout <= 0:
        p.error("--recover-timeout must be > 0")
    if not a.device_names and a.scene == DEFAULT_SCENE:
        if a.devices > len(DEFAULT_DEVICES):
            p.error("--devices: the corridor has %d devices that start at its x = 0 end" %
                    len(DEFAULT_DEVICES))
        a.device_names = ",".join(DEFAULT_DEVICES[:a.devices])
    # What the run's own code reads (runner.py) besides the flags.
    a.regenerate = False
    return a
