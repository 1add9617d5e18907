"""Candidate physical effects the nominal model may lack: a composable library.

In the shape of pysindy's feature libraries: an :class:`Effect` knows its name, its parameter
(unit, bounds, the value at which it is inactive and a starting value for fitting), where it
enters the simulation (:attr:`Effect.enters`, an ``integrators.simulator.Entry``: the kernel array
and slot, or the step stage, that the simulator packs it into) with the law it follows there, and
the residual signature it predicts; an
:class:`EffectLibrary` combines effects (``lib_a + lib_b``), lists them
(``get_feature_names``) and adds their parameters to a parameter set (``transform``).

Every effect is already part of the simulator (``integrators.simulator``), inactive by default:
its parameter, with the value at which it is inactive, is defined beside the physics that reads
it (``integrators.simulator.effect_parameter``), which the simulator uses when a parameter set
lacks it; adding the parameter to a :class:`ModelParameters` switches the effect on:

| effect | parameter | enters | plausible on COBRA |
| --- | --- | --- | --- |
| ``joint_coulomb_friction`` | ``joint_coulomb`` [N m] | ``-tau_c tanh(qdot / eps)`` at every joint | 0-1.5 |
| ``backlash`` | ``backlash`` [rad] | play of that half-width between the motor and the output the encoder reads | 0-0.05 |
| ``actuator_delay`` | ``actuator_delay`` [s] | commands reach the servos late (fractional ticks interpolated) | 0-0.1 |
| ``torque_saturation`` | ``torque_limit`` [N m] | motor torque clipped (voltage/current limit) | 1-9.9 |
| ``anisotropic_ground_friction`` | ``lateral_friction_ratio`` [1] | sideways friction = ratio x along-body friction | 0.5-3 |
| ``encoder_offset`` | ``encoder_offset`` [rad] | every encoder reads ``q + offset`` (the loop regulates the reading) | -0.1-0.1 |
| ``link_mass_error`` | ``link_mass_error`` [kg] | mass added to (or removed from) the head module, a payload | -0.3-1.2 |

Adding an effect that acts in the simulator's kernels touches two files: ``integrators/kernels.py``
(its parameter with unit, bounds and inactive value in ``EFFECT_PARAMETERS``, its slot in
``GROUND_PARAMETERS`` or ``ACTUATOR_PARAMETERS``, its physics in the kernel that reads the slot;
the simulator and the batch pack the arrays from those tables) and its :class:`Effect` here.

A fitted value outside the last column (the reasons are beside each :class:`Effect` below), or
on a bound, or whose 95 % interval reaches outside it on a side away from the inactive value,
is no physical value of the effect: the workflow reports it as a proxy for a structural
difference instead of naming it (``sysid.discrepancy.diagnose.choose``, and
``sysid.discrepancy.diagnose.name_one`` for the interval). A backlash
narrower than one encoder count (0.0015 rad) is not named either: the output's travel in such a
play is below what its encoder resolves, and every Dynamixel's loop, acting on whole counts, lets
its output wander by up to a count already (``Effect.resolution``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable, Iterator, Mapping

import numpy as np

from cobra_model.servo import RAD_PER_PULSE, SERVO_STALL_TORQUE_NM
from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters, Parameter
from integrators.simulator import Entry, effect_parameter, entry_of


@dataclass(frozen=True)
class Effect:
    """One candidate effect.

    Attributes:
        name: the effect's stable name (``joint_coulomb_friction``, ...).
        parameter: its main parameter; ``value`` is the inactive value.
        start: where a fit starts it (inside the bounds, where the effect acts).
        law: what it does where it enters (:attr:`enters`), in words.
        signature: the residual signature it predicts, in words.
        features: the localisation numbers (keys of :class:`sysid.discrepancy.signature.Signature`) whose
            magnitude indicates it, with a sign (+1: large is evidence, -1: small is evidence).
        bends: the parameter groups (``"actuator"``, ``"ground"``) that a fit of a model lacking
            the effect bends to mimic it; empty: any free parameter. The screening profiles the
            effect on the fitted model with just these put back to their values before the fit
            (``sysid.discrepancy.diagnose.screening_start``); an effect that names groups is
            refitted from the bent and from the unbent model apart, the lower training cost
            kept (``sysid.discrepancy.diagnose.screening_bases``).
        acts_below_demand: the parameter is a limit on the joints' motor torque [N m], which
            changes nothing above the largest torque the model demands and acts sharply just
            below it; its screening starts are placed at fractions of that demand
            (``sysid.discrepancy.diagnose.start_grid``) instead of fractions of its range.
        realistic: a realistic magnitude of the effect on COBRA (parameter units), at which the
            benchmarks and tests hide it.
        plausible: the values (parameter units) the physical effect can take on COBRA. A fit
            that needs the effect outside them, or on one of its bounds, uses it as a proxy
            for a difference of another structure (:meth:`implausible`); the workflow then
            reports a structural difference instead of naming it.
        resolution: the smallest departure from the inactive value (parameter units) that tells
            the effect from what the hardware does without it, such as a servo acting on whole
            encoder counts (None: no such floor). A fitted value closer to the inactive value is
            no evidence of the effect, whatever it does to the cost (:meth:`unresolved`); the
            workflow does not name it and checks the next candidate
            (``sysid.discrepancy.diagnose.choose``).
    """

    name: str
    parameter: Parameter
    start: float
    law: str
    signature: str
    features: tuple[tuple[str, float], ...]
    bends: tuple[str, ...] = ()
    acts_below_demand: bool = False
    plausible: tuple[float, float] | None = None
    realistic: float | None = None
    resolution: float | None = None

    @property
    def enters(self) -> Entry:
        """Where the simulator puts the effect's parameter (``Entry.read`` gives it back from a
        simulator): looked up in the simulator's own tables, so it cannot disagree with them."""
        return entry_of(self.parameter.name)

    @property
    def acts_through_drives(self) -> bool:
        """Whether the effect enters at the joints' drives (the servo loop, the motor, the
        encoders or the commands: ``Entry.stage`` ``"actuator"`` or ``"commands"``), so that it
        moves the body only through the joints' motion, which the encoders (and the motor
        currents, when logged) measure directly; a ground or body effect (``"ground"``,
        ``"model"``) moves the head path without going through them."""
        return self.enters.stage in ("actuator", "commands")

    def implausible(self, value: float, ci95: tuple[float, float] | None = None) -> str | None:
        """Why ``value`` of the effect's parameter, with its 95 % interval ``ci95`` when given,
        is not a physical value of the effect (None if it is): outside :attr:`plausible`, within
        1 % of the range (unit coordinates) of a bound other than the inactive value, where the
        fit wanted more than the bounds allow, or with an interval reaching past a plausible
        limit that the inactive value is not at or beyond.

        Physical reason for the interval: a value whose interval reaches past such a limit is
        not established as physical; the data support, as well as it, values no form of the
        effect takes. That is the mark of a proxy for a difference of another structure, which
        lands wherever it best bends the model, near a limit as readily as far out: on MuJoCo's
        isotropic ground under the compliant law, with a joint friction and a delay hidden and
        the delay named, a lateral/along ratio of 0.531 (interval [0.387, 0.676]) cut the
        held-out cost by 21 % (development seed 34). An effect that is there is pinned inside its
        range. An interval reaching past the limit at the inactive value (a friction's 0, a
        torque limit's stall torque) only says the effect may be absent, which is the
        significance tests' judgement, not this one's."""
        p = self.parameter
        unit = "" if p.unit == "1" else f" {p.unit}"
        if self.plausible is not None and not self.plausible[0] <= value <= self.plausible[1]:
            lo, hi = self.plausible
            return (f"{p.name} = {value:.4g}{unit} is outside what {self.name} physically takes on COBRA "
                    f"[{lo:g}, {hi:g}]{unit}")
        if self.plausible is not None and ci95 is not None and np.all(np.isfinite(ci95)):
            lo, hi = self.plausible
            if (ci95[0] < lo < p.value) or (ci95[1] > hi > p.value):
                return (f"{p.name} = {value:.4g}{unit}, its 95 % interval [{ci95[0]:.4g}, {ci95[1]:.4g}]{unit} "
                        f"reaching outside what {self.name} physically takes on COBRA [{lo:g}, {hi:g}]{unit}")
        z, z_off = float(p.to_unit_interval(value)), float(p.to_unit_interval(p.value))
        for bound, zb in ((p.min, 0.0), (p.max, 1.0)):
            if abs(z - zb) < 0.01 and abs(z_off - zb) > 0.01:
                return f"{p.name} = {value:.4g}{unit} is at its bound {bound:g}{unit}: the fit wanted more"
        return None

    def unresolved(self, value: float) -> str | None:
        """Why ``value`` of the effect's parameter is too close to its inactive value to be told
        from the hardware without the effect (None if it is not): within :attr:`resolution` of it."""
        p = self.parameter
        if self.resolution is None or abs(value - p.value) >= self.resolution:
            return None
        unit = "" if p.unit == "1" else f" {p.unit}"
        return (f"{p.name} = {value:.4g}{unit} is closer to none than the hardware resolves "
                f"({self.resolution:.4g}{unit})")

    def parameters(self, value: float | None = None, *, frozen: bool = False) -> list[Parameter]:
        """The effect's parameter at ``value`` (default: its fitting start), free unless ``frozen``."""
        v = self.start if value is None else float(value)
        try:
            return [replace(self.parameter, value=v, frozen=frozen)]
        except InputError as exc:
            raise InputError(f"effect {self.name}: {exc}") from None




