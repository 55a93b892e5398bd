#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: the packages' gtests
# and rostests (catkin_make run_tests, checked with catkin_test_results) and the
# end-to-end tests under test/. Exits non-zero on any failure.
#
# Usage: scripts/test.sh              everything (what CI runs)
#        scripts/test.sh --sanitize   ecar_core's gtests built with AddressSanitizer and
#                                     UndefinedBehaviorSanitizer (clang, build_sanitize/);
#                                     --sanitize-quick leaves out the long SLAM and
#                                     rendering tests (CI runs that one)
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh

if [[ "${1:-}" == "--sanitize" || "${1:-}" == "--sanitize-quick" ]]; then
  skip=()
  targets=()  # default: everything (the tools, every gtest and the fuzz targets)
  if [[ "$1" == "--sanitize-quick" ]]; then
    # The long ones: whole SLAM sessions on rendered sequences (minutes each under ASan),
    # neither built nor run; trajectory_eval_test runs the ecar_eval_traj tool.
    skip=(-E "$(paste -sd'|' test/sanitize/slow_tests.txt)")
    targets=(ecar_eval_traj)
    for t in src/ecar_core/test/*/*_test.cpp; do
      name="$(basename "$t" .cpp)"
      grep -qxF "^${name}\$" test/sanitize/slow_tests.txt || targets+=("$name")
    done
  fi
  bash scripts/sanitize_build.sh "${targets[@]}"
  echo "[test] ecar_core gtests with ASan + UBSan${skip:+ (quick: not $(tr -d '^$' <test/sanitize/slow_tests.txt | paste -sd' '))}"
  mkdir -p build/test_results/sanitize
  ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  GTEST_OUTPUT="xml:$ROOT/build/test_results/sanitize/" \
    ctest --test-dir build_sanitize --output-on-failure -j"$(nproc)" "${skip[@]}"
  exit $?
fi

echo "[test] building and running the package tests (catkin's run_tests targets)"
rm -rf build/test_results
catkin_make tests -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
  -j"$(nproc)" >test.log 2>&1 || {
  tail -80 test.log
  echo "[test] building the tests failed (full log: test.log)"
  exit 1
}
# Each package's tests by kind (run_tests_<package>_<kind>): the gtests (unit tests, no
# timing) in parallel, the rest one at a time: two end-to-end tests sharing the 2 cores
# play their devices in less than real time, each slowing the other (the rostests and
# session tests measure a live system: poses, VOs received, latencies).
targets="$(make -C build help | sed -n 's/^\.\.\. \(run_tests_[a-z_]*\)$/\1/p')"
unit=() live=()
for pkg in $(sed -n 's:.*<name>\(.*\)</name>.*:\1:p' src/*/package.xml); do
  for t in $(grep -E "^run_tests_${pkg}_[a-z]+\$" <<<"$targets"); do
    if [[ "$t" == *_gtest ]]; then unit+=("$t"); else live+=("$t"); fi
  done
done
{ make -C build -j"$(nproc)" "${unit[@]}" && make -C build -j1 "${live[@]}"; } >>test.log 2>&1 || {
  tail -80 test.log
  echo "[test] running the package tests failed (full log: test.log)"
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
