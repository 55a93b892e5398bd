#!/usr/bin/env bash
# Installs what is missing, builds, and runs eCAR's main job: the edge server and
# two devices in the synthetic corridor, each fed by its rendered dataset,
# headless: device_0 walks down the corridor and draws lines on the floor and a
# wall by its scripted touches, then carries one along; device_2 zig-zags in the
# first third and receives them. Prints the session summary (uploads, local
# graphs, device tracking, device-vs-server error, ATE, local graph bytes,
# latency, VO sync against ground truth). Outputs in out/demo/.
#
# Usage: scripts/demo.sh [--frames N] [--sync-mode ecar|edgeslam] [--gui]
#   --frames N   frames per device (default 400; 0 = the whole 30 m walk)
#   --gui        the same demo (device_0 and device_2) with rviz showing both
#                devices' ar_view (roslaunch launch/demo.launch), needs a display
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
FRAMES=400
SYNC=ecar
GUI=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --frames) FRAMES="$2"; shift 2 ;;
    --sync-mode) SYNC="$2"; shift 2 ;;
    --gui) GUI=1; shift ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
bash scripts/setup.sh
source scripts/env.sh

DATA="$ROOT/out/demo/datasets"
if [[ $GUI == 1 ]]; then
  # The datasets as run_session names them (rendered here when missing), then the
  # live demo with rviz.
  SUFFIX=""
  [[ $FRAMES != 0 ]] && SUFFIX="_f$FRAMES"
  for d in device_0 device_2; do
    dir="$DATA/corridor_$d$SUFFIX"
    if [[ ! -f "$dir/groundtruth.txt" ]]; then
      args=(--scene config/scenes/corridor.yaml --device "$d" --out "$dir" --quiet)
      [[ $FRAMES != 0 ]] && args+=(--frames "$FRAMES")
      rosrun ecar_sim make_dataset "${args[@]}"
    fi
  done
  exec roslaunch launch/demo.launch datasets:="$DATA" suffix:="$SUFFIX" sync_mode:="$SYNC" \
    devices:=device_0,device_2
fi

echo "[demo] server + device_0 and device_2 on the synthetic corridor ($SYNC mode), headless"
rosrun ecar_sim run_session --scene config/scenes/corridor.yaml --device-names device_0,device_2 \
  --frames "$FRAMES" --sync-mode "$SYNC" --datasets "$DATA" --out "$ROOT/out/demo/session"
