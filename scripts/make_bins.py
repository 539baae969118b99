#!/usr/bin/env python3
"""Writes `scenes/bin20.toml` and `scenes/bin50.toml`: N boxes and T-bars dropped into a bin.

    python3 scripts/make_bins.py            # rewrites both files (deterministic)

The bin: the ground half-space and four fixed walls (0.02 m thick, 0.3 m high) around a
0.56 x 0.56 m floor. The parts start in layers of a 3 x 3 grid (0.16 m apart, layers 0.13 m apart,
the lowest 0.06 m above the floor), every fourth one a T-bar, each with a yaw from a fixed
pseudo-random sequence and a tilt of up to 10 degrees about x and y; sizes vary by part. No load:
they fall, collide and settle. Masses from a density of 600 kg/m^3 (uniform inertia).
`benches/mujoco_bin.py` reads the generated files, so MuJoCo runs the same parts.
"""

import math
import os
import random

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DENSITY = 600.0
HALF = 0.28  # half the inner width of the bin (m)
WALL_T = 0.02
WALL_H = 0.30
SPACING = 0.16
LAYER = 0.13
BOTTOM = 0.06


def fmt(x):
    return repr(round(x, 6))


def vec(v):
    return "[" + ", ".join(fmt(x) for x in v) + "]"


def part(k, rng):
    """The pieces (box sizes and centres in a body frame) and mass of part k."""
    if k % 4 == 3:
        # A T-bar: crossbar 0.03 x 0.12 x 0.03, stem 0.09 x 0.03 x 0.03 (as the T-bar scene,
        # scaled by 0.6).
        pieces = [([0.03, 0.12, 0.03], [0.015, 0.0, 0.0]), ([0.09, 0.03, 0.03], [0.075, 0.0, 0.0])]
    else:
        lx = 0.07 + 0.03 * rng.random()
        ly = 0.05 + 0.03 * rng.random()
        lz = 0.04 + 0.02 * rng.random()
        pieces = [([lx, ly, lz], [0.0, 0.0, 0.0])]
    mass = sum(DENSITY * b[0] * b[1] * b[2] for b, _ in pieces)
    return pieces, mass


def scene(n):
    rng = random.Random(20 + n)
    out = []
    out.append(
        f"# A bin of {n} parts (boxes and T-bars) dropped into a box-shaped bin of four fixed walls\n"
        "# on the ground; no load, they fall, collide and settle (`docs/bodies.md#bins`).\n"
        "# Written by `python3 scripts/make_bins.py`; edit that script, not this file.\n"
        f'name = "bin{n}"\n\n'
        "[simulation]\nh = 0.01\nduration = 2.0\ngravity = [0, 0, -9.8]\n"
        'formulation = "bodies"\n\n'
        "[friction]\nmu = 0.5\ne_t = 1.0\ne_o = 1.0\ne_r = 0.02\n\n"
        '[solver]\nname = "newton"\n\n'
        '[[half_spaces]]\nname = "ground"\nnormal = [0, 0, 1]\noffset = 0\n'
    )
    c = HALF + WALL_T / 2
    walls = [
        ("wall_px", [c, 0, WALL_H / 2], [WALL_T, 2 * HALF + 2 * WALL_T, WALL_H]),
        ("wall_mx", [-c, 0, WALL_H / 2], [WALL_T, 2 * HALF + 2 * WALL_T, WALL_H]),
        ("wall_py", [0, c, WALL_H / 2], [2 * HALF, WALL_T, WALL_H]),
        ("wall_my", [0, -c, WALL_H / 2], [2 * HALF, WALL_T, WALL_H]),
    ]
    for name, pos, size in walls:
        out.append(
            f'\n[[bodies]]\nname = "{name}"\nkind = "fixed"\nposition = {vec(pos)}\n'
            f"\n[[bodies.pieces]]\nbox = {vec(size)}\n"
        )
    for k in range(n):
        layer, cell = divmod(k, 9)
        i, j = divmod(cell, 3)
        pieces, mass = part(k, rng)
        x = (i - 1) * SPACING + 0.01 * (rng.random() - 0.5)
        y = (j - 1) * SPACING + 0.01 * (rng.random() - 0.5)
        z = BOTTOM + LAYER * layer
        rpy = [20 * (rng.random() - 0.5), 20 * (rng.random() - 0.5), 360 * rng.random()]
        kind = "tbar" if len(pieces) == 2 else "box"
        out.append(
            f'\n[[bodies]]\nname = "{kind}{k}"\nmass = {fmt(mass)}\ninertia = "uniform"\n'
            f"position = {vec([x, y, z])}\nrpy_deg = {vec(rpy)}\n"
        )
        for size, center in pieces:
            out.append(f"\n[[bodies.pieces]]\nbox = {vec(size)}\ncenter = {vec(center)}\n")
    return "".join(out)


def main():
    for n in (20, 50):
        path = os.path.join(ROOT, "scenes", f"bin{n}.toml")
        with open(path, "w") as f:
            f.write(scene(n))
        print(path)


if __name__ == "__main__":
    main()
