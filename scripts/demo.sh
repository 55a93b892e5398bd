#!/usr/bin/env bash
# Installs what is missing, builds, and runs eCAR's main job.
#
# So far: generates a short synthetic sequence of the corridor (device_0 walks
# the first metres) and prints where it is, its frame count and the path of a
# contact sheet of its frames.
#
# Usage: scripts/demo.sh [--frames N]
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
FRAMES=120
while [[ $# -gt 0 ]]; do
  case "$1" in
    --frames) FRAMES="$2"; shift 2 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
bash scripts/setup.sh
source scripts/env.sh

OUT="$ROOT/out/demo/corridor_device_0"
echo "[demo] rendering $FRAMES frames of config/scenes/corridor.yaml (device_0)"
rosrun ecar_sim make_dataset --scene config/scenes/corridor.yaml --device device_0 \
  --frames "$FRAMES" --out "$OUT" --bag
