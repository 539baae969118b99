#!/usr/bin/env python3
"""The bin of ecp beside MuJoCo's on the same bin, in one run (`docs/latency.md#bins`).

    cargo build --release --bin ecp
    python3 -m pip install mujoco      # MuJoCo 4 (Python >= 3.11, for tomllib)
    python3 benches/mujoco_bin.py [--scenes bin20,bin50] [--ecp target/release/ecp] [--repeats 3]
    python3 benches/mujoco_bin.py --scenes bin50 --ecp-runs bin50=out/bin50   # ecp's from a run
    python3 benches/mujoco_bin.py --scenes bin50 --parts 1,2,5,10,20,50 --solvers none
    python3 benches/mujoco_bin.py --scenes bin50 --parts 1,2,5,10,20,50 --state settled

Both read `scenes/binN.toml`: the ground plane, the four fixed walls, each part's boxes (sizes
and centres, the mass spread over the boxes by volume: the uniform density ecp's `inertia =
"uniform"` assumes, so MuJoCo's body inertia is the same), the initial CM position and
orientation (`rpy_deg`: R = Rz Ry Rx), h = 0.01 s, g = 9.8, the elliptic friction cone with condim 4
(sliding and torsional friction), mu of `[friction]` and a torsional coefficient mu * e_r.

ecp: `ecp run scenes/binN.toml --solver S`, the median of the `step_us` figures of `summary.json`
(the solve time of each step, pair selection and overlap check not included) and the mean wall
time per step of the whole run (`wall/step`: everything, fallbacks included), the best of
`--repeats` runs; with `--ecp-runs NAME=DIR,...` the same figures from the `summary.json` of a
run already made (`ecp run scenes/NAME.toml --no-plots --out DIR`: bin50's takes many minutes),
`wall_s` of the summary per step.
MuJoCo: the time of each `mj_step` (perf_counter_ns around the call), median over the steps that
have contacts, the median over the settled steps 150-200 (the state `cargo bench --bench bodies`
times), and the mean over all steps, the best of `--repeats` runs. `--parts N,...`: MuJoCo on the
first N parts of each scene (the lowest layers first, as `bin_step(n)` of the benchmarks).
`--state LABEL`: MuJoCo only, from a state of `benches/bin50_states.csv` (the states
`cargo bench --bench bodies` starts from: `settled`, the parts at rest in a flat stack, or
`falling`) instead of the scene's initial one, `STATE_STEPS` steps, the median over all of them.

The two models are not the same physics (MuJoCo: soft point contacts with its default
solref/solimp, several per touching pair of boxes; ecp: one hard contact per pair of hulls at the
equivalent contact point), so the table compares the cost of a step of each on the same scene,
not their trajectories.
"""

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SETTLED_FROM = 150  # the first settled step (from 1) of a run from the scene's initial state
STATE_STEPS = 50  # steps from a stored state (`--state`)


