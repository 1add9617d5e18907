"""Choosing the contact law on held-out runs: fit each law, keep the one that predicts best.

A robot's ground contact differs from any model in structure, not only in parameter values
(``docs/model.md``). The simulator offers two contact laws (``SimSettings.contact``): the
compliant ground (a spring-damper normal force with the paper's Coulomb/Stribeck friction on it)
and the soft-constraint law (a contact is a constraint whose approach, penetration and slip relax
with a time constant, friction on a pyramid's edges, all contacts solved together: MuJoCo's).
No parameter of one law reproduces the other (``benchmarks/results/contact_law.md``), so the
choice is between models, made the way such choices are: each law is fitted on the training
runs with its own ground parameters free (:data:`LAW_FREE`), and the law whose fit has the lower
cost on runs the fits did not see is kept.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from cobra_model.run import Run
from integrators.simulator import CONTACT_LAWS, SimSettings
from sysid.identification.lsq import FitResult, fit_lsq
from sysid.identification.objective import Objective, Weights

#: Free parameters of each law's base fit: the actuator's damping and motor constant, and the
#: ground parameters the law reads (the soft-constraint law has no normal spring, Stribeck or
#: viscous term and its friction limit is the pyramid; its time constant replaces them).
LAW_FREE: dict[str, tuple[str, ...]] = {
    "compliant": ("joint_damping", "motor_km", "k1", "k2", "mu_c", "mu_s", "mu_v", "v_s", "friction_cone",
                  "contact_rounding"),
    "soft_constraint": ("joint_damping", "motor_km", "mu_c", "contact_time_constant", "contact_rounding"),
}


@dataclass(frozen=True)
class LawFit:
    """One contact law's fit and its cost on the held-out runs (the objective's, same weights)."""

    law: str
    fit: FitResult
    held_out_cost: float

    def to_json(self) -> dict:
        return {"law": self.law, "held_out_cost": self.held_out_cost, "train_cost": self.fit.cost,
                "status": self.fit.status.value, "seconds": self.fit.seconds,
                "params": {n: self.fit.params.value(n) for n in self.fit.params.free_names}}


@dataclass(frozen=True)
class ContactChoice:
    """Every law's fit and the chosen law (the lowest held-out cost)."""

    fits: tuple[LawFit, ...]
    chosen: str

    @property
    def best(self) -> LawFit:
        """The chosen law's fit."""
        return next(f for f in self.fits if f.law == self.chosen)

    @property
    def settings(self) -> SimSettings:
        """Simulator settings with the chosen law."""
        return SimSettings(contact=self.chosen)

    def to_json(self) -> dict:
        return {"chosen": self.chosen, "fits": [f.to_json() for f in self.fits]}


def choose_contact_law(train: Sequence[Run], held_out: Sequence[Run], start: ModelParameters | None = None, *,
                       laws: Sequence[str] = CONTACT_LAWS, weights: Weights | None = None,
                       fit: Callable[[Objective], FitResult] = fit_lsq,
                       progress: Callable[[str], None] | None = None) -> ContactChoice:
    """Fit each contact law on ``train`` and choose the one with the lowest cost on ``held_out``.

    Args:
        train: the runs every law is fitted on.
        held_out: runs no fit sees, which decide (not the runs a result is then judged on).
        start: the starting parameters (default nominal); each law frees :data:`LAW_FREE`.
        laws: the laws to try (default all of :data:`integrators.simulator.CONTACT_LAWS`).
        weights: the objective's weights for fitting and choosing.
        fit: the fitting method (default least squares with its defaults).
        progress: called with a line per law.

    Raises:
        InputError: without held-out runs, or naming an unknown law.
    """
    if not held_out:
        raise InputError("choosing a contact law needs held-out runs that no fit sees (none given)")
    unknown = [law for law in laws if law not in LAW_FREE]
    if unknown or not laws:
        raise InputError(f"unknown contact law(s) {unknown}; known: {', '.join(LAW_FREE)}")
    start = start if start is not None else ModelParameters.nominal()
    weights = weights if weights is not None else Weights()
    fits = []
    for law in laws:
        settings = SimSettings(contact=law)
        if progress is not None:
            progress(f"fitting the {law} contact law ({len(LAW_FREE[law])} free parameters)")
        result = fit(Objective(train, start.with_frozen(free=LAW_FREE[law]), weights, settings=settings))
        held = Objective(held_out, result.params, weights, settings=settings)(result.params.as_vector())
        fits.append(LawFit(law, result, float(held)))
        if progress is not None:
            progress(f"  {law}: training cost {result.cost:.4g}, held-out cost {held:.4g}")
    chosen = min(fits, key=lambda f: f.held_out_cost).law
    return ContactChoice(tuple(fits), chosen)
