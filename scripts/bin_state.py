#!/usr/bin/env python3
"""Writes the bin states the bodies benchmarks start from (`benches/bin50_states.csv`).

    cargo run --release -- run scenes/bin50.toml --no-plots --steps 11 --out out/bin50_11
    python3 scripts/bin_state.py scenes/bin50.toml out/bin50_11 11 > benches/bin50_states.csv

Two states of the scene's parts, one row per part, labelled in the `state` column:

- `falling`: the run's state at the end of step `STEP` (11: the lowest layer has landed, the five
  above it are falling), copied from the run's `trajectory.csv` as it is (Rust's shortest
  round-trip decimals, so the state is the run's, bit for bit); every step up to it must have
  converged;
- `settled`: the parts at rest in a stack, each on the floor or on the part below it in its
  column of the drop grid, flat (the scene's roll and pitch dropped, its yaw and x, y kept),
  touching (gap 0). The run itself cannot give this state in reasonable time (its landing steps
  take minutes: `docs/latency.md#bins`), and the stack is a resting state of the same parts.

`tests/user_scenes.rs` (`bin50_states_fit_the_scene`) checks both against the scene (names,
unit quaternions, no overlap, the stack at rest and staying put for a step).
"""

import argparse
import csv
import math
import os
import sys
import tomllib

FIELDS = ["x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz"]
GRID = 9  # parts per layer of the drop grid (`scripts/make_bins.py`)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", help="the bin scene file (scenes/bin50.toml)")
    parser.add_argument("run", help="the output directory of `ecp run` of that scene")
    parser.add_argument("step", type=int, help="the step (from 1) whose end state is `falling`")
    args = parser.parse_args()

    with open(args.scene, "rb") as f:
        scene = tomllib.load(f)
    parts = [b for b in scene["bodies"] if b.get("kind", "dynamic") == "dynamic"]

    with open(os.path.join(args.run, "trajectory.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    if args.step > len(rows):
        sys.exit(f"{args.run}: the trajectory has {len(rows)} steps, not {args.step}")
    failed = [k + 1 for k, r in enumerate(rows[: args.step]) if r["fallback"] == "failed"]
    if failed:
        sys.exit(f"{args.run}: steps {failed} failed; the state must come from converged steps")

    out = csv.writer(sys.stdout, lineterminator="\n")
    print(f"# The states of {scene['name']}'s parts the bodies benchmarks start from; written by")
    print(f"# `python3 scripts/bin_state.py {args.scene} <run> {args.step}` (see that script).")
    print(f"# falling: the end of step {args.step} of `ecp run {args.scene}` (Newton);")
    print("# settled: the parts at rest, stacked flat in the columns of the drop grid.")
    out.writerow(["state", "body"] + FIELDS)
    row = rows[args.step - 1]
    for b, part in enumerate(parts):
        out.writerow(["falling", part["name"]] + [row[f"{c}_b{b}"] for c in FIELDS])
    top = [0.0] * GRID
    for k, part in enumerate(parts):
        height = max(p["box"][2] for p in part["pieces"])
        if any(p.get("center", [0, 0, 0])[2] != 0 for p in part["pieces"]):
            sys.exit(f"{part['name']}: a piece off the part's mid-plane; the stack assumes none")
        cell = k % GRID
        x, y, _ = part["position"]
        yaw = math.radians(part.get("rpy_deg", [0, 0, 0])[2])
        z = top[cell] + height / 2
        top[cell] += height
        state = [x, y, z, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)] + [0.0] * 6
        out.writerow(["settled", part["name"]] + [repr(v) for v in state])


if __name__ == "__main__":
    main()
