#!/usr/bin/env bash
# Runs the libFuzzer targets of test/fuzz, each for N seconds, from its seed
# corpus in test/fuzz/corpus/<target> (copied: new inputs go to
# out/fuzz/<target>/corpus, the repository's seeds stay as they are). A crash,
# leak, timeout (a hang) or out-of-memory stops the target and fails the run;
# the input is saved as out/fuzz/<target>/crash-* (keep it as a regression seed
# once fixed: test/fuzz/corpus/<target>/regression-*).
#
# Usage: scripts/fuzz.sh [--seconds N] [--runs N] [TARGET...]
#   targets: map_file upload local_graph scene vo_request (default: all)
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
SECONDS_EACH=60
RUNS=0
TARGETS=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) SECONDS_EACH="$2"; shift 2 ;;
    --runs) RUNS="$2"; shift 2 ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    *) TARGETS+=("$1"); shift ;;
  esac
done
[[ ${#TARGETS[@]} -eq 0 ]] && TARGETS=(map_file upload local_graph scene vo_request)
bins=()
for t in "${TARGETS[@]}"; do bins+=("${t}_fuzz"); done
bash scripts/sanitize_build.sh "${bins[@]}"

status=0
for t in "${TARGETS[@]}"; do
  work="out/fuzz/$t"
  mkdir -p "$work/corpus"
  cp -n test/fuzz/corpus/"$t"/* "$work/corpus/" 2>/dev/null || true
  runs_text=""
  [[ "$RUNS" -gt 0 ]] && runs_text=" or $RUNS runs"
  echo "[fuzz] $t: ${SECONDS_EACH} s${runs_text} from $(ls "$work/corpus" | wc -l) inputs"
  limit=(-max_total_time="$SECONDS_EACH")
  [[ "$RUNS" -gt 0 ]] && limit+=(-runs="$RUNS")
  # -timeout: an input taking over 10 s is a hang; -rss_limit_mb: unbounded allocation.
  if ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=1 \
     UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
     "build_sanitize/${t}_fuzz" "$work/corpus" "${limit[@]}" -timeout=10 -rss_limit_mb=2048 \
       -max_len=1048576 -artifact_prefix="$work/" -print_final_stats=1 \
       >"$work/log.txt" 2>&1; then
    grep -E "^stat::number_of_executed_units|^stat::peak_rss_mb" "$work/log.txt" |
      sed "s/^/[fuzz] $t: /"
  else
    tail -40 "$work/log.txt"
    echo "[fuzz] $t FAILED: see $work/log.txt and $work/crash-* / leak-* / timeout-* / oom-*"
    status=1
  fi
done
exit $status
