"""Box-constrained nonlinear least squares through CasADi: the identification baseline.

Minimises ``0.5 ||r(x)||^2`` over the free parameters, ``r`` the stacked weighted residuals of
:mod:`sysid.identification.objective` (head positions over time and joint angles over time), by a
Levenberg-Marquardt iteration whose every step is a box- (and ``mu_s >= mu_c``-) constrained
quadratic programme solved by CasADi's ``conic`` interface with qpOASES (CasADi's own qrqp
corrupted the heap here on one-variable problems, found by the discrepancy workflow's
one-parameter refits; qpOASES's licence banner is kept off stdout):

    min_dz  0.5 dz^T (J^T J + lambda diag(J^T J)) dz + (J^T r)^T dz
    s.t.    0 <= z + dz <= 1,   |dz_i| <= Delta,   mu_s(z + dz) >= mu_c(z + dz)

in the parameters' unit coordinates ``z`` (log-scaled where a parameter spans decades), with a
trust region ``Delta`` per coordinate that adapts to how well the model predicts
(:data:`TRUST_RADIUS`).

Residual Jacobians are **parallel forward finite differences** (all ``d + 1`` parameter vectors
of one Jacobian simulated in one batched rollout). The analytic route, Pinocchio's
``computeABADerivatives`` propagated through the integrator, does not pay here: measured on
this machine it costs 12.8 us per step (3x an ABA) before the hand-written derivatives of the
contact and actuator kernels and the 17 x (17 + d) tangent propagation, more than the ``d + 1``
batched rollouts (about 4.4 us per environment-step), and the regularised friction makes
long-horizon sensitivities stiff. Finite differences in unit coordinates with step 1e-3 smooth
over that stiffness. A probe whose simulation diverges while the point itself simulates is
retaken on the other side of the point (:func:`retake_diverged`).

Confidence intervals come from the HAC sandwich covariance
``(J^T J)^-1 Omega (J^T J)^-1`` of :mod:`sysid.identification.intervals` (``Omega`` the prewhitened
Newey-West long-run covariance of each run's scores ``J_t^T r_t``: the residuals are time
series, and neighbouring samples' errors are correlated when anything lasts longer than one
sample) plus the start-pose term ``A P A^T``, ``A = (J^T J)^-1 J^T J_p`` and ``P`` the
covariance of every run's measured start pose (x, y, heading; see
:func:`sysid.identification.objective.start_pose_sensitivity`), mapped to physical units. With white
residuals the sandwich is the Gauss-Newton ``sigma^2 (J^T J)^-1``, ``sigma^2 = ||r||^2 / (m - d)``;
that interval is reported too (``ci_low_iid``, ``ci_high_iid``).
The start pose is a measurement too: each run is simulated from it, so its error moves the
whole head path and biases the fit by more than the noise alone says (on
``benchmarks/recovery.py`` up to 0.7 %, three times the noise-only interval). The fit also
tests the residuals for whiteness (:func:`sysid.identification.intervals.whiteness`, ``residual_whiteness``):
residuals that are not white mean a model mismatch the intervals do not cover. A parameter is
flagged as not identifiable when it sits on a bound, when it loads a flat direction of ``J``
(singular value below 1e-4 of the largest), or when its 95 % interval is wider than its value.
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager, redirect_stdout
import dataclasses
from dataclasses import dataclass, field
from enum import Enum
from typing import Callable, Iterator, Sequence

import casadi as ca
import numpy as np

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters, Parameter
from integrators.batch import Divergence
from sysid.identification.intervals import Whiteness, sandwich_covariance, whiteness
from sysid.identification.lockstep import Evaluate, Steps, run
from sysid.identification.objective import Objective


#: Horizons [s] of the continuation before the whole runs (see :func:`fit_lsq`).
DEFAULT_HORIZONS_S: tuple[float, ...] = (1.5, 3.0, 6.0)
#: Forward finite-difference step of the residual Jacobians, in unit coordinates (1 % of each
#: parameter's range, or of its decades when log-scaled). The residuals are smooth in the
#: parameters only above that scale: below it they move in small jumps, as contacts switch
#: between sticking and slipping a step earlier or later and the servo loop's quantised encoder
#: reading flips a tick. On MuJoCo-made runs (``benchmarks/mujoco_robustness.py``, development
#: seed) a 0.1 % step measured those jumps, not the slope, at a fitted point: the Gauss-Newton
#: step made the cost worse at every damping and the fit stopped where it started; with 1 %
#: three iterations cut the cost by 42 %.
FD_STEP = 1e-2
#: Initial trust region of a Levenberg-Marquardt step: at most this much of each parameter's
#: unit range (a factor ``(max/min)^0.1`` for a log-scaled one, e.g. 1.7 for ``k2``). The
#: Gauss-Newton model comes from a finite-difference Jacobian of contact rollouts, whose cost is
#: piecewise smooth (contacts switch between sticking and slipping), so it is trusted only as
#: far as it has predicted well: the region doubles (up to the whole range) after a step at its
#: edge whose actual decrease is at least 3/4 of the predicted one, and halves after a step that
#: achieved less than 1/4 of it (the usual trust-region rule). Without it the damping alone,
#: lowered after every accepted step, let a step that happened to lower the cost cross into
#: another basin: measured on MuJoCo-made runs (``tests/test_diagnose_mujoco.py``'s seed 21,
#: encoder offset 0.03 rad), the base fit ran ``k2`` to its lower bound and the offset came out
#: 0.014 rad.
TRUST_RADIUS = 0.1


class FitStatus(str, Enum):
    """Why the fit stopped."""

    CONVERGED_COST = "converged: relative cost decrease below tolerance"
    CONVERGED_STEP = "converged: step below tolerance"
    CONVERGED_MODEL = "converged: the local model predicts a relative decrease below tolerance"
    MAX_ITERATIONS = "stopped: iteration limit"
    BUDGET = "stopped: time budget"
    NO_DESCENT = "stopped: no trial step lowered the cost (the damping grew to its limit)"


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
    horizon_s: float


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
    #: The 95 % interval if the residuals were white (Gauss-Newton ``sigma^2 (J^T J)^-1`` plus the
    #: start pose): the interval before autocorrelation was allowed for (NaN when not computed).
    ci_low_iid: float = float("nan")
    ci_high_iid: float = float("nan")


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
    residual_count: int = 0
    #: Ljung-Box whiteness of the final residuals (None for methods without residuals).
    residual_whiteness: Whiteness | None = None
    #: How the intervals were computed, one line for reports ("" when they were not).
    interval_method: str = ""
    #: With the motor current fitted (``Weights.use_current``): the same fit's intervals from
    #: its head and joint residuals alone, to show what the current adds (None otherwise).
    report_without_current: list[ParameterReport] | None = None

    def to_json(self) -> dict:
        """The fit as the ``"fit"`` object of a fitted parameter file (without the parameters,
        which are the file's body, and without ``extra``, a method's own diagnostics).

        ``intervals``, ``identifiable`` and ``intervals_iid`` repeat the per-parameter
        ``report`` by name, for readers that want one field.
        """
        without = self.report_without_current
        return {
            "method": self.method, "status": self.status.value, "cost": self.cost, "initial_cost": self.initial_cost,
            "evaluations": self.evaluations, "seconds": self.seconds, "residual_count": self.residual_count,
            "intervals": {r.name: [r.ci_low, r.ci_high] for r in self.report},
            "identifiable": {r.name: r.reason for r in self.report},
            "intervals_iid": {r.name: [r.ci_low_iid, r.ci_high_iid] for r in self.report},
            "interval_method": self.interval_method,
            "intervals_without_current": {r.name: [r.ci_low, r.ci_high] for r in without} if without else None,
            "residual_whiteness": self.residual_whiteness.to_json_dict() if self.residual_whiteness else None,
            "log": [dataclasses.asdict(entry) for entry in self.log],
            "report": [dataclasses.asdict(r) for r in self.report],
            "report_without_current": [dataclasses.asdict(r) for r in without] if without else None,
            "singular_values": [float(s) for s in self.singular_values],
        }

    @classmethod
    def from_json(cls, data: dict, params: ModelParameters) -> "FitResult":
        """Inverse of :meth:`to_json`, with the fitted ``params`` (the parameter file's body)."""
        without = data.get("report_without_current")
        white = data.get("residual_whiteness")
        return cls(params, FitStatus(data["status"]), float(data["cost"]), float(data["initial_cost"]),
                   [IterationLog(**entry) for entry in data["log"]],
                   [ParameterReport(**r) for r in data["report"]], np.asarray(data["singular_values"], dtype=float),
                   int(data["evaluations"]), float(data["seconds"]), method=data["method"],
                   residual_count=int(data.get("residual_count", 0)),
                   residual_whiteness=Whiteness.from_json_dict(white) if white else None,
                   interval_method=data.get("interval_method", ""),
                   report_without_current=[ParameterReport(**r) for r in without] if without else None)


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence writes to stdout, C-level and Python-level (qpOASES prints a banner when first
    constructed; CasADi sends it to Python's ``sys.stdout`` where that is not the process's
    standard output, as in a notebook or under pytest's capture)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null, redirect_stdout(null):
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def feasible(params: ModelParameters, z: np.ndarray) -> bool:
    """Whether unit coordinates ``z`` give a valid parameter set (bounds, mu_s >= mu_c)."""
    try:
        params.from_unit(z)
    except InputError:
        return False
    return True


def forward_steps(params: ModelParameters, z: np.ndarray, step: float) -> np.ndarray:
    """Signed finite-difference steps, one per unit coordinate of ``z``: ``step``, stepping
    inward at the upper bound and away from ``mu_s = mu_c`` where a forward step is invalid."""
    h = np.where(z + step <= 1.0, step, -step)
    for j in range(z.size):
        probe = z.copy()
        probe[j] += h[j]
        if not feasible(params, probe):
            h[j] = -h[j]
    return h


def probe_residuals(evaluate: Callable[[np.ndarray, Divergence], Evaluate], params: ModelParameters, z: np.ndarray,
                    r: np.ndarray, h: np.ndarray) -> Steps[np.ndarray]:
    """The residuals at each finite-difference probe ``z + h_j e_j`` (one row per coordinate),
    for a Jacobian whose column ``j`` is ``(row_j - r) / h_j``, ``r`` the residuals at ``z``.

    A probe whose simulation diverges is retaken on the other side of ``z``
    (:func:`retake_diverged`). A coordinate with no stable feasible probe on either side gets
    ``r`` (a zero column: this iteration's step leaves it where it is)."""
    rows = np.array((yield evaluate(z[None, :] + np.diag(h), "mask")))
    rows = yield from retake_diverged(evaluate, params, z, h, rows)
    rows[np.isnan(rows).any(axis=1)] = r
    return rows


def retake_diverged(evaluate: Callable[[np.ndarray, Divergence], Evaluate], params: ModelParameters, z: np.ndarray,
                    h: np.ndarray, rows: np.ndarray) -> Steps[np.ndarray]:
    """``rows``, the residuals at the probes ``z + h_j e_j`` (NaN where the simulation diverged,
    as ``divergence="mask"`` gives them), with each diverged probe retaken at ``z - h_j`` and
    ``h_j`` reversed in place: the slope is measured from the side where the model is stable.

    Why: a ground parameter stepped by ``h_j`` can put the model where the contact sinks through
    the ground while the model at ``z`` itself simulates. A row still NaN has no stable
    feasible probe on either side; the caller decides what that means. A computation
    (:mod:`sysid.identification.lockstep`)."""
    rows = np.array(rows, dtype=float)
    for j in np.flatnonzero(np.isnan(rows).any(axis=1)):
        probe = z.copy()
        probe[j] -= h[j]
        if not feasible(params, probe):
            continue
        back = (yield evaluate(probe[None, :], "mask"))[0]
        if not np.isnan(back).any():
            h[j], rows[j] = -h[j], back
    return rows


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


#: Whole-run stages at most that :func:`fit_lsq` adds when its fitted soft contact takes another
#: physics step than the one it was fitted at (a time constant that crosses the step rule's
#: threshold back and forth is left at the last).
STEP_STAGES = 2


def fit_lsq(objective: Objective, *, max_iterations: int = 20, budget_seconds: float | None = None,
            horizons_s: Sequence[float] = DEFAULT_HORIZONS_S, fd_step: float = FD_STEP, trust_radius: float = TRUST_RADIUS,
            cost_tol: float = 1e-3,
            stage_cost_tol: float = 1e-2, step_tol: float = 1e-5,
            progress: Callable[[int, float, float], None] | None = None) -> FitResult:
    """Fit the objective's free parameters from its parameter set's current values
    (:func:`fit_lsq_steps`, its evaluations made one after the other)."""
    return run(fit_lsq_steps(objective, max_iterations=max_iterations, budget_seconds=budget_seconds,
                             horizons_s=horizons_s, fd_step=fd_step, trust_radius=trust_radius, cost_tol=cost_tol,
                             stage_cost_tol=stage_cost_tol, step_tol=step_tol, progress=progress))


def fit_lsq_steps(objective: Objective, *, max_iterations: int = 20, budget_seconds: float | None = None,
                  horizons_s: Sequence[float] = DEFAULT_HORIZONS_S, fd_step: float = FD_STEP,
                  trust_radius: float = TRUST_RADIUS, cost_tol: float = 1e-3, stage_cost_tol: float = 1e-2,
                  step_tol: float = 1e-5, progress: Callable[[int, float, float], None] | None = None
                  ) -> Steps[FitResult]:
    """Fit the objective's free parameters from its parameter set's current values, as a
    computation whose evaluations are requests (:mod:`sysid.identification.lockstep`: several
    fits run together with :func:`~sysid.identification.lockstep.run_together`).

    The fit is a continuation over the horizon: it is first run on each run's first
    ``horizons_s[0]`` seconds, its result starts the fit on the first ``horizons_s[1]`` seconds,
    and so on up to the whole runs (horizons at or beyond the longest run are skipped). A head
    path over several seconds depends strongly nonlinearly on the ground parameters, so from a
    guess 30-50 % off a fit on whole runs stops in a compensating local minimum (stiff ground,
    high static friction, no damping: ``benchmarks/recovery.py``); over short horizons the
    residuals are nearly linear in the parameters and lead it into the right basin. The shorter
    stages only have to lead there, so they stop at a looser relative cost decrease
    (``stage_cost_tol``); the whole runs get ``cost_tol``. Measured on the shipped reference
    dataset (22 runs of 11 s, all 9 parameters free, from nominal): tightening ``cost_tol`` from
    1e-3 to 1e-4 takes the whole-run stage from 2 to 8 Jacobians (51 s to 102 s in all) for a
    further 0.1 % of cost and held-out final head errors that differ by under 1 mm; without the
    6 s stage the whole-run stage needs 5 Jacobians.

    Args:
        objective: residuals over the training runs.
        max_iterations: Jacobian evaluations at most, per horizon stage.
        budget_seconds: stop after this wall time (checked between evaluations, all stages).
        horizons_s: the shorter horizons [s] of the continuation, increasing; () fits the
            whole runs only.
        fd_step: finite-difference step in unit coordinates.
        trust_radius: the first steps' largest change of any unit coordinate (:data:`TRUST_RADIUS`).
        cost_tol, step_tol: convergence tolerances (relative cost decrease, unit step norm).
        stage_cost_tol: relative cost decrease that ends a shorter-horizon stage.
        progress: called with (iteration, cost, seconds) after each Jacobian; iterations count
            on over the stages.

    With the objective's automatic step (``Objective(settings=None)``), a fit whose soft contact
    ends on another step than it was fitted at (:func:`integrators.simulator.contact_resolved`:
    at least ``STEPS_PER_CONTACT_TIME_CONSTANT`` steps per time constant) gets a further
    whole-run stage at that step, from where the last one ended (:data:`STEP_STAGES` at most):
    the values are fitted at the step their later simulations (``simulate_like``, an
    :class:`Objective` built on them) take.

    Returns:
        FitResult with the fitted parameters, an iteration log (with each entry's horizon), a
        status and per-parameter intervals and identifiability flags; ``extra["iterates"]``
        lists (seconds since the start, evaluations, parameters) of the start and of every
        accepted step, over all stages (what a benchmark plots against wall time), and
        ``extra["step_s"]`` the physics step [s] of the last stage.
    """
    if list(horizons_s) != sorted(horizons_s) or any(h <= 0 for h in horizons_s):
        raise InputError(f"horizons_s must be positive and increasing, got {list(horizons_s)}")
    if not 0.0 < trust_radius <= 1.0:
        raise InputError(f"trust_radius must be in (0, 1] (a share of each parameter's unit range), got {trust_radius}")
    t_start = time.perf_counter()
    longest = objective.longest_run_s
    params0 = objective.params
    z = params0.to_unit()
    r0 = (yield Evaluate(objective, params0.as_vector()[None]))[0]
    log: list[IterationLog] = []
    path: list[tuple[float, int, np.ndarray]] = [(0.0, objective.evaluations, z.copy())]
    done = objective.evaluations
    settings = dict(fd_step=fd_step, trust_radius=trust_radius, cost_tol=cost_tol, step_tol=step_tol, progress=progress,
                    t_start=t_start, budget_seconds=budget_seconds)
    for h in horizons_s:
        if h >= longest or (budget_seconds is not None and time.perf_counter() - t_start > budget_seconds):
            break
        stage = objective.truncated(h)
        lm = yield from _levenberg_marquardt(stage, z, max_iterations=max_iterations,
                                             first_iteration=len({e.iteration for e in log}),
                                             evaluations_before=done, **{**settings, "cost_tol": stage_cost_tol})
        z, done = lm.z, done + stage.evaluations
        log.extend(lm.log)
        path.extend(lm.path)
    objective.evaluations = done
    # the whole runs always get at least one Jacobian: the intervals are computed from it
    lm = yield from _levenberg_marquardt(objective, z, max_iterations=max(max_iterations, 1),
                                         first_iteration=len({e.iteration for e in log}), evaluations_before=0,
                                         **settings)
    z = lm.z
    log.extend(lm.log)
    path.extend(lm.path)
    for _ in range(STEP_STAGES):
        stepped = objective.with_params(params0.from_unit(z))  # the same free set, so the same z
        if stepped.settings == objective.settings:
            break
        # the fitted contact needs another step than the one fitted at (a soft contact at least
        # STEPS_PER_CONTACT_TIME_CONSTANT steps per time constant): the whole runs again at the
        # step every later simulation of these values takes (simulate_like, an Objective built on them)
        done = objective.evaluations
        objective = stepped
        lm = yield from _levenberg_marquardt(objective, z, max_iterations=max(max_iterations, 1),
                                             first_iteration=len({e.iteration for e in log}),
                                             evaluations_before=done, **settings)
        objective.evaluations += done
        z = lm.z
        log.extend(lm.log)
        path.extend(lm.path)
    fitted = params0.from_unit(z)
    blocks = objective.residual_blocks()
    start_pose = objective.start_pose_sensitivity(lm.r)
    found = uncertainty(params0, fitted, lm.J, lm.r, z, start_pose, blocks, sample_hz=objective.weights.sample_hz)
    without_current = None
    if objective.weights.use_current:
        keep = ~objective.current_rows()
        index = np.cumsum(keep) - 1  # a kept residual's row once the current rows are dropped
        n_motion = 2 + objective.spec.targets[0].q.shape[1]  # head x, y and the joints
        without_current = uncertainty(params0, fitted, lm.J[keep], lm.r[keep], z,
                                      (start_pose[0][keep], start_pose[1]),
                                      [index[b[:, :n_motion]] for b in blocks],
                                      sample_hz=objective.weights.sample_hz).report
    white = whiteness(lm.r, blocks, missing=objective.head_gaps())
    return FitResult(fitted, lm.status, lm.cost, 0.5 * float(r0 @ r0), log, found.report, found.singular_values,
                     objective.evaluations, time.perf_counter() - t_start, residual_count=lm.r.size,
                     residual_whiteness=white, interval_method=found.method,
                     report_without_current=without_current,
                     extra={"iterates": [(sec, n, params0.from_unit(zz)) for sec, n, zz in path],
                            "step_s": objective.settings.dt})


def refit_by_residual(objective: Objective, first: FitResult,
                      fit: Callable[[Objective], FitResult] = fit_lsq) -> FitResult:
    """Feasible weighted least squares: ``objective`` (the first fit's) with each channel's scale
    set to its RMS residual at ``first``'s parameters (:meth:`Objective.residual_weights`), fitted
    again from there by ``fit``. The result's ``seconds`` count both fits; its ``extra`` holds the
    ``channel_scales`` used (head [m], joints [rad]).
    """
    start = objective.with_params(first.params)
    weights = start.residual_weights(first.params.as_vector())
    second = fit(start.with_weights(weights))
    extra = dict(second.extra, channel_scales={"head_scale_m": weights.head_scale_m,
                                               "joint_scale_rad": weights.joint_scale_rad})
    return dataclasses.replace(second, seconds=first.seconds + second.seconds, extra=extra)


@dataclass
class _LMState:
    """Where one Levenberg-Marquardt stage ended."""

    z: np.ndarray
    r: np.ndarray
    J: np.ndarray
    cost: float
    status: FitStatus
    log: list[IterationLog]
    path: list[tuple[float, int, np.ndarray]]


def _levenberg_marquardt(objective: Objective, z: np.ndarray, *, max_iterations: int, budget_seconds: float | None,
                         fd_step: float, trust_radius: float, cost_tol: float, step_tol: float,
                         progress: Callable[[int, float, float], None] | None, first_iteration: int,
                         evaluations_before: int, t_start: float) -> Steps[_LMState]:
    """Box-constrained LM from unit coordinates ``z`` on one objective (see the module docstring);
    its evaluations are requests (:mod:`sysid.identification.lockstep`)."""
    params0 = objective.params
    d = len(params0.free_names)
    friction = _friction_row(params0)
    horizon = max(float(tg.duration) for tg in objective.spec.targets)

    def residuals(Z: np.ndarray, divergence: Divergence = "raise") -> Evaluate:
        return Evaluate(objective, np.array([params0.from_unit(zz).as_vector() for zz in np.atleast_2d(Z)]),
                        divergence)

    def over_budget() -> bool:
        return budget_seconds is not None and time.perf_counter() - t_start > budget_seconds

    r = (yield residuals(z))[0]
    cost = 0.5 * float(r @ r)
    log: list[IterationLog] = []
    damping = 1e-3
    radius = trust_radius
    status = FitStatus.MAX_ITERATIONS
    with _quiet_stdout():
        qp = ca.conic("lm_step", "qpoases", {"h": ca.Sparsity.dense(d, d),
                                             "a": ca.Sparsity.dense(1 if friction else 0, d)},
                      {"printLevel": "none", "error_on_fail": False})
    J = np.zeros((r.size, d))
    path: list[tuple[float, int, np.ndarray]] = []
    for k in range(max_iterations):
        it = first_iteration + k
        h = forward_steps(params0, z, fd_step)
        Rp = yield from probe_residuals(residuals, params0, z, r, h)
        J = ((Rp - r[None, :]) / h[:, None]).T
        g = J.T @ r
        H = J.T @ J
        if progress:
            progress(it, cost, time.perf_counter() - t_start)
        accepted, rejected = False, False
        while damping < 1e8 and not over_budget():
            Hd = H + damping * np.diag(np.maximum(np.diag(H), 1e-12))
            args = {"h": Hd, "g": g, "lbx": np.maximum(-z, -radius), "ubx": np.minimum(1.0 - z, radius)}
            if friction:
                a, b = friction
                args.update(a=a[None, :], lba=b - a @ z, uba=np.inf)
            # qpOASES leaves the bounds of a one-variable problem without other constraints
            # unenforced (CasADi 3.8: min 50 dz^2 - 36 dz on [-0.5, 0.1] returns 0.36); the box is
            # separable, so clipping is that problem's exact solution and a no-op otherwise
            dz = np.clip(np.array(qp(**args)["x"]).ravel(), args["lbx"], args["ubx"])
            predicted = -float(g @ dz + 0.5 * dz @ H @ dz)   # Gauss-Newton model's decrease
            if predicted < cost_tol * cost:
                # after rejected trials the damping, not a minimum, made the predicted decrease small
                status = FitStatus.NO_DESCENT if rejected else FitStatus.CONVERGED_MODEL
                break
            z_try = np.clip(z + dz, 0.0, 1.0)
            try:
                r_try = (yield residuals(z_try))[0]
                c_try = 0.5 * float(r_try @ r_try)
            except (InputError, RuntimeError):
                c_try = np.inf
            ok = c_try < cost
            log.append(IterationLog(it, cost, c_try, ok, damping, float(np.linalg.norm(dz)),
                                    evaluations_before + objective.evaluations,
                                    time.perf_counter() - t_start, horizon))
            if ok:
                rel = (cost - c_try) / max(cost, 1e-300)
                agreement = (cost - c_try) / predicted
                if agreement < 0.25:
                    radius = max(radius / 2.0, fd_step)
                elif agreement > 0.75 and np.max(np.abs(dz)) >= 0.99 * radius:
                    radius = min(2.0 * radius, 1.0)
                z, r, cost = z_try, r_try, c_try
                path.append((time.perf_counter() - t_start, evaluations_before + objective.evaluations, z.copy()))
                damping = max(damping / 3.0, 1e-9)
                accepted = True
                break
            damping *= 4.0
            rejected = True
        if over_budget():
            status = FitStatus.BUDGET
            break
        if status is FitStatus.CONVERGED_MODEL:
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
    return _LMState(z, r, J, cost, status, log, path)


@dataclass(frozen=True)
class Uncertainty:
    """What :func:`uncertainty` found: the parameter table, the singular values of ``J`` and
    one line saying how the intervals were computed."""

    report: list[ParameterReport]
    singular_values: np.ndarray
    method: str


def uncertainty(initial: ModelParameters, fitted: ModelParameters, J: np.ndarray, r: np.ndarray,
                z: np.ndarray, start_pose: tuple[np.ndarray, np.ndarray] | None = None,
                blocks: Sequence[np.ndarray] | None = None, *, sample_hz: float | None = None) -> Uncertainty:
    """95 % intervals and identifiability flags.

    Args:
        initial, fitted: parameter sets at the start and at the end of the fit.
        J: ``(m, d)`` residual Jacobian in unit coordinates; r: ``(m,)`` residuals; z: ``(d,)``
            fitted unit coordinates.
        start_pose: the start poses' (residual derivatives, standard uncertainties), whose
            covariance is added (:func:`sysid.identification.objective.start_pose_sensitivity`).
        blocks: per run, ``(S, C)`` residual indices by sample time and channel
            (:func:`sysid.identification.objective.residual_blocks`): with them the noise covariance is the
            HAC sandwich of :func:`sysid.identification.intervals.sandwich_covariance`; without them the
            Gauss-Newton ``sigma^2 (J^T J)^-1`` (white residuals assumed).
        sample_hz: residual sample rate [Hz], to state the HAC bandwidth in seconds.
    """
    m, d = J.shape
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    sigma2 = float(r @ r) / max(m - d, 1)
    flat = s < 1e-4 * s[0] if s.size and s[0] > 0 else np.ones(d, dtype=bool)
    inv_s2 = np.where(flat, 0.0, 1.0 / np.where(s > 0, s, 1.0) ** 2)
    JtJ_pinv = (Vt.T * inv_s2) @ Vt
    cov_pose = np.zeros((d, d))
    if start_pose is not None:
        J_pose, pose_std = start_pose
        through = JtJ_pinv @ J.T @ (J_pose * pose_std)      # d z per standard start-pose error
        cov_pose = through @ through.T
    cov_iid = JtJ_pinv * sigma2 + cov_pose
    if blocks is not None:
        hac = sandwich_covariance(J, r, blocks, JtJ_pinv, sample_hz=sample_hz)
        cov_z = hac.cov + cov_pose
        lag = f"{hac.bandwidth:.2f} samples" + (f" = {hac.bandwidth_s:.2f} s" if np.isfinite(hac.bandwidth_s) else "")
        method = f"HAC sandwich (Newey-West, VAR(1)-prewhitened, Bartlett bandwidth {lag}, per run)"
    else:
        cov_z = cov_iid
        method = "Gauss-Newton sigma^2 (J^T J)^-1 (white residuals assumed)"
    if start_pose is not None:
        method += " + start-pose uncertainty"
    D = _unit_jacobian(fitted)
    std = np.sqrt(np.maximum(np.diag(cov_z), 0.0)) * np.abs(D)
    std_iid = np.sqrt(np.maximum(np.diag(cov_iid), 0.0)) * np.abs(D)
    loads_flat = np.zeros(d, dtype=bool)
    for k in np.flatnonzero(flat):
        loads_flat |= np.abs(Vt[k]) > 0.3
    nominal = ModelParameters.nominal()
    out = []
    for i, name in enumerate(fitted.free_names):
        p: Parameter = fitted[name]
        half, half_iid = 1.96 * std[i], 1.96 * std_iid[i]
        at_bound = bool(z[i] < 1e-3 or z[i] > 1 - 1e-3)
        reasons = []
        if at_bound:
            reasons.append("at a bound")
        if loads_flat[i]:
            reasons.append("in a flat direction of the residual Jacobian")
        if not loads_flat[i] and half > abs(p.value):
            reasons.append("95 % interval wider than the value")
        nan = float("nan")
        out.append(ParameterReport(name, p.unit, nominal.get(name, initial.value(name)), initial.value(name), p.value,
                                   p.value - half if not loads_flat[i] else nan,
                                   p.value + half if not loads_flat[i] else nan,
                                   at_bound, not reasons, "; ".join(reasons) or "identifiable",
                                   p.value - half_iid if not loads_flat[i] else nan,
                                   p.value + half_iid if not loads_flat[i] else nan))
    return Uncertainty(out, s, method)
