"""Shared fixtures: the COBRA model, the example-robot-data URDFs (found under the install prefix)
and a disk that fills up under the run writer."""
from __future__ import annotations

import errno
import os
import sys
from pathlib import Path

import pytest

from cobra_model.model import CobraModel
from hardware.runwriter import IncrementalRunWriter


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


class FullDisk:
    """A file whose disk fills up at its ``writes``-th write: that write puts 7 bytes down,
    then fails with ENOSPC, as write(2) does."""

    def __init__(self, fh, writes: int) -> None:
        self.fh, self.left = fh, writes

    def write(self, data) -> int:
        self.left -= 1
        if self.left > 0:
            return self.fh.write(data)
        self.fh.write(bytes(data[:7]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str):
        return getattr(self.fh, name)


@pytest.fixture
def full_disk_after(monkeypatch):
    """``full_disk_after(samples)``: from then on every IncrementalRunWriter gets room for its
    header and ``samples`` lines, and cannot replace its sidecar once it has written the first."""
    return lambda samples: _full_disk_after(samples, monkeypatch)


def _full_disk_after(samples: int, monkeypatch) -> None:
    monkeypatch.setattr(IncrementalRunWriter, "_open",
                        lambda self, mode: FullDisk(self.path.open(mode, buffering=0), samples + 2))
    written = set()
    real = IncrementalRunWriter._write_sidecar

    def sidecar(self, meta):
        if self.path in written:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.add(self.path)
        real(self, meta)

    monkeypatch.setattr(IncrementalRunWriter, "_write_sidecar", sidecar)

