#!/usr/bin/env bash
# SLAM benchmarks for the targets of the SLAM core (long runs: not part of the
# test suite). Generates the synthetic datasets once into out/datasets/, then
# runs ecar_slam_offline on each target workload and writes JSON summaries and
# a markdown table to out/bench_slam/.
#
# Usage: scripts/bench_slam.sh [--quick]   (--quick: skip the JPEG quality sweep)
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
QUICK=0
[[ "${1:-}" == "--quick" ]] && QUICK=1
bash scripts/setup.sh
source scripts/env.sh
DATA="$ROOT/out/datasets"
OUT="$ROOT/out/bench_slam"
SHARED="$(cd "$ROOT/.." && pwd)/shared/data"
mkdir -p "$DATA" "$OUT"

dataset() {  # dataset SCENE DEVICE
  local dir="$DATA/$1_$2"
  if [[ ! -f "$dir/camera.yaml" ]]; then
    rosrun ecar_sim make_dataset --scene "config/scenes/$1.yaml" --device "$2" --out "$dir" --quiet
  fi
  echo "$dir"
}

run() {  # run NAME ARGS...
  local name="$1"; shift
  echo "== $name: ecar_slam_offline $*"
  rosrun ecar_core ecar_slam_offline "$@" --summary "$OUT/$name.json" --out "$OUT/$name.txt" 2>/dev/null |
    tee "$OUT/$name.log"
}

run corridor --dataset "$(dataset corridor device_0)" --every 4 --jpeg-quality 70 --no-odometry
run half_circle --dataset "$(dataset room half_circle)" --every 4 --jpeg-quality 70 --no-odometry
run shake --dataset "$(dataset room shake)" --every 4 --jpeg-quality 70 --no-odometry
run two_devices --dataset "$(dataset corridor device_0)" --devices "$(dataset corridor device_1)" \
  --every 4 --jpeg-quality 70 --no-odometry
if [[ -d "$SHARED/kitti07_0-159" ]]; then
  run kitti07 --dataset "$SHARED/kitti07_0-159"
fi
if [[ -d "$SHARED/euroc_v1_01_cam0_0-94" ]]; then
  run euroc --dataset "$SHARED/euroc_v1_01_cam0_0-94"
fi
if ((QUICK == 0)); then
  for q in 100 90 80 70 60 50 40 30 20 10; do
    run "corridor_q$q" --dataset "$(dataset corridor device_0)" --every 4 --jpeg-quality "$q" --no-odometry
  done
fi
/usr/bin/python3 - "$OUT" <<'PY'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
rows = ["| run | tracked | tracked after init/join | init (or join) upload | first overlap upload | ATE rmse (m) | keyframes | points | ORB med/p95 (ms) | tracking med/p95 (ms) | local BA med/p95 (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|"]
for f in sorted(out.glob("*.json")):
    s = json.load(open(f))
    t = s["times_ms"]
    tracked = ", ".join(f"{d['tracked']}/{d['uploads']}" for d in s["devices"])
    start = [d["init_upload"] if d["init_upload"] >= 0 else d["joined_upload"] for d in s["devices"]]
    init = ", ".join(map(str, start))
    after = ", ".join(f"{100.0 * d['tracked'] / max(1, d['uploads'] - max(0, b)):.1f}%" for d, b in zip(s["devices"], start))
    overlap = ", ".join(str(d.get("first_overlap_upload", -1)) for d in s["devices"])
    ate = s["ate"]["rmse"]
    rows.append(f"| {f.stem} | {tracked} | {after} | {init} | {overlap} | {ate if ate is None else round(ate, 4)} | {s['keyframes']} | {s['map_points']} | "
                f"{t['orb_median']:.1f}/{t['orb_p95']:.1f} | {t['tracking_median']:.1f}/{t['tracking_p95']:.1f} | {t['local_ba_median']:.1f}/{t['local_ba_p95']:.1f} |")
(out / "README.md").write_text("# SLAM benchmarks\n\n" + "\n".join(rows) + "\n")
print("\n".join(rows))
PY