EFFECTS: tuple[Effect, ...] = (
    Effect("joint_coulomb_friction",
           effect_parameter("joint_coulomb"),
           0.05, "a torque -tau_c tanh(qdot / 0.05 rad/s) at every joint",
           "joint residuals on all joints, correlated with sign(qdot), largest at velocity reversals",
           (("r_sign", 1.0), ("reversal_ratio", 1.0)),
           plausible=(0.0, 1.5), realistic=0.3),  # up to ~15 % of the XH540's 9.9 N m stall torque lost in its gearbox
    Effect("backlash",
           effect_parameter("backlash"),
           0.005, "the motor and the joint's output are two bodies with +-b of play between the teeth: "
                  "while it is open the output is free of the motor's torque and inertia, the motor "
                  "crosses it alone and the teeth meet in a plastic impact (integrators.kernels.gear_step)",
           "joint residuals of a few mrad while motors cross their play, the amplitude kept and no lag "
           "against the motion (the loop acts on the output's reading and takes the play up)",
           (("amplitude_ratio", 1.0), ("r_sign", -1.0)),
           plausible=(0.0, 0.05), realistic=0.02,  # ~3 deg: gear play (~0.25 deg) plus printed horn/coupling play
           # a Dynamixel's loop acts on its error in whole encoder counts: every servo lets its
           # output wander by up to a count, which our loop (on the continuous error) does not,
           # and Coulomb friction behind the loop stalls it within tau_c / Kp of the goal too; a
           # play narrower than a count is one of these, and its encoder does not resolve it
           resolution=RAD_PER_PULSE),
    Effect("actuator_delay",
           effect_parameter("actuator_delay"),
           0.005, "every servo receives its command late by the delay",
           "joint residuals proportional to -qdot (a time shift): best lag > 0",
           (("r_vel", 1.0), ("lag_s", 1.0)),
           plausible=(0.0, 0.1), realistic=0.04),  # a few cycles of a >= 20 Hz command bus
    Effect("torque_saturation",
           effect_parameter("torque_limit"),
           4.0, "the motor torque is clipped at the limit",
           "joint residuals grow with commanded effort; amplitudes fall short at the fast, loaded joints",
           (("r_effort", 1.0), ("amplitude_ratio", -1.0)),
           bends=("actuator",), acts_below_demand=True,  # bends: a weaker, more damped motor (measured)
           # below ~1 N m a pitch joint could not lift the next module (0.55 kg at 0.13 m: 0.7 N m)
           plausible=(1.0, SERVO_STALL_TORQUE_NM), realistic=2.5),
    Effect("anisotropic_ground_friction",
           effect_parameter("lateral_friction_ratio"),
           1.2, "sideways friction of every contact scaled by the ratio (along-body unchanged)",
           "head-path residual with joints matched; slip residual sideways to the body",
           (("head_share", 1.0), ("sideways_share", 1.0)),
           # surface anisotropy of smooth printed shells on isotropic ground stays within ~2-3x; the
           # modules' rolling sideways is already in the rigid-body dynamics, not in this ratio
           plausible=(0.5, 3.0), realistic=2.0),
    Effect("encoder_offset",
           effect_parameter("encoder_offset"),
           0.005, "the encoders read q + offset and the servo loop regulates the reading",
           "a constant offset of the joint residuals, independent of velocity",
           (("offset_score", 1.0),),
           plausible=(-0.1, 0.1), realistic=0.03),  # +-6 deg: a horn assembled a spline tooth off, a zero set by hand
    Effect("link_mass_error",
           effect_parameter("link_mass_error"),
           0.05, "the head module's mass (and inertia, scaled) changes by the parameter",
           "head-path residual growing over the run; joint residuals small",
           (("head_share", 1.0), ("sideways_share", -1.0)),
           plausible=(-0.3, 1.2), realistic=0.8),  # half the 0.6 kg head removed, up to two modules' mass carried
)


