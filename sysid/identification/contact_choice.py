"""Choosing the contact law on held-out runs: fit each law, keep the one that predicts best.

A robot's ground contact differs from any model in structure, not only in parameter values
(``docs/model.md``). The simulator offers three contact laws (``ModelParameters.contact_law``): the
compliant ground (a spring-damper normal force with the paper's Coulomb/Stribeck friction on it)
and the soft-constraint law (a contact is a constraint whose approach, penetration and slip relax
with a time constant, all contacts solved together: MuJoCo's) with friction on a pyramid's edges
(``soft_constraint``, MuJoCo's default) or in an elliptic cone (``soft_elliptic``). No parameter
of one law reproduces another (``benchmarks/results/contact_law.md``; a diamond-shaped friction
limit is not a round one), so the
choice is between models, made the way such choices are: each law is fitted on the training
runs with its own ground parameters free (:data:`LAW_FREE`), and the law whose fit has the lower
cost on runs the fits did not see is kept.

Each law is fitted from several shapes of the module ends (:data:`ROUNDING_STARTS_M`), keeping
the fit with the lowest training cost: the ends' rounding moves every contact point along its
module (from the rim of the end circle to the rounded cap), which changes the lever arms of all
ground forces at once, so the cost has a basin per shape and a local fit can stay in the one it
starts in (on MuJoCo's runs the soft-constraint law's fits end within 1.5 cm of their starting
rounding, from 0, 2.25 and 4.5 cm alike; the compliant law's mostly reach 4.5 cm from any start).

A soft law's fit also starts from both ends of the ground's stiffness (:func:`stiffness_starts`):
a soft ground (its time constant's nominal 20 ms, MuJoCo's default) and the stiffest the law
represents (the lower bound, 2 ms). A softer ground sinks the body and moves its contacts as a
sharper end does, so stiffness and shape trade off in a curved valley, and on a stiff ground the
head path over seconds makes the cost rough along it (on MuJoCo's 2 ms runs, dev seed 5, the
training cost along the time constant alone went 46, 33, 58 from 5.2 to 4.5 to 4 ms): a fit
from 20 ms stopped at 8-10 ms whatever its rounding (joints 1.3-1.5 mrad), one from 2 ms at
4.5 cm reached 2.4 ms (joints 0.56-0.66 mrad). Which starts earn a whole-run fit is screened on
the first horizon of the fit's continuation (:data:`SCREEN_HORIZON_S`, where the residuals are
nearly linear in the parameters): every start is fitted there, and only the
:data:`WHOLE_RUN_FITS` lowest go on, so the whole-run fits stay as many as the shapes (on the
same dev cases the screen's order put the basin that the whole fits found best first: stiff
0.84 against 2.7-11, twin 0.97 against 2.1-24).
"""
from __future__ import annotations

import time
from collections.abc import Generator
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

from cobra_model import design
from cobra_model.errors import InputError
from cobra_model.parameters import CONTACT_LAWS, ModelParameters
from cobra_model.run import Run
from integrators.kernels import CONTACT_LAW_PARAMETERS, SOFT_LAWS
from integrators.simulator import SimulationDiverged
from sysid.identification.executor import Executor, LocalExecutor
from sysid.identification.lockstep import Steps, run_together, unless_diverged
from sysid.identification.lsq import DEFAULT_HORIZONS_S, FitResult, fit_lsq_steps
from sysid.identification.objective import Objective, Weights

#: Free parameters of each law's base fit: the actuator's damping and motor constant, and the
#: nominal table's ground parameters the law reads (:data:`integrators.kernels.CONTACT_LAW_PARAMETERS`;
#: the soft-constraint law has no normal spring, Stribeck or viscous term and its friction limit is
#: the pyramid; its time constant replaces them).
LAW_FREE: dict[str, tuple[str, ...]] = {
    law: ("joint_damping", "motor_km", *(n for n in reads if n in ModelParameters.nominal()))
    for law, reads in CONTACT_LAW_PARAMETERS.items()
}


#: Starting values of ``contact_rounding`` [m] each law's fit runs from: sharp module ends, half
#: and fully rounded (the module radius, the parameter's upper bound).
ROUNDING_STARTS_M: tuple[float, ...] = (0.0, design.MODULE_RADIUS_M / 2, design.MODULE_RADIUS_M)


def unread_by_law(params: ModelParameters, names: Sequence[str]) -> list[str]:
    """Those of ``names`` that are ground parameters ``params``' contact law does not read."""
    ground = {n for reads in CONTACT_LAW_PARAMETERS.values() for n in reads}
    return [n for n in names if n in ground and n not in CONTACT_LAW_PARAMETERS[params.contact_law]]


