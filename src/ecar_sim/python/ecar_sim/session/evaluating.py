"""A session's metrics from its records: per device and overall, the pacing, summary.json,
metrics.csv and the TUM trajectories under DIR/traj/.

The records are a Collector's (collecting.py) or a RawCollector's (structure.py): any object
with device_frames, server_poses, graphs and metrics as documented on Collector. The VO and
plane parts of the summary are structure.py's.

    per_device = {d: device_summary(d, datasets[d], records, traj_dir, env) for d in devices}
    summary = build_summary(args, devices, pacing_summary(...), per_device,
                            overall_summary(devices, records), vo, planes)
    write_summary(out, summary); write_metrics_csv(out, records.metrics)
"""

import csv
import functools
import json
import math
import os
import shutil
import statistics
import subprocess

from ecar_msgs.msg import DeviceFrame

from ecar_sim.session import maps
from ecar_sim.session.datasets import read_frame_times

METRICS_FIELDS = ["device", "frame", "bytes_up", "bytes_down", "points", "positions",
                  "latency_ms", "upload_ms", "server_ms", "receive_ms", "align_ms",
                  "send_ms", "download_ms", "device_tracking_ms", "server_cpu_ms",
                  "device_tracking_cpu_ms", "jpeg_quality", "upload_budget"]


def percentile(values, q):
    """The q-th percentile (0..100) by linear interpolation, or None without values."""
    if not values:
        return None
    v = sorted(values)
    k = (len(v) - 1) * q / 100.0
    lo, hi = int(math.floor(k)), int(math.ceil(k))
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def rnd(x, digits=4):
    """round(x, digits), None stays None."""
    return None if x is None else round(x, digits)


