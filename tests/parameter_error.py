"""The robot's parameter error that the hidden-effect tests put in their data: the values that
make the "measured" runs (this simulator's or MuJoCo's), off our nominal model's
(``ModelParameters.nominal()``: ground Coulomb friction 0.3, joint damping 0.1 N m s/rad, motor
constant 0.0108 N m/A), as ``benchmarks/diagnose_accuracy.py``'s ``TRUTH``."""
from __future__ import annotations

from cobra_model import ModelParameters

#: Parameter name -> value (its unit: ``mu_c`` none, ``joint_damping`` N m s/rad, ``motor_km`` N m/A).
PARAMETER_ERROR: dict[str, float] = {"mu_c": 0.24, "joint_damping": 0.16, "motor_km": 0.0098}


def with_error(params: ModelParameters | None = None) -> ModelParameters:
    """``params`` (default: the nominal ones) with :data:`PARAMETER_ERROR`'s values."""
    return (params or ModelParameters.nominal()).with_values(**PARAMETER_ERROR)
