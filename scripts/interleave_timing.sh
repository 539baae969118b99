#!/usr/bin/env bash
# Interleaved per-step timing of two `ecp` binaries (docs/latency.md): each round runs every case
# with BASE_BIN, then with NEW_BIN, and prints the `summary.json` `step_us` median of each run, so
# that the machine's load moves both alike. Then the median over the rounds of each case.
#
#   scripts/interleave_timing.sh NEW_BIN ROUNDS BASE_BIN [CASE ...]
#
# A case is `scene:solver` (scene under scenes/ without `.toml`); default: desk with newton, path
# and conic, a1_sliding and tbar with newton and path.
set -euo pipefail
new=$1; rounds=$2; base=$3; shift 3
cases=("$@")
if [ ${#cases[@]} -eq 0 ]; then
  cases=(desk:newton desk:path desk:conic a1_sliding:newton tbar:newton a1_sliding:path tbar:path)
fi
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for r in $(seq 1 "$rounds"); do
  for c in "${cases[@]}"; do
    scene=${c%%:*}; solver=${c##*:}
    for which in base new; do
      bin=$base; [ "$which" = new ] && bin=$new
      "$bin" run "scenes/$scene.toml" --solver "$solver" --no-plots --quiet --out "$tmp/o" >/dev/null
      us=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['step_us']['median'])" "$tmp/o/summary.json")
      echo "$r $c $which $us" | tee -a "$tmp/all"
    done
  done
done
echo "median over $rounds rounds (base -> new):"
python3 - "$tmp/all" <<'PY'
import sys, statistics, collections
d = collections.defaultdict(list)
for line in open(sys.argv[1]):
    r, c, w, us = line.split()
    d[(c, w)].append(float(us))
for c in dict.fromkeys(k[0] for k in d):
    b, n = statistics.median(d[(c, 'base')]), statistics.median(d[(c, 'new')])
    print(f"{c:20s} {b:8.3f} -> {n:8.3f} us  ({100*(n-b)/b:+.1f} %)  new range {min(d[(c,'new')]):.3f}-{max(d[(c,'new')]):.3f}")
PY
