"""ecp.compare, ecp.fit and ecp.lcp: what the command line prints, as Python objects."""

import json

import numpy as np
import pytest

import ecp
from conftest import run_cli, scene_path


def test_compare_runs_every_combination(a1, desk, tmp_path):
    report = ecp.compare(a1, ["newton", "path"], ["hull", "point"], steps=5)
    runs = {(r["formulation"], r["solver"]) for r in report["runs"]}
    assert runs == {("hull", "newton"), ("hull", "path"), ("point", "newton"), ("point", "path")}
    assert all(r["failed_steps"] == 0 and r["steps"] == 5 for r in report["runs"])
    assert max(r["max_diff_v"] for r in report["runs"]) < 1e-8, "A1 is the same for every model"
    report = ecp.compare(desk, ["newton", "conic"], ["point"], steps=2, out=tmp_path)
    assert [s["solver"] for s in report["skipped"]] == ["conic"]
    assert json.loads((tmp_path / "compare.json").read_text())["scene"] == "desk"
    with pytest.raises(ecp.InputError, match='unknown solver "fast"'):
        ecp.compare(desk, ["fast"])


def test_fit_recovers_mu_from_a_trajectory(a1):
    reference = ecp.Simulation(a1.with_params(mu=0.3)).run(10)
    report = ecp.fit(a1.with_params(mu=0.25), reference, ["mu"])
    assert abs(report["params"]["mu"] - 0.3) < 1e-6, report
    assert report["start"]["mu"] == 0.25 and report["error"] is None
    assert report["method"] == "lbfgs" and report["steps"] == 10
    nm = ecp.fit(a1.with_params(mu=0.25), reference, ["mu"], method="nelder-mead", max_iters=200)
    assert abs(nm["params"]["mu"] - 0.3) < 1e-3, nm


def test_fit_reads_a_trajectory_csv_like_ecp_fit(a1, tmp_path):
    out = run_cli("run", str(scene_path("a1_sliding")), "--steps", "10", "--no-plots", "--quiet", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    report = ecp.fit(a1.with_params(mu=0.2), tmp_path / "trajectory.csv", ["mu"])
    assert abs(report["params"]["mu"] - 0.3) < 1e-6, report
    with pytest.raises(ecp.InputError, match="cannot read"):
        ecp.fit(a1, tmp_path / "missing.csv", ["mu"])
    with pytest.raises(ecp.InputError, match="unknown method"):
        ecp.fit(a1, tmp_path / "trajectory.csv", ["mu"], method="newton")
    with pytest.raises(ecp.InputError, match="no parameter"):
        ecp.fit(a1, tmp_path / "trajectory.csv", [])


def test_lcp_solves_like_ecp_lcp(tmp_path):
    m = [[2.0, 1.0], [1.0, 2.0]]
    q = [-5.0, -6.0]
    r = ecp.lcp(m, q)
    assert r["status"] == "solved" and r["error"] is None
    z, w = r["z"], r["w"]
    np.testing.assert_allclose(z, [4 / 3, 7 / 3], atol=1e-12)
    np.testing.assert_allclose(w, np.array(m) @ z + q, atol=1e-12)
    assert r["residual"] <= 1e-12
    path = tmp_path / "lcp.json"
    path.write_text(json.dumps({"M": m, "q": q}))
    out = run_cli("lcp", str(path))
    cli = json.loads(out.stdout)
    assert cli["z"] == list(z) and cli["pivots"] == r["pivots"]
    # No solution: Lemke's method ends on a ray.
    bad = ecp.lcp(np.array([[-1.0]]), np.array([-1.0]))
    assert bad["status"] == "ray_termination" and bad["z"].size == 0 and bad["error"]


def test_lcp_bad_input():
    with pytest.raises(ecp.InputError, match="M must be 2 × 2"):
        ecp.lcp([[1.0, 0.0]], [1.0, 2.0])
    with pytest.raises(ecp.InputError, match="non-finite"):
        ecp.lcp([[np.nan]], [1.0])
    with pytest.raises(ecp.InputError, match="empty"):
        ecp.lcp(np.zeros((0, 0)), [])
    with pytest.raises(TypeError, match="q"):
        ecp.lcp([[1.0]], ["one"])
