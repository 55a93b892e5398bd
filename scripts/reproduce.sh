#!/usr/bin/env bash
# The paper's experiments, one command: runs them (long: not part of the test suite) and writes
# CSV, PNG plots and REPORT.md (the paper's figures beside ours) into out/reproduce/.
# Implemented so far, all from one sweep of light devices on the campus link: E1 (local graph
# traffic, eCAR against edgeSLAM), E2 (sync latency against 1..20 devices, eCAR and edgeSLAM) and
# E3 (the latency's parts against devices). Needs root (network namespaces). --report-only: the
# plots and REPORT.md again from the CSV files.
#
# Usage: scripts/reproduce.sh [--quick] [--out DIR] [--report-only]
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh
exec /usr/bin/python3 -m ecar_sim.reproduce "$@"
