"""The paper's desk (scenes/desk.toml) simulated from Python, with a matplotlib plot.

    python python/examples/desk.py                 # 400 steps, plot in out/desk/python_desk.png
    python python/examples/desk.py --steps 50 --out /tmp/desk.png

Prints the final state and writes a figure of the desk's velocities and of the path of its
equivalent contact point (ECP) on the ground.
"""

import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402

import ecp  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=None, help="steps to run (default: the scene's 400)")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "desk" / "python_desk.png")
    args = parser.parse_args()

    scene = ecp.Scene.from_toml(ROOT / "scenes" / "desk.toml")
    sim = ecp.Simulation(scene)  # the scene's solver (newton) and formulation (hull)
    traj = sim.run(args.steps)

    t = traj.t
    v = traj.velocity[:, 0, :]  # steps × bodies × 3 -> the desk's
    w = traj.angular_velocity[:, 0, :]
    ecp_xy = traj.ecp[:, 0, :2]  # the ECP of the desk's one contact (with the ground)
    x_xy = traj.position[:, 0, :2]

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(t, v[:, 0], label="$v_x$ (m/s)")
    ax1.plot(t, v[:, 1], label="$v_y$ (m/s)")
    ax1.plot(t, w[:, 2], label=r"$\omega_z$ (rad/s)")
    ax1.set_xlabel("t (s)")
    ax1.set_title("desk: velocities")
    ax1.legend()
    ax1.grid(alpha=0.3)
    ax2.plot(x_xy[:, 0], x_xy[:, 1], label="centre of mass")
    ax2.plot(ecp_xy[:, 0], ecp_xy[:, 1], ".", ms=2, label="ECP")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x (m)")
    ax2.set_ylabel("y (m)")
    ax2.set_title("top view")
    ax2.legend()
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)

    s = sim.state
    print(
        f"{len(traj)} steps to t = {sim.time:.2f} s, all converged: {bool(traj.converged.all())}, "
        f"max residual {traj.residual.max():.2e}"
    )
    print(f"final position {s.position.round(4)}, velocity {s.velocity.round(4)}, "
          f"angular velocity {s.angular_velocity.round(4)}")
    print(f"plot written to {args.out}")


if __name__ == "__main__":
    main()
