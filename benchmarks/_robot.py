"""The robot every hidden-effect benchmark and test makes its "measured" runs with (this
simulator's or MuJoCo's): our nominal model (``ModelParameters.nominal()``: ground Coulomb
friction 0.3, joint damping 0.1 N m s/rad, motor constant 0.0108 N m/A) with a parameter error, so
that a diagnosis always has parameter values to fit beside the effect it must name."""
from __future__ import annotations

from cobra_model import ModelParameters

#: Parameter name -> value (its unit: ``mu_c`` none, ``joint_damping`` N m s/rad, ``motor_km`` N m/A).
PARAMETER_ERROR: dict[str, float] = {"mu_c": 0.24, "joint_damping": 0.16, "motor_km": 0.0098}


def with_error(params: ModelParameters | None = None) -> ModelParameters:
    """``params`` (default: the nominal ones) with :data:`PARAMETER_ERROR`'s values."""
    return (params or ModelParameters.nominal()).with_values(**PARAMETER_ERROR)
