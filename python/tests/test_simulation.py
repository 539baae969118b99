"""ecp.Simulation: steps, runs, states as numpy arrays, set_state, set_param, summaries,
failed steps, formulations and solvers; a Python run gives the numbers of `ecp run`."""

import csv

import numpy as np
import pytest

import ecp
from conftest import run_cli, scene_path

G, H = 9.8, 0.01


def test_steps_follow_scenario_a1(a1):
    # A box sliding at 1 m/s decelerates by μ g h per step (docs/model.md#scenarios).
    sim = ecp.Simulation(a1)
    for k in range(1, 6):
        summary = sim.step()
        assert summary.converged and summary.step == k
        assert abs(summary.t - k * H) < 1e-15
        assert summary.residual <= 1e-10
    s = sim.state
    assert s.velocity.dtype == np.float64 and s.velocity.shape == (3,)
    assert abs(s.velocity[0] - (1 - 0.3 * G * H * 5)) < 1e-9
    assert abs(s.position[2] - 0.1) < 1e-9
    assert s.orientation.shape == (4,) and abs(np.linalg.norm(s.orientation) - 1) < 1e-14
    assert len(sim.states) == 1 and sim.states[0] == s
    assert sim.steps_taken == 5 and abs(sim.time - 0.05) < 1e-15
    assert sim.summary.step == 5 and sim.summary.solver == "newton"


def test_a_run_returns_arrays_and_the_columns_of_trajectory_csv(desk):
    traj = ecp.Simulation(desk).run(50)
    assert len(traj) == 50
    assert traj.position.shape == (50, 1, 3) and traj.orientation.shape == (50, 1, 4)
    assert traj.velocity.shape == (50, 1, 3) and traj.angular_velocity.shape == (50, 1, 3)
    assert traj.states.shape == (50, 1, 13)
    assert traj.ecp.shape == (50, 1, 3) and traj.pn.shape == (50, 1)
    assert traj.converged.all() and traj.residual.max() <= 1e-9
    np.testing.assert_array_equal(traj.t, np.arange(1, 51) * H)
    cols = traj.columns()
    header = [
        "t", "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
        "ecp_x", "ecp_y", "ecp_z", "pn", "pt", "po", "pr", "sigma", "min_gap", "mode",
        "iterations", "residual", "solve_us", "fallback",
    ]
    assert list(cols) == header
    assert all(len(v) == 50 for v in cols.values())
    assert all(np.ndim(v) == 1 for v in cols.values())
    np.testing.assert_array_equal(cols["vx"], traj.velocity[:, 0, 0])
    np.testing.assert_array_equal(cols["pn"], traj.pn[:, 0])
    assert set(cols["mode"]) <= {"patch", "line", "point", "none"}
    # The desk stands on its four feet and slides: the patch is in contact, pn ≈ m g h.
    assert cols["mode"][-1] == "patch"
    assert abs(traj.pn[-1, 0] - 15 * G * H) < 1e-6


