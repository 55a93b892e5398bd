"""E4 and E5: the server's accuracy against the uploads' JPEG quality, and the devices' accuracy
against the server's.

E4 runs the SLAM core offline (ecar_slam_offline: the server's tracking and mapping without ROS)
on synthetic sequences and on KITTI 07 (real; when ../shared/data has it), the images
JPEG-compressed at each quality first, as the devices upload them. E5 runs sessions of one full
device (tracking every frame against the local graphs) in each sync mode and compares its
trajectory with the server's and with the ground truth. Writes e4_quality.csv, e4_quality.png,
e5_device_vs_server.csv, e5_device_vs_server.png and returns the report's sections.
"""

import csv
import json
import os
import subprocess
import types

from ecar_sim.reproduce import plots
from ecar_sim.reproduce.table import parse_rows, write_rows
from ecar_sim.session.datasets import ensure_dataset

E4_FIELDS = ["sequence", "quality", "jpeg_bytes_median", "uploads", "tracked", "ate_rmse_m",
             "alignment", "frames", "every"]
E5_FIELDS = ["sequence", "mode", "frames", "frames_tracked_on_device",
             "device_vs_server_rmse_m", "device_vs_server_max_m", "device_ate_sim3_m",
             "server_ate_sim3_m", "local_graph_bytes_median", "latency_ms_median"]

# Synthetic sequences: (name, scene, device). KITTI 07 is added when present.
E4_SEQUENCES = [("corridor", "corridor", "device_0"), ("half_circle", "room", "half_circle")]
E5_SEQUENCES = [("corridor", "corridor", "device_0"), ("zigzag", "corridor", "device_2"),
                ("half_circle", "room", "half_circle"), ("shake", "room", "shake")]
KITTI = "kitti07_0-159"


def shared_data(root):
    return os.path.join(os.path.dirname(root), "shared", "data")


def synthetic_dataset(root, scene, device, frames=0):
    """The device's rendered dataset under out/datasets (made once, as run_session does)."""
    args = types.SimpleNamespace(
        datasets=os.path.join(root, "out", "datasets"), frames=frames, regenerate=False,
        scene=os.path.join(root, "config", "scenes", scene + ".yaml"))
    return ensure_dataset(args, None, scene, device)


def offline_point(out, sequence, dataset, quality, every, frames):
    """One ecar_slam_offline run; its E4 row."""
    name = os.path.join(out, "runs", "e4_%s_q%03d" % (sequence, quality))
    cmd = ["rosrun", "ecar_core", "ecar_slam_offline", "--dataset", dataset, "--every",
           str(every), "--jpeg-quality", str(quality), "--no-odometry", "--summary",
           name + ".json"]
    if frames:
        cmd += ["--frames", str(frames)]
    print("[reproduce] " + " ".join(cmd), flush=True)
    with open(name + ".log", "w") as log:
        subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
    with open(name + ".json") as f:
        s = json.load(f)
    d = s["devices"][0]
    return {"sequence": sequence, "quality": quality, "jpeg_bytes_median": s["jpeg_bytes_median"],
            "uploads": d["uploads"], "tracked": d["tracked"], "ate_rmse_m": s["ate"]["rmse"],
            "alignment": s["alignment"], "frames": frames, "every": every}


def run_quality(root, out, quick):
    """E4: every sequence at every quality; returns the rows (also in e4_quality.csv)."""
    qualities = [100, 50, 10] if quick else list(range(100, 0, -10))
    sequences = []
    for name, scene, device in E4_SEQUENCES[:1] if quick else E4_SEQUENCES:
        # (--quick renders only the frames it runs: a third of the corridor's, 18 s less.)
        frames = 240 if quick else 0
        sequences.append((name, synthetic_dataset(root, scene, device, frames), 4, frames))
    kitti = os.path.join(shared_data(root), KITTI)
    if os.path.isdir(kitti):
        # KITTI runs at 10 Hz: every frame is uploaded (the devices' every 4th of 30 Hz is 7.5).
        sequences.append(("kitti07", kitti, 1, 80 if quick else 0))
    else:
        print("[reproduce] E4: %s is absent: KITTI 07 left out" % kitti, flush=True)
    rows = [offline_point(out, name, dataset, q, every, frames)
            for name, dataset, every, frames in sequences for q in qualities]
    write_rows(os.path.join(out, "e4_quality.csv"), E4_FIELDS, rows)
    return rows