class EffectLibrary:
    """An ordered, composable set of effects."""

    def __init__(self, effects: Iterable[Effect] = EFFECTS):
        self.effects = tuple(effects)
        names = [e.name for e in self.effects]
        if len(set(names)) != len(names):
            raise InputError(f"duplicate effects in a library: {names}")

    def __add__(self, other: "EffectLibrary") -> "EffectLibrary":
        return EffectLibrary(self.effects + tuple(e for e in other.effects if e.name not in self.names))

    def __iter__(self) -> Iterator[Effect]:
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def help_text(self) -> str:
        """``joint_coulomb_friction [N m], backlash [rad], ...``: each effect with its value's unit."""
        return ", ".join(f"{e.name} [{e.parameter.unit}]" for e in self.effects)

    def get_feature_names(self) -> list[str]:
        """Effect names with their parameter: ``joint_coulomb_friction(joint_coulomb [N m])``."""
        return [f"{e.name}({e.parameter.name} [{e.parameter.unit}])" for e in self.effects]

    def __getitem__(self, name: str) -> Effect:
        for e in self.effects:
            if e.name == name:
                return e
        raise InputError(f"unknown effect {name!r}; known: {', '.join(self.names)}")

    def transform(self, params: ModelParameters, values: Mapping[str, float | None], *,
                  frozen: bool = False) -> ModelParameters:
        """``params`` with the named effects' parameters added (value None: the fitting start)."""
        extra: list[Parameter] = []
        for name, value in values.items():
            extra += self[name].parameters(value, frozen=frozen)
        return params.with_parameters(extra)


def parse_effects(text: Iterable[str], library: EffectLibrary | None = None) -> dict[str, float]:
    """``NAME=VALUE[,NAME=VALUE]`` strings (the CLI's ``--effect``) to {effect: value}."""
    lib = library or EffectLibrary()
    out: dict[str, float] = {}
    for chunk in text:
        for item in filter(None, (s.strip() for s in chunk.split(","))):
            name, sep, value = item.partition("=")
            if not sep:
                raise InputError(f"--effect {item!r}: expected NAME=VALUE, e.g. joint_coulomb_friction=0.2")
            lib[name.strip()]
            try:
                out[name.strip()] = float(value)
            except ValueError:
                raise InputError(f"--effect {item!r}: VALUE must be a number in SI units") from None
    return out
