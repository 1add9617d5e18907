"""Benchmark results as artefacts: ``benchmarks/results/<name>.json`` and ``<name>.md``.

Every file records the machine, the package versions and the date of the run, so that the
README can quote a table together with where and when it was measured.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"

#: Packages whose versions change the figures.
PACKAGES: tuple[str, ...] = ("numpy", "scipy", "pin", "casadi", "mujoco", "numba", "stable-baselines3", "torch")


def environment() -> dict[str, Any]:
    """Machine, Python and package versions, and the UTC date of the run."""
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version()},
        "versions": versions,
    }


def environment_markdown(env: dict[str, Any]) -> str:
    """One paragraph naming the machine, versions and date of ``env`` (from :func:`environment`)."""
    m = env["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in env["versions"].items() if v)
    return (f"Measured {env['date_utc']} on {m['platform']} ({m['processor']}, {m['cpu_count']} CPUs), "
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
