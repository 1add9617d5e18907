"""``cobra diagnose``: find where simulation and measurement disagree and name the missing effect."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from cobra_cli.common import add_contact_option, check_writable, law_starts, start_lines
from cobra_model.errors import InputError
from sysid.discrepancy.diagnose import DiagnoseConfig, channel_weights, diagnose
from sysid.discrepancy.effects import EffectLibrary
from sysid.discrepancy.report import OUTPUTS, write_diagnosis
from sysid.gap.report import head_text
from sysid.identification.splits import expand, read_runs

def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose", help="find the physical effect the model lacks, add it, refit, show the gap",
        description="Fit the model, localise the residuals, try the library of candidate effects "
                    f"({', '.join(EffectLibrary().names)}), name the one the "
                    "held-out runs support, add it and refit. A manifest.json among RUNS gives its split.")
    p.add_argument("runs", nargs="+", metavar="RUNS", help="training run CSVs or a dataset manifest.json")
    p.add_argument("--holdout", nargs="*", default=[], metavar="RUN", help="held-out runs (added to a manifest's)")
    p.add_argument("--out", required=True, type=Path, help="output folder (report.html, diagnosis.json, "
                   "augmented_params.json)")
    p.add_argument("--json", action="store_true", help="print diagnosis.json instead of the summary")
    p.add_argument("--max-effects", type=int, default=2, help="effects to look for in turn (default 2)")
    p.add_argument("--params", help="starting parameter file (default nominal)")
    add_contact_option(p, "fit and diagnose", choose="diagnose under each law and keep the diagnosis whose "
                       "final model has the lower held-out cost (the time of one diagnosis per law)")
    p.add_argument("--free", help="comma-separated parameters the fits tune (default: all not frozen that the "
                   "contact law reads)")
    p.add_argument("--fit-runs", type=int, default=DiagnoseConfig.fit_runs,
                   help=f"training runs used by the fits, spread over the gaits (default "
                        f"{DiagnoseConfig.fit_runs}; 0 = all)")
    p.add_argument("--no-current", action="store_true",
                   help="leave the motor currents out (default: when every run has current_1..current_11, the fits "
                        "and judgements weigh them as a third channel beside the head path and the joints)")
    p.add_argument("--force", action="store_true", help="overwrite outputs in --out")
    p.add_argument("--no-check", action="store_true", help="skip the data check before fitting (gaps, "
                   "dropouts, saturated joints, parameters the runs cannot pin down, which it freezes)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return diagnose_to(args.out, args.runs, holdout=args.holdout, max_effects=args.max_effects, params=args.params,
                       contact_law=args.contact, free=args.free, fit_runs=args.fit_runs, force=args.force, check=not args.no_check,
                       json_out=args.json, use_current=False if args.no_current else None,
                       friction_step=args.friction_step)


def diagnose_to(out: Path, runs: Sequence[str], *, holdout: Sequence[str] = (), max_effects: int = 2,
                params: str | None = None, contact_law: str | None = None, free: str | None = None,
                fit_runs: int = DiagnoseConfig.fit_runs,
                force: bool = False, check: bool = True, json_out: bool = False,
                use_current: bool | None = None, friction_step: str | None = None) -> int:
    """``cobra diagnose``'s work (also ``cobra demo``'s last step): the arguments are the command's
    options; writes ``OUTPUTS`` into ``out`` and prints the summary (or the JSON). Returns 0."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a directory")
    if out.exists():
        for name in OUTPUTS:
            check_writable(out / name, force)
    if max_effects < 0:
        raise InputError(f"--max-effects must be >= 0, got {max_effects}")
    if fit_runs < 0:
        raise InputError(f"--fit-runs must be >= 0 (0: every training run), got {fit_runs}")
    train_paths, val_paths = expand(list(runs))
    val_paths += [Path(p) for p in holdout]
    if not train_paths or not val_paths:
        raise InputError("diagnose needs training runs and held-out runs (--holdout, or a manifest's validation)")
    train, held = read_runs(train_paths), read_runs(val_paths)
    config = DiagnoseConfig(max_effects=max_effects, fit_runs=fit_runs, use_current=use_current)
    # with --json, stdout carries only the JSON
    starts, checks = law_starts(params, contact_law, free, None, train, held, check=check,
                                out=sys.stderr if json_out else sys.stdout, weights=channel_weights([*train, *held], config),
                                friction_step=friction_step)
    from tqdm import tqdm
    bar = tqdm(desc="diagnose", unit="step", leave=False, disable=None)

    def progress(message: str) -> None:
        bar.update(1)
        bar.set_postfix_str(message)
        if bar.disable:
            print(f"  ... {message}", flush=True, file=sys.stderr if json_out else sys.stdout)  # --json: stdout is the JSON

    if len(starts) > 1:
        result = diagnose(train, held, law_starts=starts, config=config, progress=progress)
    else:
        result = diagnose(train, held, params=next(iter(starts.values())), config=config, progress=progress)
    bar.close()
    doc = write_diagnosis(result, out, checks[result.params_before.contact_law])
    if json_out:
        print(json.dumps(doc, indent=2, default=float))
        return 0
    for line in start_lines(result.base_starts, "the base fit's "):
        print(line)
    print(result.verdict)
    for d in result.structural:
        print(f"  structural difference (not named): {d.name} would cut the held-out cost by "
              f"{100 * d.held_out_improvement:.0f} % only with {d.why}")
    for e in result.effects:
        ci_text = f" (95% [{e.ci95[0]:.4g}, {e.ci95[1]:.4g}])" if e.ci95 else ""
        print(f"  {e.name}: {e.parameter} = {e.value:.4g} {e.unit}{ci_text}; held-out cost "
              f"-{100 * e.held_out_cost_reduction:.0f} %, dBIC {e.delta_bic:.0f}")
    gb, ga = result.gap_before, result.gap_after
    print(f"  held-out head final error {head_text(gb.head_final_error_m, ga.head_final_error_m)}, "
          f"joint RMSE {gb.joint_rmse_rad:.4f} -> {ga.joint_rmse_rad:.4f} rad ({result.seconds:.0f} s)")
    white = result.fits[-1].residual_whiteness
    if white is not None:
        print(f"  {white.console_line()}")
    print(f"report: {out / 'report.html'}; model with the effect: {out / 'augmented_params.json'}")
    return 0
