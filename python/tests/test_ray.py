"""ecp.ray on a local Ray (2 CPUs): a sweep split into tasks gathers bitwise the table of
ecp.batch on the same grid."""

import numpy as np
import pytest

import ecp
from conftest import scene_path

ray = pytest.importorskip("ray", reason="Ray is installed by scripts/test")
import ecp.ray  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_split_keeps_order_and_sizes():
    assert ecp.ray.split(list(range(7)), 3) == [[0, 1, 2], [3, 4], [5, 6]]
    assert ecp.ray.split([1, 2], 5) == [[1], [2]]


def test_a_ray_sweep_gives_the_table_of_ecp_batch(local_ray):
    scene = ecp.Scene.from_toml(scene_path("a2_push_slide"))
    grid = {"mu": np.linspace(0.1, 0.5, 5), "fx": [10.0, 30.0, 50.0]}
    swept = ecp.ray.sweep(scene, grid=grid, steps=20, chunks=4)
    local = ecp.batch(scene, grid=grid, steps=20, threads=2)
    assert swept.chunks == 4 and len(swept) == 15 and swept.failed == 0
    assert list(swept.table) == list(local.table)
    for name, column in local.table.items():
        if isinstance(column, np.ndarray):
            assert swept.table[name].dtype == column.dtype, name
            assert swept.table[name].tobytes() == column.tobytes(), name
        else:
            assert swept.table[name] == column, name
    np.testing.assert_array_equal(swept.timings["index"], np.arange(15, dtype=np.uint64))
    # Slides once f_x > μ m g: v = (f_x/m − μ g) t after 20 steps.
    k = 2 * 3 + 2  # μ = 0.3, f_x = 50 N
    assert abs(swept.table["vx"][k] - (5.0 - 0.3 * 9.8) * 0.2) < 1e-9


def test_points_and_bad_calls(local_ray):
    scene = ecp.Scene.from_toml(scene_path("a1_sliding"))
    points = [{"mu": 0.1}, {"mu": 0.2}, {"mu": 0.3}]
    swept = ecp.ray.sweep(scene, points=points, steps=5, chunks=2, threads_per_task=1)
    local = ecp.batch(scene, points=points, steps=5)
    assert swept.table["vx"].tobytes() == local.table["vx"].tobytes()
    with pytest.raises(ecp.InputError, match="one of them"):
        ecp.ray.sweep(scene, steps=5)
    with pytest.raises(ecp.InputError, match="tables only"):
        ecp.ray.sweep(scene, points=points, records=True)
