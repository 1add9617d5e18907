"""Files shipped inside the installed package, found with :mod:`importlib.resources`.

The checkout keeps them where a reader looks for them (``urdf/``, ``data/reference/``,
``examples/``); ``pyproject.toml`` maps those folders into the packages as package data
(``cobra_model.urdf``, ``sysid.reference``, ``hardware.examples``), so an install from a wheel
and an editable install find the same files by package name.
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def shipped_path(package: str, name: str = "") -> Path:
    """The file ``name`` of data package ``package`` (the package's folder if ``name`` is empty).

    Packages are installed as folders on disk (wheel or editable install), so the path can be
    handed to libraries that open files by name (Pinocchio's URDF parser).
    """
    resource = files(package).joinpath(name) if name else files(package)
    return Path(str(resource))
