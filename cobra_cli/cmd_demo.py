"""``cobra demo``: the main job on the shipped reference dataset (what ``make demo`` runs).

The whole story on ``data/reference``: the nominal model's gap per gait on the held-out runs,
then the discrepancy workflow (``cobra diagnose``): the fitted model, the missing effect it names
with its evidence, the gap after adding it, and where the report is.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from cobra_cli.common import check_writable
from cobra_cli.progress import progress_bar
from cobra_model.model import CobraModel
from cobra_model.run import Run
from cobra_model.run_files import read_run
from integrators.simulate import simulate_like
from sysid.generators.dataset import DATA_DIR, load_manifest
from sysid.gap.metrics import compare_runs
from viz.replay import write_replay_html
from sysid.gap.plots import plot_error_bars, plot_head_paths, plot_joint_responses, plot_window_correlation


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on the shipped reference dataset",
                       description="Reproduce the shipped reference runs with the nominal model and "
                                   "report the sim-to-real gap per gait.")
    p.add_argument("--data", type=Path, default=DATA_DIR, help="dataset folder with manifest.json")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="folder for the plots (default out/demo)")
    p.add_argument("--force", action="store_true", help="overwrite plots of an earlier demo in --out")
    p.add_argument("--skip-diagnose", action="store_true", help="only the nominal gap (seconds, not minutes)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    manifest = args.data / "manifest.json"
    if not manifest.is_file():
        raise FileNotFoundError(f"{manifest} does not exist (regenerate with `python -m sysid.generators.dataset`)")
    train, validation = load_manifest(manifest)
    figures = {name: args.out / name for name in ("head_paths.png", "head_error_per_gait.png", "joints_5_6.png",
                                                  "window_correlation.png", "replay.html")}
    args.out.mkdir(parents=True, exist_ok=True)
    for path in figures.values():
        check_writable(path, args.force)
    model = CobraModel.load()
    print(f"COBRA: {model.n_joints} joints, {model.total_mass:.2f} kg, {len(model.features)} contact points")
    print(f"reference dataset {args.data}: {len(train)} training runs, {len(validation)} held-out runs")
    print("nominal model vs held-out runs (the gap to close):")
    print(f"  {'run':22s} {'f [Hz]':>6s} {'head final [m]':>15s} {'head mean [m]':>14s} "
          f"{'joint RMSE [rad]':>17s} {'corr. mean':>10s} {'sim [s]':>8s}")
    paths: list[tuple[str, Run]] = []
    finals: dict[str, dict[str, float]] = {}
    reports = []
    for path in validation:
        measured = read_run(path)
        t0 = time.perf_counter()
        with progress_bar(path.stem) as bar:
            simulated = simulate_like(measured, model=model, progress=bar)
        wall = time.perf_counter() - t0
        report = compare_runs(measured, simulated)
        f = measured.gait_frequency_hz
        paths += [(f"measured {f} Hz", measured), (f"nominal model {f} Hz", simulated)]
        finals[f"{f} Hz"] = {"nominal model": report.head.final}
        reports.append((f, measured, simulated, report))
        print(f"  {path.stem:22s} {f:6.2f} {report.head.final:15.3f} {report.head.mean:14.3f} "
              f"{report.mean_joint_rmse:17.4f} {report.mean_window_correlation:10.3f} {wall:8.2f}")
    plot_head_paths(paths, figures["head_paths.png"], title="held-out runs: measured vs nominal model")
    plot_error_bars(finals, figures["head_error_per_gait.png"], "final head position error [m]",
                    title="nominal model, held-out runs (paper Eq. 7)")
    f, measured, simulated, report = reports[len(reports) // 2]
    plot_joint_responses([("measured", measured), ("nominal model", simulated)], figures["joints_5_6.png"],
                         title=f"joints 5 and 6 at {f} Hz")
    plot_window_correlation([("nominal model", report)], figures["window_correlation.png"],
                            title=f"sliding-window correlation at {f} Hz")
    write_replay_html(measured, [("nominal model", simulated)], figures["replay.html"])
    print(f"plots: {', '.join(str(p) for p in figures.values())}")
    if args.skip_diagnose:
        return 0
    print("\ndiscrepancy workflow (cobra diagnose) on the training runs, judged on the held-out runs:")
    from cobra_cli.cmd_diagnose import diagnose_to
    return diagnose_to(args.out / "diagnosis", [str(manifest)], max_effects=2, fit_runs=6, force=args.force)