def test_a_python_run_gives_the_numbers_of_ecp_run_bit_for_bit(desk, tmp_path):
    out = run_cli("run", str(scene_path("desk")), "--steps", "120", "--no-plots", "--quiet", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    with open(tmp_path / "trajectory.csv") as f:
        rows = list(csv.DictReader(f))
    traj = ecp.Simulation(desk).run(120)
    cols = traj.columns()
    assert len(rows) == 120
    for name in ["t", "x", "y", "qw", "qz", "vx", "vy", "wz", "ecp_x", "ecp_y", "pn", "pt", "pr"]:
        csv_values = np.array([float(r[name]) for r in rows])
        # trajectory.csv writes the shortest representation that reads back exactly.
        assert csv_values.tobytes() == np.asarray(cols[name]).tobytes(), name


def test_set_state_changes_the_next_step(a1):
    sim = ecp.Simulation(a1)
    sim.step()
    sim.set_state(velocity=[2.0, 0.0, 0.0])
    assert sim.state.velocity[0] == 2.0
    sim.step()
    assert abs(sim.state.velocity[0] - (2.0 - 0.3 * G * H)) < 1e-9
    # A whole State, for another body index: refused with a clear message.
    with pytest.raises(ecp.InputError, match="out of range"):
        sim.set_state(sim.state, body=1)
    with pytest.raises(ecp.InputError, match="finite"):
        sim.set_state(velocity=[np.nan, 0, 0])
    with pytest.raises(ValueError, match="3 numbers"):
        sim.set_state(velocity=[1, 0])
    s = ecp.State([0, 0, 0.1], velocity=[0.5, 0, 0])
    sim.set_state(s)
    assert sim.state.position[2] == 0.1 and sim.state.velocity[0] == 0.5


def test_set_param_applies_from_the_next_step_and_the_clock_goes_on(a1):
    sim = ecp.Simulation(a1)
    sim.run(5)
    sim.set_param("mu", 0.1)
    assert sim.scene.get_param("mu") == 0.1
    traj = sim.run(5)
    np.testing.assert_array_equal(traj.step, np.arange(6, 11))
    assert abs(sim.time - 0.1) < 1e-15 and sim.steps_taken == 10
    want = 1 - 0.3 * G * H * 5 - 0.1 * G * H * 5
    assert abs(sim.state.velocity[0] - want) < 1e-9
    with pytest.raises(ecp.InputError, match="set_state"):
        sim.set_param("vx0", 1.0)
    with pytest.raises(ecp.InputError, match="> 0"):
        sim.set_param("e_r", 0.0)
    with pytest.raises(ecp.InputError, match="unknown parameter"):
        sim.set_param("friction", 0.3)


def test_set_param_keeps_time_dependent_loads_at_the_right_time(desk):
    # The desk's push is 22.5 sin(2πt) + 22.5 N: after a rebuild at t = 1 s the loads must go on
    # from t = 1 s. Setting μ to its own value changes nothing but the warm start.
    straight = ecp.Simulation(desk).run(200)
    sim = ecp.Simulation(desk)
    sim.run(100)
    sim.set_param("mu", desk.get_param("mu"))
    second = sim.run(100)
    assert np.abs(second.states[-1] - straight.states[-1]).max() < 1e-6
    assert np.abs(second.velocity - straight.velocity[100:]).max() < 1e-6


def test_a_step_that_cannot_be_solved_raises_and_keeps_the_state(desk):
    sim = ecp.Simulation(desk, max_iterations=1, fallbacks=False)
    before = sim.state
    with pytest.raises(ecp.SimulationError) as e:
        sim.step()
    assert "could not be solved" in str(e.value) and "fallbacks off" in str(e.value)
    assert e.value.summary.converged is False and e.value.summary.method == "failed"
    assert sim.state == before, "a failed iterate is never taken"
    with pytest.raises(ecp.SimulationError) as e:
        ecp.Simulation(desk, max_iterations=1, fallbacks=False).run(10)
    assert len(e.value.trajectory) == 1 and not e.value.trajectory.converged[0]
    traj = ecp.Simulation(desk, max_iterations=1, fallbacks=False).run(3, keep_going=True)
    assert len(traj) == 3 and not traj.converged.any()


def test_formulations_and_solvers(a1):
    for formulation in ["hull", "union", "reduced", "point"]:
        sim = ecp.Simulation(a1, formulation=formulation)
        sim.run(5)
        assert sim.formulation == formulation
        assert abs(sim.state.velocity[0] - (1 - 0.3 * G * H * 5)) < 1e-8, formulation
    for solver in ["newton", "path", "conic"]:
        sim = ecp.Simulation(a1, solver=solver)
        sim.run(5)
        assert abs(sim.state.velocity[0] - (1 - 0.3 * G * H * 5)) < 1e-8, solver
    with pytest.raises(ecp.InputError, match="conic backend cannot solve the point formulation"):
        ecp.Simulation(a1, solver="conic", formulation="point")
    with pytest.raises(ecp.InputError, match='unknown solver "lemke"'):
        ecp.Simulation(a1, solver="lemke")
    with pytest.raises(ecp.InputError, match='unknown formulation "convex"'):
        ecp.Simulation(a1, formulation="convex")
    with pytest.raises(ecp.InputError, match="tolerance"):
        ecp.Simulation(a1, tolerance=float("nan"))
    with pytest.raises(TypeError):
        ecp.Simulation("scenes/a1_sliding.toml")
    with pytest.raises(TypeError):
        ecp.Simulation(a1).run("ten")


def test_set_state_and_set_param_on_a_formulation_without_set_state(a1):
    sim = ecp.Simulation(a1, formulation="point")
    sim.run(3)
    sim.set_state(velocity=[0.5, 0, 0])
    sim.step()
    assert abs(sim.state.velocity[0] - (0.5 - 0.3 * G * H)) < 1e-8
    sim.set_param("mu", 0.2)
    sim.step()
    assert abs(sim.state.velocity[0] - (0.5 - 0.3 * G * H - 0.2 * G * H)) < 1e-8
    assert sim.steps_taken == 5
