"""Sweeps on Ray: one grid of runs split into Ray tasks, each an :func:`ecp.batch` chunk.

The table that comes back is the one :func:`ecp.batch` gives for the same scene and grid, bit
for bit: every run is computed by one thread from start to end whatever machine runs it, the
points are split in order and the chunks put back in order. Only the timings differ.

On one machine::

    import ray, ecp, ecp.ray
    ray.init(num_cpus=2)
    result = ecp.ray.sweep(scene, grid={"mu": [0.1, 0.2, 0.3], "fx": [20, 40]})

On a cluster, connect to it instead (``ray.init(address="auto")`` on a node of the cluster, or
``ray.init(address="ray://HEAD:10001")`` from outside); the same call then spreads the chunks
over the nodes. Every node needs this package installed (``pip install ./python`` from a
checkout, or a Ray ``runtime_env``), and scenes with meshes need the mesh files at the same paths.
"""

from __future__ import annotations

from typing import Any, Dict, List, Mapping, Optional, Sequence

import numpy as np

import ecp

__all__ = ["SweepResult", "sweep", "split"]


class SweepResult:
    """The gathered results of a sweep: ``table`` (the columns of :attr:`ecp.BatchResult.table`,
    one row per point in grid order), ``timings`` (wall-clock times, not results) and
    ``chunks`` (the number of Ray tasks)."""

    def __init__(self, table: Dict[str, Any], timings: Dict[str, Any], chunks: int):
        self.table = table
        self.timings = timings
        self.chunks = chunks

    def __len__(self) -> int:
        return len(self.table["index"]) if "index" in self.table else 0

    @property
    def failed(self) -> int:
        """Runs with a failed step or an error."""
        failed = np.asarray(self.table["failed_steps"]) > 0
        errors = np.array([bool(e) for e in self.table["error"]], dtype=bool)
        return int(np.count_nonzero(failed | errors))

    def __repr__(self) -> str:
        return f"SweepResult(runs={len(self)}, failed={self.failed}, chunks={self.chunks})"


def split(points: Sequence[Any], chunks: int) -> List[Sequence[Any]]:
    """``points`` in ``chunks`` consecutive pieces of nearly equal length (none empty)."""
    n = len(points)
    chunks = max(1, min(chunks, n))
    size, extra = divmod(n, chunks)
    out, start = [], 0
    for k in range(chunks):
        end = start + size + (1 if k < extra else 0)
        out.append(points[start:end])
        start = end
    return out


def _run_chunk(scene: "ecp.Scene", points: List[Dict[str, float]], options: Dict[str, Any]):
    """One Ray task: an :func:`ecp.batch` over ``points``; its table and timings."""
    result = ecp.batch(scene, points=points, **options)
    return result.table, result.timings


def _concat(parts: List[Dict[str, Any]], offsets: List[int]) -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for name in parts[0]:
        columns = [p[name] for p in parts]
        if name == "index":
            columns = [np.asarray(c) + np.uint64(off) for c, off in zip(columns, offsets)]
        if isinstance(columns[0], np.ndarray):
            out[name] = np.concatenate(columns)
        else:
            out[name] = [v for c in columns for v in c]
    return out


def sweep(
    scene: "ecp.Scene",
    grid: Optional[Mapping[str, Sequence[float]]] = None,
    points: Optional[Sequence[Mapping[str, float]]] = None,
    *,
    chunks: Optional[int] = None,
    threads_per_task: int = 1,
    **options: Any,
) -> SweepResult:
    """Runs ``scene`` at every point of ``grid`` (or of ``points``) as Ray tasks and gathers one
    table, the same as ``ecp.batch(scene, grid=grid, ...)`` gives.

    ``chunks`` (default: the cluster's CPUs divided by ``threads_per_task``) is the number of
    tasks; each runs :func:`ecp.batch` on ``threads_per_task`` threads and asks Ray for as many
    CPUs. ``options`` are those of :func:`ecp.batch` (``steps``, ``solver``, ``formulation``,
    ``fallbacks``, ``keep_going``); records are not gathered (use :func:`ecp.batch` on one
    machine for trajectories). Call ``ray.init(...)`` first.
    """
    import ray

    if not ray.is_initialized():
        raise RuntimeError(
            "Ray is not initialised: call ray.init(num_cpus=N) on one machine or "
            "ray.init(address='auto') on a node of a cluster first"
        )
    if (grid is None) == (points is None):
        raise ecp.InputError("give grid={name: values} or points=[{name: value}, ...], one of them")
    if options.get("records"):
        raise ecp.InputError("ecp.ray.sweep gathers tables only; run ecp.batch(..., records=True) for trajectories")
    if "threads" in options:
        raise ecp.InputError("ecp.ray.sweep sets each task's threads from threads_per_task")
    if threads_per_task < 1:
        raise ecp.InputError(f"threads_per_task must be at least 1, not {threads_per_task}")
    if grid is not None:
        point_list = [dict(p) for p in ecp.grid_points(scene, dict(grid))]
    else:
        point_list = [dict(p) for p in points]  # type: ignore[union-attr]
    if not point_list:
        raise ecp.InputError("the sweep has no point")
    if chunks is None:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        chunks = max(1, cpus // threads_per_task)
    pieces = split(point_list, chunks)
    offsets = list(np.cumsum([0] + [len(p) for p in pieces[:-1]]))
    task = ray.remote(num_cpus=threads_per_task)(_run_chunk)
    batch_options = dict(options, threads=threads_per_task)
    refs = [task.remote(scene, list(p), batch_options) for p in pieces]
    results = ray.get(refs)
    table = _concat([r[0] for r in results], [int(o) for o in offsets])
    timings = _concat([r[1] for r in results], [int(o) for o in offsets])
    return SweepResult(table, timings, len(pieces))
