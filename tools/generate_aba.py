"""Regenerate ``integrators/_aba_cobra.c``: COBRA's ABA as straight-line C code (``make aba-codegen``).

Pinocchio's ABA (WORLD convention), run by Pinocchio itself on CasADi's symbolic scalar
(``pinocchio/autodiff/casadi.hpp``, shipped in the ``libpinocchio`` wheel) for the kinematic
structure of ``urdf/cobra.urdf``, and written out by CasADi's code generator
(``tools/generate_aba.cpp``). The joints, parents and placements are fixed in the code; the
bodies' inertias, the armature and the gravity are inputs. ``_aba.cpp`` includes the file and
uses it for every model of that structure, Pinocchio's ABA for any other
(:attr:`integrators.native.NativeModel.generated`). The file is committed: a build needs no
CasADi headers. Run this after changing the URDF's joints or link frames, then reinstall
(``make install``) so that the extension is rebuilt.

Usage: ``.venv/bin/python tools/generate_aba.py [--urdf PATH]``.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from importlib.metadata import distribution
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cobra_model.model import DEFAULT_URDF, CobraModel  # noqa: E402
from cobra_model.pinocchio_fields import model_fields  # noqa: E402


def compile_generator(build: Path) -> Path:
    """``tools/generate_aba.cpp`` compiled against Pinocchio's and CasADi's headers and libraries."""
    pin = distribution("libpinocchio").locate_file("cmeel.prefix")
    eigen = distribution("cmeel-eigen").locate_file("cmeel.prefix")
    casadi = Path(distribution("casadi").locate_file("casadi"))
    exe = build / "generate_aba"
    cmd = ["g++", "-std=c++17", "-O1", str(ROOT / "tools" / "generate_aba.cpp"), "-o", str(exe),
           f"-I{pin / 'include'}", f"-I{eigen / 'include' / 'eigen3'}", f"-I{casadi / 'include'}",
           "-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
           "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DNDEBUG",
           f"-L{pin / 'lib'}", f"-L{casadi}", "-lpinocchio_default", "-lcasadi",
           f"-Wl,-rpath,{pin / 'lib'}", f"-Wl,-rpath,{casadi}"]
    subprocess.run(cmd, check=True)
    return exe


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--urdf", type=Path, default=DEFAULT_URDF, help="robot file (default: urdf/cobra.urdf)")
    args = parser.parse_args(argv)
    try:
        f = model_fields(CobraModel.load(args.urdf))
    except (OSError, ValueError) as exc:  # a missing or unreadable file, a joint type _aba.cpp does not build
        parser.error(f"--urdf {args.urdf}: {exc}")
    rows = np.hstack([f.code[:, None], f.parent[:, None], f.placement, f.inertia, f.axis])
    with tempfile.TemporaryDirectory() as tmp:
        fields = Path(tmp) / "model.txt"
        with fields.open("w") as out:
            out.write(f"{len(f.code)} {len(f.armature)}\n")
            np.savetxt(out, rows, fmt="%.17g")
            np.savetxt(out, f.armature[None], fmt="%.17g")
            np.savetxt(out, f.gravity[None], fmt="%.17g")
        t0 = time.perf_counter()
        print("compiling tools/generate_aba.cpp (a few minutes: Pinocchio's templates on CasADi's scalar) ...",
              file=sys.stderr, flush=True)
        exe = compile_generator(Path(tmp))
        print(f"compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        subprocess.run([str(exe), str(fields), str(ROOT / "integrators")], check=True)
    print("now reinstall (make install) so that integrators/_aba.cpp is rebuilt with it", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
