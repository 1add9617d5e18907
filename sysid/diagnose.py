"""The discrepancy workflow: fit, localise, try candidate effects, name one, refit, show the gap.

1. **Fit** the current model by least squares (:func:`sysid.lsq.fit_lsq`) on the training runs.
2. **Localise** the disagreement of the fitted model on training and held-out runs
   (:func:`sysid.signature.localise`).
3. **Try every candidate** of the :class:`sysid.effects.EffectLibrary`: add its parameter to the
   fitted model and refit it together with the free parameters (few iterations, starting the
   effect at the best of a small grid of values between inactive and its bounds, so that a
   limit inactive at its nominal value starts where it acts).
4. **Rank and name**: a candidate's evidence is (a) the held-out residual cost of the augmented
   model relative to the current one (hold-out validation: the held-out runs take no part in
   any fit) and (b) the Bayesian information criterion on the training residuals,
   ``dBIC = n ln(RSS_1 / RSS_0) + k ln(n)``, which charges the ``k`` added parameters. The best
   candidate by held-out improvement is named only when its held-out cost falls by at least
   ``min_improvement`` and ``dBIC < bic_threshold``; its signature match (how well the
   localisation numbers fit what the effect predicts) breaks near-ties and is reported.
   Otherwise the report says that no candidate explains the gap and describes the signature.
5. **Add it and refit** all free parameters with the effect; repeat for up to ``max_effects``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from cobra_model.parameters import ModelParameters
from cobra_model.runs import Run
from integrators.runs import simulate_like
from sysid.effects import Effect, EffectLibrary
from sysid.lsq import FitResult, fit_lsq
from sysid.objective import Objective
from sysid.report import HeldOut, gap_summary, pair_held_out
from sysid.signature import Signature, localise


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of the workflow (documented defaults).

    Attributes:
        max_effects: effects to look for, one after the other.
        fit_runs: training runs used by the fits (spread over the gaits; 0 = all).
        fit_iterations: least-squares iterations of the base and final fits.
        screen_iterations: iterations of each candidate's one-parameter refit.
        min_improvement: held-out cost reduction a named effect must bring (fraction).
        bic_threshold: dBIC below which the added parameter is worth its cost (-10: strong).
    """

    max_effects: int = 2
    fit_runs: int = 6
    fit_iterations: int = 6
    screen_iterations: int = 4
    min_improvement: float = 0.2
    bic_threshold: float = -10.0


@dataclass(frozen=True)
class Candidate:
    """One candidate's evidence."""

    name: str
    value: float
    unit: str
    held_out_improvement: float
    runs_improved: float
    delta_bic: float
    signature_match: float
    train_cost: float
    held_out_cost: float

    def to_json(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.unit,
                "held_out_improvement": self.held_out_improvement, "runs_improved": self.runs_improved,
                "delta_bic": self.delta_bic,
                "signature_match": self.signature_match, "train_cost": self.train_cost,
                "held_out_cost": self.held_out_cost}


@dataclass
class Diagnosis:
    """What the workflow found (see :meth:`to_json` for ``diagnosis.json``)."""

    effects: list[dict] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    signature: Signature | None = None
    signature_after: Signature | None = None
    held: list[HeldOut] = field(default_factory=list)
    gap_before: dict = field(default_factory=dict)
    gap_after: dict = field(default_factory=dict)
    params_before: ModelParameters | None = None
    params_after: ModelParameters | None = None
    fits: list[FitResult] = field(default_factory=list)
    seconds: float = 0.0
    verdict: str = ""

    def to_json(self) -> dict:
        return {
            "effects": self.effects,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "signature": self.signature.to_json() if self.signature else None,
            "signature_after": self.signature_after.to_json() if self.signature_after else None,
            "candidates": [[c.to_json() for c in r] for r in self.rounds],
            "verdict": self.verdict,
            "seconds": self.seconds,
        }


