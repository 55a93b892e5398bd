"""E6 and E7: virtual objects. E6, the VO sync latency against the number of devices sharing the
campus link, through the local graphs (eCAR) and relayed to every device at once (direct
sharing); E7, how often a device holds a VO it should see, by distance (corridor) and by angle
(half circle), with VOs on grid cells (eCAR) or attached to keyframes (the baseline).

E6's sessions are E2's (light devices on --link campus in scaled time; device_0 draws the
corridor scene's strokes): the graph points are E2's eCAR rows when e2_e3.csv has them, and the
direct points run here. E7 runs full devices on loopback, as scripts/bench_vo.sh does. Writes
e6_vo_latency.csv, e6_vo_latency.png, e7_success.csv, e7_success.png and returns the report's
sections.
"""

import json
import os
import subprocess

from ecar_sim.reproduce import plots, scaling
from ecar_sim.reproduce.table import parse_rows, write_rows

# The paper's VO sync latency (ms) with 2 and with 20 devices.
PAPER_VO_LATENCY = {"graph": {2: 56.0, 20: 69.0}, "direct": {2: 28.0, 20: 494.0}}
E6_FIELDS = ["share", "devices", "vo_latency_ms_median", "vo_latency_scaled_ms_median",
             "vo_latency_ms_p95", "vo_changes_measured", "vo_never_received", "time_scale",
             "frames"]
E7_FIELDS = ["scenario", "attach", "by", "bin", "bin_start", "success", "expected",
             "overall_success", "playback_rate"]
# E7's sessions: scenario -> (scene, devices, rate in the full run, by).
E7_SCENARIOS = {"corridor": ("corridor", "device_0,device_1,watcher", 0.2, "by_distance"),
                "half_circle": ("room", "painter,circle", 0.3, "by_angle")}


def vo_row(share, row):
    """E6's row of one session (a row of scaling.run_point with its VO figures)."""
    scale = row["time_scale"]
    median = row.get("vo_latency_ms_median")
    return {"share": share, "devices": row["devices"], "vo_latency_ms_median": median,
            # The link's parts and the wait for the next upload scale with the playback; the
            # server's few ms are scaled too (this understates by at most that much).
            "vo_latency_scaled_ms_median": None if median is None else median * scale,
            "vo_latency_ms_p95": row.get("vo_latency_ms_p95"),
            "vo_changes_measured": row.get("vo_changes_measured"),
            "vo_never_received": row.get("vo_never_received"),
            "time_scale": scale, "frames": row["frames"]}


def run_latency(root, out, quick):
    """E6: graph rows from E2's sweep (or run here), direct rows run here."""
    counts = scaling.counts(quick)[1:]  # at least two devices: one draws, the others receive
    frames, rate, quality = scaling.settings(quick)
    earlier = {}
    path = os.path.join(out, "e2_e3.csv")
    if os.path.exists(path):
        earlier = {r["devices"]: r for r in parse_rows(path)
                   if r["mode"] == "ecar" and r.get("vo_latency_ms_median") is not None and
                   r["frames"] == frames and r["time_scale"] == rate}
    rows = []
    for n in counts:
        graph = earlier.get(n) or scaling.run_point(root, out, "ecar", n, frames, rate, quality)
        rows.append(vo_row("graph", graph))
        rows.append(vo_row("direct", scaling.run_point(root, out, "ecar", n, frames, rate,
                                                       quality, vo_share="direct")))
    write_rows(os.path.join(out, "e6_vo_latency.csv"), E6_FIELDS, rows)
    return rows