def free_for_law(params: ModelParameters) -> tuple[ModelParameters, str | None]:
    """``params`` with its free set fitted to its contact law, and a line saying what changed
    (None if nothing did): free ground parameters the law does not read are frozen (no data can
    move them), and under a soft-constraint law ``contact_time_constant`` is freed, since it is
    that law's normal stiffness and damping as ``k1`` and ``k2`` are the compliant ground's."""
    frozen = unread_by_law(params, params.free_names)
    freed = ["contact_time_constant"] if (params.contact_law in SOFT_LAWS
                                          and "contact_time_constant" not in params.free_names) else []
    if not frozen and not freed:
        return params, None
    adapted = params.with_frozen(frozen=frozen, free=[n for n in params.free_names if n not in frozen] + freed)
    parts = ([f"{', '.join(frozen)} do not enter it (frozen)"] if frozen else []) + \
            ([f"{', '.join(freed)} freed (its normal stiffness and damping)"] if freed else [])
    return adapted, f"{params.contact_law} contact law: {'; '.join(parts)}"


def nominal_start(law: str, free: Sequence[str]) -> ModelParameters:
    """The nominal parameters under contact ``law`` with ``free`` free, then fitted to the law by
    :func:`free_for_law` (as ``cobra diagnose --contact``): the benchmarks' start of every fit."""
    return free_for_law(ModelParameters.nominal().with_contact_law(law).with_frozen(free=list(free)))[0]


#: Whole-run fits at most per law: the starts with the lowest cost after :data:`SCREEN_HORIZON_S`
#: go on (as many as the shapes of the ends, so a second stiffness adds only screening).
WHOLE_RUN_FITS = len(ROUNDING_STARTS_M)

#: Horizon [s] on which every start is fitted first, to rank them: the first stage of
#: :func:`sysid.identification.lsq.fit_lsq`'s continuation.
SCREEN_HORIZON_S = DEFAULT_HORIZONS_S[0]


#: The ground parameters whose cost has a basin per value range, so that a fit starts from
#: several of their values (:func:`fit_starts`): the ends' shape and the ground's stiffness.
BASIN_PARAMETERS: tuple[str, ...] = ("contact_rounding", "contact_time_constant")


def stiffness_starts(params: ModelParameters) -> tuple[float, ...]:
    """The ``contact_time_constant`` values [s] a fit of ``params`` starts from: its own value (the
    nominal 20 ms: a soft ground) and the law's stiffest (the parameter's lower bound) when it is
    free; none when it is frozen (module docstring)."""
    if "contact_time_constant" not in params.free_names:
        return ()
    own, stiffest = float(params.contact_time_constant), float(params["contact_time_constant"].min)
    return (own, stiffest) if own != stiffest else (own,)


def shape_starts(params: ModelParameters, rounding_starts: Sequence[float] = ROUNDING_STARTS_M) -> tuple[float, ...]:
    """The ``contact_rounding`` values [m] a fit of ``params`` starts from: ``rounding_starts``
    when ``contact_rounding`` is free, none (one fit from ``params`` itself) when it is frozen."""
    return tuple(rounding_starts) if "contact_rounding" in params.free_names else ()


def fit_starts(params: ModelParameters, rounding_starts: Sequence[float] = ROUNDING_STARTS_M) -> list[dict[str, float]]:
    """The starting values a fit of ``params`` runs from: every shape of the ends
    (:func:`shape_starts`) with every stiffness (:func:`stiffness_starts`), stiffness outermost;
    one empty start (``params`` itself) when neither is free."""
    shapes = [{"contact_rounding": r} for r in shape_starts(params, rounding_starts)] or [{}]
    stiffnesses = [{"contact_time_constant": tc} for tc in stiffness_starts(params)] or [{}]
    return [{**tc, **r} for tc in stiffnesses for r in shapes]


def fit_count(params: ModelParameters, rounding_starts: Sequence[float] = ROUNDING_STARTS_M) -> int:
    """How many fits :func:`fit_from_shapes` runs at most for ``params`` (screens and whole-run fits)."""
    n = len(fit_starts(params, rounding_starts))
    return n + WHOLE_RUN_FITS if n > WHOLE_RUN_FITS else n


def describe_start(values: Mapping[str, float]) -> str:
    """``contact_time_constant 0.002 s, contact_rounding 0.045 m`` (one of :func:`fit_starts`), or
    ``its own start`` for the empty one."""
    units = {"contact_rounding": "m", "contact_time_constant": "s"}
    return ", ".join(f"{n} {v:g} {units[n]}" for n, v in values.items()) or "its own start"


