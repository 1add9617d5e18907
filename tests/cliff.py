"""An objective stand-in for the finite-difference Jacobians' divergence handling
(``test_datacheck``, ``test_screening``): residuals linear in the free parameters' unit
coordinates, and a simulation that "diverges" (NaN rows, or an error) outside a box of them."""
from __future__ import annotations

import numpy as np

from cobra_model.parameters import ModelParameters
from integrators.batch import Divergence
from integrators.simulator import SimulationDiverged


class Cliff:
    """``residuals(X) = A z(X)`` with ``z`` the unit coordinates of the rows ``X``; a row with any
    coordinate outside ``[low, high]`` diverges."""

    def __init__(self, params: ModelParameters, A: np.ndarray, low: np.ndarray, high: np.ndarray):
        self.params, self.A, self.low, self.high = params, np.asarray(A, float), np.asarray(low), np.asarray(high)
        self.longest_run_s = 1.0   # shorter than every horizon that caps an objective
        self.evaluations = 0

    def unit(self, x: np.ndarray) -> np.ndarray:
        return np.array([self.params[n].to_unit_interval(v) for n, v in zip(self.params.free_names, x)])

    def residuals(self, X: np.ndarray, divergence: Divergence = "raise") -> np.ndarray:
        Z = np.array([self.unit(x) for x in np.atleast_2d(X)])
        R = Z @ self.A.T
        off = ((Z < self.low) | (Z > self.high)).any(axis=1)
        if off.any() and divergence == "raise":
            raise SimulationDiverged(f"rows {np.flatnonzero(off).tolist()} fell off the cliff")
        R[off] = np.nan
        self.evaluations += len(R)
        return R
