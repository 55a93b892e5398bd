#!/usr/bin/env bash
# End to end: make_dataset renders a short corridor sequence with a bag; the
# dataset reads back (ground truth evaluates to zero error against itself), the
# bag holds every frame's topics, and bad input gives a clear error, no crash.
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/env.sh"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
fails=0
check() {  # check NAME CONDITION...
  local name="$1"; shift
  if "$@"; then echo "  ok   $name"; else echo "  FAIL $name"; fails=$((fails + 1)); fi
}

out="$TMP/corridor"
rosrun ecar_sim make_dataset --scene "$ROOT/config/scenes/corridor.yaml" --device device_1 \
  --frames 12 --out "$out" --bag --quiet >"$TMP/make.log" 2>&1
check "make_dataset exits 0" test $? -eq 0
check "prints the frame count" grep -q "^frames: *12 " "$TMP/make.log"
check "12 images listed" test "$(grep -vc '^#' "$out/rgb.txt")" -eq 12
check "12 images written" test "$(ls "$out/rgb" | wc -l)" -eq 12
for f in camera.yaml groundtruth.txt imu.txt gravity.txt odometry.txt contact_sheet.png; do
  check "$f written" test -s "$out/$f"
done
rosrun ecar_core ecar_eval_traj "$out/groundtruth.txt" "$out/groundtruth.txt" --se3 \
  --summary "$TMP/ate.json" >/dev/null 2>&1
check "ground truth evaluates against itself" /usr/bin/python3 -c "
import json; s = json.load(open('$TMP/ate.json'))
assert s['ate']['translation']['n'] == 12 and s['ate']['translation']['rmse'] < 1e-9, s"
info="$(rosbag info --yaml "$out/device_1.bag")"
for topic in /device_1/camera/image_raw /device_1/camera/camera_info /device_1/imu /tf /device_1/odometry; do
  check "bag has 12 messages on $topic" /usr/bin/python3 -c "
import sys, yaml; info = yaml.safe_load(sys.stdin)
n = {t['topic']: t['messages'] for t in info['topics']}
assert n.get('$topic') == 12, n" <<<"$info"
done

# Bad input: an unknown device, a malformed scene.
rosrun ecar_sim make_dataset --scene "$ROOT/config/scenes/corridor.yaml" --device nobody \
  --out "$TMP/x" >"$TMP/bad.log" 2>&1
rc=$?
check "unknown device: exit 1" test $rc -eq 1
check "unknown device: names it" grep -q "no device named 'nobody'" "$TMP/bad.log"
printf 'name: x\ncamera: {width: 64}\nspaces: []\n' >"$TMP/bad.yaml"
rosrun ecar_sim make_dataset --scene "$TMP/bad.yaml" --device d --out "$TMP/y" >"$TMP/bad2.log" 2>&1
rc=$?
check "bad scene: exit 1" test $rc -eq 1
check "bad scene: names file and key" grep -q "bad.yaml: camera: missing key 'height'" "$TMP/bad2.log"

echo "dataset_pipeline_test: $fails failure(s)"
exit $((fails > 0))
