#!/usr/bin/env bash
# Every launch file under launch/ resolves (well-formed XML, includes found,
# required args given, recursion of multi_device.launch ends) and starts the
# nodes it should: `roslaunch --nodes` with the args a user gives.
set -o pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/env.sh"
failures=0
check() {  # check FILE EXPECTED_NODE_COUNT ARGS...
  local file="$1" expected="$2"; shift 2
  local out
  if ! out="$(roslaunch --nodes "$ROOT/launch/$file" "$@" 2>&1)"; then
    echo "  FAIL $file: roslaunch --nodes failed: $out"
    failures=$((failures + 1)); return
  fi
  local n
  n="$(grep -c '^/' <<<"$out")"
  if [[ "$n" != "$expected" ]]; then
    echo "  FAIL $file $*: $n nodes, expected $expected: $out"
    failures=$((failures + 1)); return
  fi
  echo "  ok   $file $* ($n nodes)"
}
check server.launch 9
check device.launch 1 device:=device_0
check player.launch 1 dataset:=/tmp
check multi_device.launch 8 devices:=4 datasets:=/tmp
check demo.launch 15 datasets:=/tmp
check demo.launch 14 datasets:=/tmp rviz:=false
check replay.launch 11 bag:=/tmp/x.bag
echo "launch_files_test: $failures failure(s)"
exit $((failures > 0))