def quat_rpy(rpy_deg):
    """(w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (math.radians(a) / 2 for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def fmt(v):
    return " ".join(f"{x:.9g}" for x in v)


def first_parts(scene, n):
    """`scene` with its first `n` dynamic bodies (fixed bodies kept)."""
    out, kept = dict(scene), []
    for b in scene["bodies"]:
        if b.get("kind", "dynamic") == "dynamic":
            if n == 0:
                continue
            n -= 1
        kept.append(b)
    out["bodies"] = kept
    return out


def mjcf(scene):
    """The MJCF model of a bin scene file (boxes only, unrotated pieces, as `make_bins.py` writes)."""
    fr = scene["friction"]
    mu, er = fr["mu"], fr["e_r"]
    friction = f'friction="{mu} {mu * er:.9g} 0.0001" condim="4"'
    h = scene["simulation"]["h"]
    out = [
        f'<mujoco model="{scene.get("name", "bin")}">',
        f'  <option timestep="{h}" gravity="0 0 -9.8" cone="elliptic" integrator="Euler"/>',
        "  <worldbody>",
        f'    <geom name="ground" type="plane" size="0 0 1" {friction}/>',
    ]
    for b in scene["bodies"]:
        kind = b.get("kind", "dynamic")
        if kind == "fixed":
            (piece,) = b["pieces"]
            half = [x / 2 for x in piece["box"]]
            out.append(
                f'    <geom name="{b["name"]}" type="box" size="{fmt(half)}" '
                f'pos="{fmt(b["position"])}" {friction}/>'
            )
            continue
        if kind != "dynamic":
            sys.exit(f"{b['name']}: only fixed and dynamic bodies are supported")
        vols = [p["box"][0] * p["box"][1] * p["box"][2] for p in b["pieces"]]
        centers = [p.get("center", [0, 0, 0]) for p in b["pieces"]]
        total = sum(vols)
        cm = [sum(v * c[i] for v, c in zip(vols, centers)) / total for i in range(3)]
        quat = quat_rpy(b.get("rpy_deg", [0, 0, 0]))
        out.append(f'    <body name="{b["name"]}" pos="{fmt(b["position"])}" quat="{fmt(quat)}">')
        out.append("      <freejoint/>")
        for p, v, c in zip(b["pieces"], vols, centers):
            half = [x / 2 for x in p["box"]]
            pos = [c[i] - cm[i] for i in range(3)]
            mass = b["mass"] * v / total
            out.append(
                f'      <geom type="box" size="{fmt(half)}" pos="{fmt(pos)}" mass="{mass:.9g}" '
                f"{friction}/>"
            )
        out.append("    </body>")
    out += ["  </worldbody>", "</mujoco>"]
    return "\n".join(out)


def read_state(label, names):
    """The poses (x, y, z, qw, qx, qy, qz) labelled `label` in benches/bin50_states.csv, by name."""
    poses = {}
    with open(os.path.join(ROOT, "benches", "bin50_states.csv")) as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        for r in rows:
            if r["state"] == label:
                poses[r["body"]] = [float(r[c]) for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    missing = [n for n in names if n not in poses]
    if missing:
        sys.exit(f"benches/bin50_states.csv: no {label} state of {missing}")
    return [poses[n] for n in names]


def mujoco_run(mujoco, xml, steps, poses=None):
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    if poses is not None:
        # One free joint per part, in scene order: CM position, then the quaternion (w, x, y, z).
        for i, pose in enumerate(poses):
            data.qpos[7 * i : 7 * i + 7] = pose
        mujoco.mj_forward(model, data)
    times, contact = [], []
    for _ in range(steps):
        t0 = time.perf_counter_ns()
        mujoco.mj_step(model, data)
        elapsed = (time.perf_counter_ns() - t0) * 1e-3
        times.append(elapsed)
        if data.ncon > 0:
            contact.append(elapsed)
    settled = statistics.median(times[SETTLED_FROM - 1:] if poses is None else times)
    return statistics.median(contact), statistics.mean(times), len(contact), data.ncon, settled


def ecp_run(binary, path, solver):
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        subprocess.run(
            [binary, "run", path, "--solver", solver, "--out", out, "--no-plots", "--quiet"],
            check=True,
        )
        wall = time.perf_counter() - start
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
    steps = summary.get("steps") or summary.get("planned_steps")
    return summary["step_us"]["median"], wall * 1e6 / steps


def ecp_summary(run_dir):
    """The figures of `ecp_run` from a run already made."""
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    if summary["failed_steps"]:
        sys.exit(f"{run_dir}: {summary['failed_steps']} failed steps")
    return summary["solver"], summary["step_us"]["median"], summary["wall_s"] * 1e6 / summary["steps"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ecp", default=os.path.join(ROOT, "target", "release", "ecp"),
                        help="the ecp binary (default: target/release/ecp)")
    parser.add_argument("--scenes", default="bin20,bin50")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each; the best is kept")
    parser.add_argument("--solvers", default="newton,path", help="ecp backends to run, or none")
    parser.add_argument("--ecp-runs", default="", help="NAME=DIR,...: ecp's figures from these runs")
    parser.add_argument("--parts", default="", help="N,...: MuJoCo on the first N parts of each scene")
    parser.add_argument("--state", default="", help="settled|falling: MuJoCo from that stored state")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    solvers = [] if args.solvers == "none" or args.state else args.solvers.split(",")
    runs_of = dict(item.split("=", 1) for item in args.ecp_runs.split(",") if item)
    if solvers and not os.path.exists(args.ecp):
        sys.exit(f"no ecp binary at {args.ecp}: run `cargo build --release --bin ecp` first "
                 "or give --ecp PATH")
    try:
        import mujoco
    except ImportError:
        sys.exit("MuJoCo is not installed: `python3 -m pip install mujoco`")

    print("| scene | simulator | median step (µs) | settled median (µs) | mean step (µs) | "
          "× MuJoCo (median) | notes |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        path = os.path.join(ROOT, "scenes", f"{name}.toml")
        with open(path, "rb") as f:
            scene = tomllib.load(f)
        steps = math.ceil(scene["simulation"]["duration"] / scene["simulation"]["h"] - 1e-9)
        parts = [int(n) for n in args.parts.split(",")] if args.parts else [None]
        for n in parts:
            label = name if n is None else f"{name}, first {n}"
            part_scene = scene if n is None else first_parts(scene, n)
            xml = mjcf(part_scene)
            poses = None
            if args.state:
                label += f", from {args.state}"
                names = [b["name"] for b in part_scene["bodies"] if b.get("kind", "dynamic") == "dynamic"]
                poses = read_state(args.state, names)
            n_steps = STATE_STEPS if poses is not None else steps
            runs = [mujoco_run(mujoco, xml, n_steps, poses) for _ in range(args.repeats)]
            mj = min(r[0] for r in runs)
            mj_mean = min(r[1] for r in runs)
            mj_settled = min(r[4] for r in runs)
            print(f"| {label} | MuJoCo {mujoco.__version__} (elliptic, condim 4) | {mj:.1f} | "
                  f"{mj_settled:.1f} | {mj_mean:.1f} | 1.00 | {runs[0][2]} of {n_steps} steps with "
                  f"contacts, {runs[0][3]} contacts at the end |")
        if name in runs_of:
            solver, med, wall = ecp_summary(runs_of[name])
            print(f"| {name} | ecp {solver} (`{runs_of[name]}`) | {med:.1f} | | {wall:.1f} "
                  f"(wall/step) | {med / mj:.2f} | |")
            continue
        for solver in solvers:
            res = [ecp_run(args.ecp, path, solver) for _ in range(args.repeats)]
            med = min(r[0] for r in res)
            wall = min(r[1] for r in res)
            print(f"| {name} | ecp {solver} | {med:.1f} | | {wall:.1f} (wall/step) | "
                  f"{med / mj:.2f} | |")


if __name__ == "__main__":
    main()
