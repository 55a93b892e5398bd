#!/usr/bin/env bash
# Soak and fault injection: light devices walking their routes back and forth against one
# server for minutes, with the server killed (SIGKILL) and restarted from its autosave and
# database, the devices killed and restarted, the VO database's disk full for a while, and
# hostile inputs mixed in. Reports server memory over time, acknowledged VOs lost, device
# recoveries, crashes and every hostile input's outcome (OUT/REPORT.md, summary.json,
# memory.png). Needs root for the disk-full fault (a tmpfs; --disk-full-for 0 without it).
#
# Usage: scripts/soak.sh [--devices 8] [--minutes 10] [--out out/soak] [soak flags...]
#        scripts/soak.sh --quick     the short version CI runs (2 devices, 2 minutes,
#                                    every fault at least once)
# Every flag: rosrun ecar_sim soak --help
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh
args=("$@")
if [[ "${1:-}" == "--quick" ]]; then
  # Short routes; two server kills, one device restart, 20 s of full disk; memory growth
  # reported, not judged (no server life is long enough).
  args=(--devices 2 --minutes 2 --frames 160 --kill-every 40 --restart-devices-every 65
        --disk-full-at 0.3 --disk-full-for 15 --hostile-every 2 --autosave-period 15
        --warmup 30 --max-growth 0 --recover-timeout 60 --out "$ROOT/out/soak_quick"
        "${@:2}")
fi
exec rosrun ecar_sim soak "${args[@]}"
