"""E8: four devices draw one picture together (the room scene's artist_0..artist_3: a square on
the floor, one side each, and its diagonals). One session of four full devices with their
ar_view recorded (run_session --ar-views); writes e8_montage.png (the four devices' last
ar_view frames side by side), e8_drawing.csv (each device's VOs held at the end, and the
drawn-position agreement between devices) and returns the report's section.
"""

import json
import os
import subprocess

import matplotlib.image as mpimg

from ecar_sim.reproduce import plots
from ecar_sim.reproduce.table import parse_rows, write_rows
from ecar_sim.session.structure import RawCollector

DEVICES = ["artist_0", "artist_1", "artist_2", "artist_3"]
FIELDS = ["device", "objects_held_at_end", "objects_accepted", "tracked_after_first_graph",
          "device_vs_server_rmse_m", "agreement_max_m", "agreement_near_max_m",
          "success_other_devices", "vo_latency_ms_median", "playback_rate", "view"]


def run(root, out, quick):
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    folder = os.path.join(out, "runs", "e8_artists")
    cmd = ["rosrun", "ecar_sim", "run_session", "--scene",
           os.path.join(root, "config", "scenes", "room.yaml"), "--device-names",
           ",".join(DEVICES), "--rate", "0.5" if quick else "0.35", "--ar-views", "--out",
           folder]
    print("[reproduce] " + " ".join(cmd), flush=True)
    with open(folder + ".log", "w") as log:
        subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
    with open(os.path.join(folder, "summary.json")) as f:
        s = json.load(f)
    rows = rows_of(s, folder, out)
    write_rows(os.path.join(out, "e8_drawing.csv"), FIELDS, rows)
    return report(out, rows)


def rows_of(summary, folder, out):
    """E8's rows: one per device, from the session's summary and ar_view files."""
    vo = summary.get("vo") or {}
    agreement = vo.get("position_agreement") or {}
    held = held_at_end(os.path.join(folder, "vo_raw.json.gz"))
    rows = []
    for d in DEVICES:
        per = summary["per_device"].get(d, {})
        view = os.path.join(folder, "ar_view_%s.png" % d)
        rows.append({
            "device": d, "objects_held_at_end": held.get(d),
            "objects_accepted": vo.get("objects"),
            "tracked_after_first_graph": per.get("tracked_after_first_graph"),
            "device_vs_server_rmse_m": per.get("device_vs_server_rmse_m"),
            "agreement_max_m": agreement.get("max_m"),
            "agreement_near_max_m": agreement.get("near_max_m"),
            "success_other_devices": vo.get("success_other_devices"),
            "vo_latency_ms_median": (vo.get("latency") or {}).get("median_ms"),
            "playback_rate": summary["pacing"]["achieved_rate"],
            "view": os.path.relpath(view, out) if os.path.exists(view) else None})
    return rows


def held_at_end(raw_path):
    """{device: VOs held in its last recorded frame} from a session's vo_raw.json.gz."""
    records = RawCollector(raw_path)
    out = {}
    for d, frames in records.device_frames.items():
        if frames:
            out[d] = len(frames[max(frames)].held)
    return out


def report(out, rows=None):
    if rows is None:
        rows = parse_rows(os.path.join(out, "e8_drawing.csv"))
    images, titles = [], []
    for r in rows:
        if r["view"] and os.path.exists(os.path.join(out, r["view"])):
            images.append(mpimg.imread(os.path.join(out, r["view"])))
            titles.append("%s: %s VOs held" % (r["device"], r["objects_held_at_end"]))
    if images:
        plots.montage(images, titles, os.path.join(out, "e8_montage.png"))
    return section(rows, bool(images))


def section(rows, montage):
    r0 = rows[0] if rows else {}

    def cm(x):
        return "-" if x is None else "%.2f" % (100.0 * x)

    lines = [
        "## E8: four devices draw one picture together",
        "",
        "The room scene's `artist_0..3` (full devices side by side on an arc around a floor "
        "point) each draw one side of a 0.6 m square on the floor, one after the other, and two "
        "of them a diagonal (`run_session --device-names artist_0,artist_1,artist_2,artist_3 "
        "--ar-views`). Each device's last `ar_view` frame:",
        "",
        "![E8](e8_montage.png)" if montage else "(no ar_view frame was recorded)",
        "",
        "Drawn-position agreement (where two devices draw the same VO in the real world, from "
        "their own pose estimates): %s cm at most over all frames, %s cm from within 10 m; "
        "%s VOs accepted; VOs held by the other devices in %s of the frames that show them; "
        "playback %sx real time." % (
            cm(r0.get("agreement_max_m")), cm(r0.get("agreement_near_max_m")),
            r0.get("objects_accepted", "-"),
            "-" if r0.get("success_other_devices") is None else
            "%.1f%%" % (100.0 * r0["success_other_devices"]), r0.get("playback_rate", "-")),
        "",
        "| device | VOs held at the end | tracked after its first graph | device vs server "
        "RMSE (cm) |",
        "|---|---|---|---|",
    ]
    for r in rows:
        t = r["tracked_after_first_graph"]
        lines.append("| %s | %s | %s | %s |" % (
            r["device"], "-" if r["objects_held_at_end"] is None else r["objects_held_at_end"],
            "-" if t is None else "%.1f%%" % (100.0 * t), cm(r["device_vs_server_rmse_m"])))
    return "\n".join(lines) + "\n"
