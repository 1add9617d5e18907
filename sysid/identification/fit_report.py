"""What ``cobra fit`` writes: the fitted parameter file with its fit record, and the HTML report."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from sysid.gap.report import HeldOut, HtmlReport, held_out_figures
from sysid.identification.datacheck import DataCheck
from sysid.identification.lsq import FitResult


def fit_document(result: FitResult, train_runs: Sequence[Path], check: DataCheck | None,
                 contact_choice: dict | None = None) -> dict:
    """The fitted parameter file's content: the parameters (``ModelParameters.to_json_dict``)
    with a ``"fit"`` record: the fit's result, its training runs, the data check and, when the
    contact law was chosen (``cobra fit --contact choose``), every law's fit and costs
    (``ContactChoice.to_json``)."""
    doc = result.params.to_json_dict()
    doc["fit"] = {**result.to_json(), "train_runs": [str(p) for p in train_runs],
                  "data_check": check.to_json_dict() if check is not None else None}
    if contact_choice is not None:
        doc["fit"]["contact_choice"] = contact_choice
    return doc


def write_fit_report(result: FitResult, held: Sequence[HeldOut], report_dir: Path) -> Path:
    """``report_dir/report.html``: parameters with intervals, the iteration log, PPO's reward
    curve (if ``reward_curve.png`` is there) and the held-out figures (start -> fitted)."""
    report_dir.mkdir(parents=True, exist_ok=True)
    without = {r.name: r for r in result.report_without_current or []}
    page = HtmlReport(f"cobra fit ({result.method}): {result.status.value}")
    page.heading("Parameters")
    nan = float("nan")
    extra = ["95% low without current", "95% high without current"] if without else []
    page.table(["name", "unit", "nominal", "start", "fitted", "95% low", "95% high", *extra, "at bound", "note"],
               [[r.name, r.unit, r.nominal, r.initial, r.value, r.ci_low, r.ci_high,
                 *([without[r.name].ci_low, without[r.name].ci_high] if r.name in without else
                   [nan, nan] if without else []),
                 "yes" if r.at_bound else "", r.reason] for r in result.report])
    page.paragraph(f"{result.evaluations} objective evaluations, {result.seconds:.1f} s, cost "
                   f"{result.initial_cost:.4g} -> {result.cost:.4g}.")
    if result.interval_method:
        page.paragraph(f"Intervals: {result.interval_method}.")
    if result.residual_whiteness is not None:
        page.paragraph(f"Residuals: {result.residual_whiteness.verdict}.")
    if result.log:
        page.heading("Iteration log")
        page.table(["iteration", "horizon [s]", "cost", "trial cost", "accepted", "damping", "evaluations", "seconds"],
                   [[e.iteration, e.horizon_s, e.cost, e.trial_cost, "yes" if e.accepted else "", e.damping,
                     e.evaluations, e.seconds] for e in result.log])
    if result.method == "ppo" and (report_dir / "reward_curve.png").exists():
        page.figure(report_dir / "reward_curve.png", "PPO reward curve")
    if held:
        held_out_figures(held, report_dir, ("before", "after"), page)
    return page.write(report_dir / "report.html")
