"""Shared fixtures: the COBRA model and the example-robot-data URDFs (found under the install prefix)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from cobra_model.model import CobraModel


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
