"""Every benchmark script imports, and `make bench` runs each one: a module renamed under a script
shows here, not hours into `make bench` (``fault_matrix.py`` imported ``read_run`` from where the
restructuring had moved it out of, unnoticed for two weeks)."""
from __future__ import annotations

import re
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py"))
#: The scripts run from the command line: not the shared helpers (a leading "_", and held_out.py).
RUNNABLE = {n for n in SCRIPTS if not n.startswith("_") and n != "held_out"}


@pytest.mark.parametrize("name", SCRIPTS)
def test_the_script_imports(name, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))  # as `python benchmarks/NAME.py` has it
    module = runpy.run_path(str(ROOT / "benchmarks" / f"{name}.py"), run_name=f"benchmark_{name}")
    if name in RUNNABLE:
        assert callable(module.get("main")), f"benchmarks/{name}.py has no main()"


def test_make_bench_runs_every_script():
    makefile = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^bench:.*\n((?:\t.*\n)+)", makefile, re.MULTILINE)
    assert recipe, "the Makefile has no bench target"
    ran = set(re.findall(r"benchmarks/(\w+)\.py", recipe[1]))
    assert ran <= set(SCRIPTS), f"make bench runs scripts that do not exist: {sorted(ran - set(SCRIPTS))}"
    assert RUNNABLE <= ran, f"make bench leaves out: {sorted(RUNNABLE - ran)}"
