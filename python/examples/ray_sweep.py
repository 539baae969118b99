"""A sweep of friction μ × push force on Ray: the box of scene A2 (scenes/a2_push_slide.toml)
pushed at its centre of mass, on a grid of μ and f_x, split into Ray tasks that each run an
ecp.batch chunk; the gathered table is checked bit for bit against ecp.batch on this machine.

    python python/examples/ray_sweep.py                     # local Ray with 2 CPUs, 9 × 6 grid
    python python/examples/ray_sweep.py --mu 3 --fx 2 --steps 10
    python python/examples/ray_sweep.py --address auto      # on a node of a running Ray cluster

Prints the final velocity of every grid point: the box stays put while f_x ≤ μ m g (stick) and
slides with v = (f_x/m − μ g) t beyond.
"""

import argparse
import pathlib

import numpy as np
import ray

import ecp
import ecp.ray

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mu", type=int, default=9, help="number of μ values in [0.1, 0.5]")
    parser.add_argument("--fx", type=int, default=6, help="number of push forces in [10, 60] N")
    parser.add_argument("--steps", type=int, default=None, help="steps per run (default: the scene's 50)")
    parser.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray (ignored with --address)")
    parser.add_argument("--address", default=None, help="a Ray cluster to connect to, e.g. auto")
    args = parser.parse_args()

    if args.address:
        ray.init(address=args.address)
    else:
        ray.init(num_cpus=args.cpus, include_dashboard=False, log_to_driver=False)
    try:
        scene = ecp.Scene.from_toml(ROOT / "scenes" / "a2_push_slide.toml")
        grid = {"mu": np.linspace(0.1, 0.5, args.mu), "fx": np.linspace(10.0, 60.0, args.fx)}
        swept = ecp.ray.sweep(scene, grid=grid, steps=args.steps)
        local = ecp.batch(scene, grid=grid, steps=args.steps)
        same = all(
            (np.asarray(swept.table[k]).tobytes() == np.asarray(local.table[k]).tobytes())
            if isinstance(local.table[k], np.ndarray)
            else swept.table[k] == local.table[k]
            for k in local.table
        )
        vx = np.asarray(swept.table["vx"]).reshape(args.mu, args.fx)
        print(f"{len(swept)} runs in {swept.chunks} Ray tasks, {swept.failed} failed; "
              f"identical to ecp.batch: {same}")
        print("final v_x (m/s); rows μ, columns f_x (N)")
        print("   μ \\ f_x " + " ".join(f"{f:7.1f}" for f in grid["fx"]))
        for mu, row in zip(grid["mu"], vx):
            print(f"{mu:10.3f} " + " ".join(f"{v:7.3f}" for v in row))
        if not same:
            raise SystemExit("the Ray sweep differs from ecp.batch")
    finally:
        ray.shutdown()


if __name__ == "__main__":
    main()
