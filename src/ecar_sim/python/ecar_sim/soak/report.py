"""A soak's results: summary.json (what passed and the figures), memory.csv (every sample),
memory.png (server and devices memory over time, the faults marked) and REPORT.md (the same for
people, with the table of hostile inputs), and the lines printed at the end.
"""

import csv
import json
import os
import statistics

from ecar_sim.session.report import log
from ecar_sim.soak import memory


def build(args, soak, ledger, hostile, editor):
    """The summary dict of a finished run; its "passed" and "failures" say what held."""
    lives = memory.growth(soak.samples, args.warmup)
    judged = [l for l in lives if l.judged]
    recovered = [r["seconds"] for r in soak.recoveries if r["seconds"] is not None]
    unrecovered = [r for r in soak.recoveries if r["seconds"] is None]
    crashes = [{"what": g.what, "life": life, "why": why, "log_tail": tail}
               for g in (soak.server, soak.light) for life, why, tail in g.crashes]
    lost = {}
    for c in soak.checks:
        for l in c.get("lost", []):
            lost.setdefault(l["object_id"], dict(l, first_seen=c["when"]))
    hostile_rows = [{"kind": k, "what": w, "sent": n, "refused": ok, "outcome": o}
                    for k, w, n, ok, o in hostile.table()]
    failures = []
    if crashes:
        failures.append("%d crash(es): %s" % (len(crashes), "; ".join(
            "%s: %s" % (c["what"], c["why"]) for c in crashes)))
    if soak.hangs:
        failures.append("the server stopped answering (a hang, restarted) at %s s" %
                        ", ".join("%.0f" % t for t in soak.hangs))
    if lost:
        failures.append("%d acknowledged VO change(s) lost" % len(lost))
    if any("error" in c for c in soak.checks):
        failures.append("the database could not be read: " + "; ".join(
            c["error"] for c in soak.checks if "error" in c))
    if unrecovered:
        failures.append("%d device recoveries missing: %s" % (len(unrecovered), ", ".join(
            "%s after %s" % (r["device"], r["fault"]) for r in unrecovered[:10])))
    not_refused = [r for r in hostile_rows if r["refused"] < r["sent"]]
    if not_refused:
        failures.append("hostile inputs not refused: " + ", ".join(
            "%s (%s)" % (r["kind"], r["outcome"]) for r in not_refused))
    worst = max((l.percent for l in judged), default=None)
    if args.max_growth and worst is not None and worst > args.max_growth:
        failures.append("server memory grew %.1f%% after warm-up (at most %g%%)" %
                        (worst, args.max_growth))
    kills = [e for e in soak.events if e["kind"] == "server killed"]
    return {
        "scene": args.scene, "devices": soak.devices, "minutes": args.minutes,
        "frames": args.frames, "kill_every_s": args.kill_every,
        "restart_devices_every_s": args.restart_devices_every,
        "disk_full": {"at_s": round(args.disk_full_at * 60 * args.minutes, 1),
                      "for_s": args.disk_full_for} if args.disk_full_for else None,
        "memory": {
            "warmup_s": args.warmup, "window_s": memory.WINDOW_S,
            "lives": [l._asdict() for l in lives],
            # The same growth for the two parts of resident memory (reported, not judged).
            "parts": {part: [l._asdict() for l in memory.growth(soak.samples, args.warmup, field)]
                      for part, field in (("anonymous", "server_anon_kib"),
                                          ("file", "server_file_kib"))},
            "max_growth_percent": worst,
            "server_peak_mb": _peak(soak.samples, "server_kib"),
            "devices_peak_mb": _peak(soak.samples, "devices_kib"),
            "map_sizes": soak.map_sizes},
        "faults": {"server_kills": len(kills),
                   "device_restarts": sum(1 for e in soak.events
                                          if e["kind"] == "devices killed"),
                   "events": soak.events},
        "recovery": {"recoveries": len(soak.recoveries), "unrecovered": unrecovered,
                     "median_s": round(statistics.median(recovered), 2) if recovered else None,
                     "max_s": max(recovered) if recovered else None,
                     "by_fault": soak.recoveries},
        "vo": {"acknowledged_objects": len(ledger.acked()),
               "accepted_results": ledger.accepted,
               "rejected_by_reason": dict(ledger.rejected.most_common()),
               "editor_sessions": editor.connects,
               "lost": sorted(lost.values(), key=lambda l: l["object_id"]),
               "checks": soak.checks},
        "hostile": hostile_rows,
        "crashes": crashes,
        "hangs_s": soak.hangs,
        "failures": failures,
        "passed": not failures,
    }


