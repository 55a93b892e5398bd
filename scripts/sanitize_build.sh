#!/usr/bin/env bash
# Builds test/sanitize into build_sanitize/: ecar_core, its tools and gtests with
# AddressSanitizer + UndefinedBehaviorSanitizer, and the libFuzzer targets of
# test/fuzz (clang). Used by `scripts/test.sh --sanitize` and `scripts/fuzz.sh`;
# needs the workspace built (devel/include holds the generated messages).
#
# Usage: scripts/sanitize_build.sh [TARGET...]   (default: everything)
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
if ! command -v clang++ >/dev/null; then
  echo "[sanitize] clang++ is missing: run scripts/setup.sh" >&2
  exit 1
fi
if [[ ! -f devel/include/ecar_msgs/LocalGraph.h ]]; then
  echo "[sanitize] building the workspace first (the generated messages)"
  bash scripts/setup.sh
fi
mkdir -p build_sanitize
if [[ ! -f build_sanitize/CMakeCache.txt ]]; then
  CC=clang CXX=clang++ cmake -S test/sanitize -B build_sanitize \
    -DECAR_MSGS_INCLUDE="$ROOT/devel/include" >build_sanitize/configure.log 2>&1 || {
    tail -30 build_sanitize/configure.log
    echo "[sanitize] configuring failed (build_sanitize/configure.log)" >&2
    exit 1
  }
fi
targets=()
for t in "$@"; do targets+=(--target "$t"); done
echo "[sanitize] building ${*:-everything} in build_sanitize (clang, ASan + UBSan)"
cmake --build build_sanitize -j"$(nproc)" "${targets[@]}" >build_sanitize/build.log 2>&1 || {
  grep -E "error|Error" build_sanitize/build.log | head -30
  echo "[sanitize] build failed (build_sanitize/build.log)" >&2
  exit 1
}
