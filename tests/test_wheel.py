"""The package installs from a built wheel and runs from anywhere (issue 20 item 1).

The wheel is built from a copy of the sources (nothing is written into the checkout) and installed
without dependencies into a fresh virtual environment whose dependencies come from this one (a
``.pth`` line: no network). From a directory outside the checkout, ``CobraModel.load()`` must find
the URDF shipped in the wheel, ``cobra simulate`` must run, and ``cobra demo --skip-diagnose`` must
read the shipped reference dataset; the example bus configuration must be in the wheel as well.

The fresh environment's numba cache starts empty, so its first rollout also shows what a new
user's compiles: a compliant-ground rollout and batch compile no other contact law's solver or
loop (each law's loop prunes the others' branches, ``integrators.kernels.LAW_LOOPS``) and one
copy of the compliant loop, which the batch reuses. Either regression puts tens of seconds back
on every first run and on each test worker (``docs/benchmarks.md``, "The first rollout on a
machine compiles the kernels").
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parent.parent
#: What a build needs: the metadata, the packages and the directories mapped into them as data.
SOURCES = ("pyproject.toml", "setup.py", "README.md", "cobra_model", "integrators", "sysid", "hardware", "viz", "cobra_cli",
           "urdf", "data", "examples")


def _run(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{' '.join(map(str, args))} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(the fresh environment's bin directory, a work directory outside the checkout)."""
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc", "*.so")  # the wheel builds its own extension
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=ignore)
        else:
            shutil.copy2(path, src / name)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", str(base / "dist"), str(src)], cwd=base)
    wheel, = (base / "dist").glob("cobra_sysid-*.whl")
    env_dir = base / "env"
    venv.create(env_dir, with_pip=True)
    bin_dir = env_dir / "bin"
    site, = (env_dir / "lib").glob("python*/site-packages")
    # the dependencies are this environment's: its site-packages as a path (read first: "00"),
    # with its .pth hooks (Pinocchio's cmeel prefix) but not the editable install's finder, so
    # the checkout is not importable from the fresh environment
    deps = Path(sysconfig.get_paths()["purelib"])
    (site / "00_cobra_deps.pth").write_text(f"{deps}\n")
    for pth in deps.glob("*.pth"):
        if not pth.name.startswith("__editable__") and not (site / pth.name).exists():
            shutil.copy2(pth, site / pth.name)
    _run([str(bin_dir / "python"), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], cwd=base)
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    assert {"cobra_model/urdf/cobra.urdf", "sysid/reference/manifest.json", "hardware/examples/bus.toml"} <= names
    assert any(n.startswith("integrators/_aba.") and n.endswith(".so") for n in names)  # Pinocchio's ABA for the loops
    work = base / "elsewhere"
    work.mkdir()
    return bin_dir, work


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}


def test_the_model_loads_from_the_wheel_not_the_checkout(installed):
    bin_dir, work = installed
    out = _run([str(bin_dir / "python"), "-c",
                "from cobra_model import CobraModel; from cobra_model.design import DEFAULT_URDF_PATH; "
                "from sysid.generators.dataset import DATA_DIR; from hardware.config import EXAMPLE_CONFIG, load_bus_config; "
                "m = CobraModel.load(); c = load_bus_config(EXAMPLE_CONFIG); "
                "print(m.n_joints, len(c.servo_ids)); print(DEFAULT_URDF_PATH); print(DATA_DIR); print(EXAMPLE_CONFIG)"],
               cwd=work, env=_env())
    counts, *paths = out.split("\n")[:4]
    assert counts == "11 11"
    env_dir = bin_dir.parent.resolve()
    for path in paths:
        assert Path(path).resolve().is_relative_to(env_dir) and Path(path).exists(), (path, env_dir)


#: A compliant rollout and batch in the fresh environment; prints what numba compiled (JSON).
FIRST_ROLLOUT = """
import json
import numpy as np
import integrators.kernels as K
from cobra_model import CobraModel, ModelParameters
from integrators import Simulator
from integrators.batch import BatchSimulator
model, params = CobraModel.load(), ModelParameters.nominal()
sim = Simulator(model, params)
state = sim.rest_state()
goals = np.zeros((20, model.n_joints))
sim.rollout(state, goals, 0.01)
BatchSimulator(model, [params, params]).rollout([state, state], np.repeat(goals[:, None], 2, axis=1), 0.01)
others = ("soft_contact_acceleration", "soft_elliptic_acceleration", "implicit_friction_acceleration",
          "soft_pyramid_loop", "soft_elliptic_loop", "compliant_implicit_loop")
print(json.dumps({"compiled": [n for n in others if getattr(K, n).signatures],
                  "compliant_loops": len(K.compliant_loop.signatures),
                  "from_cache": sum(f.stats.cache_hits.total() for f in (K.compliant_loop, K.compliant_batch))}))
"""


def test_a_first_rollout_compiles_its_own_contact_law_only(installed):
    bin_dir, work = installed
    report = json.loads(_run([str(bin_dir / "python"), "-c", FIRST_ROLLOUT], cwd=work, env=_env()).splitlines()[-1])
    assert report["from_cache"] == 0  # compiled in this process: what it compiled is below
    assert report["compiled"] == []
    assert report["compliant_loops"] == 1


def test_cobra_simulate_and_the_demo_run_from_the_wheel(installed):
    bin_dir, work = installed
    _run([str(bin_dir / "cobra"), "simulate", "--duration", "1", "--out", "sim.csv"], cwd=work, env=_env())
    assert (work / "sim.csv").stat().st_size > 0 and (work / "sim.json").exists()
    out = _run([str(bin_dir / "cobra"), "demo", "--skip-diagnose", "--out", "demo"], cwd=work, env=_env())
    assert "held-out runs" in out and (work / "demo" / "head_paths.png").exists()
