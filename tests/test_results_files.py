"""A benchmark's results file says which code, on which CPU, measured it."""
from __future__ import annotations

import subprocess
from pathlib import Path

import benchmarks._results as results


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout.strip()


def test_the_commit_is_marked_modified_by_a_code_change_not_by_results_or_prose(tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    (repo / "benchmarks" / "results").mkdir(parents=True)
    _git(tmp_path, "init", "-q", str(repo))
    for name in ("kernels.py", "README.md", "benchmarks/results/speed.json"):
        (repo / name).write_text("1\n")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c")
    head = _git(repo, "rev-parse", "--short=7", "HEAD")
    monkeypatch.setattr(results, "REPO", repo)
    assert results.code_commit() == head
    (repo / "README.md").write_text("2\n")  # a benchmark rewrites results and the README's table
    (repo / "benchmarks" / "results" / "speed.json").write_text("2\n")
    (repo / "notes.py").write_text("untracked\n")
    assert results.code_commit() == head
    (repo / "kernels.py").write_text("2\n")  # the code measured is not the commit's
    assert results.code_commit() == head + "+modified"
    monkeypatch.setattr(results, "REPO", tmp_path / "not a checkout")
    assert results.code_commit() is None


def test_the_environment_names_the_cpu_numbas_target_and_the_commit(monkeypatch):
    import llvmlite.binding
    import numba

    monkeypatch.setattr(results, "code_commit", lambda: "abc1234")
    env = results.environment()
    machine = env["machine"]
    assert machine["cpu"] and env["commit"] == "abc1234"
    assert machine["numba_target"] == (numba.config.CPU_NAME or llvmlite.binding.get_host_cpu_name())
    monkeypatch.setattr(numba.config, "CPU_NAME", "x86-64")  # NUMBA_CPU_NAME: compiled for another CPU
    assert results.environment()["machine"]["numba_target"] == "x86-64"
    text = results.environment_markdown(env)
    assert "at commit abc1234" in text and f"numba compiling for {machine['numba_target']}" in text
    # a file written before these fields still renders
    old = {"date_utc": "2026-01-02T03:04:05+00:00", "versions": {"numpy": "1"},
           "machine": {"platform": "p", "processor": "x", "cpu_count": 2, "python": "3"}}
    assert results.environment_markdown(old) == "Measured 2026-01-02T03:04:05+00:00 on p (x, 2 CPUs), Python 3; numpy 1."

