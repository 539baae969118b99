"""ecp.batch: results in input order, bitwise identical on 1 and 2 threads and from run to run
(timings kept apart), grids, points, lists of scenes, failed runs, the interpreter released."""

import threading
import time

import numpy as np
import pytest

import ecp
from conftest import run_cli, scene_path


def same_table(a, b):
    assert list(a) == list(b)
    for name in a:
        if isinstance(a[name], np.ndarray):
            assert a[name].dtype == b[name].dtype, name
            assert a[name].tobytes() == b[name].tobytes(), name
        else:
            assert a[name] == b[name], name


TRAJECTORY_ARRAYS = ["t", "states", "ecp", "pn", "pt", "po", "pr", "sigma", "min_gap", "energy", "residual", "iterations"]


def test_a_batch_is_bitwise_identical_on_one_and_two_threads_and_from_run_to_run(desk):
    grid = {"mu": np.linspace(0.15, 0.3, 3), "vx0": [0.1, 0.4]}
    runs = [ecp.batch(desk, grid=grid, steps=60, threads=t, records=True) for t in (1, 2, 2)]
    assert [r.threads for r in runs] == [1, 2, 2]
    for other in runs[1:]:
        same_table(runs[0].table, other.table)
        for ta, tb in zip(runs[0].trajectories, other.trajectories):
            for name in TRAJECTORY_ARRAYS:
                assert getattr(ta, name).tobytes() == getattr(tb, name).tobytes(), name
    table = runs[0].table
    assert "wall_s" not in table, "timings are not results"
    assert set(runs[0].timings) == {"index", "wall_s", "solve_s"}
    assert len(runs[0].trajectories) == 6 and len(runs[0].trajectories[0]) == 60


def test_grid_order_and_values(desk):
    grid = {"mu": [0.2, 0.3], "vx0": [0.1, 0.2, 0.3]}
    r = ecp.batch(desk, grid=grid, steps=5, threads=2)
    t = r.table
    np.testing.assert_array_equal(t["index"], np.arange(6, dtype=np.uint64))
    np.testing.assert_array_equal(t["mu"], [0.2, 0.2, 0.2, 0.3, 0.3, 0.3])
    np.testing.assert_array_equal(t["vx0"], [0.1, 0.2, 0.3] * 2)
    assert t["scene"] == ["desk"] * 6 and t["error"] == [""] * 6
    np.testing.assert_array_equal(t["steps"], [5] * 6)
    assert r.failed == 0 and len(r) == 6
    # grid_points gives the same points in the same order.
    points = ecp.grid_points(desk, grid)
    assert [(p["mu"], p["vx0"]) for p in points] == list(zip(t["mu"], t["vx0"]))
    by_points = ecp.batch(desk, points=points, steps=5, threads=1)
    same_table(by_points.table, t)
    # Each row is the run of its scene alone.
    alone = ecp.Simulation(desk.with_params(mu=0.3, vx0=0.2)).run(5)
    assert t["vx"][4] == alone.velocity[-1, 0, 0] and t["wz"][4] == alone.angular_velocity[-1, 0, 2]


def test_the_cli_sweep_and_a_linspace_grid_give_the_same_table(a1, tmp_path):
    out = run_cli("sweep", str(scene_path("a1_sliding")), "--param", "mu=0.1:0.5:9", "--steps", "8", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    import csv

    with open(tmp_path / "sweep.csv") as f:
        rows = list(csv.DictReader(f))
    table = ecp.batch(a1, grid={"mu": np.linspace(0.1, 0.5, 9)}, steps=8).table
    assert len(rows) == 9
    for name in ["mu", "vx", "x", "energy", "max_residual"]:
        assert np.array([float(r[name]) for r in rows]).tobytes() == table[name].tobytes(), name


def test_a_list_of_scenes_with_a_failing_one(a1):
    drop = ecp.Scene.from_toml(scene_path("a5_drop"))
    r = ecp.batch([a1, drop], steps=3, formulation="reduced", records=True)
    assert r.table["scene"] == ["a1_sliding", "a5_drop"]
    assert [len(t) for t in r.trajectories] == [3, 0], "one trajectory per row"
    assert r.errors[0] is None and "reduced" in r.errors[1]
    assert r.failed == 1
    np.testing.assert_array_equal(r.table["converged_steps"], [3, 0])


def test_bad_batch_arguments(a1, desk):
    with pytest.raises(ecp.InputError, match="unknown parameter"):
        ecp.batch(a1, grid={"friction": [0.1]})
    with pytest.raises(ecp.InputError, match="μ must be ≥ 0"):
        ecp.batch(a1, grid={"mu": [-0.1, 0.2]})
    with pytest.raises(ecp.InputError, match="function of time"):
        ecp.batch(desk, grid={"fx": [1.0, 2.0]})
    with pytest.raises(ecp.InputError, match="not both"):
        ecp.batch(a1, grid={"mu": [0.1]}, points=[{"mu": 0.1}])
    with pytest.raises(ecp.InputError, match="one scene"):
        ecp.batch([a1, desk], grid={"mu": [0.1]})
    with pytest.raises(ecp.InputError, match="at least 1"):
        ecp.batch(a1, threads=0)
    with pytest.raises(ecp.InputError, match="no value"):
        ecp.batch(a1, grid={"mu": []})
    with pytest.raises(TypeError, match="ecp.Scene"):
        ecp.batch(["scenes/a1_sliding.toml"])
    with pytest.raises(TypeError):
        ecp.batch(a1, grid={"mu": ["low", "high"]})


def test_the_interpreter_is_released_while_a_batch_runs(desk):
    # A batch long enough (about a second, whatever the build's speed) that the main thread can
    # run Python while it is inside it: with the interpreter held, the main thread could only
    # go on once the batch had returned.
    started = time.perf_counter()
    ecp.batch(desk, steps=100, threads=1)
    per_run = time.perf_counter() - started
    runs = max(2, min(400, int(1.0 / max(per_run, 1e-4))))
    done = {}

    def work():
        done["result"] = ecp.batch(desk, grid={"mu": np.linspace(0.2, 0.25, runs)}, steps=100, threads=1)

    worker = threading.Thread(target=work)
    worker.start()
    time.sleep(0.05)
    total = sum(i for i in range(20_000))  # Python bytecode on this thread
    alive = worker.is_alive()
    worker.join()
    assert total == 199_990_000
    assert alive, "the main thread could not run while the batch ran"
    assert len(done["result"]) == runs