def signature_match(effect: Effect, sig: Signature) -> float:
    """How well the localisation numbers fit what ``effect`` predicts, in [0, 1]."""
    values = {
        "r_sign": sig.r_sign, "r_vel": sig.r_vel, "r_effort": max(sig.r_effort, 0.0),
        "reversal_ratio": float(np.tanh(max(sig.reversal_ratio - 1.0, 0.0))),
        "lag_s": float(np.clip(sig.lag_s / 0.05, 0.0, 1.0)),
        "amplitude_ratio": float(np.clip(sig.amplitude_ratio, 0.0, 1.0)),
        "head_share": sig.head_share, "sideways_share": sig.sideways_share,
        "offset_score": float(np.clip(sig.offset_score / 2.0, 0.0, 1.0)),
    }
    scores = [values[k] if sign > 0 else 1.0 - values[k] for k, sign in effect.features]
    return float(np.mean(scores))


#: Fractions of the way from an effect's inactive value to each of its bounds tried as its
#: screening start (the bound itself is not tried: there the effect is extreme).
START_FRACTIONS: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2, 0.4, 0.6, 0.8)


def start_grid(effect: Effect) -> list[float]:
    """Values of the effect's parameter tried as its screening start (see :func:`screening_start`).

    From the inactive value towards each bound that differs from it, at
    :data:`START_FRACTIONS` of the way (in unit coordinates: logarithmic for log-scaled
    parameters). A limit such as ``torque_limit``, inactive at the stall torque, is only
    active below the largest torque the gait demands, and its cost is flat above it: a start
    on the flat part never moves.
    """
    p = effect.parameter
    z0 = float(p.to_unit_interval(p.value))
    out = []
    for end in (0.0, 1.0):
        if abs(end - z0) > 1e-12:
            out += [float(p.from_unit_interval(z0 + f * (end - z0))) for f in START_FRACTIONS]
    return out


def screening_start(effect: Effect, current: ModelParameters, objective: Objective,
                    library: EffectLibrary) -> float:
    """The grid value of the effect's parameter with the lowest training cost (one batched
    evaluation, the current parameters held; values whose simulation diverges are skipped)."""
    grid = start_grid(effect)
    trial = library.transform(current, {effect.name: grid[0]})
    X = np.array([trial.with_values(**{effect.parameter.name: v}).as_vector() for v in grid])
    grid_objective = Objective(objective.runs, trial)
    try:
        costs = [float(r @ r) for r in grid_objective.residuals(X)]
    except RuntimeError:  # an extreme grid value diverged: try them one by one
        costs = [_cost_or_inf(grid_objective, x) for x in X]
    return grid[int(np.argmin(costs))]


def _cost_or_inf(objective: Objective, x: np.ndarray) -> float:
    """Sum of squared residuals at ``x``, infinite where the simulation diverges."""
    try:
        r = objective.residuals(x[None])[0]
    except RuntimeError:
        return float("inf")
    return float(r @ r)


def _spread(runs: Sequence[Run], n: int) -> list[Run]:
    """Up to ``n`` runs taken round-robin over the gait frequencies."""
    if n <= 0 or n >= len(runs):
        return list(runs)
    by_f: dict[float, list[Run]] = {}
    for r in runs:
        by_f.setdefault(float(r.meta.get("gait", {}).get("frequency_hz", 0.0)), []).append(r)
    out: list[Run] = []
    while len(out) < n:
        for lst in by_f.values():
            if lst and len(out) < n:
                out.append(lst.pop(0))
    return out


def _cost(obj: Objective, params: ModelParameters) -> tuple[float, int]:
    r = obj.residuals(params.as_vector())[0]
    return float(r @ r), r.size


