"""The reproduction's plots (matplotlib, Agg; PNG)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLOURS = {"ecar": "tab:blue", "edgeslam": "tab:red"}
NAMES = {"ecar": "eCAR", "edgeslam": "edgeSLAM"}


def against_devices(rows, key, value, series, paper, ylabel, title, path):
    """Median latency (scaled back to real time) against devices, one line per series (rows
    whose `key` is the series' id; value: the column), with the paper's points dashed.
    series: [(id, colour, label)]; paper: {id: {devices: ms}}."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for ident, colour, label in series:
        pts = sorted((r["devices"], r[value]) for r in rows
                     if r[key] == ident and r[value] is not None)
        if pts:
            ax.plot(*zip(*pts), "o-", color=colour, label="%s (ours)" % label)
        ref = sorted(paper.get(ident, {}).items())
        if ref:
            ax.plot(*zip(*ref), "s--", color=colour, alpha=0.5, label="%s (paper)" % label)
    ax.set_xticks(sorted({r["devices"] for r in rows}))  # the measured counts, not 2.5, 7.5
    ax.set_xlabel("devices sharing the campus link")
    ax.set_ylabel(ylabel)
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def latency_vs_devices(rows, paper, path):
    """E2: median sync latency (scaled back to real time) against devices, each mode, with the
    paper's points."""
    against_devices(rows, "mode", "latency_scaled_ms_median",
                    [(m, COLOURS[m], NAMES[m]) for m in ("ecar", "edgeslam")], paper,
                    "sync latency, median (ms)", "E2: sync latency against devices", path)


def parts_vs_devices(rows, path):
    """E3: the latency's parts (upload and download scaled back, server align and the rest)
    against devices, one panel per mode."""
    modes = [m for m in ("ecar", "edgeslam") if any(r["mode"] == m for r in rows)]
    fig, axes = plt.subplots(1, len(modes), figsize=(5.2 * len(modes), 4.0), squeeze=False)
    for ax, mode in zip(axes[0], modes):
        rs = sorted((r for r in rows if r["mode"] == mode), key=lambda r: r["devices"])
        n = [r["devices"] for r in rs]
        for key, label in (("upload_scaled_ms_median", "device upload"),
                           ("receive_ms_median", "server receive"),
                           ("align_ms_median", "server align"),
                           ("send_ms_median", "server send"),
                           ("download_scaled_ms_median", "device download")):
            pts = [(k, r.get(key)) for k, r in zip(n, rs) if r.get(key) is not None]
            if pts:
                ax.plot(*zip(*pts), "o-", label=label)
        ax.set_yscale("log")
        ax.set_xticks(n)
        ax.set_xlabel("devices")
        ax.set_ylabel("median (ms)")
        ax.set_title("E3: %s" % NAMES[mode])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def ate_vs_quality(rows, path):
    """E4: ATE (cm) against JPEG quality, one line per sequence, and the JPEG's size beside."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.4, 4.0))
    for seq in sorted({r["sequence"] for r in rows}):
        rs = sorted((r for r in rows if r["sequence"] == seq), key=lambda r: r["quality"])
        q = [r["quality"] for r in rs]
        ax.plot(q, [100.0 * r["ate_rmse_m"] if r["ate_rmse_m"] is not None else float("nan")
                    for r in rs], "o-", label=seq)
        bx.plot(q, [(r["jpeg_bytes_median"] or 0) / 1000.0 for r in rs], "o-", label=seq)
    ax.set_yscale("log")
    ax.set_xlabel("JPEG quality")
    ax.set_ylabel("server ATE RMSE, Sim(3) (cm)")
    ax.set_title("E4: accuracy against JPEG quality")
    bx.set_xlabel("JPEG quality")
    bx.set_ylabel("upload JPEG, median (kB)")
    bx.set_title("E4: upload size against JPEG quality")
    for a in (ax, bx):
        a.axvline(70, color="grey", ls=":", lw=1)
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def device_vs_server(rows, path):
    """E5: device-vs-server RMSE and the two ATEs per sequence, eCAR and edgeSLAM side by side."""
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    fig, ax = plt.subplots(figsize=(max(6.4, 1.6 * len(seqs) + 2), 4.2))
    width = 0.13
    keys = (("device_vs_server_rmse_m", "device vs server", ""),
            ("device_ate_sim3_m", "device ATE", "//"), ("server_ate_sim3_m", "server ATE", ".."))
    k = 0
    for mode in ("ecar", "edgeslam"):
        for key, label, hatch in keys:
            vals = []
            for s in seqs:
                r = next((r for r in rows if r["sequence"] == s and r["mode"] == mode), None)
                vals.append(100.0 * r[key] if r and r[key] is not None else 0.0)
            x = [i + (k - 2.5) * width for i in range(len(seqs))]
            ax.bar(x, vals, width, color=COLOURS[mode], hatch=hatch, edgecolor="black", lw=0.4,
                   alpha=0.85, label="%s: %s" % (NAMES[mode], label))
            k += 1
    ax.set_xticks(range(len(seqs)))
    ax.set_xticklabels(seqs)
    ax.set_ylabel("RMSE (cm)")
    ax.set_title("E5: device against server accuracy")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


SHARE_COLOURS = {"graph": "tab:blue", "direct": "tab:orange"}


def vo_latency_vs_devices(rows, paper, path):
    """E6: VO sync latency (scaled back) against devices, graph and direct, with the paper's."""
    against_devices(rows, "share", "vo_latency_scaled_ms_median",
                    [(s, SHARE_COLOURS[s], s) for s in ("graph", "direct")], paper,
                    "VO sync latency, median (ms)", "E6: VO sync latency, graph against direct",
                    path)


def vo_success(rows, path):
    """E7: VO success per distance (or angle) bin, grid against keyframe, one panel per
    scenario."""
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows)) or ["none"]
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5.4 * len(scenarios), 4.0),
                             squeeze=False)
    for ax, scenario in zip(axes[0], scenarios):
        rs = [r for r in rows if r["scenario"] == scenario]
        for attach, colour in (("grid", "tab:blue"), ("keyframe", "tab:red")):
            pts = sorted((r["bin_start"], 100.0 * r["success"]) for r in rs
                         if r["attach"] == attach and r["success"] is not None)
            if pts:
                ax.plot(*zip(*pts), "o-", color=colour, label=attach)
        by = rs[0]["by"] if rs else "by_distance"
        ax.set_xlabel("distance to the VO (m)" if by == "by_distance" else
                      "angle from the registering view (deg)")
        ax.set_ylabel("success (%)")
        ax.set_ylim(-5, 105)
        ax.set_title("E7: %s" % scenario)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def montage(images, titles, path):
    """E8: the devices' ar_view frames side by side (2 columns)."""
    n = max(1, len(images))
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 4.8 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, img, title in zip(axes.flat, images, titles):
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
