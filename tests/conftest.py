"""Shared fixtures: the COBRA model, the example-robot-data URDFs (found under the install prefix)
and a disk that fills up under the run writer."""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Iterator

import pytest

from cobra_model.model import CobraModel
from hardware import faults
from hardware.emulator import EmulatorProcess
from integrators.batch import THREADS_ENV

# Under pytest-xdist each worker has a core of its own: its batches run on one thread, so that two
# workers' batches do not fight over the cores (the suite's wall time, docs/benchmarks.md). The
# threaded paths stay under test where a test asks for threads (tests/test_batch.py,
# tests/test_soft_contact.py); the results do not depend on the count.
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    os.environ.setdefault(THREADS_ENV, "1")


@pytest.fixture(scope="session")
def cobra() -> CobraModel:
    return CobraModel.load()


def erd_robots_dir() -> Path:
    """example-robot-data's robots folder: the PyPI package installs it under the prefix, no loader."""
    for base in (Path(sys.prefix), *map(Path, sys.path)):
        for cand in (base / "cmeel.prefix" / "share" / "example-robot-data" / "robots",
                     base / "share" / "example-robot-data" / "robots",
                     base / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
                     / "cmeel.prefix" / "share" / "example-robot-data" / "robots"):
            if cand.is_dir():
                return cand
    pytest.fail("example-robot-data is not installed (it is a dependency in pyproject.toml)")


@pytest.fixture(scope="session")
def erd_dir() -> Path:
    return erd_robots_dir()


@pytest.fixture
def emulators() -> Iterator[list[EmulatorProcess]]:
    """Emulated buses a test starts (append them); each is stopped at the end."""
    started: list[EmulatorProcess] = []
    yield started
    for emu in started:
        emu.stop()


@pytest.fixture
def full_disk_after() -> Iterator:
    """``full_disk_after(samples)``: from then on, to the test's end, the run writer's disk is
    full after ``samples`` lines (:func:`hardware.faults.full_disk_after`)."""
    with contextlib.ExitStack() as stack:
        yield lambda samples: stack.enter_context(faults.full_disk_after(samples))
