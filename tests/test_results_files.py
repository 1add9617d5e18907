"""A benchmark's results file says which code, on which CPU, measured it."""
from __future__ import annotations

import subprocess
from pathlib import Path

import benchmarks._results as results


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout.strip()


def test_the_commit_is_the_codes_and_marked_modified_by_a_code_change_not_by_results_or_prose(tmp_path, monkeypatch):
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
    _git(repo, "add", "README.md", "benchmarks")  # prose and results committed: the code is the same
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "docs")
    assert results.code_commit() == head
    (repo / "kernels.py").write_text("2\n")  # the code measured is not the commit's
    assert results.code_commit() == head + "+modified"
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "code")
    assert results.code_commit() == _git(repo, "rev-parse", "--short=7", "HEAD") != head
    monkeypatch.setattr(results, "REPO", tmp_path / "not a checkout")
    assert results.code_commit() is None


def test_the_environment_names_the_cpu_numbas_target_and_the_commit(monkeypatch):
    import llvmlite.binding
    import numba

    import threadpoolctl

    monkeypatch.setattr(results, "code_commit", lambda: "abc1234")
    monkeypatch.setattr(results, "COMMIT_AT_START", "abc1234")
    env = results.environment()
    machine = env["machine"]
    numpys_blas = [lib["internal_api"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]
    assert machine["cpu"] and env["commit"] == "abc1234"
    assert numpys_blas and machine["blas"].split()[0] == numpys_blas[0]  # openblas in numpy's PyPI wheel
    assert machine["numba_target"] == (numba.config.CPU_NAME or llvmlite.binding.get_host_cpu_name())
    monkeypatch.setattr(numba.config, "CPU_NAME", "x86-64")  # NUMBA_CPU_NAME: compiled for another CPU
    assert results.environment()["machine"]["numba_target"] == "x86-64"
    text = results.environment_markdown(env)
    assert "at commit abc1234" in text and f"numba compiling for {machine['numba_target']}" in text
    # a file written before these fields still renders
    old = {"date_utc": "2026-01-02T03:04:05+00:00", "versions": {"numpy": "1"},
           "machine": {"platform": "p", "processor": "x", "cpu_count": 2, "python": "3"}}
    assert results.environment_markdown(old) == "Measured 2026-01-02T03:04:05+00:00 on p (x, 2 CPUs), Python 3; numpy 1."


def test_a_run_during_which_the_code_changed_says_so(monkeypatch):
    monkeypatch.setattr(results, "COMMIT_AT_START", "abc1234")  # the benchmark started here
    monkeypatch.setattr(results, "code_commit", lambda: "def5678")  # and a commit landed meanwhile
    env = results.environment()
    assert env["commit"] == "abc1234, changed to def5678 during the run"
    assert "at commit abc1234, changed to def5678 during the run on " in results.environment_markdown(env)
    monkeypatch.setattr(results, "code_commit", lambda: "abc1234")
    assert results.environment()["commit"] == "abc1234"


def test_a_runs_fingerprint_is_the_same_for_the_same_data_and_changes_with_one_bit():
    import dataclasses

    import numpy as np

    from cobra_model.run_files import read_run
    from sysid.generators.dataset import DATA_DIR

    runs = [read_run(DATA_DIR / "run_01_0p35hz.csv"), read_run(DATA_DIR / "run_02_0p50hz.csv")]
    again = [read_run(DATA_DIR / "run_01_0p35hz.csv"), read_run(DATA_DIR / "run_02_0p50hz.csv")]
    assert results.runs_fingerprint(runs) == results.runs_fingerprint(again)
    assert results.runs_fingerprint(runs) != results.runs_fingerprint(runs[::-1])  # the order counts
    q = runs[0].q.copy()
    q[100, 3] = np.nextafter(q[100, 3], np.inf)  # one joint sample, one bit
    assert results.runs_fingerprint([dataclasses.replace(runs[0], q=q), runs[1]]) != results.runs_fingerprint(runs)
    current = np.zeros_like(runs[0].q)  # currents logged as zeros are not currents left out
    assert (results.runs_fingerprint([dataclasses.replace(runs[0], current=current)])
            != results.runs_fingerprint(runs[:1]))
