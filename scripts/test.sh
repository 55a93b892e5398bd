#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: the packages' gtests
# and rostests (catkin_make run_tests, checked with catkin_test_results) and the
# end-to-end tests under test/. Exits non-zero on any failure.
#
# Usage: scripts/test.sh
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh

echo "[test] building and running the package tests (catkin_make run_tests)"
rm -rf build/test_results
catkin_make run_tests -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 -j"$(nproc)" >test.log 2>&1 || {
  tail -80 test.log
  echo "[test] catkin_make run_tests failed (full log: test.log)"
  exit 1
}
status=0
catkin_test_results build/test_results || status=1

# End-to-end tests under test/: rostest launch files and executable scripts.
shopt -s nullglob
for t in test/*.test; do
  echo "[test] rostest $t"
  rostest --text "$ROOT/$t" || status=1
done
for t in test/*_test.sh test/*_test.py; do
  echo "[test] $t"
  "$ROOT/$t" || status=1
done

/usr/bin/python3 scripts/count_results.py build/test_results
exit $status
