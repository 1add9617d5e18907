"""One interface for evaluating many independent jobs: local processes or a Ray cluster.

Both identification methods evaluate the objective for many parameter vectors. The work is cut
into chunks and handed to an :class:`Executor`: :class:`LocalExecutor` (a process pool on this
machine, or in-process with ``workers=1``) by default, :class:`RayExecutor` for sweeps that
outgrow one machine (``pip install 'cobra-sysid[ray]'``; ``address=None`` starts a local Ray,
``"auto"`` or ``"ray://host:port"`` joins a cluster).
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Protocol, Sequence

from cobra_model.errors import InputError


class Executor(Protocol):
    """Maps a picklable function over items, preserving order."""

    workers: int

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
        ...

    def close(self) -> None:
        ...


class LocalExecutor:
    """A pool of ``workers`` local processes (in-process when ``workers == 1``)."""

    def __init__(self, workers: int | None = None):
        self.workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
        if self.workers == 1 or len(items) <= 1:
            return [fn(item) for item in items]
        if self._pool is None:
            # spawn, not fork: the parent runs numba and OpenMP thread pools that a fork would copy
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"))
        return list(self._pool.map(fn, items))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


class RayExecutor:
    """Ray tasks; ``address=None`` starts a local instance with ``num_cpus`` CPUs."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None):
        try:
            import ray
        except ImportError as exc:
            raise InputError("--executor ray needs Ray: pip install 'cobra-sysid[ray]'") from exc
        self._ray = ray
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if address is None:
                kwargs["num_cpus"] = num_cpus or os.cpu_count() or 1
            else:
                kwargs["address"] = address
            ray.init(**kwargs)
        self.workers = int(ray.cluster_resources().get("CPU", 1))

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
        remote = self._ray.remote(fn)
        return self._ray.get([remote.remote(item) for item in items])

    def close(self) -> None:
        """Leave the Ray instance running for other users of this process."""


def make_executor(kind: str = "local", *, workers: int | None = None, ray_address: str | None = None) -> Executor:
    """``"local"`` or ``"ray"`` (the CLI's ``--executor``)."""
    if kind == "local":
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(ray_address, workers)
    raise InputError(f"--executor must be 'local' or 'ray', got {kind!r}")
