"""Benchmark results as artefacts: ``benchmarks/results/<name>.json`` and ``<name>.md``.

Every file records the machine, the package versions, the code's commit and the date of the
run, so that the README can quote a table together with where and when it was measured. The
machine includes its CPU, the CPU numba compiles the kernels for and the BLAS kernels numpy
runs (OpenBLAS picks them by CPU, or by ``OPENBLAS_CORETYPE``): the same code and data can round
differently on another CPU (other vector instructions, other fused multiply-adds, other
summation orders), and a fit on a rough cost can follow that roundoff into another basin.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any, Iterable

import numpy as np

REPO = Path(__file__).resolve().parent.parent
RESULTS_DIR = REPO / "benchmarks" / "results"

#: Packages whose versions change the figures.
PACKAGES: tuple[str, ...] = ("numpy", "scipy", "pin", "casadi", "mujoco", "numba", "stable-baselines3", "torch")


def code_commit() -> str | None:
    """The checkout's last commit that changed code, that is anything but results and prose
    (``benchmarks/results``, ``*.md``), with ``+modified`` when such tracked files differ from
    it; None outside a git checkout. A commit of prose or results alone (the docs of a rerun,
    written while the next one runs) changes no measured code and so not this."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, check=True,
                              timeout=30).stdout.strip()
    code = ("--", ".", ":(exclude)benchmarks/results", ":(exclude)*.md")
    try:
        head = git("log", "-1", "--format=%H", *code)[:7]
        changed = git("status", "--porcelain", "--untracked-files=no", *code)
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+modified" if changed else "")


#: The code's commit when this module was imported, that is when a benchmark started: a run of
#: hours (``diagnose_matrix``) measures the code it started with, and its worker processes may
#: import the checkout's later code, so a change in between must show in the file it writes.
COMMIT_AT_START: str | None = code_commit()


def run_commit() -> str | None:
    """The commit a benchmark ran at: :data:`COMMIT_AT_START`, followed by ``, changed to X
    during the run`` when the checkout's code (:func:`code_commit`) is another now."""
    now = code_commit()
    if now == COMMIT_AT_START:
        return now
    return f"{COMMIT_AT_START}, changed to {now} during the run"


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or what :mod:`platform` knows of it."""
    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def runs_fingerprint(runs: Iterable[Any]) -> str:
    """The first 16 hex digits of a SHA-256 over the runs' arrays (time, commands, joints, head
    pose, joint velocities and currents when logged, tracked bodies by name), in order: equal
    on two machines when they generated the same data to the last bit, so that a result that
    moved between hosts can be told apart from data that did."""
    digest = hashlib.sha256()
    for run in runs:
        arrays = [run.t, run.q_ref, run.q, run.head_pos, run.head_quat, run.dq, run.current]
        arrays += [run.bodies[name] for name in sorted(run.bodies)]
        for a in arrays:
            digest.update(b"-" if a is None else np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return digest.hexdigest()[:16]


def environment() -> dict[str, Any]:
    """Machine (with its CPU, numba's compilation target and the BLAS kernels numpy runs), Python
    and package versions, the code's commit (:func:`run_commit`) and the UTC date of the run."""
    import llvmlite.binding
    import numba  # the CPU numba compiles for (NUMBA_CPU_NAME, else this one) decides the kernels' roundoff
    import threadpoolctl  # and the kernels OpenBLAS picked for this CPU (or OPENBLAS_CORETYPE), numpy's

    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version(), "cpu": cpu_name(),
                    "numba_target": numba.config.CPU_NAME or llvmlite.binding.get_host_cpu_name(),
                    "blas": ", ".join(f"{lib['internal_api']} {lib.get('architecture') or '?'}"
                                      for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas")},
        "versions": versions,
        "commit": run_commit(),
    }


def environment_markdown(env: dict[str, Any]) -> str:
    """One paragraph naming the machine, versions and date of ``env`` (from :func:`environment`)."""
    m = env["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in env["versions"].items() if v)
    cpu = f"; {m['cpu']}, numba compiling for {m['numba_target']}, BLAS {m.get('blas', '?')}" if m.get("cpu") else ""
    commit = f" at commit {env['commit']}" if env.get("commit") else ""
    return (f"Measured {env['date_utc']}{commit} on {m['platform']} ({m['processor']}, {m['cpu_count']} CPUs{cpu}), "
            f"Python {m['python']}; {versions}.")


def write_results(name: str, rows: list[dict], meta: dict, markdown: str,
                  env: dict[str, Any] | None = None) -> tuple[Path, Path]:
    """Write ``results/<name>.json`` (meta + environment + rows) and ``results/<name>.md``.

    Args:
        name: file stem, e.g. ``"mujoco_fit"``.
        rows: one JSON-serialisable dict per table row.
        meta: what was run (seeds, configurations, settings); the environment is added.
        markdown: the table and its notes; the environment paragraph is appended.
        env: the environment the rows were measured in, when they come from an earlier run's
            file (a summary recomputed from measured rows keeps their machine and date);
            default: this run's (:func:`environment`).

    Returns:
        The paths of the JSON and Markdown files.
    """
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    env = env or environment()
    json_path = RESULTS_DIR / f"{name}.json"
    md_path = RESULTS_DIR / f"{name}.md"
    json_path.write_text(json.dumps({"benchmark": name, "meta": meta, "environment": env, "rows": rows},
                                    indent=2, default=float) + "\n")
    md_path.write_text(markdown.rstrip() + "\n\n" + environment_markdown(env) + "\n")
    return json_path, md_path


def publish(name: str, rows: list[dict], meta: dict, markdown: str) -> int:
    """:func:`write_results`, then the table to stdout and the files' paths to stderr; returns
    0, a script's exit status."""
    json_path, md_path = write_results(name, rows, meta, markdown)
    print(markdown)
    print(f"wrote {json_path} and {md_path}", file=sys.stderr)
    return 0
