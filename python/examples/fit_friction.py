"""Fitting μ and e_r of the desk from a noisy trajectory with scipy.optimize on ecp's exact
gradients.

    python python/examples/fit_friction.py              # 100 steps (1 s) of the desk
    python python/examples/fit_friction.py --steps 40 --noise 0.002

A "measured" trajectory is simulated with the scene's μ = 0.22 and e_r = 0.1 and its
velocities and angular velocities get Gaussian noise. Starting from μ = 0.15, e_r = 0.05,
L-BFGS-B minimises the squared velocity differences L(μ, e_r); ecp.trajectory_gradient gives L
and its exact gradient (implicit differentiation of every step, chained by an adjoint sweep).
The parameters are optimised in log-coordinates, θ = θ0 · exp(u), so they stay positive.
"""

import argparse
import pathlib

import numpy as np
import scipy.optimize

import ecp

ROOT = pathlib.Path(__file__).resolve().parents[2]
PARAMS = ["mu", "e_r"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--noise", type=float, default=0.002, help="noise standard deviation (m/s, rad/s)")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()

    truth = ecp.Scene.from_toml(ROOT / "scenes" / "desk.toml")
    measured = ecp.Simulation(truth).run(args.steps)
    rng = np.random.default_rng(args.seed)
    reference = {
        "velocity": measured.velocity + rng.normal(0.0, args.noise, measured.velocity.shape),
        "angular_velocity": measured.angular_velocity
        + rng.normal(0.0, args.noise, measured.angular_velocity.shape),
    }
    weights = {"velocity": 1.0, "angular_velocity": 1.0}

    start = truth.with_params(mu=0.15, e_r=0.05)
    theta0 = np.array([start.get_param(p) for p in PARAMS])
    evaluations = []

    def loss_and_gradient(u):
        theta = theta0 * np.exp(u)
        scene = start.with_params(dict(zip(PARAMS, theta)))
        g = ecp.trajectory_gradient(scene, PARAMS, reference=reference, weights=weights)
        evaluations.append((theta, g.loss, len(g.events)))
        return g.loss, g.gradient * theta  # dL/du = dL/dθ · θ

    result = scipy.optimize.minimize(
        loss_and_gradient, np.zeros(2), jac=True, method="L-BFGS-B", options={"gtol": 1e-12, "ftol": 1e-15}
    )
    mu, e_r = theta0 * np.exp(result.x)
    print(f"truth:  mu = {truth.get_param('mu'):.4f}, e_r = {truth.get_param('e_r'):.4f}")
    print(f"start:  mu = {theta0[0]:.4f}, e_r = {theta0[1]:.4f}")
    print(f"fitted: mu = {mu:.4f}, e_r = {e_r:.4f}  ({result.nit} iterations, "
          f"{len(evaluations)} gradient evaluations, loss {result.fun:.3e}, {result.message})")
    events = evaluations[-1][2]
    print(f"mode switches or degenerate steps in the window at the fit: {events}")


if __name__ == "__main__":
    main()
