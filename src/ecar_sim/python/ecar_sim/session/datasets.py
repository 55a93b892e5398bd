"""The devices of a session and their rendered datasets (TUM layout, from make_dataset).

A device's dataset is kept under --datasets as <scene>_<device>[_f<frames>] with a
scene.sha256 of what it was rendered from (the scene without its other devices), and reused
while that digest and the frame count still match.
"""

import hashlib
import json
import os
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import yaml

from ecar_sim.session.launching import describe_exit
from ecar_sim.session.report import log


def scene_devices(scene_file, count, names):
    """(scene name, chosen device names): the comma-separated `names` when given, else the
    scene's first `count` devices. Exits with a message naming what is missing."""
    with open(scene_file) as f:
        scene = yaml.safe_load(f)
    available = [d["name"] for d in scene.get("devices", [])]
    if names:
        chosen = [n.strip() for n in names.split(",") if n.strip()]
        unknown = [n for n in chosen if n not in available]
        if unknown:
            raise SystemExit("run_session: %s has no device %s (it has %s)" %
                             (scene_file, ", ".join(unknown), ", ".join(available)))
        return scene["name"], chosen
    if count > len(available):
        raise SystemExit("run_session: %s has %d devices, --devices %d asked for more" %
                         (scene_file, len(available), count))
    return scene["name"], available[:count]


def dataset_frames(folder):
    """Frames listed in the folder's rgb.txt (0 when there is none)."""
    path = os.path.join(folder, "rgb.txt")
    if not os.path.exists(path):
        return 0
    with open(path) as f:
        return sum(1 for line in f if line.strip() and not line.startswith("#"))


def scene_digest(scene_file, device):
    """A digest of what one device's dataset depends on: the scene without its other devices."""
    with open(scene_file) as f:
        scene = yaml.safe_load(f)
    scene["devices"] = [d for d in scene.get("devices", []) if d.get("name") == device]
    return hashlib.sha256(json.dumps(scene, sort_keys=True).encode()).hexdigest()


def dataset_folder(datasets, scene_name, device, frames):
    """Where a device's dataset of `frames` frames (0 = all) is kept under `datasets`."""
    suffix = "_f%d" % frames if frames else ""
    return os.path.join(datasets, "%s_%s%s" % (scene_name, device, suffix))


def ensure_dataset(args, env, scene_name, device):
    """The device's dataset under args.datasets, rendered (make_dataset) unless one made from
    the same scene description and frame count is there (or args.regenerate). Raises
    RuntimeError when make_dataset fails."""
    folder = dataset_folder(args.datasets, scene_name, device, args.frames)
    digest = scene_digest(args.scene, device)
    digest_file = os.path.join(folder, "scene.sha256")
    have = dataset_frames(folder)
    complete = os.path.exists(os.path.join(folder, "groundtruth.txt"))
    try:
        with open(digest_file) as f:
            same_scene = f.read().strip() == digest
    except OSError:
        same_scene = False
    if have and complete and same_scene and (not args.frames or have == args.frames) and \
            not args.regenerate:
        log("reusing %s (%d frames)" % (folder, have))
        return folder
    log("rendering %s%s" % (folder, "" if not have or same_scene else " (the scene changed)"))
    if os.path.isdir(folder):
        shutil.rmtree(folder)
    cmd = ["rosrun", "ecar_sim", "make_dataset", "--scene", args.scene, "--device", device,
           "--out", folder, "--quiet"]
    if args.frames:
        cmd += ["--frames", str(args.frames)]
    r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL)
    if r.returncode != 0:
        raise RuntimeError("make_dataset for %s %s (see its messages)" %
                           (device, describe_exit(r.returncode)))
    with open(digest_file, "w") as f:
        f.write(digest + "\n")
    return folder


def ensure_datasets(args, env, scene_name, devices):
    """{device: its dataset folder} (ensure_dataset for each), rendered one per core at a time
    (make_dataset renders on one core). Raises RuntimeError when one fails."""
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        return dict(zip(devices, pool.map(
            lambda d: ensure_dataset(args, env, scene_name, d), devices)))


def read_frame_times(folder):
    """Dataset timestamps by frame index (rgb.txt order)."""
    with open(os.path.join(folder, "rgb.txt")) as f:
        return [float(line.split()[0]) for line in f if line.strip() and not line.startswith("#")]


def read_fps(folder):
    """The frame rate in the folder's camera.yaml (30 when it is missing or unreadable)."""
    try:
        with open(os.path.join(folder, "camera.yaml")) as f:
            return float(yaml.safe_load(f).get("fps", 30.0)) or 30.0
    except (OSError, ValueError, AttributeError, yaml.YAMLError):
        return 30.0
