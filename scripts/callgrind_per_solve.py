#!/usr/bin/env python3
"""Instructions per solve, by function, from two callgrind runs of a repeated solve.

    valgrind --tool=callgrind --callgrind-out-file=F5 target/release/examples/step_latency desk-newton 5
    valgrind --tool=callgrind --callgrind-out-file=F25 target/release/examples/step_latency desk-newton 25
    python3 scripts/callgrind_per_solve.py F5 F25 20 [ROWS]

The difference of the two runs divided by the difference of their repetitions (here 20) is the
cost of one solve without the set-up (docs/latency.md). Prints the total and the ROWS (default 40)
costliest functions by self cost.
"""
import collections
import re
import subprocess
import sys


def load(path):
    out = subprocess.run(['callgrind_annotate', '--threshold=100', path],
                         capture_output=True, text=True, check=True).stdout
    cost = collections.Counter()
    for line in out.splitlines():
        m = re.match(r'\s*([\d,]+) \([^)]*\)\s+(.*)', line)
        if m and 'PROGRAM TOTALS' not in line:
            cost[m.group(2).split(' [')[0]] += int(m.group(1).replace(',', ''))
    return cost


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    few, many, reps = load(sys.argv[1]), load(sys.argv[2]), float(sys.argv[3])
    rows = int(sys.argv[4]) if len(sys.argv) > 4 else 40
    per = {k: (many[k] - few.get(k, 0)) / reps for k in many}
    print(f'total per solve {sum(per.values()):.0f}')
    for name, v in sorted(per.items(), key=lambda kv: -kv[1])[:rows]:
        if v > 300:
            print(f'{v:10.0f} {name[:150]}')


if __name__ == '__main__':
    main()
