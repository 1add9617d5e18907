"""Figures of the sim-to-real gap, written as PNG files (matplotlib, Agg backend).

Each function draws one figure from :class:`cobra_model.run.Run` objects or
:class:`sysid.gap.metrics.GapReport` objects, writes it to ``out`` (parent directories are created,
an existing file is replaced: callers decide whether that is allowed) and returns the path. The
figures follow the paper's:

* :func:`plot_head_paths` - head paths in the ground plane (the trajectory-comparison figure);
* :func:`plot_head_errors` - ground-plane head error over time (Eq. 7 along the run);
* :func:`plot_joint_responses` - commanded and actual angles of two representative joints
  (joints 5 and 6, the joint-response figure);
* :func:`plot_window_correlation` - sliding-window correlation of each run with its command, with
  the min-max band over the joints (the correlation figure);
* :func:`plot_error_bars` - grouped bars, e.g. final head error per gait before/after tuning (the
  Euclidean-distance figure);
* :func:`plot_confusion` - the discrepancy workflow's confusion matrix (hidden vs named effect).

Figures are built on :class:`matplotlib.figure.Figure` with an explicit Agg canvas, never through
``pyplot``: no global figure state, no GUI backend, safe in worker processes.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from cobra_model.errors import InputError
from cobra_model.run import NUM_JOINTS, Run
from sysid.gap.metrics import GapReport

#: Joints shown by :func:`plot_joint_responses` by default: the paper's representative pitch
#: (5) and yaw (6) joints.
REPRESENTATIVE_JOINTS: tuple[int, ...] = (5, 6)
#: Resolution of the written PNGs [dots per inch].
DPI = 120
#: Colour of the commanded trajectory.
COMMAND_COLOUR = "black"


def _new_figure(width: float, height: float) -> Figure:
    """A figure of ``width`` x ``height`` inches attached to an Agg canvas."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, out: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``out``, creating parent directories; returns the path."""
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png", dpi=DPI)
    return path


def _colours(count: int) -> list[str]:
    """``count`` distinct colours from matplotlib's default cycle (repeating past ten)."""
    return [f"C{i % 10}" for i in range(count)]


def _require(items: Sequence[object], function: str, what: str) -> None:
    if not items:
        raise InputError(f"{function}: nothing to plot; expected at least one {what}")


def _finite_ends(xy: np.ndarray) -> tuple[int, int] | None:
    """Indices of the first and last rows of ``xy`` (N, 2) without NaN, or ``None``."""
    ok = np.flatnonzero(np.isfinite(xy).all(axis=1))
    return (int(ok[0]), int(ok[-1])) if ok.size else None


def plot_head_paths(runs: Sequence[tuple[str, Run]], out: str | Path, *,
                    title: str = "Head path in the ground plane") -> Path:
    """Head paths of several runs in the world x-y plane, start (circle) and end (square) marked.

    Axes are equal so that distances read true. Motion-capture dropouts show as gaps; a run
    without any head sample is listed in the legend as "no motion capture".

    Args:
        runs: ``(label, run)`` pairs, drawn in order (e.g. measured, then simulated ones).
        out: PNG path.
        title: figure title.

    Raises:
        InputError: if ``runs`` is empty.
    """
    _require(runs, "plot_head_paths", "run")
    fig = _new_figure(7.0, 6.0)
    ax = fig.add_subplot()
    for (label, run), colour in zip(runs, _colours(len(runs))):
        xy = run.head_pos[:, :2]
        ends = _finite_ends(xy)
        if ends is None:
            ax.plot([], [], color=colour, label=f"{label} (no motion capture)")
            continue
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.5, label=label)
        first, last = ends
        ax.plot(*xy[first], "o", color=colour, ms=7, mfc="white", mew=2)
        ax.plot(*xy[last], "s", color=colour, ms=7)
    handles, _ = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], ls="", marker="o", color="grey", mfc="white", mew=2, label="start"),
        Line2D([], [], ls="", marker="s", color="grey", label="end"),
    ]
    ax.legend(handles=handles, loc="best", fontsize="small")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    return _save(fig, out)


def plot_head_errors(reports: Sequence[tuple[str, GapReport]], out: str | Path, *,
                     title: str = "Head position error (ground plane)") -> Path:
    """Ground-plane head error of each report over time, its final value marked and annotated.

    Args:
        reports: ``(label, report)`` pairs, e.g. ``[("untuned", r0), ("tuned", r1)]``; each curve
            is :attr:`GapReport.head` ``.distance`` against its time base.
        out: PNG path.
        title: figure title.

    Raises:
        InputError: if ``reports`` is empty.
    """
    _require(reports, "plot_head_errors", "report")
    fig = _new_figure(8.0, 4.0)
    ax = fig.add_subplot()
    for (label, report), colour in zip(reports, _colours(len(reports))):
        head = report.head
        ax.plot(head.t, head.distance, color=colour, lw=1.5,
                label=f"{label}: mean {head.mean:.3f} m, final {head.final:.3f} m")
        if np.isfinite(head.final):
            ax.plot(head.final_t, head.final, "o", color=colour)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("head error [m]")
    ax.set_ylim(bottom=0.0)
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize="small")
    ax.grid(True, alpha=0.3)
    return _save(fig, out)