def run_success(root, out, quick):
    """E7: each scenario with VOs on grid cells and attached to keyframes."""
    rows = []
    for scenario, (scene, devices, rate, by) in E7_SCENARIOS.items():
        if quick and scenario != "half_circle":
            continue
        for attach in ("grid", "keyframe"):
            folder = os.path.join(out, "runs", "e7_%s_%s" % (scenario, attach))
            cmd = ["rosrun", "ecar_sim", "run_session", "--scene",
                   os.path.join(root, "config", "scenes", scene + ".yaml"), "--device-names",
                   devices, "--rate", "%g" % (0.75 if quick else rate), "--vo-attach", attach,
                   "--vo-share", "graph", "--out", folder]
            print("[reproduce] " + " ".join(cmd), flush=True)
            with open(folder + ".log", "w") as log:
                subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
            with open(os.path.join(folder, "summary.json")) as f:
                s = json.load(f)
            vo = s["vo"] or {}
            for b in vo.get(by, []):
                rows.append({"scenario": scenario, "attach": attach, "by": by, "bin": b["bin"],
                             "bin_start": float(b["bin"].split("-")[0]),
                             "success": b["success"], "expected": b["expected"],
                             "overall_success": vo.get("success_other_devices"),
                             "playback_rate": s["pacing"]["achieved_rate"]})
    write_rows(os.path.join(out, "e7_success.csv"), E7_FIELDS, rows)
    return rows


def run(root, out, quick):
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    return report(out, run_latency(root, out, quick), run_success(root, out, quick))


def report(out, e6=None, e7=None):
    if e6 is None:
        e6 = parse_rows(os.path.join(out, "e6_vo_latency.csv"))
    if e7 is None:
        e7 = parse_rows(os.path.join(out, "e7_success.csv"))
    plots.vo_latency_vs_devices(e6, PAPER_VO_LATENCY, os.path.join(out, "e6_vo_latency.png"))
    plots.vo_success(e7, os.path.join(out, "e7_success.png"))
    return latency_section(e6) + "\n" + success_section(e7)


def num(x, fmt="%.1f"):
    return "-" if x is None else fmt % x


def latency_section(rows):
    """REPORT.md's E6 (markdown)."""
    r0 = rows[0] if rows else {"frames": 0, "time_scale": 1.0}
    lines = [
        "## E6: VO sync latency against devices, through the graph and direct",
        "",
        "E2's sessions (light devices on `--link campus`, %d frames each, in scaled time at "
        "rate %g); `device_0` draws the corridor scene's strokes. Latency: from the server "
        "accepting a change to the version arriving on another device that sees it "
        "(`DeviceFrame.object_received`). Through the graph a VO reaches a device in the local "
        "graph answering its next upload; direct (`--vo-share direct`) the server relays every "
        "change to every device at once. Scaled back: measured x %g." % (
            r0["frames"], r0["time_scale"], r0["time_scale"]),
        "",
        "![E6](e6_vo_latency.png)",
        "",
        "| share | devices | VO latency median, scaled back (ms) | measured (ms) | p95 measured | "
        "changes measured | never received | paper (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        paper = PAPER_VO_LATENCY[r["share"]].get(r["devices"])
        lines.append("| %s | %d | %s | %s | %s | %s | %s | %s |" % (
            r["share"], r["devices"], num(r["vo_latency_scaled_ms_median"]),
            num(r["vo_latency_ms_median"]), num(r["vo_latency_ms_p95"]),
            num(r["vo_changes_measured"], "%d"), num(r["vo_never_received"], "%d"),
            "%.0f" % paper if paper else "-"))
    return "\n".join(lines) + "\n"


def success_section(rows):
    """REPORT.md's E7 (markdown)."""
    lines = [
        "## E7: VO success by distance and angle, grid cells against keyframes",
        "",
        "Full devices on loopback (`scripts/bench_vo.sh`'s sessions). Success: the frames of the "
        "devices other than the owner in which the device holds a VO its ground-truth view "
        "shows. Corridor: by distance to the VO; half circle: by the angle around the VO "
        "between the registering camera and the receiving one.",
        "",
        "![E7](e7_success.png)",
        "",
        "| scenario | attach | bin | success | frames expected | overall (other devices) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append("| %s | %s | %s | %s | %d | %s |" % (
            r["scenario"], r["attach"], r["bin"], scaling.pct(r["success"]), r["expected"],
            scaling.pct(r["overall_success"])))
    return "\n".join(lines) + "\n"
