"""Box-constrained nonlinear least squares through CasADi: the identification baseline.

Minimises ``0.5 ||r(x)||^2`` over the free parameters, ``r`` the stacked weighted residuals of
:mod:`sysid.objective` (head positions over time and joint angles over time), by a
Levenberg-Marquardt iteration whose every step is a box- (and ``mu_s >= mu_c``-) constrained
quadratic programme solved by CasADi's ``conic`` interface with qpOASES (CasADi's own qrqp
corrupted the heap here on one-variable problems, found by the discrepancy workflow's
one-parameter refits; qpOASES's licence banner is kept off stdout):

    min_dz  0.5 dz^T (J^T J + lambda diag(J^T J)) dz + (J^T r)^T dz
    s.t.    0 <= z + dz <= 1,   mu_s(z + dz) >= mu_c(z + dz)

in the parameters' unit coordinates ``z`` (log-scaled where a parameter spans decades).

Residual Jacobians are **parallel forward finite differences** (all ``d + 1`` parameter vectors
of one Jacobian simulated in one batched rollout). The analytic route, Pinocchio's
``computeABADerivatives`` propagated through the integrator, does not pay here: measured on
this machine it costs 12.8 us per step (3x an ABA) before the hand-written derivatives of the
contact and actuator kernels and the 17 x (17 + d) tangent propagation, more than the ``d + 1``
batched rollouts (about 4.4 us per environment-step), and the regularised friction makes
long-horizon sensitivities stiff. Finite differences in unit coordinates with step 1e-3 smooth
over that stiffness.

Confidence intervals come from the Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` with
``sigma^2 = ||r||^2 / (m - d)``, mapped to physical units; a parameter is flagged as not
identifiable when it sits on a bound, when it loads a flat direction of ``J`` (singular value
below 1e-4 of the largest), or when its 95 % interval is wider than its value.
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import Enum
from typing import Callable, Iterator

import casadi as ca
import numpy as np

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters, Parameter
from sysid.objective import Objective


class FitStatus(str, Enum):
    """Why the fit stopped."""

    CONVERGED_COST = "converged: relative cost decrease below tolerance"
    CONVERGED_STEP = "converged: step below tolerance"
    MAX_ITERATIONS = "stopped: iteration limit"
    BUDGET = "stopped: time budget"
    NO_DESCENT = "stopped: no descent direction found (damping limit)"


@dataclass(frozen=True)
class IterationLog:
    """One accepted or rejected LM step."""

    iteration: int
    cost: float
    trial_cost: float
    accepted: bool
    damping: float
    step_norm: float
    evaluations: int
    seconds: float


@dataclass(frozen=True)
class ParameterReport:
    """Fitted value of one parameter with its 95 % interval and identifiability."""

    name: str
    unit: str
    nominal: float
    initial: float
    value: float
    ci_low: float
    ci_high: float
    at_bound: bool
    identifiable: bool
    reason: str


@dataclass(frozen=True)
class FitResult:
    """What a fit found and how it got there."""

    params: ModelParameters
    status: FitStatus
    cost: float
    initial_cost: float
    log: list[IterationLog]
    report: list[ParameterReport]
    singular_values: np.ndarray
    evaluations: int
    seconds: float
    method: str = "lsq"
    extra: dict = field(default_factory=dict)


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence C-level writes to stdout (qpOASES prints a banner when first constructed)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _feasible(params: ModelParameters, z: np.ndarray) -> bool:
    """Whether unit coordinates ``z`` give a valid parameter set (bounds, mu_s >= mu_c)."""
    try:
        params.from_unit(z)
    except InputError:
        return False
    return True


def _unit_jacobian(params: ModelParameters) -> np.ndarray:
    """d x / d z of the free parameters (diagonal)."""
    out = []
    for p in params:
        if p.frozen:
            continue
        x = p.value
        out.append(x * np.log(p.max / p.min) if p.log_scale else p.max - p.min)
    return np.array(out)


def _friction_row(params: ModelParameters) -> tuple[np.ndarray, float] | None:
    """Linear constraint ``a.z >= b`` in unit coordinates for mu_s >= mu_c (when expressible)."""
    free = params.free_names
    if "mu_s" not in params or "mu_c" not in params:
        return None
    ps, pc = params["mu_s"], params["mu_c"]
    if ps.log_scale or pc.log_scale:
        return None
    a = np.zeros(len(free))
    b = 0.0
    if "mu_s" in free:
        a[free.index("mu_s")] += ps.max - ps.min
    else:
        b -= ps.value
    if "mu_c" in free:
        a[free.index("mu_c")] -= pc.max - pc.min
    else:
        b += pc.value
    b += pc.min - ps.min if "mu_s" in free and "mu_c" in free else (
        -ps.min if "mu_s" in free else pc.min if "mu_c" in free else 0.0)
    return (a, b) if np.any(a) else None


def fit_lsq(objective: Objective, *, max_iterations: int = 20, budget_seconds: float | None = None,
            fd_step: float = 1e-3, cost_tol: float = 1e-4, step_tol: float = 1e-5,
            progress: Callable[[int, float, float], None] | None = None) -> FitResult:
    """Fit the objective's free parameters from its parameter set's current values.

    Args:
        objective: residuals over the training runs.
        max_iterations: Jacobian evaluations at most.
        budget_seconds: stop after this wall time (checked between evaluations).
        fd_step: finite-difference step in unit coordinates.
        cost_tol, step_tol: convergence tolerances (relative cost decrease, unit step norm).
        progress: called with (iteration, cost, seconds) after each Jacobian.

    Returns:
        FitResult with the fitted parameters, an iteration log, a status and per-parameter
        intervals and identifiability flags.
    """
    t_start = time.perf_counter()
    params0 = objective.params
    names = params0.free_names
    d = len(names)
    z = params0.to_unit()
    friction = _friction_row(params0)

    def residuals(Z: np.ndarray) -> np.ndarray:
        X = np.array([params0.from_unit(zz).as_vector() for zz in np.atleast_2d(Z)])
        return objective.residuals(X)

    r = residuals(z)[0]
    cost0 = cost = 0.5 * float(r @ r)
    log: list[IterationLog] = []
    damping = 1e-3
    status = FitStatus.MAX_ITERATIONS
    with _quiet_stdout():
        qp = ca.conic("lm_step", "qpoases", {"h": ca.Sparsity.dense(d, d),
                                             "a": ca.Sparsity.dense(1 if friction else 0, d)},
                      {"printLevel": "none", "error_on_fail": False})
    J = np.zeros((r.size, d))
    for it in range(max_iterations):
        # forward differences, stepping inward at the upper bound and away from mu_s = mu_c
        h = np.where(z + fd_step <= 1.0, fd_step, -fd_step)
        for j in range(d):
            probe = z.copy()
            probe[j] += h[j]
            if not _feasible(params0, probe):
                h[j] = -h[j]
        Zp = z[None, :] + np.diag(h)
        Rp = residuals(Zp)
        J = ((Rp - r[None, :]) / h[:, None]).T
        g = J.T @ r
        H = J.T @ J
        if progress:
            progress(it, cost, time.perf_counter() - t_start)
        accepted = False
        while damping < 1e8:
            if budget_seconds is not None and time.perf_counter() - t_start > budget_seconds:
                break
            Hd = H + damping * np.diag(np.maximum(np.diag(H), 1e-12))
            args = {"h": Hd, "g": g, "lbx": -z, "ubx": 1.0 - z}
            if friction:
                a, b = friction
                args.update(a=a[None, :], lba=b - a @ z, uba=np.inf)
            dz = np.array(qp(**args)["x"]).ravel()
            z_try = np.clip(z + dz, 0.0, 1.0)
            try:
                r_try = residuals(z_try)[0]
                c_try = 0.5 * float(r_try @ r_try)
            except (InputError, RuntimeError):
                c_try = np.inf
            ok = c_try < cost
            log.append(IterationLog(it, cost, c_try, ok, damping, float(np.linalg.norm(dz)), objective.evaluations,
                                    time.perf_counter() - t_start))
            if ok:
                rel = (cost - c_try) / max(cost, 1e-300)
                z, r, cost = z_try, r_try, c_try
                damping = max(damping / 3.0, 1e-9)
                accepted = True
                break
            damping *= 4.0
        if budget_seconds is not None and time.perf_counter() - t_start > budget_seconds:
            status = FitStatus.BUDGET
            break
        if not accepted:
            status = FitStatus.NO_DESCENT
            break
        if rel < cost_tol:
            status = FitStatus.CONVERGED_COST
            break
        if log[-1].step_norm < step_tol:
            status = FitStatus.CONVERGED_STEP
            break
    fitted = params0.from_unit(z)
    report, sv = _uncertainty(params0, fitted, J, r, z)
    return FitResult(fitted, status, cost, cost0, log, report, sv, objective.evaluations,
                     time.perf_counter() - t_start)


def _uncertainty(initial: ModelParameters, fitted: ModelParameters, J: np.ndarray, r: np.ndarray,
                 z: np.ndarray) -> tuple[list[ParameterReport], np.ndarray]:
    """95 % intervals from the Gauss-Newton covariance and identifiability flags."""
    m, d = J.shape
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    sigma2 = float(r @ r) / max(m - d, 1)
    flat = s < 1e-4 * s[0] if s.size and s[0] > 0 else np.ones(d, dtype=bool)
    inv_s2 = np.where(flat, 0.0, 1.0 / np.where(s > 0, s, 1.0) ** 2)
    cov_z = (Vt.T * inv_s2) @ Vt * sigma2
    D = _unit_jacobian(fitted)
    std = np.sqrt(np.maximum(np.diag(cov_z), 0.0)) * np.abs(D)
    loads_flat = np.zeros(d, dtype=bool)
    for k in np.flatnonzero(flat):
        loads_flat |= np.abs(Vt[k]) > 0.3
    nominal = ModelParameters.nominal()
    out = []
    for i, name in enumerate(fitted.free_names):
        p: Parameter = fitted[name]
        half = 1.96 * std[i]
        at_bound = bool(z[i] < 1e-3 or z[i] > 1 - 1e-3)
        reasons = []
        if at_bound:
            reasons.append("at a bound")
        if loads_flat[i]:
            reasons.append("in a flat direction of the residual Jacobian")
        if not loads_flat[i] and half > abs(p.value):
            reasons.append("95 % interval wider than the value")
        out.append(ParameterReport(name, p.unit, nominal.get(name, initial.value(name)), initial.value(name), p.value,
                                   p.value - half if not loads_flat[i] else float("nan"),
                                   p.value + half if not loads_flat[i] else float("nan"),
                                   at_bound, not reasons, "; ".join(reasons) or "identifiable"))
    return out, s
