"""run_session's command line: every flag, its checks, and paths made absolute.

Every path argument is resolved against the directory the user runs the command from, at
parse time, so that children started elsewhere (roslaunch runs nodes from ROS_HOME) see the
same files.

    args = parse_args(["--scene", "config/scenes/corridor.yaml", "--out", "out/s"])
    args.scene  # "/<cwd>/config/scenes/corridor.yaml"
"""

import argparse
import os


def _workspace_root():
    """The catkin workspace holding this file (REPO/src/ecar_sim/python/ecar_sim/session/)."""
    path = os.path.realpath(__file__)
    for _ in range(6):
        path = os.path.dirname(path)
    return path


REPO_ROOT = _workspace_root()

# Flags that name files or folders, made absolute by parse_args.
PATH_FLAGS = ("scene", "datasets", "out", "server_config")


def build_parser(description=None):
    """The argparse parser of run_session (defaults as documented in the README)."""
    p = argparse.ArgumentParser(prog="run_session", description=description,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene",
                   help="scene file (config/scenes/*.yaml); required unless --reevaluate")
    p.add_argument("--devices", type=int, default=1, help="number of devices (the scene's first N)")
    p.add_argument("--device-names", default="",
                   help="comma-separated devices of the scene to use instead of the first N")
    p.add_argument("--sync-mode", choices=["ecar", "edgeslam"], default="ecar")
    p.add_argument("--vo-attach", choices=["grid", "keyframe"], default="grid",
                   help="how the server attaches VOs: to grid cells (eCAR) or to the nearest "
                        "keyframe (baseline)")
    p.add_argument("--vo-share", choices=["graph", "direct"], default="graph",
                   help="VOs travel in local graphs (eCAR) or straight to every other device "
                        "(baseline)")
    p.add_argument("--vo-range", type=float, default=40.0,
                   help="a VO farther than this from a camera is not expected on it, m")
    p.add_argument("--every", type=int, default=4, help="upload every Nth frame")
    p.add_argument("--jpeg-quality", type=int, default=70)
    p.add_argument("--rate", type=float, default=1.0,
                   help="playback speed relative to real time (upper bound; pacing may slow it)")
    p.add_argument("--frames", type=int, default=0, help="frames per device (0 = whole trajectory)")
    p.add_argument("--pacing", choices=["camera", "lockstep"], default="camera",
                   help="camera: each player publishes at the playback rate as a camera does, "
                        "and a device that is busy when a frame comes skips it (counted in the "
                        "summary); lockstep: each player waits for its device to be done with "
                        "every frame and for its uploads' graphs (--in-flight), so no frame is "
                        "skipped and playback slows down instead")
    p.add_argument("--light", action="store_true",
                   help="light devices, as the paper's device simulators: all in one nodelet "
                        "manager, no players; each plays its dataset's uploads (JPEGs encoded "
                        "once, launch/light_devices.launch) and tracks only those frames")
    p.add_argument("--ar-views", action="store_true",
                   help="subscribe to every device's ar_view (the camera image with the VOs "
                        "drawn; full devices only) and write each device's last one to "
                        "OUT/ar_view_<device>.png")
    p.add_argument("--in-flight", type=int, default=1,
                   help="lockstep: uploads a device may have waiting for their local graph "
                        "before the player waits (0 = no pacing by round trip)")
    p.add_argument("--workers", type=int, default=2, help="server tracking worker threads")
    p.add_argument("--link", default="loopback",
                   help="the link the server and the devices share: a profile of config/links "
                        "(loopback, campus, wifi) or a profile file; shaped links run the server "
                        "and the devices in network namespaces of their own (needs root)")
    p.add_argument("--upload-budget", choices=("link", "off"), default="link",
                   help="link: on a shaped --link the server knows its up rate (uplink_capacity) "
                        "and gives each device its share, within which the device lowers its "
                        "JPEG quality (down to min_jpeg_quality); off: no budgets, every upload "
                        "at --jpeg-quality (what the link then does to latency)")
    p.add_argument("--server-config", default="",
                   help="server parameter file instead of config/server.yaml (for A/B runs)")
    p.add_argument("--datasets", default=os.path.join(REPO_ROOT, "out", "datasets"),
                   help="where generated datasets are kept and reused")
    p.add_argument("--regenerate", action="store_true", help="render the datasets again")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="give up after this many seconds (0 = 4x the sequence length + 120 s)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--reevaluate", action="store_true",
                   help="run nothing: recompute the VO and plane metrics of the session in --out "
                        "from its vo_raw.json.gz (after a change to ecar_sim.vo_metrics)")
    return p


def resolve_paths(args, cwd=None):
    """Makes every path flag of args absolute against cwd (default: the current directory);
    empty and missing values stay as they are."""
    cwd = cwd or os.getcwd()
    for name in PATH_FLAGS:
        value = getattr(args, name, None)
        if value:
            setattr(args, name, os.path.normpath(os.path.join(cwd, os.path.expanduser(value))))
    return args


def parse_args(argv, description=None, cwd=None):
    """The checked arguments, paths absolute (see resolve_paths). Exits with a usage error
    (status 2) naming the flag on a bad value."""
    p = build_parser(description)
    a = p.parse_args(argv)
    resolve_paths(a, cwd)
    if a.reevaluate:
        return a
    if not a.scene:
        p.error("--scene is required")
    if a.devices < 1:
        p.error("--devices must be >= 1")
    if a.every < 1:
        p.error("--every must be >= 1")
    if not 1 <= a.jpeg_quality <= 100:
        p.error("--jpeg-quality must be in 1..100")
    if a.rate <= 0:
        p.error("--rate must be > 0")
    if a.frames < 0:
        p.error("--frames must be >= 0")
    if a.light and a.pacing == "lockstep":
        p.error("--light plays at --rate by itself: it cannot be paced by --pacing lockstep")
    return a
