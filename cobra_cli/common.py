"""Helpers shared by the subcommands: loading parameters, refusing to overwrite outputs."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Sequence, TextIO

from cobra_model.errors import InputError
from cobra_model.parameters import CONTACT_LAWS, FRICTION_STEPS, ModelParameters
from cobra_model.run import Run

if TYPE_CHECKING:
    from sysid.identification.contact_choice import StartFit
    from sysid.identification.datacheck import DataCheck
    from sysid.identification.objective import Weights


def load_params(path: str | Path | None, contact_law: str | None = None,
                friction_step: str | None = None) -> ModelParameters:
    """The parameter file at ``path`` (nominal parameters when None), under ``contact_law`` and
    ``friction_step`` if given, else under the file's (the nominal set's: compliant, explicit)."""
    params = ModelParameters.nominal() if path is None else ModelParameters.load(path)
    params = params if contact_law is None else params.with_contact_law(contact_law)
    return params if friction_step is None else params.with_friction_step(friction_step)


def fit_start(path: str | Path | None, contact_law: str | None, free: str | None, frozen: str | None = None,
              out: TextIO | None = None, friction_step: str | None = None) -> ModelParameters:
    """The starting parameters of ``cobra fit`` and ``cobra diagnose``: the parameter file (nominal
    when None) under ``contact_law`` and ``friction_step`` (the file's if None),
    ``--free``/``--frozen`` applied. Without
    ``--free`` the free set follows the law (``sysid.identification.contact_choice.free_for_law``),
    which is said on ``out`` (default: standard output).

    Raises:
        InputError: for unknown names, or a ``--free`` ground parameter the law does not read.
    """
    from sysid.identification.contact_choice import free_for_law, unread_by_law

    start = load_params(path, contact_law, friction_step)
    free_names, frozen_names = parse_names(free, "--free"), parse_names(frozen, "--frozen")
    try:
        params = start.with_frozen(frozen=frozen_names, free=free_names or None)
    except InputError as exc:
        raise InputError(f"--free/--frozen: {exc}") from None
    unread = unread_by_law(params, free_names)
    if unread:
        raise InputError(f"--free {','.join(unread)}: the {params.contact_law} contact law does not read "
                         f"{'it' if len(unread) == 1 else 'them'} (--contact chooses the law)")
    if free_names:
        return params
    params, changed = free_for_law(params)
    if changed:
        print(changed, file=out or sys.stdout)
    return params.with_frozen(frozen=frozen_names)  # the user's --frozen still holds


def chosen_laws(contact: str | None) -> tuple[str, ...] | None:
    """The contact laws ``--contact`` chooses among: every law of :data:`CONTACT_LAWS` for
    ``choose``, the listed ones for a comma-separated list (``compliant,soft_constraint``); None
    for one law (or none given: the parameter file's).

    Raises:
        InputError: naming the value if a listed law is unknown.
    """
    if contact is None:
        return None
    if contact == "choose":
        return CONTACT_LAWS
    laws = listed_laws(contact)
    return laws if len(laws) > 1 else None


def listed_laws(contact: str) -> tuple[str, ...]:
    """The laws of a ``--contact`` value other than ``choose``: one law or a comma-separated list.

    Raises:
        InputError: naming the value if a law is unknown or none is given.
    """
    laws = tuple(dict.fromkeys(law.strip() for law in contact.split(",") if law.strip()))
    unknown = [law for law in laws if law not in CONTACT_LAWS]
    if unknown or not laws:
        raise InputError(f"--contact {contact!r}: expected one of {', '.join(CONTACT_LAWS)}, 'choose' (all of "
                         f"them) or a comma-separated list of laws to choose among")
    return laws


def _contact_value(text: str) -> str:
    """argparse type of ``--contact`` where choosing is allowed: the value, checked."""
    try:
        chosen_laws(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--contact ")) from None  # argparse names it
    return text


def law_starts(path: str | Path | None, contact_law: str | None, free: str | None, frozen: str | None,
               train: Sequence[Run], held_out: Sequence[Run], *, check: bool, out: TextIO | None = None,
               weights: Weights | None = None, friction_step: str | None = None
               ) -> tuple[dict[str, ModelParameters], dict[str, DataCheck | None]]:
    """The starting parameters of ``cobra fit`` and ``cobra diagnose`` per contact law they try:
    the laws :func:`chosen_laws` reads from ``--contact``, else the one law given (the
    parameter file's when None), each from :func:`fit_start` (under ``friction_step``, the
    file's when None), with the data check's frozen
    parameters when ``check`` (run per law: each law frees its own ground parameters; on the
    channels of ``weights``, the objective's defaults when None). Returns
    (law -> start, law -> data check or None); findings go to ``out`` (default stdout).

    Raises:
        InputError: ``--free`` with ``choose`` (each law fits the free set it reads), or what
            :func:`fit_start` and the data check raise.
    """
    from cobra_cli.cmd_check import check_before_fit

    laws = chosen_laws(contact_law)
    choosing = laws is not None
    if choosing and free:
        raise InputError(f"--contact {contact_law} fits each law with the free set it reads; drop --free, or give "
                         f"one law ({', '.join(CONTACT_LAWS)}) with it")
    starts: dict[str, ModelParameters] = {}
    checks: dict[str, DataCheck | None] = {}
    for law in laws if choosing else (listed_laws(contact_law)[0] if contact_law else None,):
        start = fit_start(path, law, free, frozen, out=out, friction_step=friction_step)
        data_check = None
        if check:
            if choosing:
                print(f"data check of the {law} contact law's free parameters:", file=out or sys.stdout)
            start, data_check = check_before_fit(train, start, held_out=held_out, out=out, weights=weights)
        starts[start.contact_law], checks[start.contact_law] = start, data_check
    return starts, checks


def start_lines(starts: Sequence[StartFit], fit: str = "") -> list[str]:
    """The training cost a fit (``fit``: which, e.g. "the base fit's ") reached from each of its
    starts (``fit_from_shapes``), one line each; none when it had one start."""
    if len(starts) < 2:
        return []
    return ([f"{fit}training cost from each start (screened on the first seconds, then the whole runs):"]
            + [f"  {one.describe():55s} " + (f"screen {one.screen_cost:.4g}  " if one.screen_cost is not None else "")
               + (f"whole runs {one.cost:.4g}" if one.cost is not None
                  else "(diverged: left out)" if one.diverged else "(not kept)") for one in starts])


def add_contact_option(p: argparse.ArgumentParser, what: str, choose: str = "") -> None:
    """``--contact LAW``: the contact law to {what} with, overriding the parameter file's; with
    ``choose`` (what choosing does, for the help), also ``--contact choose`` (every law) and a
    comma-separated list of laws to choose among (:func:`chosen_laws`). And ``--friction-step``,
    how the compliant ground's friction is stepped, overriding the parameter file's."""
    p.add_argument("--friction-step", choices=FRICTION_STEPS, default=None,
                   help=f"how the compliant ground's friction is stepped to {what}: 'explicit' (its sign regularised "
                        "at 1 cm/s: faithful to the Stribeck curve above 2.65 cm/s) or 'implicit' (at the step's end "
                        "slip, the sign at 1 mm/s: faithful above 2.65 mm/s, below v_s's lower bound; a few times "
                        "the cost) (default: the parameter file's, which a fit records; explicit for the nominal "
                        "parameters)")
    laws = ("'compliant' (spring-damper ground, Stribeck friction), 'soft_constraint' (MuJoCo's default: a soft "
            "constraint on the friction pyramid, time constant from the parameter contact_time_constant) or "
            "'soft_elliptic' (the same on MuJoCo's elliptic friction cone)")
    if choose:
        p.add_argument("--contact", type=_contact_value, default=None, metavar="LAW|choose|LAW,LAW...",
                       help=f"contact law to {what} with: {laws}; or 'choose' (every law) or a comma-separated "
                            f"list of laws: {choose} (default: the parameter file's law, which a fit records; "
                            "compliant for the nominal parameters)")
        return
    p.add_argument("--contact", choices=CONTACT_LAWS, default=None,
                   help=f"contact law to {what} with: {laws} (default: the parameter file's law, which a fit "
                        "records; compliant for the nominal parameters)")


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
