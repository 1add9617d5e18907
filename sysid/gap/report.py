"""HTML report pages (fit, diagnose): a title, tables, figures and the 3-D replay, one folder.

The page is plain HTML with the PNGs beside it and the replay as a separate offline page
(``replay.html``) it links to and embeds in an ``<iframe>``.
"""
from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from cobra_model.run import Run
from integrators.simulate import simulate_like
from cobra_model.parameters import ModelParameters
from sysid.gap.metrics import GapReport, compare_runs

CSS = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
       "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}"
       "th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}img{max-width:100%;margin:.5em 0}"
       "iframe{width:100%;height:520px;border:1px solid #ccc}.bad{color:#b00}")


@dataclass
class HtmlReport:
    """An HTML page assembled section by section."""

    title: str
    parts: list[str] = field(default_factory=list)

    def heading(self, text: str) -> None:
        self.parts.append(f"<h2>{html.escape(text)}</h2>")

    def paragraph(self, text: str) -> None:
        self.parts.append(f"<p>{html.escape(text)}</p>")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]]) -> None:
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{_cell(c)}</td>" for c in row) + "</tr>" for row in rows)
        self.parts.append(f"<table><tr>{head}</tr>{body}</table>")

    def figure(self, path: Path, caption: str) -> None:
        self.parts.append(f'<figure><img src="{html.escape(path.name)}" alt="{html.escape(caption)}">'
                          f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    def replay(self, path: Path, caption: str) -> None:
        self.parts.append(f'<p><a href="{html.escape(path.name)}">{html.escape(caption)}</a> '
                          "(3-D replay: play and scrub in the browser)</p>"
                          f'<iframe src="{html.escape(path.name)}" title="{html.escape(caption)}"></iframe>')

    def write(self, path: Path) -> Path:
        page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{CSS}</style></head><body><h1>{html.escape(self.title)}</h1>{''.join(self.parts)}</body></html>")
        path.write_text(page, encoding="utf-8")
        return path


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


@dataclass(frozen=True)
class HeldOut:
    """A held-out run simulated with the parameters before and after, and both gaps."""

    name: str
    freq_hz: float
    measured: Run
    before: Run
    after: Run
    gap_before: GapReport
    gap_after: GapReport


def evaluate_held_out(runs: Sequence[Run], before: ModelParameters, after: ModelParameters) -> list[HeldOut]:
    """Simulate each held-out run with both parameter sets and compare with the measurement."""
    return pair_held_out(runs, [simulate_like(r, params=before) for r in runs],
                         [simulate_like(r, params=after) for r in runs])


def pair_held_out(runs: Sequence[Run], before: Sequence[Run], after: Sequence[Run]) -> list[HeldOut]:
    """Held-out runs with their simulations before and after, compared with the measurement."""
    out = []
    for run, sim_b, sim_a in zip(runs, before, after):
        name = Path(str(run.source)).stem if run.source else "run"
        out.append(HeldOut(name, run.gait_frequency_hz, run, sim_b, sim_a,
                           compare_runs(run, sim_b), compare_runs(run, sim_a)))
    return out


def has_head_errors(before: float | None, after: float | None) -> bool:
    """Whether both final head errors [m] exist (joint-only runs give None or NaN)."""
    return before is not None and after is not None and bool(np.isfinite(before) and np.isfinite(after))


def head_text(before: float | None, after: float | None) -> str:
    """``"0.0123 -> 0.0045 m"``, or why there is no head error (joint-only runs: None or NaN)."""
    if not has_head_errors(before, after):
        return "omitted (joint-only runs: no head pose)"
    return f"{before:.4f} -> {after:.4f} m"


@dataclass(frozen=True)
class GapSummary:
    """``cobra compare`` metrics of a set of held-out runs and their means.

    Attributes:
        head_final_error_m, head_mean_error_m: means over the runs that have a head pose [m]
            (None when none has: joint-only runs).
        joint_rmse_rad: mean over the runs of their mean joint RMSE [rad].
        runs: each run's ``cobra compare`` metrics (JSON form), by run name.
    """

    head_final_error_m: float | None
    head_mean_error_m: float | None
    joint_rmse_rad: float
    runs: dict[str, dict]

    @classmethod
    def of(cls, gaps: Mapping[str, GapReport]) -> "GapSummary":
        """The summary of the gaps of named runs."""
        def mean(values: Sequence[float]) -> float | None:
            finite = [v for v in values if np.isfinite(v)]
            return float(np.mean(finite)) if finite else None

        return cls(mean([g.head.final for g in gaps.values()]), mean([g.head.mean for g in gaps.values()]),
                   float(np.mean([g.mean_joint_rmse for g in gaps.values()])),
                   {name: g.to_json_dict() for name, g in gaps.items()})

    def to_json(self) -> dict:
        """``{"mean": {...}, "runs": {...}}`` as in ``diagnosis.json``."""
        return {"mean": {"head_final_error_m": self.head_final_error_m, "head_mean_error_m": self.head_mean_error_m,
                         "joint_rmse_rad": self.joint_rmse_rad}, "runs": self.runs}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "GapSummary":
        """Inverse of :meth:`to_json`."""
        m = data["mean"]
        return cls(m["head_final_error_m"], m["head_mean_error_m"], m["joint_rmse_rad"], dict(data["runs"]))


def held_out_figures(held: Sequence[HeldOut], out_dir: Path, labels: tuple[str, str], report: HtmlReport) -> None:
    """Per-gait error bars, head paths, joint responses, correlation and the replay of one run."""
    from sysid.gap import plots
    from viz.replay import write_replay_html

    b, a = labels
    joint_only = any(h.gap_after.head_omitted for h in held)
    unit = "joint RMSE [rad]" if joint_only else "final head error [m]"

    def value(gap: GapReport) -> float:
        return gap.mean_joint_rmse if joint_only else gap.head.final

    table = {f"{h.freq_hz:g} Hz ({h.name})": {b: value(h.gap_before), a: value(h.gap_after)} for h in held}
    report.heading("Held-out runs: final head position error (paper Eq. 7)" if not joint_only else
                   "Held-out runs: joint RMSE (joint-only runs: no head pose, head metrics omitted)")
    rows = [[h.name, h.freq_hz, h.gap_before.head.final, h.gap_after.head.final, h.gap_before.head.mean,
             h.gap_after.head.mean, h.gap_before.mean_joint_rmse, h.gap_after.mean_joint_rmse] for h in held]
    report.table(["run", "f [Hz]", f"final [m] {b}", f"final [m] {a}", f"mean [m] {b}", f"mean [m] {a}",
                  f"joint RMSE [rad] {b}", f"joint RMSE [rad] {a}"], rows)
    report.figure(plots.plot_error_bars(table, out_dir / "held_out_head_error.png", unit,
                                        title=f"held-out {unit.split(' [')[0]}, {b} vs {a}"), "per-gait held-out error")
    if not joint_only:
        paths = [(f"{lab} {h.freq_hz:g} Hz", r) for h in held
                 for lab, r in (("measured", h.measured), (b, h.before), (a, h.after))]
        report.figure(plots.plot_head_paths(paths, out_dir / "held_out_head_paths.png", title="held-out head paths"),
                      "head paths: measured, before and after")
    mid = held[len(held) // 2]
    report.figure(plots.plot_joint_responses([("measured", mid.measured), (b, mid.before), (a, mid.after)],
                                             out_dir / "joint_responses.png", title=f"joints 5 and 6, {mid.name}"),
                  "joint responses")
    report.figure(plots.plot_window_correlation([(b, mid.gap_before), (a, mid.gap_after)],
                                                out_dir / "window_correlation.png",
                                                title=f"sliding-window correlation, {mid.name}"),
                  "sliding-window correlation before and after")
    replay = write_replay_html(mid.measured, [(b, mid.before), (a, mid.after)], out_dir / "replay.html")
    report.replay(replay, f"replay of {mid.name}: measured (solid), {b} and {a} (ghosts)")