def _peak(samples, field):
    values = [getattr(s, field) for s in samples if getattr(s, field) is not None]
    return round(max(values) / 1024.0, 1) if values else None


def write(out, summary, soak):
    """summary.json, memory.csv, memory.png and REPORT.md into out."""
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=str)
    with open(os.path.join(out, "memory.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "server_life", "server_rss_kib", "devices_rss_kib",
                    "server_rss_anon_kib", "server_rss_file_kib"])
        for s in soak.samples:
            w.writerow([s.t, s.life, s.server_kib or "", s.devices_kib or "",
                        s.server_anon_kib or "", s.server_file_kib or ""])
    plot_memory(os.path.join(out, "memory.png"), soak.samples, summary)
    with open(os.path.join(out, "REPORT.md"), "w") as f:
        f.write(markdown(summary))


def plot_memory(path, samples, summary):
    """Server and light devices' resident memory against time, kills and restarts marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for field, label, colour in (("server_kib", "server (nodelet manager)", "tab:blue"),
                                 ("server_anon_kib", "server: anonymous (heap, stacks)",
                                  "tab:cyan"),
                                 ("server_file_kib", "server: mapped files (code)", "0.5"),
                                 ("devices_kib", "light devices (one manager)", "tab:green")):
        pts = [(s.t, getattr(s, field) / 1024.0) for s in samples
               if getattr(s, field) is not None]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], ".", ms=2, color=colour,
                    label=label)
    marks = {"server killed": ("tab:red", "server kill -9"),
             "devices killed": ("tab:orange", "devices kill -9")}
    shown = set()
    full = None
    for e in summary["faults"]["events"]:
        if e["kind"] in marks:
            colour, label = marks[e["kind"]]
            ax.axvline(e["t"], color=colour, lw=1, ls="--",
                       label=None if label in shown else label)
            shown.add(label)
        elif e["kind"] == "disk full":
            full = e["t"]
        elif e["kind"] == "disk space back" and full is not None:
            ax.axvspan(full, e["t"], color="0.85", label="VO database's disk full")
    sizes = summary["memory"].get("map_sizes") or []
    if sizes:
        ax2 = ax.twinx()
        ax2.plot([m["t"] for m in sizes], [m["keyframes"] for m in sizes], "s-", ms=3, lw=0.8,
                 color="tab:purple", label="map keyframes (save_map)")
        ax2.set_ylabel("keyframes in the map", color="tab:purple")
        ax2.set_ylim(bottom=0)
        ax2.legend(loc="lower center", fontsize=8)
    growth = summary["memory"]["max_growth_percent"]
    ax.set_title("Soak: %d light devices, %.0f min; server memory growth after warm-up: %s" % (
        len(summary["devices"]), summary["minutes"],
        "n/a (no life long enough)" if growth is None else "%.1f%%" % growth))
    ax.set_xlabel("time since start (s)")
    ax.set_ylabel("resident memory (MB)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(s):
    """REPORT.md of a summary."""
    m, r, v = s["memory"], s["recovery"], s["vo"]
    lines = ["# Soak report", "",
             "**%s**" % ("PASSED" if s["passed"] else "FAILED: " + "; ".join(s["failures"])), "",
             "%d light devices of `%s` (%d frames each, back and forth), %.1f min; server "
             "kill -9 every %s, devices kill -9 every %s, VO database disk full %s." % (
                 len(s["devices"]), os.path.basename(s["scene"]), s["frames"], s["minutes"],
                 "%g s" % s["kill_every_s"] if s["kill_every_s"] else "never",
                 "%g s" % s["restart_devices_every_s"] if s["restart_devices_every_s"]
                 else "never",
                 "at %g s for %g s" % (s["disk_full"]["at_s"], s["disk_full"]["for_s"])
                 if s["disk_full"] else "never"), "",
             "## Memory", "", "![memory](memory.png)", "",
             "| server life | from (s) | to (s) | after warm-up (MB) | at the end (MB) | "
             "growth |", "|---|---|---|---|---|---|"]
    for l in m["lives"]:
        lines.append("| %d | %.0f | %.0f | %s | %s | %s |" % (
            l["index"], l["start"], l["end"],
            "-" if l["base_kib"] is None else "%.1f" % (l["base_kib"] / 1024.0),
            "-" if l["end_kib"] is None else "%.1f" % (l["end_kib"] / 1024.0),
            "not judged (shorter than warm-up + %.0f s)" % (2 * m["window_s"])
            if l["percent"] is None else "%+.1f%%" % l["percent"]))
    lines += ["", "Peak: server %s MB, light devices %s MB." % (m["server_peak_mb"],
                                                              m["devices_peak_mb"]), ""]
    for part, lives in sorted(m.get("parts", {}).items()):
        judged = [l for l in lives if l["judged"]]
        if judged:
            lines.append("Server's %s resident memory, by life after warm-up: %s." % (
                part, ", ".join("%d: %.1f -> %.1f MB (%+.1f%%)" % (
                    l["index"], l["base_kib"] / 1024.0, l["end_kib"] / 1024.0, l["percent"])
                    for l in judged)))
    lines.append("")
    if m.get("map_sizes"):
        lines += ["The map over time (save_map every minute): " + ", ".join(
            "%.0f s: %d keyframes, %d points, %d objects" % (
                x["t"], x["keyframes"], x["map_points"], x["objects"])
            for x in m["map_sizes"]), ""]
    lines += [
              "## Faults and recovery", "",
              "%d server kills, %d device restarts; %d device recoveries, median %s s, "
              "longest %s s; %d missing." % (
                  s["faults"]["server_kills"], s["faults"]["device_restarts"],
                  r["recoveries"], r["median_s"], r["max_s"], len(r["unrecovered"])), "",
              "## Virtual objects", "",
              "%d objects acknowledged (%d accepted changes); lost: %d. Database checks:" % (
                  v["acknowledged_objects"], v["accepted_results"], len(v["lost"])), ""]
    for c in v["checks"]:
        lines.append("- %s (%.0f s): %s" % (c["when"], c["t"], c.get("error") or
                                             "%d acknowledged, %d rows, %d lost" % (
                                                 c["acked"], c["rows"], len(c["lost"]))))
    lines += ["", "Rejections by reason: " + ", ".join(
        "%s %d" % kv for kv in list(v["rejected_by_reason"].items())[:12]), "",
        "## Hostile and malformed inputs", "",
        "| kind | input | sent | refused | outcome (a failing one, else the first) |",
        "|---|---|---|---|---|"]
    for h in s["hostile"]:
        lines.append("| %s | %s | %d | %d | %s |" % (h["kind"], h["what"], h["sent"],
                                                    h["refused"],
                                                    h["outcome"].replace("|", "/")[:200]))
    if s["crashes"]:
        lines += ["", "## Crashes", ""]
        for c in s["crashes"]:
            lines += ["- %s (life %d): %s" % (c["what"], c["life"], c["why"]), "", "```"] + \
                c["log_tail"] + ["```"]
    return "\n".join(lines) + "\n"


def print_summary(s, out):
    """The run's result in a few lines."""
    m, r, v = s["memory"], s["recovery"], s["vo"]
    log("server memory growth after warm-up %s (peak %s MB); %d server kills, %d device "
        "restarts, recoveries median %s s, longest %s s, %d missing" % (
            "n/a" if m["max_growth_percent"] is None else "%.1f%%" % m["max_growth_percent"],
            m["server_peak_mb"], s["faults"]["server_kills"], s["faults"]["device_restarts"],
            r["median_s"], r["max_s"], len(r["unrecovered"])))
    log("%d VOs acknowledged, %d lost; hostile inputs: %d kinds, %d sent, %d refused; "
        "%d crashes" % (v["acknowledged_objects"], len(v["lost"]), len(s["hostile"]),
                        sum(h["sent"] for h in s["hostile"]),
                        sum(h["refused"] for h in s["hostile"]), len(s["crashes"])))
    log("%s (report: %s)" % ("PASSED" if s["passed"] else "FAILED: " +
                                   "; ".join(s["failures"]), os.path.join(out, "REPORT.md")))
