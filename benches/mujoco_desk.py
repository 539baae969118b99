#!/usr/bin/env python3
"""The desk step of ecp beside MuJoCo's on the same desk, in one run (`docs/latency.md`).

    cargo build --release --bin ecp
    python3 -m pip install mujoco      # MuJoCo 4 (any Python >= 3.9)
    python3 benches/mujoco_desk.py [--ecp target/release/ecp] [--repeats 5]

ecp: `ecp run scenes/desk.toml --solver S` for each backend, the median of the `step_us`
figures of `summary.json` (the solve time of each step), the best of `--repeats` runs.

MuJoCo: the same desk (15 kg, inertia diag(1.325, 1.325, 0.625) kg m², a 0.5 x 0.5 x 0.05 m top
and four 0.06 x 0.06 x 0.85 m legs as box geoms), the ground plane, h = 0.01 s, the elliptic
friction cone with condim 4 (sliding and torsional friction), mu = 0.22 and a torsional
coefficient mu * e_r = 0.022 m, the paper's wrench applied at the CM (`xfrc_applied`), the same
initial state; the time of each `mj_step` (perf_counter_ns around the call), median over the
steps that have contacts, the best of `--repeats` runs. With MuJoCo's default contact softness
(solref 0.02 s) at h = 0.01 s the desk chatters: about a third of its steps have contacts, the
others are in the air (the table says how many).

The two models are not the same physics (MuJoCo: four soft point contacts, one per foot, with
its default solref/solimp; ecp: one hard patch contact at the equivalent contact point), so the
table compares the cost of a step of each on the same scene, not their trajectories.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

DESK_XML = """
<mujoco model="desk">
  <option timestep="0.01" gravity="0 0 -9.8" cone="elliptic" integrator="Euler"/>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1" condim="4" friction="0.22 0.022 0.0001"/>
    <body name="desk" pos="0 0 0.45">
      <freejoint/>
      <inertial pos="0 0 0" mass="15" diaginertia="1.325 1.325 0.625"/>
      <geom type="box" size="0.25 0.25 0.025" pos="0 0 0.425" condim="4"
            friction="0.22 0.022 0.0001" contype="1" conaffinity="1"/>
      <geom type="box" size="0.03 0.03 0.425" pos="0.22 0.22 -0.025" condim="4"
            friction="0.22 0.022 0.0001"/>
      <geom type="box" size="0.03 0.03 0.425" pos="-0.22 0.22 -0.025" condim="4"
            friction="0.22 0.022 0.0001"/>
      <geom type="box" size="0.03 0.03 0.425" pos="-0.22 -0.22 -0.025" condim="4"
            friction="0.22 0.022 0.0001"/>
      <geom type="box" size="0.03 0.03 0.425" pos="0.22 -0.22 -0.025" condim="4"
            friction="0.22 0.022 0.0001"/>
    </body>
  </worldbody>
</mujoco>
"""


def wrench(t):
    """The desk's load of `scenes/desk.toml`: world frame, at the CM."""
    return (
        22.5 * math.sin(2 * math.pi * t) + 22.5,
        22.5 * math.cos(2 * math.pi * t) + 22.5,
        0.0,
        0.0,
        0.0,
        2.1 * math.cos(2 * math.pi * t),
    )


def mujoco_run(mujoco, steps):
    model = mujoco.MjModel.from_xml_string(DESK_XML)
    data = mujoco.MjData(model)
    data.qvel[:] = [0.3, 0.2, 0.0, 0.0, 0.0, 0.5]
    body = model.body("desk").id
    times = []
    for k in range(steps):
        data.xfrc_applied[body, :] = wrench(k * model.opt.timestep)
        t0 = time.perf_counter_ns()
        mujoco.mj_step(model, data)
        elapsed = (time.perf_counter_ns() - t0) * 1e-3
        # `ncon` after the step: the contacts that step used.
        if data.ncon > 0:
            times.append(elapsed)
    return statistics.median(times), len(times)


def ecp_run(binary, solver):
    with tempfile.TemporaryDirectory() as out:
        subprocess.run(
            [binary, "run", os.path.join(ROOT, "scenes", "desk.toml"), "--solver", solver,
             "--out", out, "--no-plots", "--quiet"],
            check=True,
        )
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
    return summary["step_us"]["median"], summary


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ecp", default=os.path.join(ROOT, "target", "release", "ecp"),
                        help="the ecp binary (default: target/release/ecp)")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each; the best is kept")
    parser.add_argument("--solvers", default="newton,path,conic")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    if not os.path.exists(args.ecp):
        sys.exit(f"no ecp binary at {args.ecp}: run `cargo build --release --bin ecp` first "
                 "or give --ecp PATH")
    try:
        import mujoco
    except ImportError:
        sys.exit("MuJoCo is not installed: `python3 -m pip install mujoco`")

    rows = []
    mj, contact_steps = min(mujoco_run(mujoco, 400) for _ in range(args.repeats))
    rows.append((f"MuJoCo {mujoco.__version__} (elliptic, condim 4)", mj, contact_steps))
    for solver in args.solvers.split(","):
        best = min(ecp_run(args.ecp, solver)[0] for _ in range(args.repeats))
        rows.append((f"ecp {solver}", best, 400))
    print("| desk, 400 steps, h = 0.01 s | median step (µs) | × MuJoCo | steps in contact |")
    print("|---|---|---|---|")
    for name, us, contact in rows:
        print(f"| {name} | {us:.1f} | {us / mj:.2f} | {contact} |")


if __name__ == "__main__":
    main()
