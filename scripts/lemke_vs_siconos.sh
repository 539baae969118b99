#!/usr/bin/env bash
# The pivoting core against Siconos' lexicographic Lemke (issue 18, item 4;
# docs/backends.md#lemke-speed), in one command:
#
#   scripts/lemke_vs_siconos.sh [ROUNDS] [REPEAT] [OUT_DIR]
#
# ROUNDS (default 5) interleaved rounds; in each, every n of 10, 30, 100, 300 is solved by
# `ecp lcp FILE --repeat REPEAT` (default 1000; REPEAT/5 at n = 300), by Siconos from C
# (benches/siconos_lemke.c) and from Python (benches/siconos_lemke.py), one right after the
# other, so that the machine's load moves all three alike. Each run reports the best and the
# median of its warm solves (µs). The summary: per n and solver, the best of the rounds' bests,
# the median of the rounds' medians, the spread of the bests, the pivots, how often ours was below
# Siconos from C in the same round, and max |z_ours − z_Siconos| (from C).
#
# Environment: ECP (default target/release/ecp), BASE (another `ecp` binary timed as a fourth
# column, e.g. /work/base11/ecp; default none), PYTHON (default /usr/bin/python3, the one with
# Debian's python3-siconos).
#
# Needs Debian's Siconos (`apt-get install -y python3-siconos libsiconos-numerics-dev`) and a
# C compiler; builds target/siconos_lemke and writes target/lcp/lcp_n*.{json,txt} (the instances
# of `examples/lcp_instances.rs`, ecp::lcp::random_lcp(n, 1)) when they are missing. The raw
# JSON lines go to OUT_DIR (default a fresh temporary directory, printed), with `uptime` per round.
set -euo pipefail
rounds=${1:-5}
repeat=${2:-1000}
cd "$(dirname "$0")/.."
out=${3:-$(mktemp -d /tmp/lemke_vs_siconos.XXXXXX)}
mkdir -p "$out"
ecp=${ECP:-target/release/ecp}
base=${BASE:-}
python=${PYTHON:-/usr/bin/python3}
sizes=(10 30 100 300)

if ! "$python" -c 'import siconos.numerics' 2>/dev/null || [ ! -f /usr/include/siconos/numerics/LCP_Solvers.h ]; then
  echo "Siconos is missing: apt-get install -y python3-siconos libsiconos-numerics-dev" >&2
  exit 2
fi
[ -x "$ecp" ] || { echo "no $ecp: cargo build --release --bin ecp" >&2; exit 2; }
if [ ! -x target/siconos_lemke ] || [ benches/siconos_lemke.c -nt target/siconos_lemke ]; then
  cc -O2 -o target/siconos_lemke benches/siconos_lemke.c -I/usr/include/siconos/numerics \
    -I/usr/include/siconos -lsiconos_numerics -lm
fi
for n in "${sizes[@]}"; do
  if [ ! -f "target/lcp/lcp_n$n.json" ]; then
    cargo run --release --quiet --example lcp_instances -- target/lcp >/dev/null
  fi
  if [ ! -f "target/lcp/lcp_n$n.txt" ] || [ "target/lcp/lcp_n$n.json" -nt "target/lcp/lcp_n$n.txt" ]; then
    python3 benches/lcp_to_text.py "target/lcp/lcp_n$n.json" >"target/lcp/lcp_n$n.txt"
  fi
done

echo "raw results in $out"
: >"$out/runs.jsonl"
: >"$out/uptime.txt"
for r in $(seq 1 "$rounds"); do
  echo "round $r: $(uptime)" | tee -a "$out/uptime.txt"
  for n in "${sizes[@]}"; do
    rep=$repeat
    [ "$n" -ge 300 ] && rep=$((repeat / 5 > 0 ? repeat / 5 : 1))
    json=target/lcp/lcp_n$n.json
    # Rotate the order per round, so that no solver always runs first after a size change.
    order=(ours c py)
    [ -n "$base" ] && order+=(base)
    k=$(((r - 1) % ${#order[@]}))
    order=("${order[@]:k}" "${order[@]:0:k}")
    for who in "${order[@]}"; do
      case $who in
        ours) line=$("$ecp" lcp "$json" --repeat "$rep") ;;
        base) line=$("$base" lcp "$json" --repeat "$rep") ;;
        c) line=$(target/siconos_lemke "target/lcp/lcp_n$n.txt" "$rep") ;;
        py) line=$("$python" benches/siconos_lemke.py "$json" --repeat "$rep") ;;
      esac
      # One line per run: round, solver, n, then the solver's own JSON.
      "$python" -c 'import json, sys
d = json.loads(sys.argv[4])
print(json.dumps({"round": int(sys.argv[1]), "who": sys.argv[2], "n": int(sys.argv[3]), **d}))' \
        "$r" "$who" "$n" "$line" >>"$out/runs.jsonl"
    done
  done
done
echo "end: $(uptime)" | tee -a "$out/uptime.txt"

"$python" - "$out/runs.jsonl" <<'PY'
import collections, json, statistics, sys

runs = [json.loads(l) for l in open(sys.argv[1])]
by = collections.defaultdict(list)
for d in runs:
    by[(d["n"], d["who"])].append(d)
names = {"ours": "ours", "base": "BASE", "c": "Siconos C", "py": "Siconos Py"}
whos = [w for w in ("ours", "base", "c", "py") if any(k[1] == w for k in by)]
print()
print("µs per warm solve: best of the rounds' bests (their range) / median of the rounds' medians")
print("| n | pivots (ours / Siconos) | " + " | ".join(names[w] for w in whos)
      + " | ours < C in rounds | max |z − z_C| |")
print("|---|---|" + "---|" * len(whos) + "---|---|")
for n in sorted({k[0] for k in by}):
    cells = []
    for w in whos:
        ds = by[(n, w)]
        bests = [d["best_us"] for d in ds]
        meds = [d["median_us"] for d in ds]
        cells.append(f"{min(bests):.3f} ({min(bests):.3f}–{max(bests):.3f}) / {statistics.median(meds):.3f}")
    ours = {d["round"]: d for d in by[(n, "ours")]}
    c = {d["round"]: d for d in by[(n, "c")]}
    below = sum(ours[r]["best_us"] < c[r]["best_us"] for r in ours if r in c)
    dz = max(max(abs(a - b) for a, b in zip(ours[r]["z"], c[r]["z"])) for r in ours if r in c)
    piv = f'{by[(n, "ours")][0]["pivots"]} / {by[(n, "c")][0]["pivots"]}'
    print(f"| {n} | {piv} | " + " | ".join(cells) + f" | {below}/{len(ours)} | {dz:.1e} |")
bad = [d for d in runs if d.get("status", "solved") != "solved" or d.get("info", 0) != 0
       or d["residual"] > 1e-12]
if bad:
    print(f"NOT SOLVED or residual > 1e-12 in {len(bad)} runs:", bad[:3])
PY
