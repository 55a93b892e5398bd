#!/usr/bin/env bash
# Every launch file under launch/ resolves (well-formed XML, includes found,
# required args given, recursion of multi_device.launch ends) and starts the
# nodes it should: `roslaunch --nodes` with the args a user gives. Every arg a
# user can set has a doc=; device lists and replay's clock reach the nodes.
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
check multi_device.launch 4 devices:=device_0,device_2 datasets:=/tmp
check demo.launch 15 datasets:=/tmp
check demo.launch 14 datasets:=/tmp rviz:=false
check demo.launch 16 datasets:=/tmp devices:=3 rviz:=false
check replay.launch 11 bag:=/tmp/x.bag
check light_devices.launch 4 devices:=device_0,device_1,device_2 datasets:=/tmp/a,/tmp/b,/tmp/c

expect() {  # expect WHAT PATTERN OUTPUT
  if grep -q -- "$2" <<<"$3"; then echo "  ok   $1"; else
    echo "  FAIL $1: no '$2' in: $3"; failures=$((failures + 1)); fi
}
nodes="$(roslaunch --nodes "$ROOT/launch/demo.launch" datasets:=/tmp 2>&1)"
expect "demo.launch runs the headless demo's devices" "/device_2/device" "$nodes"
expect "demo.launch: rviz for those devices" "--devices device_0,device_2" \
  "$(roslaunch --args rviz "$ROOT/launch/demo.launch" datasets:=/tmp 2>&1)"
expect "multi_device.launch plays each device's dataset" "/tmp/corridor_device_2_f9" \
  "$(roslaunch --dump-params "$ROOT/launch/multi_device.launch" devices:=device_0,device_2 \
     datasets:=/tmp suffix:=_f9 2>&1)"
expect "light_devices.launch gives each device its dataset" "/device_2/device/light/dataset: /tmp/c" \
  "$(roslaunch --dump-params "$ROOT/launch/light_devices.launch" devices:=device_0,device_1,device_2 \
     datasets:=/tmp/a,/tmp/b,/tmp/c 2>&1)"
expect "replay.launch plays with --clock" "--clock --hz=1000" \
  "$(roslaunch --args device_0_bag "$ROOT/launch/replay.launch" bag:=/tmp/x.bag 2>&1)"
expect "replay.launch sets /use_sim_time" "/use_sim_time: true" \
  "$(roslaunch --dump-params "$ROOT/launch/replay.launch" bag:=/tmp/x.bag 2>&1)"
undocumented="$(/usr/bin/python3 - "$ROOT"/launch/*.launch <<'PY'
import sys
import xml.etree.ElementTree as ET
for path in sys.argv[1:]:
    for arg in ET.parse(path).getroot().iter("arg"):
        if "value" not in arg.attrib and not arg.get("doc", "").strip():
            print("%s: arg %s" % (path, arg.get("name")))
PY
)"
if [[ -z "$undocumented" ]]; then echo "  ok   every settable arg has a doc"; else
  echo "  FAIL args without doc=: $undocumented"; failures=$((failures + 1)); fi
echo "launch_files_test: $failures failure(s)"
exit $((failures > 0))
