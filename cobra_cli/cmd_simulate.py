"""``cobra simulate``: write a simulated run (``cobra-run/1``) of the sidewinding gait."""
from __future__ import annotations

import argparse

import numpy as np

from cobra_cli.common import add_contact_option, check_run_writable, load_params
from cobra_cli.progress import progress_bar
from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from cobra_model.model import CobraModel
from cobra_model.run_files import read_run, write_run
from integrators.simulate import record_period, simulate_gait, simulate_like
from integrators.simulator import SCHEMES, STEPS_PER_CONTACT_TIME_CONSTANT, SimSettings, Simulator, contact_resolved
from sysid.discrepancy.effects import EffectLibrary, parse_effects


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate the sidewinding gait (or reproduce a run) and write a run",
        description="Simulate COBRA and write a cobra-run/1 run (CSV + JSON sidecar).")
    p.add_argument("--freq", type=float, default=0.5, help="gait frequency [Hz] (default 0.5)")
    p.add_argument("--duration", type=float, default=8.0, help="simulated time [s] (default 8)")
    p.add_argument("--out", required=True, help="output run CSV")
    p.add_argument("--params", help="parameter file (default: nominal parameters)")
    p.add_argument("--from", dest="from_run", metavar="RUN.csv",
                   help="reproduce this run: its initial pose and q_ref columns (ignores --freq/--duration)")
    p.add_argument("--dt", type=float, default=None,
                   help="physics step [s] (default 0.001, or the fraction of the servo period that gives a "
                        f"soft contact at least {STEPS_PER_CONTACT_TIME_CONSTANT} steps per time constant)")
    p.add_argument("--control-dt", type=float, default=None,
                   help="servo loop period [s], a multiple of --dt (default = --dt)")
    p.add_argument("--scheme", choices=SCHEMES, default="velocity",
                   help="physics step: 'velocity' (semi-implicit Euler, the fits' step) or 'momentum' "
                        "(symplectic Euler on the momentum: bounded energy error, ~30x the cost) (default velocity)")
    add_contact_option(p, "simulate")
    p.add_argument("--heading", type=float, default=0.0, help="initial heading [deg] (default 0)")
    p.add_argument("--rate", type=float, default=100.0, help="output sample rate [Hz] (default 100)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE[,NAME=VALUE]",
                   help="add a physical effect the nominal model lacks, VALUE its main parameter in SI "
                        f"units: {EffectLibrary().help_text()}")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_run_writable(args.out, args.force)
    params = load_params(args.params, args.contact, args.friction_step)
    if args.effect:
        params = EffectLibrary().transform(params, parse_effects(args.effect), frozen=True)
    try:
        dt = SimSettings.dt if args.dt is None else args.dt
        settings = SimSettings(dt=dt, control_dt=args.control_dt or dt, scheme=args.scheme)
        if args.dt is None:
            settings = contact_resolved(settings, params)
    except ValueError as exc:
        raise InputError(f"--dt/--control-dt/--scheme: {exc}") from None
    if not (np.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration must be > 0 s, got {args.duration}")
    if not np.isfinite(args.heading):
        raise InputError(f"--heading must be a finite angle [deg], got {args.heading}")
    sim = Simulator(CobraModel.load(), params, settings)
    sim.check_steps()
    try:
        every = record_period(args.rate, settings.dt)
    except InputError as exc:
        raise InputError(f"--rate: {exc}") from None
    with progress_bar("simulating") as bar:
        if args.from_run:
            result = simulate_like(read_run(args.from_run), simulator=sim, progress=bar)
        else:
            result = simulate_gait(SidewindingGait(args.freq), args.duration, simulator=sim,
                                   heading_rad=float(np.deg2rad(args.heading)), sample_rate_hz=args.rate,
                                   progress=bar)
    write_run(result, out, force=args.force)
    h0, h1 = result.head_pos[0], result.head_pos[-1]
    print(f"wrote {out} ({len(result.t)} samples, {result.t[-1] - result.t[0]:.2f} s); head moved from "
          f"({h0[0]:.3f}, {h0[1]:.3f}) to ({h1[0]:.3f}, {h1[1]:.3f}) m")
    rate = 1.0 / (every * settings.dt)
    if not args.from_run and abs(rate - args.rate) > 1e-6 * args.rate:
        steps = "every physics step" if every == 1 else f"every {every} physics steps"
        print(f"note: sampled at {rate:.4g} Hz, one sample {steps} of {settings.dt:g} s "
              f"(the nearest to --rate {args.rate:g} Hz)")
    return 0