def write_tum(path, poses, times):
    """A TUM trajectory file of poses {frame: (position, orientation xyzw)} stamped with the
    dataset's frame times (frames past the end of times are left out)."""
    with open(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for frame in sorted(poses):
            if frame >= len(times):
                continue
            p, q = poses[frame]
            f.write("%.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f\n" % ((times[frame],) + tuple(p) +
                                                                   tuple(q)))


@functools.lru_cache(maxsize=None)
def ros_executable(package, name):
    """The command that runs a package's executable: its path in the workspace (catkin's
    libexec folders, where rosrun looks), found once per process; ["rosrun", package, name]
    when catkin_find does not know it. (rosrun costs about 0.5 s per call on this machine: a
    session evaluates four trajectories per device.)"""
    try:
        r = subprocess.run(["catkin_find", "--without-underlays", "--libexec", package],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        folders = r.stdout.split() if r.returncode == 0 else []
    except OSError:
        folders = []
    for folder in folders:
        path = os.path.join(folder, name)
        if os.path.isfile(path) and os.access(path, os.X_OK):
            return (path,)
    return ("rosrun", package, name)


def ate(gt, est, env, sim3):
    """ATE RMSE (m) of a TUM trajectory against ground truth (ecar_eval_traj, SE(3) or Sim(3)
    alignment), or None when it cannot be computed."""
    summary = est + (".sim3.json" if sim3 else ".se3.json")
    cmd = list(ros_executable("ecar_core", "ecar_eval_traj")) + [
        gt, est, "--summary", summary, "--sim3" if sim3 else "--se3"]
    r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        return None
    with open(summary) as f:
        return json.load(f)["ate"]["translation"]["rmse"]


def rotation_angle_deg(q1, q2):
    """Angle (deg) of the rotation between two unit quaternions (x, y, z, w)."""
    dot = abs(sum(a * b for a, b in zip(q1, q2)))
    return math.degrees(2.0 * math.acos(min(1.0, dot)))


def device_summary(device, dataset, records, traj_dir, env, ate_rmse=ate, final=None,
                   uploads_only=False):
    """summary.json's per_device entry of one device; writes its trajectories (device and
    server estimates, ground truth copied) into traj_dir. ate_rmse(gt, est, env, sim3) gives
    the ATE (ecar_eval_traj by default). The pose metrics use the device's frames in the
    session's final map `final` (session.maps; all frames for records without map ids); a
    device never in the final map (its own map, not merged by the end) is measured in its last
    map instead (the ATE fits one transform per device; `final_map` is the map measured in,
    `session_final_map` the session's).
    uploads_only: a light device, which takes only the frames it uploads (frames_skipped is
    then None)."""
    frames = records.device_frames.get(device, {})
    in_final = maps.frames_of(records, device, final)
    own = maps.last_map(records, device)
    if not in_final.in_final and own is not None:
        in_final = maps.frames_of(records, device, own)
    all_server = records.server_poses[device]
    server = {f: p for f, p in all_server.items() if in_final.server(f)}
    times = read_frame_times(dataset)
    uploads = sum(1 for e in frames.values() if e.uploaded)
    started = [f for f, e in frames.items() if e.status != DeviceFrame.NOT_INITIALISED]
    tracked = [f for f, e in frames.items() if e.status == DeviceFrame.OK]
    device_poses = {f: (frames[f].position, frames[f].orientation) for f in tracked
                    if in_final.device(f)}
    common = sorted(set(device_poses) & set(server))
    errors = [math.dist(device_poses[f][0], server[f][0]) for f in common]
    rot = [rotation_angle_deg(device_poses[f][1], server[f][1]) for f in common]
    dev_file = os.path.join(traj_dir, "%s_device.txt" % device)
    srv_file = os.path.join(traj_dir, "%s_server.txt" % device)
    write_tum(dev_file, device_poses, times)
    write_tum(srv_file, server, times)
    gt = os.path.join(dataset, "groundtruth.txt")
    shutil.copy(gt, os.path.join(traj_dir, "%s_groundtruth.txt" % device))
    rows = [r for r in records.metrics if r["device"] == device]

    def traj_ate(path, poses, sim3):
        return rnd(ate_rmse(gt, path, env, sim3)) if len(poses) > 2 else None

    return {
        "dataset": dataset,
        "frames": len(frames),
        "frames_skipped": None if uploads_only else max(0, len(times) - len(frames)),
        "uploads": uploads,
        "graphs_received": records.graphs[device],
        "graphs_with_pose": len(server),
        "round_trips_measured": len(rows),
        "frames_tracked_on_device": len(tracked),
        "frames_after_first_graph": len(started),
        "tracked_after_first_graph": rnd(len(tracked) / len(started)) if started else None,
        "device_vs_server_frames": len(common),
        "device_vs_server_rmse_m": rnd(math.sqrt(sum(e * e for e in errors) / len(errors)),
                                       5) if errors else None,
        "device_vs_server_max_m": rnd(max(errors), 5) if errors else None,
        "device_vs_server_rot_median_deg": rnd(statistics.median(rot), 4) if rot else None,
        "device_ate_se3_m": traj_ate(dev_file, device_poses, False),
        "device_ate_sim3_m": traj_ate(dev_file, device_poses, True),
        "server_ate_se3_m": traj_ate(srv_file, server, False),
        "server_ate_sim3_m": traj_ate(srv_file, server, True),
        "median_latency_ms": rnd(percentile([r["latency_ms"] for r in rows], 50), 2),
        "upload_ms_median": rnd(percentile([r["upload_ms"] for r in rows], 50), 2),
        "download_ms_median": rnd(percentile([r["download_ms"] for r in rows], 50), 2),
        "upload_bytes": sum(r["bytes_up"] for r in rows),
        "download_bytes": sum(r["bytes_down"] for r in rows),
        **in_final.summary(all_server),
        "session_final_map": final,
    }


def overall_summary(devices, records, time_scale=1.0):
    """summary.json's overall entry: local graph bytes, bytes per tracked point, latency,
    server and device times over every round trip of the session. A session in scaled time
    (time_scale = its rate, != 1, on a shaped link whose rates were scaled with it) also gets
    `scaled_back`: the link's parts of each round trip (upload, download) times time_scale, as
    at real time on the unscaled link; the server's part as measured (its work does not scale)."""
    rows = records.metrics
    with_points = [r for r in rows if r["points"] > 0]
    out = {
        "round_trips": len(rows),
        "local_graph_bytes_median": percentile([r["bytes_down"] for r in rows], 50),
        "local_graph_bytes_p95": percentile([r["bytes_down"] for r in rows], 95),
        "bytes_per_point_median": rnd(percentile(
            [r["bytes_down"] / r["points"] for r in with_points], 50), 2),
        "points_per_graph_median": percentile([r["points"] for r in rows], 50),
        "upload_bytes_median": percentile([r["bytes_up"] for r in rows], 50),
        # The uploads' JPEG quality (lower than --jpeg-quality within an uplink budget) and
        # the devices' budgets, bytes/s (0: none; in the session's time, as measured).
        "jpeg_quality_median": percentile([r["jpeg_quality"] for r in rows
                                           if r.get("jpeg_quality")], 50),
        "jpeg_quality_min": min([r["jpeg_quality"] for r in rows if r.get("jpeg_quality")],
                                default=None),
        "upload_budget_median": percentile([r.get("upload_budget", 0) for r in rows], 50),
        "latency_ms_median": rnd(percentile([r["latency_ms"] for r in rows], 50), 2),
        "latency_ms_p95": rnd(percentile([r["latency_ms"] for r in rows], 95), 2),
        "server_ms_median": rnd(percentile([r["server_ms"] for r in rows], 50), 2),
        "server_ms_p95": rnd(percentile([r["server_ms"] for r in rows], 95), 2),
        # The latency's parts: device -> server (upload), on the server (receive: waiting for a
        # worker and decoding the JPEG; align; send: composing and publishing the local graph;
        # server_other = receive + send), server -> device (download).
        "upload_ms_median": rnd(percentile([r["upload_ms"] for r in rows], 50), 2),
        "receive_ms_median": rnd(percentile([r.get("receive_ms", 0.0) for r in rows], 50), 2),
        "align_ms_median": rnd(percentile([r.get("align_ms", 0.0) for r in rows], 50), 2),
        "send_ms_median": rnd(percentile([r.get("send_ms", 0.0) for r in rows], 50), 2),
        "server_other_ms_median": rnd(percentile(
            [r["server_ms"] - r.get("align_ms", 0.0) for r in rows], 50), 2),
        "download_ms_median": rnd(percentile([r["download_ms"] for r in rows], 50), 2),
        "device_tracking_ms_median": rnd(percentile(
            [e.tracking_time * 1e3 for d in devices for e in records.device_frames[d].values()],
            50), 2),
        # CPU times (each thread's own clock, so not inflated by the other processes on the
        # cores): the server's threads per upload (decoding, ORB, tracking, grid, composing;
        # not the background mapping), and the device's tracking of the uploaded frames.
        "server_cpu_ms_median": rnd(percentile(
            [r["server_cpu_ms"] for r in rows if "server_cpu_ms" in r], 50), 2),
        "server_cpu_ms_p95": rnd(percentile(
            [r["server_cpu_ms"] for r in rows if "server_cpu_ms" in r], 95), 2),
        "device_tracking_cpu_ms_median": rnd(percentile(
            [r["device_tracking_cpu_ms"] for r in rows if "device_tracking_cpu_ms" in r], 50), 2),
    }
    if time_scale != 1.0:
        s = time_scale
        latency = [r["upload_ms"] * s + r["server_ms"] + r["download_ms"] * s for r in rows]
        out["scaled_back"] = {
            "time_scale": s,
            "latency_ms_median": rnd(percentile(latency, 50), 2),
            "latency_ms_p95": rnd(percentile(latency, 95), 2),
            "upload_ms_median": rnd(percentile([r["upload_ms"] * s for r in rows], 50), 2),
            "download_ms_median": rnd(percentile([r["download_ms"] * s for r in rows], 50), 2),
        }
    return out


def playback_rate(spans, fps):
    """The slowest device's playback speed (x real time) from spans {device: (frames, first
    frame wall time, last frame wall time)}: (frames - 1) / fps over the wall time between
    its first and last frame; None when no device has a span yet."""
    rates = [(n - 1) / fps / (last - first) for n, first, last in spans.values()
             if first is not None and last is not None and last > first]
    return min(rates) if rates else None


def pacing_summary(requested, achieved, wall_seconds, pacing="lockstep", skipped=0):
    """summary.json's pacing entry: did playback keep the requested rate (within 10 %)?
    achieved is playback_rate's (None counts as 0); pacing is run_session's --pacing and
    skipped the frames the devices skipped in all."""
    rate = achieved or 0.0
    kept_up = rate >= 0.9 * requested
    if not kept_up:
        note = ("the machine could not keep up at rate %g: %s paced playback to %.2fx real time"
                % (requested, "the round trips" if pacing == "lockstep" else "the players",
                   rate))
    elif pacing == "camera" and skipped:
        note = ("playback kept the requested rate; the devices skipped %d frames they were too "
                "busy for" % skipped)
    else:
        note = "playback kept the requested rate"
    return {
        "pacing": pacing,
        "requested_rate": requested,
        "achieved_rate": rnd(rate, 3),
        "kept_up": kept_up,
        "frames_skipped": skipped,
        "wall_seconds": rnd(wall_seconds, 1),
        "note": note,
    }


def link_summary(profile, sent, wall, time_scale=1.0):
    """The link's part of the summary: the profile, and per direction the bytes that crossed
    it (tc's counters of each end, everything the hosts sent) and their share of its rate over
    the session's wall time; the bytes are None on loopback (not shaped, not counted). In scaled
    time the rates are the scaled ones (profile is scaled) and the utilisation is the same as
    at real time."""
    out = {"profile": profile.name, "description": profile.description,
           "shaped": profile.shaped, "time_scale": time_scale if profile.shaped else 1.0}
    if not profile.shaped or sent is None:
        return out
    for direction, rate in (("down", profile.down_bytes_per_s), ("up", profile.up_bytes_per_s)):
        out[direction + "_bytes_per_s"] = rate
        out[direction + "_bytes"] = sent[direction]
        out[direction + "_utilisation"] = (round(sent[direction] / (rate * wall), 4)
                                           if wall > 0 else None)
    return out


def build_summary(args, devices, pacing, per_device, overall, vo, planes, link=None):
    """The dict written as summary.json (keys in their documented order)."""
    return {
        "scene": args.scene, "devices": devices, "sync_mode": args.sync_mode,
        "every": args.every, "jpeg_quality": args.jpeg_quality, "in_flight": args.in_flight,
        "upload_budget": getattr(args, "upload_budget", "link"),
        "light": getattr(args, "light", False),
        "workers": args.workers, "server_config": args.server_config or None,
        "vo_attach": args.vo_attach, "vo_share": args.vo_share,
        "vo_range": args.vo_range,
        "link": link, "pacing": pacing, "per_device": per_device, "overall": overall,
        "vo": vo, "planes": planes,
    }


def read_summary(out):
    """out/summary.json."""
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


def write_summary(out, summary):
    """out/summary.json."""
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)


def write_metrics_csv(out, rows):
    """out/metrics.csv: one row per round trip, by device and frame, floats to 3 decimals."""
    with open(os.path.join(out, "metrics.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=METRICS_FIELDS)
        w.writeheader()
        for r in sorted(rows, key=lambda r: (r["device"], r["frame"])):
            w.writerow({k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()})