def diagnose(train: Sequence[Run], holdout: Sequence[Run], *, params: ModelParameters | None = None,
             library: EffectLibrary | None = None, config: DiagnoseConfig = DiagnoseConfig(),
             progress: Callable[[str], None] = lambda msg: None) -> Diagnosis:
    """Run the workflow; ``params`` gives the starting values and which parameters are free."""
    t0 = time.perf_counter()
    library = library or EffectLibrary()
    start = params or ModelParameters.nominal()
    fit_set = _spread(train, config.fit_runs)
    result = Diagnosis()
    progress(f"fitting the current model ({', '.join(start.free_names)}) on {len(fit_set)} runs")
    base = fit_lsq(Objective(fit_set, start), max_iterations=config.fit_iterations)
    result.fits.append(base)
    current = base.params
    result.params_before = current
    sims_before = [simulate_like(r, params=current) for r in holdout]
    progress("localising the disagreement")
    train_pairs = [(r, simulate_like(r, params=current)) for r in fit_set]
    result.signature = localise(train_pairs + list(zip(holdout, sims_before)))
    remaining = list(library.names)
    for round_ in range(config.max_effects):
        train_obj = Objective(fit_set, current)
        hold_obj = Objective(list(holdout), current)
        rss0, n = _cost(train_obj, current)
        hold0_runs = hold_obj.run_costs(current.as_vector())
        hold0 = float(hold0_runs.sum())
        candidates: list[Candidate] = []
        for name in remaining:
            effect = library[name]
            progress(f"round {round_ + 1}: trying {name}")
            # the effect's parameter and the current free ones refit together: the current fit
            # has bent its parameters to mimic the missing effect, which a lone refit cannot undo
            trial = library.transform(current, {name: screening_start(effect, current, train_obj, library)})
            # from the fitted model no horizon continuation is needed: it already is in the basin
            fit = fit_lsq(Objective(fit_set, trial), max_iterations=config.screen_iterations, horizons_s=())
            augmented = fit.params
            rss1 = 2.0 * fit.cost
            hold1_runs = Objective(list(holdout), augmented).run_costs(augmented.as_vector())
            hold1 = float(hold1_runs.sum())
            k = len(trial.free_names)
            dbic = n * np.log(max(rss1, 1e-300) / max(rss0, 1e-300)) + k * np.log(n)
            candidates.append(Candidate(name, augmented.value(effect.parameter.name), effect.parameter.unit,
                                        1.0 - hold1 / hold0 if hold0 > 0 else 0.0,
                                        float(np.mean(hold1_runs < hold0_runs)), float(dbic),
                                        signature_match(effect, result.signature), rss1, hold1))
        candidates.sort(key=lambda c: c.held_out_improvement, reverse=True)
        if len(candidates) > 1 and candidates[1].held_out_improvement > 0.9 * candidates[0].held_out_improvement \
                and candidates[1].signature_match > candidates[0].signature_match:
            candidates[0], candidates[1] = candidates[1], candidates[0]
        result.rounds.append(candidates)
        best = candidates[0] if candidates else None
        if (best is None or best.held_out_improvement < config.min_improvement or best.runs_improved < 1.0
                or best.delta_bic >= config.bic_threshold):
            break
        progress(f"round {round_ + 1}: {best.name} explains the gap; refitting with it")
        effect = library[best.name]
        augmented = library.transform(current, {best.name: best.value})
        final = fit_lsq(Objective(fit_set, augmented), max_iterations=config.fit_iterations)
        result.fits.append(final)
        current = final.params
        interval = next((r for r in final.report if r.name == effect.parameter.name), None)
        result.effects.append({
            "name": best.name,
            "params": {effect.parameter.name: {"value": current.value(effect.parameter.name),
                                               "unit": effect.parameter.unit,
                                               "ci95": [interval.ci_low, interval.ci_high] if interval else None}},
            "evidence": {"held_out_cost_reduction": best.held_out_improvement,
                         "held_out_runs_improved": best.runs_improved, "delta_bic": best.delta_bic,
                         "signature_match": best.signature_match, "predicted_signature": effect.signature},
            "held_out_improvement": best.held_out_improvement,
        })
        remaining.remove(best.name)
    result.params_after = current
    sims_after = [simulate_like(r, params=current) for r in holdout]
    result.held = pair_held_out(holdout, sims_before, sims_after)
    result.gap_before, result.gap_after = gap_summary(result.held, "before"), gap_summary(result.held, "after")
    result.signature_after = localise(list(zip(holdout, sims_after)))
    if result.effects:
        names = " and ".join(e["name"] for e in result.effects)
        result.verdict = (f"missing effect{'s' if len(result.effects) > 1 else ''}: {names}; held-out final head "
                          f"error {result.gap_before['mean']['head_final_error_m']:.4f} -> "
                          f"{result.gap_after['mean']['head_final_error_m']:.4f} m")
    else:
        result.verdict = ("no candidate effect explains the gap significantly; residual signature: "
                          + result.signature.summary())
    result.seconds = time.perf_counter() - t0
    return result
