"""``cobra fit``: identify the parameter vector by least squares (CasADi) or PPO."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from cobra_cli.common import add_contact_option, check_writable, chosen_laws, law_starts, start_lines
from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from sysid.identification.executor import make_executor
from sysid.identification.fit_report import fit_document, write_fit_report
from sysid.identification.lsq import FitResult
from sysid.identification.objective import Objective, Weights
from sysid.identification.splits import expand, read_runs


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="identify the parameters from measured runs (least squares or PPO)",
        description="Tune the parameter vector so that simulated runs match measured ones. A dataset "
                    "manifest.json among RUNS contributes its train/validation split.")
    p.add_argument("runs", nargs="+", metavar="RUNS", help="run CSVs or a dataset manifest.json")
    p.add_argument("--method", choices=("lsq", "ppo"), default="lsq", help="least squares (default) or PPO")
    p.add_argument("--holdout", nargs="*", default=[], metavar="RUN", help="held-out runs (added to a manifest's)")
    p.add_argument("--params", help="starting parameter file (default: nominal)")
    add_contact_option(p, "fit", choose="fit each law with the ground parameters it reads and keep the one with "
                       "the lower cost on the held-out runs (least squares; needs held-out runs)")
    p.add_argument("--free", help="comma-separated names to tune (default: every parameter not frozen that the "
                   "contact law reads)")
    p.add_argument("--frozen", help="comma-separated names to hold fixed")
    p.add_argument("--budget-seconds", type=float, default=None, help="wall-time budget [s] (least squares with "
                   "contact_rounding free: shared by its fits from each shape of the module ends)")
    p.add_argument("--max-iterations", type=int, default=20, help="least squares: Jacobian evaluations at most")
    p.add_argument("--timesteps", type=int, default=2048, help="PPO: environment steps (parameter vectors "
                   "tried) at most")
    p.add_argument("--seed", type=int, default=0, help="random seed (PPO)")
    p.add_argument("--envs", type=int, default=32, help="PPO: environments stepped together, their parameter "
                   "vectors simulated in one batch (default 32)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="where evaluations run")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (with --executor ray)")
    p.add_argument("--workers", type=int, default=1, help="local processes for evaluations (default 1: "
                   "in-process, the batch already uses both cores)")
    p.add_argument("--out", required=True, help="fitted parameter file (JSON)")
    p.add_argument("--report", metavar="DIR", help="write report.html with figures into DIR")
    p.add_argument("--force", action="store_true", help="overwrite --out and report files")
    p.add_argument("--current", action="store_true",
                   help="least squares: also fit the measured motor currents (current_* columns in every run); "
                        "the table then shows each interval without them too")
    p.add_argument("--channel-weights", choices=("fixed", "residual"), default="fixed",
                   help="least squares: fixed (default) weighs 1 cm of head error as 0.01 rad of joint error; "
                        "residual then refits with each channel weighted by its RMS residual (feasible weighted "
                        "least squares: when the model's structure differs from the data's, above all the "
                        "ground, the head path's unexplained error no longer pulls the actuator values)")
    p.add_argument("--no-check", action="store_true", help="skip the data check before fitting (gaps, "
                   "dropouts, saturated joints, parameters the runs cannot pin down, which it freezes)")
    p.set_defaults(func=run)


def bound_warnings(result: FitResult, fitted: ModelParameters) -> list[str]:
    """One warning per parameter the fit left at a bound (the report's ``at_bound``), naming the bound."""
    lines = []
    for r in result.report:
        if not r.at_bound:
            continue
        p = fitted[r.name]
        lower = float(p.to_unit_interval(p.value)) < 0.5
        bound = p.min if lower else p.max
        unit = "" if p.unit in ("", "1") else f" {p.unit}"
        lines.append(f"WARNING: {r.name} ended at its {'lower' if lower else 'upper'} bound {bound:.4g}{unit}: "
                     "the data push it beyond its range")
    return lines


def run(args: argparse.Namespace) -> int:
    out = check_writable(args.out, args.force)
    report_dir = Path(args.report) if args.report else None
    if report_dir is not None:
        if report_dir.exists() and not report_dir.is_dir():
            raise InputError(f"--report {report_dir}: exists and is not a directory")
        if report_dir.exists():
            check_writable(report_dir / "report.html", args.force)
    choosing = chosen_laws(args.contact) is not None
    if choosing and args.method != "lsq":
        raise InputError(f"--contact {args.contact}: only least squares fits each contact law (--method lsq)")
    if args.channel_weights != "fixed" and args.method != "lsq":
        raise InputError(f"--channel-weights {args.channel_weights}: only least squares refits with new channel "
                         "weights (--method lsq)")
    if args.current and args.method != "lsq":
        raise InputError("--current: only least squares fits the motor current (--method lsq)")
    if args.method == "ppo" and (args.envs < 1 or args.timesteps < 1):
        raise InputError(f"--envs and --timesteps must be >= 1 (PPO's environments and steps), got "
                         f"{args.envs} and {args.timesteps}")
    if args.budget_seconds is not None and not args.budget_seconds > 0:
        raise InputError(f"--budget-seconds must be > 0 s (the fit's wall-time budget), got {args.budget_seconds:g}")
    if args.max_iterations < 1:
        raise InputError(f"--max-iterations must be >= 1 (least squares' Jacobian evaluations), got "
                         f"{args.max_iterations}")
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1 (local processes for evaluations), got {args.workers}")
    train_paths, val_paths = expand(args.runs)
    val_paths += [Path(p) for p in args.holdout]
    if not train_paths:
        raise InputError("no training runs given")
    if choosing and not val_paths:
        raise InputError(f"--contact {args.contact} needs held-out runs to choose on (--holdout RUN..., or a dataset "
                         "manifest with a validation split); none given")
    train = read_runs(train_paths)
    validation = read_runs(val_paths)
    weights = Weights(use_current=args.current)
    starts, checks = law_starts(args.params, args.contact, args.free, args.frozen, train, validation,
                                check=not args.no_check, weights=weights, friction_step=args.friction_step)
    params = next(iter(starts.values()))
    executor = make_executor(args.executor, workers=args.workers, ray_address=args.ray_address)
    if choosing:
        print(f"fitting each contact law on {len(train)} runs, keeping the one with the lower cost on the "
              f"{len(validation)} held-out runs: "
              + "; ".join(f"{law}: {', '.join(p.free_names)}" for law, p in starts.items()))
    else:
        print(f"fitting {', '.join(params.free_names)} on {len(train)} runs ({len(validation)} held out) "
              f"by {args.method}, {params.contact_law} contact law")
    from tqdm import tqdm
    bar = tqdm(desc=args.method, unit="it", leave=False, disable=None)

    def progress(step: int, cost: float, seconds: float) -> None:
        bar.update(1)
        bar.set_postfix(cost=f"{cost:.4g}", s=f"{seconds:.0f}")

    choice = None
    if args.method == "lsq":
        from sysid.identification.contact_choice import choose_contact_law, fit_count, fit_from_shapes
        from sysid.identification.lsq import fit_lsq, refit_by_residual
        # contact_rounding (and a soft law's time constant) free: fits from each shape of the module
        # ends (and a soft and a stiff ground), the lowest cost kept; the budget is shared by every
        # fit (each start's screen and whole-run fit, each law, the refit)
        fits = sum(fit_count(p) for p in starts.values()) + (args.channel_weights == "residual")
        budget = args.budget_seconds / fits if args.budget_seconds is not None else None

        def lsq(o: Objective) -> FitResult:
            return fit_lsq(o, max_iterations=args.max_iterations, budget_seconds=budget, progress=progress)

        if choosing:
            choice = choose_contact_law(train, validation, laws=tuple(starts), weights=weights, fit=lsq, starts=starts,
                                        executor=executor, progress=lambda line: bar.write(line))
            for f in choice.fits:
                print(f"  {f.law:15s} training cost {f.fit.cost:.4g}, held-out cost {f.held_out_cost:.4g}"
                      + ("  <- chosen" if f.law == choice.chosen else ""))
            result, params = choice.best.fit, starts[choice.chosen]
            shapes_starts = choice.best.starts
        else:
            shapes = fit_from_shapes(Objective(train, params, weights, executor=executor), lsq,
                                     label="fitting", progress=lambda line: bar.write(line))
            result, shapes_starts = shapes.best, shapes.starts
        for line in start_lines(shapes_starts):
            print(line)
        if args.channel_weights == "residual":
            result = refit_by_residual(Objective(train, result.params, weights, executor=executor), result, lsq)
            scales = result.extra["channel_scales"]
            print(f"refitted with each channel weighted by its RMS residual: head {scales['head_scale_m'] * 1e3:.3g} mm, "
                  f"joints {scales['joint_scale_rad'] * 1e3:.3g} mrad (cost in these units)")
    else:
        from sysid.identification.ppo import fit_ppo
        curve = report_dir / "reward_curve.png" if report_dir else None
        if curve is not None:
            report_dir.mkdir(parents=True, exist_ok=True)
        def ppo_progress(timesteps: int, best_total: float, mean_reward: float) -> None:
            bar.update(timesteps - bar.n)
            bar.set_postfix(best=f"{best_total:.4g}", reward=f"{mean_reward:.4g}")

        bar.total = args.timesteps
        result = fit_ppo(Objective(train, params, weights, executor=executor), budget_seconds=args.budget_seconds,
                         total_timesteps=args.timesteps, seed=args.seed, n_envs=args.envs, progress=ppo_progress,
                         curve_png=curve)
    bar.close()
    executor.close()
    fitted = result.params
    out.write_text(json.dumps(fit_document(result, train_paths, checks[params.contact_law],
                                           choice.to_json() if choice is not None else None),
                              indent=2, default=float) + "\n")
    print(f"{result.status.value} after {result.evaluations} evaluations in {result.seconds:.1f} s; "
          f"cost {result.initial_cost:.4g} -> {result.cost:.4g}")
    print(f"  {'parameter':16s} {'nominal':>10s} {'start':>10s} {'fitted':>10s} {'95% interval':>25s}  note")
    without = {r.name: r for r in result.report_without_current or []}
    for r in result.report:
        ci = f"[{r.ci_low:.4g}, {r.ci_high:.4g}]"
        note = r.reason
        if r.name in without:
            wo = without[r.name]
            note += (f"; without the current [{wo.ci_low:.4g}, {wo.ci_high:.4g}] "
                     f"({(wo.ci_high - wo.ci_low) / (r.ci_high - r.ci_low):.2f} x as wide)")
        print(f"  {r.name:16s} {r.nominal:10.4g} {r.initial:10.4g} {r.value:10.4g} {ci:>25s}  {note}")
    if result.interval_method:
        print(f"  intervals: {result.interval_method}")
    if result.residual_whiteness is not None:
        print(result.residual_whiteness.console_line())
    for line in bound_warnings(result, fitted):
        print(line)
    print(f"wrote {out}")
    held = []
    if validation:
        from sysid.gap.report import evaluate_held_out, head_text
        held = evaluate_held_out(validation, params, fitted)
        print("held-out runs, before -> after: final head error, joint RMSE"
              + (" (these runs also chose the contact law, which favours the after figures)" if choosing else ""))
        for h in held:
            b, a = h.gap_before, h.gap_after
            print(f"  {h.name:22s} {h.freq_hz:5.2f} Hz  head {head_text(b.head.final, a.head.final)}, "
                  f"joints {b.mean_joint_rmse:.4f} -> {a.mean_joint_rmse:.4f} rad")
            if a.head_omitted:
                print(f"    {a.head_omitted}")
    if report_dir is not None:
        print(f"report: {write_fit_report(result, held, report_dir)}")
    return 0
