"""ecp: rigid bodies in intermittent contact, with an equivalent contact point.

Geometrically implicit time stepping (Xie & Chakraborty) built on a mixed complementarity
problem per step, solved in Rust by interchangeable backends. This package is a thin layer over
the Rust library: scenes (TOML files or dicts), simulations stepped from Python, step
sensitivities and trajectory gradients as numpy arrays, ``compare``, ``fit``, ``lcp``, and
batches of runs on every core (:func:`batch`); :mod:`ecp.ray` spreads a sweep over a Ray
cluster. The guide is ``docs/python.md`` in the repository.

>>> import ecp
>>> scene = ecp.Scene.from_toml("scenes/desk.toml")        # doctest: +SKIP
>>> traj = ecp.Simulation(scene).run(100)                  # doctest: +SKIP
>>> traj.velocity.shape                                    # doctest: +SKIP
(100, 1, 3)
"""

from ._ecp import (
    BatchResult,
    InputError,
    InternalError,
    Scene,
    Simulation,
    SimulationError,
    State,
    StepSensitivity,
    Summary,
    Trajectory,
    TrajectoryGradient,
    __version__,
    batch,
    compare,
    fit,
    grid_points,
    lcp,
    trajectory_gradient,
)

__all__ = [
    "BatchResult",
    "InputError",
    "InternalError",
    "Scene",
    "Simulation",
    "SimulationError",
    "State",
    "StepSensitivity",
    "Summary",
    "Trajectory",
    "TrajectoryGradient",
    "__version__",
    "batch",
    "compare",
    "fit",
    "grid_points",
    "lcp",
    "trajectory_gradient",
]
