#!/usr/bin/env bash
# The paper's experiments, one command: runs them (long: not part of the test suite; --quick is,
# in test/reproduce_quick_test.py) and writes CSV, PNG plots and REPORT.md (the paper's figures
# beside ours) into out/reproduce/: E1 local graph traffic, E2 sync latency against 1..20
# devices and E3 its parts (one sweep of light devices on the campus link, eCAR and edgeSLAM);
# E4 server ATE against JPEG quality and E5 device-vs-server ATE; E6 VO sync latency, graph
# against direct, and E7 VO success by distance and angle, grid against keyframe; E8 four
# devices drawing one picture. Needs root (network namespaces).
#   --quick         fewer and shorter sessions (about 10 minutes on 2 cores; the full run 90)
#   --only E4,E8    only these experiments (those sharing sessions run together); REPORT.md
#                   keeps the sections of the others already in the folder
#   --out DIR       instead of out/reproduce
#   --report-only   the plots and REPORT.md again from the CSV files
#
# Usage: scripts/reproduce.sh [--quick] [--only E1,...] [--out DIR] [--report-only]
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh
exec /usr/bin/python3 -m ecar_sim.reproduce "$@"
