#!/usr/bin/env bash
# Session benchmarks for the server and device targets (long runs: not part of
# the test suite). Runs run_session on the synthetic corridor: 1 device in ecar
# and edgeslam mode (traffic side by side), then 2, 4 and 8 devices (latency and
# server time under load), and writes every summary plus a markdown table to
# out/bench_sessions/README.md.
#
# Usage: scripts/bench_sessions.sh [--frames N]   (default 400 frames per device;
#        0 = the whole 30 m walk)
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
FRAMES=400
[[ "${1:-}" == "--frames" ]] && FRAMES="$2"
bash scripts/setup.sh
source scripts/env.sh
OUT="$ROOT/out/bench_sessions"
mkdir -p "$OUT"

run() {  # run NAME ARGS...
  local name="$1"; shift
  echo "== $name: run_session $*"
  rosrun ecar_sim run_session --scene config/scenes/corridor.yaml --frames "$FRAMES" \
    --out "$OUT/$name" "$@" | tee "$OUT/$name.log"
}

run ecar_1 --devices 1 --sync-mode ecar
run edgeslam_1 --devices 1 --sync-mode edgeslam
run ecar_2 --devices 2 --device-names device_0,device_3
run ecar_4 --devices 4 --device-names device_0,device_3,device_4,device_5
run ecar_8 --devices 8 --device-names device_0,device_2,device_3,device_4,device_5,device_6,device_7,device_1

/usr/bin/python3 - "$OUT" <<'PY'
import json, os, sys
out = sys.argv[1]
rows = []
for name in ["ecar_1", "edgeslam_1", "ecar_2", "ecar_4", "ecar_8"]:
    path = os.path.join(out, name, "summary.json")
    if not os.path.exists(path):
        continue
    s = json.load(open(path))
    o = s["overall"]
    devs = s["per_device"].values()
    dvs = [d["device_vs_server_rmse_m"] for d in devs if d["device_vs_server_rmse_m"] is not None]
    trk = [d["tracked_after_first_graph"] for d in devs if d["tracked_after_first_graph"] is not None]
    graphs = sum(d["graphs_received"] for d in devs)
    uploads = sum(d["uploads"] for d in devs)
    f = lambda x, k=1.0, n=1: "n/a" if x is None else "%.*f" % (n, x * k)
    rows.append("| %s | %d | %s | %s | %s/%s | %s | %s | %s | %s | %s | %s | %d/%d | %s |" % (
        name, len(s["devices"]), s["sync_mode"], f(o["local_graph_bytes_median"], 1, 0),
        f(o["points_per_graph_median"], 1, 0), f(o["bytes_per_point_median"], 1, 1),
        f(o["latency_ms_median"]), f(o["latency_ms_p95"]), f(o["server_ms_median"]),
        f(max(dvs) if dvs else None, 100, 2), f(min(trk) if trk else None, 100, 1),
        f(s["pacing"]["achieved_rate"], 1, 2), graphs, uploads,
        "yes" if s["pacing"]["kept_up"] else "no"))
with open(os.path.join(out, "README.md"), "w") as f:
    f.write("# Session benchmarks (scripts/bench_sessions.sh)\n\n")
    f.write("| run | devices | mode | graph B median | points / B per point | latency ms median | "
            "p95 | server ms median | worst device-vs-server cm | worst device tracked % | "
            "playback rate | graphs/uploads | kept up |\n")
    f.write("|" + "---|" * 13 + "\n")
    f.write("\n".join(rows) + "\n")
print(open(os.path.join(out, "README.md")).read())
PY
