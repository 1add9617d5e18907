"""The README is a user document that quotes current results, and its links lead somewhere."""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import headline  # noqa: E402


def test_the_headline_table_is_the_current_results():
    """Every figure of the README's table is rendered from benchmarks/results/ (run
    ``python benchmarks/headline.py`` after a benchmark)."""
    assert headline.main(["--check"]) == 0


def test_the_readme_is_short_and_its_local_links_exist():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    targets = re.findall(r"\]\(([^)#]+)\)", text)
    assert targets, "expected links to the docs"
    missing = [t for t in targets if not t.startswith("http") and not (ROOT / t).exists()]
    assert not missing, missing


def test_a_headline_row_is_rendered_from_its_results_file(tmp_path, monkeypatch):
    """The table follows the file: a changed figure in a results file changes the row."""
    import json
    doc = json.loads((headline.RESULTS / "fault_matrix.json").read_text())
    doc["rows"] = doc["rows"][:2]
    (tmp_path / "fault_matrix.json").write_text(json.dumps(doc))
    monkeypatch.setattr(headline, "RESULTS", tmp_path)
    table = headline.render()
    assert "| 2 of 2 | all |" in table and "`sim_speed.json` missing" in table


def test_a_malformed_results_file_or_missing_markers_get_one_line_naming_the_file(tmp_path, monkeypatch, capsys):
    (tmp_path / "fault_matrix.json").write_text('{"rows": [')
    monkeypatch.setattr(headline, "RESULTS", tmp_path)
    assert headline.main(["--check"]) == 2
    assert "fault_matrix.json: not valid JSON" in capsys.readouterr().err
    (tmp_path / "fault_matrix.json").write_text('{"rows": []}')
    assert headline.main(["--check"]) == 2
    assert "fault_matrix.json: missing or malformed entry" in capsys.readouterr().err
    (tmp_path / "fault_matrix.json").unlink()
    readme = tmp_path / "README.md"
    readme.write_text("no table here\n")
    monkeypatch.setattr(headline, "README", readme)
    assert headline.main([]) == 2
    assert "README.md: expected the markers" in capsys.readouterr().err
    assert readme.read_text() == "no table here\n"  # nothing written


@pytest.mark.slow
def test_the_readme_api_example_runs(capsys):
    """The README's API block, executed as written (from the repository root)."""
    text = (ROOT / "README.md").read_text()
    block = text.split("## API entry points", 1)[1].split("```python", 1)[1].split("```", 1)[0]
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)
        exec(compile(block, "README.md", "exec"), {})
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert "mu_c" in out and "joint_damping" in out