@dataclass(frozen=True)
class StartFit:
    """One start of :func:`fit_from_shapes`: its starting ``values``, its cost after the screen
    on the first :data:`SCREEN_HORIZON_S` (None when not screened) and its whole-run training
    cost (None when the screen did not keep it); ``diverged``: a simulation its fit asked for
    diverged, and the start was left out."""

    values: Mapping[str, float]
    screen_cost: float | None
    cost: float | None
    diverged: bool = False

    def to_json(self) -> dict:
        return {**self.values, "screen_cost": self.screen_cost, "train_cost": self.cost, "diverged": self.diverged}

    def describe(self) -> str:
        """The start's values (:func:`describe_start`)."""
        return describe_start(self.values)


@dataclass(frozen=True)
class ShapeFits:
    """The fit with the lowest training cost over the starts, every start's screen and whole-run
    cost, and the wall time [s] of all its fits."""

    best: FitResult
    starts: tuple[StartFit, ...]
    seconds: float


def fit_each(fit: Callable[[Objective], FitResult | Steps[FitResult]], objectives: Sequence[Objective]
             ) -> list[FitResult | None]:
    """``fit`` of each objective, None for one whose simulation diverged (a start no simulation
    follows: the others go on). Where ``fit`` returns a computation
    (:func:`sysid.identification.lsq.fit_lsq_steps`) rather than a result, the fits run
    together (:func:`sysid.identification.lockstep.run_together`: their evaluations share
    batches, their results bit-for-bit those of one after the other)."""
    out: list = []
    for o in objectives:
        try:
            out.append(fit(o))
        except SimulationDiverged:
            out.append(None)
    steps = [k for k, r in enumerate(out) if isinstance(r, Generator)]
    for k, result in zip(steps, run_together([unless_diverged(out[k]) for k in steps])):
        out[k] = result
    return out


def fit_from_shapes(objective: Objective, fit: Callable[[Objective], FitResult | Steps[FitResult]] = fit_lsq_steps,
                    rounding_starts: Sequence[float] = ROUNDING_STARTS_M, label: str = "fitting",
                    progress: Callable[[str], None] | None = None,
                    whole_run_fits: int = WHOLE_RUN_FITS) -> ShapeFits:
    """``fit`` of ``objective`` from each of its starts (:func:`fit_starts`: the shapes of the
    module ends and, under a soft law, a soft and a stiff ground), the lowest training cost kept;
    one fit from its own start when neither shape nor stiffness is free. A start whose fit asks
    for a simulation that diverges is left out (``StartFit.diverged``); only when every start's
    does is that an error.

    With more starts than ``whole_run_fits``, each is first fitted on the runs' first
    :data:`SCREEN_HORIZON_S` and only the ``whole_run_fits`` lowest of those go on, each from
    where its screen ended (module docstring: why several starts, why the screen). A ``fit``
    that returns computations (the default) runs the screens together, then the whole-run
    fits together (:func:`fit_each`). ``progress`` gets ``label`` and the starts.
    """
    t0 = time.perf_counter()
    start = objective.params
    starts = fit_starts(start, rounding_starts)
    screen = len(starts) > whole_run_fits and objective.longest_run_s > SCREEN_HORIZON_S
    screened: list[FitResult | None] = [None] * len(starts)
    if screen:
        if progress is not None:
            progress(f"{label}: screening the starts {'; '.join(map(describe_start, starts))} on the first "
                     f"{SCREEN_HORIZON_S:g} s")
        screened = fit_each(fit, [objective.with_params(start.with_values(**values)).truncated(SCREEN_HORIZON_S)
                                  for values in starts])
        kept = sorted(sorted((k for k in range(len(starts)) if screened[k] is not None),
                             key=lambda k: screened[k].cost)[:whole_run_fits])
    else:
        kept = list(range(len(starts)))
    if progress is not None:
        progress(f"{label} from {'; '.join(describe_start(starts[k]) for k in kept)}")
    whole = dict(zip(kept, fit_each(fit, [objective.with_params(screened[k].params if screened[k] is not None
                                                                else start.with_values(**starts[k]))
                                          for k in kept])))
    diverged = [(screen and screened[k] is None) or (k in whole and whole[k] is None) for k in range(len(starts))]
    records = tuple(StartFit(values, screened[k].cost if screened[k] is not None else None,
                             whole[k].cost if whole.get(k) is not None else None, diverged[k])
                    for k, values in enumerate(starts))
    fits = [r for r in whole.values() if r is not None]
    if not fits:
        raise SimulationDiverged(f"{label}: the simulation diverged from every start "
                                 f"({'; '.join(map(describe_start, starts))})")
    if any(diverged) and progress is not None:
        progress(f"{label}: the simulation diverged from "
                 f"{'; '.join(describe_start(v) for v, d in zip(starts, diverged) if d)}; that start left out")
    return ShapeFits(min(fits, key=lambda r: r.cost), records, time.perf_counter() - t0)


