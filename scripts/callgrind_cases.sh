#!/usr/bin/env bash
# Instructions per solve of the latency cases under callgrind (docs/latency.md), which do not depend
# on the machine's load: each case of `step_latency` run at two repetition counts, the difference
# over the difference of the counts.
#
#   scripts/callgrind_cases.sh STEP_LATENCY_BINARY OUT_DIR [CASE ...]
#
# Default cases: desk-steps, desk-steps-path, desk-steps-conic (whole desk steps 21-120), a1-steps
# (whole A1 steps 2-50), tbar-newton, tbar-path, a1-newton, a1-path, desk-sensitivity (repeated
# solves, 5 -> 25). Per-function tables: scripts/callgrind_per_solve.py OUT_DIR/CASE.LO OUT_DIR/CASE.HI.
set -euo pipefail
bin=$(realpath "$1"); out=$2; shift 2
cases=("$@")
if [ ${#cases[@]} -eq 0 ]; then
  cases=(desk-steps desk-steps-path desk-steps-conic a1-steps tbar-newton tbar-path a1-newton a1-path desk-sensitivity)
fi
mkdir -p "$out"
total() { callgrind_annotate "$1" 2>/dev/null | awk '/PROGRAM TOTALS/ {gsub(",","",$1); print $1}'; }
for c in "${cases[@]}"; do
  case $c in
    a1-steps*) lo=1; hi=50 ;;
    *-steps*) lo=20; hi=120 ;;
    *) lo=5; hi=25 ;;
  esac
  for n in $lo $hi; do
    valgrind --tool=callgrind --callgrind-out-file="$out/$c.$n" "$bin" "$c" "$n" >/dev/null 2>&1
  done
  a=$(total "$out/$c.$lo"); b=$(total "$out/$c.$hi")
  echo "$c $(( (b - a) / (hi - lo) ))" | tee -a "$out/totals.txt"
done
