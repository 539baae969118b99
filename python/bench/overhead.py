"""The Python package's overhead on a 400-step desk run: ``ecp.Simulation(scene).run()`` from
Python against the same run inside Rust (the wall time an ``ecp.batch`` job measures for the
set-up and the 400 steps with every record kept). Build the extension optimised first:

    cd python && maturin develop --release && cd ..
    python python/bench/overhead.py [--repeats 30]

Each figure is the best of ``--repeats`` alternating repetitions (the machine may be shared).
"""

import argparse
import pathlib
import time

import ecp

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    scene = ecp.Scene.from_toml(ROOT / "scenes" / "desk.toml")
    python_best = rust_best = float("inf")
    for _ in range(args.repeats):
        started = time.perf_counter()
        traj = ecp.Simulation(scene).run()
        python_best = min(python_best, time.perf_counter() - started)
        assert len(traj) == 400 and traj.converged.all()
        batch = ecp.batch(scene, threads=1, records=True)
        rust_best = min(rust_best, float(batch.timings["wall_s"][0]))
    overhead = python_best / rust_best - 1
    print(f"400-step desk run: Python Simulation.run() {python_best * 1e3:.2f} ms, "
          f"Rust {rust_best * 1e3:.2f} ms (best of {args.repeats}); overhead {100 * overhead:+.1f} %")


if __name__ == "__main__":
    main()
