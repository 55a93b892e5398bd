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
    rosrun ecar_sim make_dataset --scene "config/scenes/$1.yaml" --device "$2" --out "$dir" --quiet >&2
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
# Issue 12: loops, the atlas (maps that start apart and merge), a device that
# goes blank and resumes somewhere new, two cameras in one map.
run ring_loop --dataset "$(dataset ring walker)" --every 4 --jpeg-quality 70
run ring_no_loop --dataset "$(dataset ring walker)" --every 4 --jpeg-quality 70 --no-loops
run atlas_ring_small --dataset "$(dataset ring_small walker)" --devices "$(dataset ring_small walker_b)" \
  --every 4 --jpeg-quality 70 --atlas
run atlas_ring_small_no_odometry --dataset "$(dataset ring_small walker)" \
  --devices "$(dataset ring_small walker_b)" --every 4 --jpeg-quality 70 --atlas --no-odometry
run atlas_blind --dataset "$(dataset ring_small blind)" --every 4 --jpeg-quality 70 --atlas
run atlas_corridor --dataset "$(dataset corridor device_0)" --devices "$(dataset corridor device_1)" \
  --every 4 --jpeg-quality 70 --atlas
run two_cameras --dataset "$(dataset corridor device_0)" --devices "$(dataset corridor phone_800)" \
  --every 4 --jpeg-quality 70
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
# The atlas's events: merges (found at, first overlap, delay), tracking gaps,
# loops, and the ATE after the last merge (SE(3) with odometry, and Sim(3)).
events = ["| run | maps | merges: upload (first overlap, delay) | gaps: lost, blank, tracked again (delay, new map) | loops: upload (moved m, ms) | ATE after merges SE(3)/Sim(3) (m) | keyframe ATE Sim(3) (m), scale error |",
          "|---|---|---|---|---|---|---|"]
for f in sorted(out.glob("*.json")):
    s = json.load(open(f))
    if "merges" not in s:
        continue
    merges = "; ".join(f"{m['device']} {m['upload']} ({m.get('overlap_device')} {m.get('overlap_upload')}, {m.get('delay_uploads')})" for m in s["merges"]) or "-"
    gaps = "; ".join(f"{g['lost_upload']}, {g['blank_uploads']}, {g['tracked_upload']} ({g['delay_uploads']}, {'new' if g['new_map'] else 'same'})"
                     for d in s["devices"] for g in d.get("gaps", []) if g["blank_uploads"] > 0 or g["tracked_upload"] - g["lost_upload"] >= 3) or "-"
    loops = "; ".join(f"{l['upload']} ({l['moved_m']:.3f}, {l['ms']:.0f})" for l in s.get("loop_closures", [])) or "-"
    after = s.get("ate_after_merges"); after3 = s.get("ate_after_merges_sim3")
    after_txt = f"{after['rmse']:.4f}/{after3['rmse']:.4f}" if after and after3 and after.get("n") else "-"
    kf = s.get("ate_keyframes_sim3") or s.get("ate_keyframes")
    scale = s.get("scale_keyframes_sim3")
    kf_txt = f"{kf['rmse']:.4f}" + (f", {100.0 * (scale - 1.0):+.2f}%" if scale else "") if kf else "-"
    events.append(f"| {f.stem} | {s['maps']} | {merges} | {gaps} | {loops} | {after_txt} | {kf_txt} |")
text = "# SLAM benchmarks\n\n" + "\n".join(rows) + "\n\n## Atlas events\n\n" + "\n".join(events) + "\n"
(out / "README.md").write_text(text)
print(text)
PY
