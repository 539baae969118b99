#!/usr/bin/python3
"""Times Siconos' lexicographic Lemke (siconos.numerics.lcp_lexicolemke) on the LCP files that
`ecp lcp` reads, best and median of N warm solves, for the table of docs/backends.md#lemke-speed.

Not part of the build or the tests. Needs Debian's Siconos and Python:

    apt-get install -y python3-siconos
    cargo run --release --example lcp_instances -- target/lcp
    /usr/bin/python3 benches/siconos_lemke.py target/lcp/lcp_n*.json --repeat 200

Prints one JSON line per file: {"file", "n", "status", "pivots", "best_us", "median_us",
"residual", "call_us"}. Each solve is timed around the call from Python; "call_us" is the best
time of a call to a no-op C function (numpy's empty of one element), the interpreter's share.
"""

import argparse
import json
import statistics
import time

import numpy as np
import siconos.numerics as sn


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--repeat", type=int, default=200)
    args = parser.parse_args()
    for path in args.files:
        with open(path) as f:
            data = json.load(f)
        m = np.ascontiguousarray(np.array(data["M"], dtype=float))
        q = np.array(data["q"], dtype=float)
        n = len(q)
        lcp = sn.LCP(m, q)
        z = np.zeros(n)
        w = np.zeros(n)
        options = sn.SolverOptions(sn.SICONOS_LCP_LEMKE)
        info = sn.lcp_lexicolemke(lcp, z, w, options)  # first (cold) solve
        pivots = int(options.iparam[1])
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter_ns()
            sn.lcp_lexicolemke(lcp, z, w, options)
            times.append((time.perf_counter_ns() - t0) / 1e3)
        calls = []
        for _ in range(args.repeat):
            t0 = time.perf_counter_ns()
            np.empty(1)
            calls.append((time.perf_counter_ns() - t0) / 1e3)
        wz = m @ z + q
        residual = float(np.max(np.abs(np.minimum(z, wz))))
        print(json.dumps({
            "file": path,
            "n": n,
            "status": "solved" if info == 0 else f"info {info}",
            "pivots": pivots,
            "best_us": min(times),
            "median_us": statistics.median(times),
            "residual": residual,
            "call_us": min(calls),
        }))


if __name__ == "__main__":
    main()
