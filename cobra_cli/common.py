"""Helpers shared by the subcommands: loading parameters, refusing to overwrite outputs."""
from __future__ import annotations

import argparse
from pathlib import Path

from cobra_model.errors import InputError
from cobra_model.parameters import CONTACT_LAWS, ModelParameters


def load_params(path: str | Path | None, contact_law: str | None = None) -> ModelParameters:
    """The parameter file at ``path`` (nominal parameters when None), under ``contact_law`` if
    given, else under the file's law (the nominal set's: compliant)."""
    params = ModelParameters.nominal() if path is None else ModelParameters.load(path)
    return params if contact_law is None else params.with_contact_law(contact_law)


def add_contact_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--contact LAW``: the contact law to {what} with, overriding the parameter file's."""
    p.add_argument("--contact", choices=CONTACT_LAWS, default=None,
                   help=f"contact law to {what} with: 'compliant' (spring-damper ground, Stribeck friction) or "
                        "'soft_constraint' (MuJoCo's: a soft constraint on the friction pyramid, time constant "
                        "from the parameter contact_time_constant) (default: the parameter file's law, which a "
                        "fit records; compliant for the nominal parameters)")


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse to overwrite an existing file unless ``force`` (names the path and the flag)."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass --force to overwrite it")
    if path.parent and not path.parent.exists():
        raise FileNotFoundError(f"output directory {path.parent} does not exist")
    return path


def check_run_writable(path: str | Path, force: bool) -> Path:
    """A run's CSV path (must end in ``.csv``); refuses if the CSV or its JSON sidecar exists."""
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise InputError(f"--out {path}: a run file must end in .csv (its sidecar is NAME.json)")
    check_writable(path.with_suffix(".json"), force)
    return check_writable(path, force)


def parse_names(text: str | None, option: str) -> list[str]:
    """Comma-separated parameter names of ``option`` ([] when not given)."""
    if not text:
        return []
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(f"{option}: expected comma-separated parameter names")
    return names