def session_point(root, out, sequence, scene, device, mode, frames):
    """One run_session of one full device; its E5 row."""
    folder = os.path.join(out, "runs", "e5_%s_%s" % (sequence, mode))
    cmd = ["rosrun", "ecar_sim", "run_session", "--scene",
           os.path.join(root, "config", "scenes", scene + ".yaml"), "--device-names", device,
           "--sync-mode", mode, "--out", folder]
    if frames:
        cmd += ["--frames", str(frames)]
    print("[reproduce] " + " ".join(cmd), flush=True)
    with open(folder + ".log", "w") as log:
        subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
    with open(os.path.join(folder, "summary.json")) as f:
        s = json.load(f)
    d, o = s["per_device"][device], s["overall"]
    return {"sequence": sequence, "mode": mode, "frames": d["frames"],
            "frames_tracked_on_device": d["frames_tracked_on_device"],
            "device_vs_server_rmse_m": d["device_vs_server_rmse_m"],
            "device_vs_server_max_m": d["device_vs_server_max_m"],
            "device_ate_sim3_m": d["device_ate_sim3_m"],
            "server_ate_sim3_m": d["server_ate_sim3_m"],
            "local_graph_bytes_median": o["local_graph_bytes_median"],
            "latency_ms_median": o["latency_ms_median"]}


def run_device_accuracy(root, out, quick):
    """E5: each sequence in each sync mode; returns the rows (also in e5_device_vs_server.csv)."""
    sequences = E5_SEQUENCES[:1] if quick else E5_SEQUENCES
    frames = 150 if quick else 0
    rows = [session_point(root, out, name, scene, device, mode, frames)
            for name, scene, device in sequences for mode in ("ecar", "edgeslam")]
    write_rows(os.path.join(out, "e5_device_vs_server.csv"), E5_FIELDS, rows)
    return rows


def run(root, out, quick):
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    e4 = run_quality(root, out, quick)
    e5 = run_device_accuracy(root, out, quick)
    return report(out, e4, e5)


def report(out, e4=None, e5=None):
    """Plots and the report's E4 and E5 sections (from the rows, or out's CSV files)."""
    if e4 is None:
        e4 = parse_rows(os.path.join(out, "e4_quality.csv"))
    if e5 is None:
        e5 = parse_rows(os.path.join(out, "e5_device_vs_server.csv"))
    plots.ate_vs_quality(e4, os.path.join(out, "e4_quality.png"))
    plots.device_vs_server(e5, os.path.join(out, "e5_device_vs_server.png"))
    return quality_section(e4) + "\n" + device_section(e5)


def cm(x):
    return "-" if x is None else "%.2f" % (100.0 * x)


def quality_section(rows):
    """REPORT.md's E4 (markdown)."""
    lines = [
        "## E4: the server's accuracy against the uploads' JPEG quality",
        "",
        "The SLAM core offline (`ecar_slam_offline --jpeg-quality Q --no-odometry`), each "
        "uploaded image JPEG-compressed at quality Q first; ATE after a Sim(3) fit. The paper "
        "chose quality 70 after the same sweep; its devices upload every 4th frame, as here "
        "(KITTI 07 at 10 Hz uploads every frame).",
        "",
        "![E4](e4_quality.png)",
        "",
        "| sequence | quality | JPEG median (kB) | tracked / uploads | ATE RMSE (cm) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        size = r["jpeg_bytes_median"]
        lines.append("| %s | %d | %s | %d / %d | %s |" % (
            r["sequence"], r["quality"], "-" if size is None else "%.1f" % (size / 1000.0),
            r["tracked"], r["uploads"], cm(r["ate_rmse_m"])))
    return "\n".join(lines) + "\n"


def device_section(rows):
    """REPORT.md's E5 (markdown)."""
    lines = [
        "## E5: the devices' accuracy against the server's",
        "",
        "One full device per session (`run_session --device-names D --sync-mode M`): it tracks "
        "every frame against the local graphs it receives; the server aligns every 4th. "
        "Device-vs-server: the distance between the two poses of the frames both have (the "
        "paper's measure of how far the device strays from the global map); ATE of each "
        "trajectory after a Sim(3) fit.",
        "",
        "![E5](e5_device_vs_server.png)",
        "",
        "| sequence | mode | frames tracked on device | device vs server RMSE (cm) | max (cm) | "
        "device ATE (cm) | server ATE (cm) | local graph median (B) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append("| %s | %s | %d / %d | %s | %s | %s | %s | %.0f |" % (
            r["sequence"], r["mode"], r["frames_tracked_on_device"], r["frames"],
            cm(r["device_vs_server_rmse_m"]), cm(r["device_vs_server_max_m"]),
            cm(r["device_ate_sim3_m"]), cm(r["server_ate_sim3_m"]),
            r["local_graph_bytes_median"] or 0))
    return "\n".join(lines) + "\n"