@dataclass(frozen=True)
class LawFit:
    """One contact law's fit (its parameters carry the law; the lowest training cost over the
    starts), its cost on the held-out runs (the objective's, same weights), each start's screen
    and training cost (:class:`StartFit`) and the seconds of all its starts' fits."""

    law: str
    fit: FitResult
    held_out_cost: float
    starts: tuple[StartFit, ...]
    seconds: float

    def to_json(self) -> dict:
        return {"law": self.law, "held_out_cost": self.held_out_cost, "train_cost": self.fit.cost,
                "starts": [s.to_json() for s in self.starts],
                "status": self.fit.status.value, "seconds": self.fit.seconds, "seconds_all_starts": self.seconds,
                "params": {n: self.fit.params.value(n) for n in self.fit.params.free_names}}


@dataclass(frozen=True)
class ContactChoice:
    """Every law's fit and the chosen law (the lowest held-out cost)."""

    fits: tuple[LawFit, ...]
    chosen: str

    @property
    def best(self) -> LawFit:
        """The chosen law's fit."""
        return self.fit_of(self.chosen)

    def fit_of(self, law: str) -> LawFit:
        """The fit of contact law ``law``.

        Raises:
            InputError: when ``law`` was not fitted, naming the laws that were.
        """
        for f in self.fits:
            if f.law == law:
                return f
        raise InputError(f"no fit of the {law!r} contact law here; fitted: {', '.join(f.law for f in self.fits)}")

    def to_json(self) -> dict:
        return {"chosen": self.chosen, "fits": [f.to_json() for f in self.fits]}


def choose_contact_law(train: Sequence[Run], held_out: Sequence[Run], start: ModelParameters | None = None, *,
                       laws: Sequence[str] = CONTACT_LAWS, weights: Weights | None = None,
                       rounding_starts: Sequence[float] = ROUNDING_STARTS_M,
                       fit: Callable[[Objective], FitResult | Steps[FitResult]] = fit_lsq_steps,
                       starts: Mapping[str, ModelParameters] | None = None, executor: Executor | None = None,
                       progress: Callable[[str], None] | None = None,
                       whole_run_fits: int = WHOLE_RUN_FITS) -> ContactChoice:
    """Fit each contact law on ``train`` and choose the one with the lowest cost on ``held_out``.

    Args:
        train: the runs every law is fitted on.
        held_out: runs no fit sees, which decide (not the runs a result is then judged on).
        start: the starting parameters (default nominal); each law frees :data:`LAW_FREE`.
        laws: the laws to try (default all of :data:`cobra_model.parameters.CONTACT_LAWS`).
        weights: the objective's weights for fitting and choosing.
        rounding_starts: the ``contact_rounding`` values [m] each law's fit starts from, a soft
            law's from a soft and a stiff ground each (:func:`fit_from_shapes`; the lowest
            training cost is kept).
        fit: the fitting method (default least squares with its defaults, each start's fits
            together: :func:`fit_from_shapes`).
        starts: per law, its starting parameters with their free set (overriding ``start`` and
            :data:`LAW_FREE` for that law; ``cobra fit --contact choose`` passes the free set
            the data check left each law).
        executor: where the objectives' evaluations run (default in-process).
        progress: called with a line per law.
        whole_run_fits: per law, the screened starts that go on to a whole-run fit.

    Raises:
        InputError: without held-out runs, naming an unknown law, or without rounding starts.
    """
    if not held_out:
        raise InputError("choosing a contact law needs held-out runs that no fit sees (none given)")
    unknown = [law for law in laws if law not in LAW_FREE]
    if unknown or not laws:
        raise InputError(f"unknown contact law(s) {unknown}; known: {', '.join(LAW_FREE)}")
    if not rounding_starts:
        raise InputError("rounding_starts: give at least one starting contact_rounding [m]")
    start = start if start is not None else ModelParameters.nominal()
    weights = weights if weights is not None else Weights()
    executor = executor if executor is not None else LocalExecutor(1)
    fits = []
    for law in laws:
        law_start = (starts[law] if starts is not None and law in starts
                     else start.with_contact_law(law).with_frozen(free=LAW_FREE[law]))
        if law_start.contact_law != law:
            raise InputError(f"starts[{law!r}] is under the {law_start.contact_law} contact law")
        shapes = fit_from_shapes(Objective(train, law_start, weights, executor=executor), fit, rounding_starts,
                                 f"fitting the {law} contact law ({len(law_start.free_names)} free parameters)",
                                 progress, whole_run_fits)
        result = shapes.best
        held = Objective(held_out, result.params, weights, executor=executor)(result.params.as_vector())
        fits.append(LawFit(law, result, float(held), shapes.starts, shapes.seconds))
        if progress is not None:
            progress(f"  {law}: training cost {result.cost:.4g}, held-out cost {held:.4g}")
    chosen = min(fits, key=lambda f: f.held_out_cost).law
    return ContactChoice(tuple(fits), chosen)
