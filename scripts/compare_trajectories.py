#!/usr/bin/env python3
"""The largest entry difference between two runs' trajectory.csv (or contacts.csv).

    python3 scripts/compare_trajectories.py A/trajectory.csv B/trajectory.csv [--per-column]

Columns of timings, iteration and evaluation counts, residuals and fallbacks are skipped: they
differ between runs of the same code. Prints `<difference> <column> row <i>`, or with
--per-column the largest difference of every compared column.
"""
import csv
import sys

SKIP = ('us', 'time_', 'wall', '_ms', 'iterations', 'f_evals', 'residual', 'attempt',
        'fallback', 'lu', 'qp')


def main():
    args = [a for a in sys.argv[1:] if not a.startswith('--')]
    if len(args) != 2:
        sys.exit(__doc__)
    a, b = (list(csv.DictReader(open(p))) for p in args)
    if len(a) != len(b):
        print('ROWS DIFFER', len(a), len(b))
    worst, per_col = (0.0, '', 0), {}
    for i, (ra, rb) in enumerate(zip(a, b)):
        for k in ra:
            if any(s in k for s in SKIP):
                continue
            try:
                d = abs(float(ra[k]) - float(rb[k]))
            except (TypeError, ValueError):
                continue
            per_col[k] = max(per_col.get(k, 0.0), d)
            if d > worst[0]:
                worst = (d, k, i)
    if '--per-column' in sys.argv:
        for k, d in sorted(per_col.items(), key=lambda kv: -kv[1]):
            print(f'{d:.2e} {k}')
    else:
        print('%.2e %s row %d' % worst)


if __name__ == '__main__':
    main()
