"""What run_session prints: every line starts with "[run_session] ".

The summary lines (print_summary) are the session's result as scripts/demo.sh shows it;
their format is part of the interface. During playback a progress line (progress_line)
every few seconds says how far the devices are.
"""

PREFIX = "[run_session] "


def log(text):
    """Prints one line with the run_session prefix, flushed (the output is often piped)."""
    print(PREFIX + text, flush=True)


def fmt(x, unit="", scale=1.0, digits=1):
    """x * scale with `digits` decimals and the unit, or "n/a" for None."""
    return "n/a" if x is None else ("%.*f%s" % (digits, x * scale, unit))


def progress_line(elapsed_s, frames_played, frames_total, uploads, graphs, rate):
    """One progress line (without the prefix) from per-device counts (dicts by device, in
    session order) and the playback rate so far (x real time, None before two frames):

      "20 s: frames 124/240, uploads 31 (device_0 16, device_2 15), local graphs 29,
       playback 0.45x real time" (one line)
    """
    per_device = ", ".join("%s %d" % (d, n) for d, n in uploads.items())
    return "%.0f s: frames %d/%d, uploads %d (%s), local graphs %d, playback %s real time" % (
        elapsed_s, sum(frames_played.values()), sum(frames_total.values()),
        sum(uploads.values()), per_device, sum(graphs.values()), fmt(rate, "x", 1.0, 2))


def print_summary(s, out):
    """The summary lines of a session summary (summary.json's dict) written to out."""
    o = s["overall"]
    log("%s" % s["pacing"]["note"])
    link = s.get("link")
    if link and link.get("down_bytes") is not None:
        log("link %s: down %.2f MB (%s of %.2f MB/s), up %.2f MB (%s of %.2f MB/s) over the "
            "session" % (link["profile"], link["down_bytes"] / 1e6,
                         fmt(link["down_utilisation"], "%", 100.0), link["down_bytes_per_s"] / 1e6,
                         link["up_bytes"] / 1e6, fmt(link["up_utilisation"], "%", 100.0),
                         link["up_bytes_per_s"] / 1e6))
    for d, r in s["per_device"].items():
        log("%s: uploads %d, graphs %d (%d with a pose), device tracked %s after its first graph, "
            "device-vs-server %s over %d frames, ATE device %s / server %s" %
            (d, r["uploads"], r["graphs_received"], r["graphs_with_pose"],
             fmt(r["tracked_after_first_graph"], "%", 100.0), fmt(r["device_vs_server_rmse_m"],
                                                                  " cm", 100.0, 2),
             r["device_vs_server_frames"], fmt(r["device_ate_se3_m"], " cm", 100.0, 2),
             fmt(r["server_ate_se3_m"], " cm", 100.0, 2)))
        if r.get("frames_skipped"):
            log("%s: %d of %d frames skipped (the device was busy when they came, as behind a "
                "camera's driver)" % (d, r["frames_skipped"], r["frames"] + r["frames_skipped"]))
        if r.get("session_final_map") is not None and r.get("final_map") is not None and \
                r["final_map"] != r["session_final_map"]:
            log("%s: never in the session's final map %s: measured in its own map %s" %
                (d, r["session_final_map"], r["final_map"]))
        if len(r.get("maps", [])) > 1:
            log("%s: server maps %s; measured in the final map %s from frame %s (%d server poses "
                "in other maps left out)" % (d, r["maps"], r["final_map"],
                                            r["final_map_from_frame"],
                                            r["server_poses_other_maps"]))
    log("local graph %s B median (p95 %s B), %s B per tracked point; latency %s ms median (p95 %s);"
        " server %s ms median" % (fmt(o["local_graph_bytes_median"], "", 1, 0),
                                   fmt(o["local_graph_bytes_p95"], "", 1, 0),
                                   fmt(o["bytes_per_point_median"], "", 1, 1),
                                   fmt(o["latency_ms_median"]), fmt(o["latency_ms_p95"]),
                                   fmt(o["server_ms_median"])))
    sb = o.get("scaled_back")
    if sb:
        log("scaled back from time scale %g to real time (link parts x %g, server as measured): "
            "latency %s ms median (p95 %s), upload %s ms, download %s ms" % (
                sb["time_scale"], sb["time_scale"], fmt(sb["latency_ms_median"]),
                fmt(sb["latency_ms_p95"]), fmt(sb["upload_ms_median"]),
                fmt(sb["download_ms_median"])))
    if o.get("upload_ms_median") is not None:
        log("latency's parts, medians: upload %s ms, on the server %s ms (receive %s: worker "
            "queue and JPEG decoding; align %s; send %s: composing and publishing), download "
            "%s ms" % (
                fmt(o["upload_ms_median"]), fmt(o["server_ms_median"]),
                fmt(o.get("receive_ms_median")), fmt(o["align_ms_median"]),
                fmt(o.get("send_ms_median")), fmt(o["download_ms_median"])))
    if o.get("server_cpu_ms_median") is not None:
        log("CPU time (each thread's own clock), medians: server %s ms per upload (p95 %s: "
            "decoding, ORB, tracking, grid, composing; background mapping not in it), device "
            "tracking %s ms per uploaded frame" % (
                fmt(o["server_cpu_ms_median"]), fmt(o.get("server_cpu_ms_p95")),
                fmt(o.get("device_tracking_cpu_ms_median"))))
    pl = s.get("planes")
    if pl:
        off = pl.get("off_surface", [])
        log("planes: %d, labelled right %d (%s)%s, %d removed by the server (fused), %d left in "
            "merged maps; %s" % (
            pl["planes"], pl["labelled_right"], ", ".join(pl["found"]),
            ", %d of them more than %.0f cm off their surface (%s)" % (
                len(off), 100 * pl.get("max_distance_m", 0.05),
                ", ".join(map(str, off))) if off else "",
            pl.get("removed", 0),
            pl.get("other_maps", 0),
            "; ".join("%d %s on %s %.1f cm %.1f deg" % (r["id"], r["label"], r["true_surface"],
                                                        100 * (r["distance_m"] or 0),
                                                        r["angle_deg"] or 0)
                      for r in pl["detail"])))
    vo = s.get("vo")
    if vo:
        lat = vo["latency"]
        log("VOs (%s attach, %s share): %d objects, %d changes; success %s overall, %s on other "
            "devices; change -> held on another device %s ms median (%s round trips, max %s); "
            "position agreement %s max (%s max from within %g m)" %
            (s["vo_attach"], s["vo_share"], vo["objects"], vo["changes"],
             fmt(vo["success"], "%", 100.0), fmt(vo["success_other_devices"], "%", 100.0),
             fmt(lat["median_ms"]), fmt(lat["median_round_trips"], "", 1, 2),
             fmt(lat["max_round_trips"], "", 1, 2),
             fmt(vo["position_agreement"]["max_m"], " cm", 100.0, 2),
             fmt(vo["position_agreement"]["near_max_m"], " cm", 100.0, 2),
             vo["position_agreement"]["near_limit_m"]))
        for key in ("by_distance", "by_angle"):
            log("  %s: %s" % (key, ", ".join("%s %s (%d)" % (b["bin"], fmt(b["success"], "%",
                                                                           100.0), b["expected"])
                                              for b in vo[key])))
    log("wrote %s/summary.json and %s/metrics.csv" % (out, out))
