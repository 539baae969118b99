"""Step sensitivities and trajectory gradients as numpy arrays, against finite differences and
closed forms, with their degeneracy reports."""

import numpy as np
import pytest

import ecp

G, H = 9.8, 0.01


def test_a1_step_sensitivity_in_closed_form(a1):
    # One step of A1: v⁺ = v − μ g h, so dv⁺/dμ = −g h and dv⁺/dv = 1.
    sim = ecp.Simulation(a1)
    sim.step()
    s = sim.step_sensitivity()
    assert s.step == 1
    assert s.inputs[:4] == ["mu", "e_t", "e_o", "e_r"] and len(s.inputs) == 4 + 26
    assert s.d_state.shape == (13, 30) and s.dz.shape[1] == 30
    assert len(s.status) == s.dz.shape[0]
    k = s.inputs.index("mu")
    np.testing.assert_allclose(s.d_state[:, k], s.d_state_by("mu"), rtol=0, atol=0)
    assert abs(s.d_state_by("mu")[7] - (-G * H)) < 1e-10
    assert abs(s.d_state_by("vx")[7] - 1.0) < 1e-10
    assert s.solve in ("direct", "regularised")
    assert isinstance(s.degeneracies, list)
    with pytest.raises(ecp.InputError, match="no step input"):
        s.d_state_by("friction")


def test_desk_step_sensitivities_match_finite_differences(desk):
    sim = ecp.Simulation(desk)
    sim.run(50)
    start = sim.states[0]
    sim.step()
    s = sim.step_sensitivity()
    assert s.step == 51 and s.is_regular, s.degeneracies

    def step_from(scene, state, **change):
        other = ecp.Simulation(scene)
        other.run(50)
        other.set_state(state)
        for name, value in change.items():
            other.set_param(name, value)
        other.step()
        return other.state.to_array()

    base = step_from(desk, start)
    np.testing.assert_allclose(base, sim.state.to_array(), rtol=0, atol=1e-9)
    delta = 1e-6
    for name in ["vx", "wz"]:
        i = {"vx": 7, "wz": 12}[name]
        plus = start.to_array().copy()
        minus = start.to_array().copy()
        plus[i] += delta
        minus[i] -= delta
        mk = lambda a: ecp.State(a[0:3], a[3:7], a[7:10], a[10:13])
        fd = (step_from(desk, mk(plus)) - step_from(desk, mk(minus))) / (2 * delta)
        np.testing.assert_allclose(s.d_state_by(name), fd, rtol=1e-4, atol=1e-7, err_msg=name)
    for name in ["mu", "e_r"]:
        v = desk.get_param(name)
        fd = (step_from(desk, start, **{name: v + delta}) - step_from(desk, start, **{name: v - delta})) / (2 * delta)
        np.testing.assert_allclose(s.d_state_by(name), fd, rtol=1e-4, atol=1e-7, err_msg=name)


def test_sensitivities_need_a_converged_step_of_the_hull_formulation(a1):
    with pytest.raises(ecp.SimulationError, match="no step to differentiate"):
        ecp.Simulation(a1).step_sensitivity()
    sim = ecp.Simulation(a1, formulation="point")
    sim.step()
    with pytest.raises(ecp.SimulationError, match="no step sensitivities"):
        sim.step_sensitivity()


def test_terminal_loss_gradient_in_closed_form(a1):
    # x_K = h Σ_k (1 − μ g h k) after 10 steps: dx_K/dμ = −g h² Σ k; L = |x_K − target|².
    scene = a1.with_params(mu=0.3)
    g = ecp.trajectory_gradient(scene, ["mu"], target=[0, 0, 0], steps=10)
    x = g.trajectory.position[-1, 0, 0]
    assert abs(g.gradient[0] - 2 * x * (-G * H * H * 55)) < 1e-9
    assert g.params == ["mu"] and g.mode == "adjoint"
    assert g.wrench_gradient.shape == (10, 1, 6)
    assert len(g.trajectory) == 10


def test_reference_loss_gradient_matches_finite_differences_in_both_modes(desk):
    reference = ecp.Simulation(desk.with_params(mu=0.25, e_r=0.08)).run(40)
    params = ["mu", "e_r", "mass"]
    adj = ecp.trajectory_gradient(desk, params, reference=reference)
    fwd = ecp.trajectory_gradient(desk, params, reference=reference, mode="forward")
    np.testing.assert_allclose(adj.gradient, fwd.gradient, rtol=1e-9)
    assert adj.loss > 0 and adj.events == [] and len(adj.trajectory) == 40
    for k, name in enumerate(params):
        v = desk.get_param(name)
        d = 1e-6 * max(1.0, abs(v))
        lp = ecp.trajectory_gradient(desk.with_params({name: v + d}), params, reference=reference).loss
        lm = ecp.trajectory_gradient(desk.with_params({name: v - d}), params, reference=reference).loss
        fd = (lp - lm) / (2 * d)
        assert abs(adj.gradient[k] - fd) <= 1e-4 * abs(fd) + 1e-9, (name, adj.gradient[k], fd)
    # A reference given as arrays is the same loss as the trajectory itself.
    arrays = {
        "position": reference.position,
        "orientation": reference.orientation,
        "velocity": reference.velocity[:, 0, :],  # one body: steps × 3 is accepted
        "angular_velocity": reference.angular_velocity,
    }
    again = ecp.trajectory_gradient(desk, params, reference=arrays)
    assert again.loss == adj.loss
    np.testing.assert_array_equal(again.gradient, adj.gradient)


def test_gradient_arguments_are_checked(desk):
    with pytest.raises(ecp.InputError, match="either reference"):
        ecp.trajectory_gradient(desk, ["mu"])
    with pytest.raises(ecp.InputError, match="unknown gradient mode"):
        ecp.trajectory_gradient(desk, ["mu"], target=[0, 0, 0], steps=2, mode="reverse")
    with pytest.raises(ecp.InputError, match="has no step sensitivities"):
        ecp.trajectory_gradient(desk, ["mu"], target=[0, 0, 0], steps=2, formulation="point")
    with pytest.raises(ecp.InputError, match="shape"):
        ecp.trajectory_gradient(desk, ["mu"], reference={"velocity": np.zeros((5, 2))})
    with pytest.raises(ecp.InputError, match="weighs position"):
        ecp.trajectory_gradient(desk, ["mu"], reference={"velocity": np.zeros((5, 3))}, weights={"position": 1.0})
    with pytest.raises(ecp.InputError, match="non-finite"):
        ecp.trajectory_gradient(desk, ["mu"], reference={"velocity": np.full((5, 3), np.nan)})
    with pytest.raises(ecp.InputError, match="unknown weight"):
        ecp.trajectory_gradient(desk, ["mu"], reference={"velocity": np.zeros((5, 3))}, weights={"speed": 1.0})