def plot_joint_responses(runs: Sequence[tuple[str, Run]], out: str | Path, *,
                         joints: Sequence[int] = REPRESENTATIVE_JOINTS,
                         title: str = "Joint responses") -> Path:
    """Commanded and actual angles of a few joints, one panel per joint, shared time axis.

    The command drawn is the first run's ``q_ref`` (all runs of one comparison share it); each
    run's measured ``q`` follows under its label.

    Args:
        runs: ``(label, run)`` pairs, e.g. ``[("measured", hw), ("simulated", sim)]``.
        out: PNG path.
        joints: joint numbers 1..11 from the head (odd pitch, even yaw).
        title: figure title.

    Raises:
        InputError: if ``runs`` or ``joints`` is empty or a joint number is outside 1..11.
    """
    _require(runs, "plot_joint_responses", "run")
    _require(joints, "plot_joint_responses", "joint")
    bad = [j for j in joints if not 1 <= j <= NUM_JOINTS]
    if bad:
        raise InputError(f"plot_joint_responses: joints {bad} are outside 1..{NUM_JOINTS}")
    fig = _new_figure(8.0, 2.6 * len(joints) + 0.6)
    axes: list[Axes] = list(fig.subplots(len(joints), 1, sharex=True, squeeze=False)[:, 0])
    command = runs[0][1]
    colours = _colours(len(runs))
    for ax, joint in zip(axes, joints):
        k = joint - 1
        ax.plot(command.t, command.q_ref[:, k], color=COMMAND_COLOUR, ls="--", lw=1.2,
                label="commanded")
        for (label, run), colour in zip(runs, colours):
            ax.plot(run.t, run.q[:, k], color=colour, lw=1.3, label=label)
        kind = "pitch" if joint % 2 == 1 else "yaw"
        ax.set_ylabel(f"q_{joint} [rad]")
        ax.set_title(f"joint {joint} ({kind})", fontsize="medium")
        ax.grid(True, alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper right",
               fontsize="small", ncols=len(runs) + 1)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title, x=0.02, ha="left")
    return _save(fig, out)


def _correlation_curve(ax: Axes, t: np.ndarray, summary: Mapping[str, Any], colour: str,
                       label: str) -> None:
    """Mean correlation curve of a :func:`sysid.gap.metrics.correlation_summary` with its band."""
    ax.fill_between(t, summary["min_curve"], summary["max_curve"], color=colour, alpha=0.2, lw=0)
    ax.plot(t, summary["mean_curve"], color=colour, lw=1.5,
            label=f"{label} (mean {summary['mean']:.3f})")


def plot_window_correlation(reports: Sequence[tuple[str, GapReport]], out: str | Path, *,
                            title: str = "Sliding-window correlation with the command") -> Path:
    """Sliding-window correlation of ``q`` with the command, averaged over the joints, with band.

    As in the paper's correlation figure: each curve is the mean over the 11 joints of the
    windowed Pearson correlation between a run's joint angles and its commanded angles, at the
    window centre times; the shaded band spans the joints' minimum to maximum. The first report's
    measured run is drawn as "measured", then each report's simulated run under its label.

    Args:
        reports: ``(label, report)`` pairs sharing one measured run, e.g.
            ``[("default", r0), ("tuned", r1)]``.
        out: PNG path.
        title: figure title.

    Raises:
        InputError: if ``reports`` is empty.
    """
    _require(reports, "plot_window_correlation", "report")
    fig = _new_figure(8.0, 4.0)
    ax = fig.add_subplot()
    colours = _colours(len(reports) + 1)
    first = reports[0][1]
    _correlation_curve(ax, first.correlation_t, first.correlation["measured_vs_command"],
                       colours[0], "measured")
    for (label, report), colour in zip(reports, colours[1:]):
        _correlation_curve(ax, report.correlation_t, report.correlation["simulated_vs_command"],
                           colour, label)
    ax.set_xlabel("window centre t [s]")
    ax.set_ylabel("correlation with command")
    ax.set_title(f"{title} ({first.window_s:g} s window; band: min-max over joints)")
    ax.legend(loc="lower left", fontsize="small")
    ax.grid(True, alpha=0.3)
    return _save(fig, out)


