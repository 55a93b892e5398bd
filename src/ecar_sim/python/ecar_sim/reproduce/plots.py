"""The reproduction's plots (matplotlib, Agg; PNG)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLOURS = {"ecar": "tab:blue", "edgeslam": "tab:red"}
NAMES = {"ecar": "eCAR", "edgeslam": "edgeSLAM"}


def latency_vs_devices(rows, paper, path):
    """E2: median sync latency (scaled back to real time) against devices, each mode, with the
    paper's points."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for mode in ("ecar", "edgeslam"):
        pts = sorted((r["devices"], r["latency_scaled_ms_median"]) for r in rows
                     if r["mode"] == mode)
        if pts:
            ax.plot(*zip(*pts), "o-", color=COLOURS[mode], label="%s (ours)" % NAMES[mode])
        ref = sorted(paper.get(mode, {}).items())
        if ref:
            ax.plot(*zip(*ref), "s--", color=COLOURS[mode], alpha=0.5,
                    label="%s (paper)" % NAMES[mode])
    ax.set_xlabel("devices sharing the campus link")
    ax.set_ylabel("sync latency, median (ms)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("E2: sync latency against devices")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
        ax.set_xlabel("devices")
        ax.set_ylabel("median (ms)")
        ax.set_title("E3: %s" % NAMES[mode])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
