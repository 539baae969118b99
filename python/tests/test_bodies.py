"""Bodies touching bodies through the package: scene D1 (a box on a box on the ground) loads
through the same scene loading as `ecp run`, runs with the multi-body formulation, and its
contacts read as the columns of contacts.csv (docs/outputs.md#contactscsv)."""

import numpy as np

import ecp
from conftest import scene_path


def test_d1_stack_runs_and_reads_its_contacts():
    scene = ecp.Scene.from_toml(scene_path("d1_stack"))
    sim = ecp.Simulation(scene)
    traj = sim.run(20)
    assert len(traj) == 20
    assert np.all(traj.converged)
    # Nothing moves (docs/model.md#scenarios, D1).
    assert np.max(np.abs(traj.velocity)) <= 1e-9
    c = traj.contacts()
    assert list(c)[:4] == ["step", "t", "body_a", "body_b"]
    assert len(c["pn"]) == 40  # A–ground and B–A at each of the 20 steps
    top = [i for i, (a, b) in enumerate(zip(c["body_a"], c["body_b"])) if (a, b) == ("B", "A")]
    bottom = [i for i, (a, b) in enumerate(zip(c["body_a"], c["body_b"])) if (a, b) == ("A", "ground")]
    assert len(top) == 20 and len(bottom) == 20
    np.testing.assert_allclose(c["pn"][top], 1.0 * 9.8 * 0.01, atol=1e-9)
    np.testing.assert_allclose(c["pn"][bottom], 3.0 * 9.8 * 0.01, atol=1e-9)
    np.testing.assert_allclose(c["a1_z"][top], 0.2, atol=1e-8)
    np.testing.assert_allclose(c["n_z"][top], 1.0, atol=1e-12)
    assert set(c["mode"][i] for i in top) == {"patch"}