def plot_error_bars(table: Mapping[str, Mapping[str, float]], out: str | Path, ylabel: str, *,
                    title: str = "") -> Path:
    """Grouped bar chart: one group per outer key, one bar per inner key, values annotated.

    E.g. the paper's Euclidean-distance figure: ``{"0.35 Hz": {"untuned": 0.41, "tuned": 0.12},
    "0.5 Hz": {...}}`` with ``ylabel="final head error [m]"``. Series (inner keys) keep the order
    in which they first appear; a series missing from a group, or a NaN value, leaves a gap.

    Args:
        table: group label -> (series label -> value).
        out: PNG path.
        ylabel: y-axis label, with its unit.
        title: figure title (none if empty).

    Raises:
        InputError: if ``table`` has no values.
    """
    groups = list(table)
    series = list(dict.fromkeys(name for group in groups for name in table[group]))
    _require(series, "plot_error_bars", "value")
    fig = _new_figure(max(5.0, 1.2 * len(groups) * max(1, len(series)) + 2.0), 4.5)
    ax = fig.add_subplot()
    x = np.arange(len(groups), dtype=float)
    width = 0.8 / len(series)
    for i, (name, colour) in enumerate(zip(series, _colours(len(series)))):
        values = np.array([table[group].get(name, np.nan) for group in groups], dtype=float)
        bars = ax.bar(x + (i - 0.5 * (len(series) - 1)) * width, np.nan_to_num(values), width,
                      color=colour, label=name)
        ax.bar_label(bars, labels=["" if np.isnan(v) else f"{v:.3g}" for v in values],
                     fontsize="small", padding=2)
    ax.set_xticks(x, groups)
    ax.set_ylabel(ylabel)
    ax.margins(y=0.12)
    if title:
        ax.set_title(title)
    ax.legend(fontsize="small")
    ax.grid(True, axis="y", alpha=0.3)
    return _save(fig, out)


#: Localisation numbers drawn by :func:`plot_signature` (all in [0, 1] or near it).
SIGNATURE_KEYS: tuple[str, ...] = ("head_share", "r_sign", "r_vel", "r_effort", "offset_score",
                                   "sideways_share")


def plot_signature(signatures: Sequence[tuple[str, Any]], out: str | Path, *, title: str = "") -> Path:
    """Residual signatures side by side: the localisation numbers and the joint residual RMS
    per gait-phase bin, one colour per signature (e.g. before / after adding an effect)."""
    _require(signatures, "plot_signature", "signatures")
    fig = _new_figure(10, 4)
    ax1, ax2 = fig.subplots(1, 2)
    colours = _colours(len(signatures))
    width = 0.8 / len(signatures)
    x = np.arange(len(SIGNATURE_KEYS))
    for k, (label, sig) in enumerate(signatures):
        vals = [getattr(sig, key) for key in SIGNATURE_KEYS]
        ax1.bar(x + k * width, vals, width, label=label, color=colours[k])
        ax2.plot(np.arange(8) / 8 + 1 / 16, sig.phase_rms_rad, "o-", color=colours[k], label=label)
    ax1.set_xticks(x + 0.4 - width / 2, SIGNATURE_KEYS, rotation=30, ha="right")
    ax1.set_ylabel("localisation number")
    ax1.set_title("residual signature")
    ax1.legend()
    ax2.set_xlabel("gait phase [cycles]")
    ax2.set_ylabel("joint residual RMS [rad]")
    ax2.set_title("joint residual over the gait cycle")
    ax2.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return _save(fig, out)


def plot_confusion(counts: np.ndarray, truth: Sequence[str], named: Sequence[str], out: str | Path, *,
                   title: str = "") -> Path:
    """Heatmap of a confusion matrix: ``counts[i, j]`` datasets with effect ``truth[i]`` hidden
    whose diagnosis named ``named[j]`` first ("none": nothing named); each cell annotated."""
    counts = np.asarray(counts)
    if counts.shape != (len(truth), len(named)):
        raise InputError(f"plot_confusion: counts {counts.shape} does not match {len(truth)} x {len(named)} labels")
    fig = _new_figure(1.2 + 0.75 * len(named), 1.0 + 0.5 * len(truth))
    ax = fig.add_subplot()
    ax.imshow(counts, cmap="Blues", vmin=0, aspect="auto")
    for i in range(len(truth)):
        for j in range(len(named)):
            ax.text(j, i, str(int(counts[i, j])), ha="center", va="center",
                    color="white" if counts[i, j] > 0.6 * counts.max() else "black")
    ax.set_xticks(range(len(named)), named, rotation=40, ha="right")
    ax.set_yticks(range(len(truth)), truth)
    ax.set_xlabel("named first")
    ax.set_ylabel("hidden")
    if title:
        ax.set_title(title, fontsize=10)
    return _save(fig, out)
