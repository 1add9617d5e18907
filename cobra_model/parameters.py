"""The one parameter vector every identification method tunes.

A :class:`Parameter` is an object (name, unit, value, bounds, frozen flag, log scaling) and a
:class:`ModelParameters` is an ordered, immutable set of them that turns into and back from a
flat vector (``as_vector`` / ``update_from_vector`` / ``bounds``), in the shape of MuJoCo's
``sysid`` parameters.

Adding a parameter touches one place: append a :class:`Parameter` to :data:`NOMINAL` (and use
it where it enters the physics). Actuator parameters are shared by all joints by default;
``with_per_joint("armature")`` replaces the shared one by ``armature_1`` .. ``armature_11``
and :meth:`ModelParameters.per_joint` returns the (11,) array either way.

Nominal actuator values follow the XH540-W270 datasheet at 12 V: from the stall torque
``tau_s = 9.9 N m`` and no-load speed ``w0 = 39 rpm = 4.084 rad/s`` of the DC-motor model
``tau = r Km (V - r Km qdot) / R`` one gets ``r Km = V / w0 = 2.938 N m/A`` at the joint, so
``Km = 2.938 / 272.5 = 0.01078 N m/A`` at the motor, and ``R = r Km V / tau_s = 3.561 Ohm``.
The resistance is held fixed (:data:`WINDING_RESISTANCE_OHM`); ``motor_km`` is tuned.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from cobra_model import design, servo
from cobra_model.errors import InputError

PARAMS_FORMAT = "cobra-params/1"

#: r * Km at the joint [N m/A] = V / no-load speed (datasheet derivation, see module docstring).
JOINT_TORQUE_CONSTANT_NM_A = servo.SUPPLY_VOLTAGE_V / servo.SERVO_NO_LOAD_SPEED_RAD_S
#: Motor torque constant at the motor shaft [N m/A] (datasheet derivation).
NOMINAL_MOTOR_KM = JOINT_TORQUE_CONSTANT_NM_A / servo.SERVO_GEAR_RATIO
#: Winding resistance [Ohm] from the stall point (datasheet derivation); not tuned.
WINDING_RESISTANCE_OHM = JOINT_TORQUE_CONSTANT_NM_A * servo.SUPPLY_VOLTAGE_V / servo.SERVO_STALL_TORQUE_NM


@dataclass(frozen=True)
class Parameter:
    """One tunable physical parameter.

    Attributes:
        name: stable identifier used in parameter files and ``--free``/``--frozen``.
        unit: SI unit string.
        value: current value in ``unit``.
        min, max: physical bounds (inclusive).
        frozen: held fixed by every identification method when True.
        log_scale: optimisers work on ``log(value)`` (for parameters spanning decades).
        group: ``"actuator"`` (internal dynamics), ``"ground"`` (external) or an effect name.
        doc: one-line meaning.
    """

    name: str
    unit: str
    value: float
    min: float
    max: float
    frozen: bool = False
    log_scale: bool = False
    group: str = "actuator"
    doc: str = ""

    def __post_init__(self) -> None:
        if not (self.min <= self.max):
            raise InputError(f"parameter {self.name!r}: min {self.min} > max {self.max}")
        if self.log_scale and self.min <= 0:
            raise InputError(f"parameter {self.name!r}: log-scaled but min {self.min} <= 0")
        if not (math.isfinite(self.value) and self.min <= self.value <= self.max):
            raise InputError(
                f"parameter {self.name!r} = {self.value} {self.unit} is outside its bounds "
                f"[{self.min}, {self.max}]"
            )

    def to_unit_interval(self, value: float | np.ndarray) -> float | np.ndarray:
        """Map a value to [0, 1] across the bounds (in log space when ``log_scale``)."""
        if self.log_scale:
            lo, hi = math.log(self.min), math.log(self.max)
            return (np.log(value) - lo) / (hi - lo)
        return (np.asarray(value) - self.min) / (self.max - self.min)

    def from_unit_interval(self, x: float | np.ndarray) -> float | np.ndarray:
        """Inverse of :meth:`to_unit_interval`; ``x`` in [0, 1] gives a value within the bounds
        (``exp(log(max))`` can round one ulp above ``max``: the result is clipped to them)."""
        if self.log_scale:
            lo, hi = math.log(self.min), math.log(self.max)
            value = np.exp(lo + np.asarray(x) * (hi - lo))
        else:
            value = self.min + np.asarray(x) * (self.max - self.min)
        return np.clip(value, self.min, self.max)


#: Relative round-off (of ``mu_c``) by which unit coordinates on the edge ``mu_s = mu_c`` may map
#: to ``mu_s < mu_c``; :meth:`ModelParameters.from_unit` closes such a gap.
EDGE_RTOL = 1e-12

#: Nominal parameter set: the single table of what can be tuned.
NOMINAL: tuple[Parameter, ...] = (
    Parameter("armature", "kg m^2", 0.03, 1e-4, 0.5, log_scale=True, group="actuator",
              doc="transmission (reflected rotor) inertia at the joint"),
    Parameter("joint_damping", "N m s/rad", 0.1, 1e-4, 5.0, log_scale=True, group="actuator",
              doc="internal viscous damping of the gearbox at the joint"),
    Parameter("motor_km", "N m/A", NOMINAL_MOTOR_KM, 0.003, 0.03, log_scale=True, group="actuator",
              doc="DC-motor torque constant at the motor shaft (back-EMF constant in V s/rad)"),
    Parameter("k1", "N/m", 1.0e4, 1.0e3, 5.0e4, log_scale=True, group="ground",
              doc="ground normal stiffness per contact point"),
    Parameter("k2", "N s/m", 30.0, 1.0, 200.0, log_scale=True, group="ground",
              doc="ground normal damping per contact point"),
    Parameter("mu_c", "1", 0.3, 0.02, 1.5, group="ground",
              doc="Coulomb (kinetic) friction coefficient"),
    Parameter("mu_s", "1", 0.45, 0.02, 2.0, group="ground",
              doc="static friction coefficient (>= mu_c)"),
    Parameter("mu_v", "N s/m", 0.5, 1e-3, 20.0, log_scale=True, group="ground",
              doc="viscous friction coefficient per contact point"),
    Parameter("v_s", "m/s", 0.05, 0.005, 0.5, log_scale=True, group="ground",
              doc="Stribeck velocity"),
    Parameter("friction_cone", "1", 0.0, 0.0, 0.95, frozen=True, group="ground",
              doc="shape of the sliding-friction limit: 0 per-axis box (the paper's law), "
                  "0.5 isotropic circle, toward 1 the diamond of a pyramidal cone"),
    Parameter("contact_time_constant", "s", 0.02, 0.002, 0.1, log_scale=True, frozen=True, group="ground",
              doc="time constant of the soft-constraint contact law (SimSettings(contact=\"soft_constraint\") "
                  "only; MuJoCo's solref[0]): how fast a contact's approach, penetration and slip relax"),
    Parameter("contact_rounding", "m", 0.0, 0.0, design.MODULE_RADIUS_M, frozen=True, group="ground",
              doc="edge radius of the modules' ends where they touch the ground: 0 sharp "
                  "cylinder rim, the module radius a hemispherical (capsule) end"),
)

_NOMINAL_BY_NAME: dict[str, Parameter] = {p.name: p for p in NOMINAL}

#: The ground-contact laws a model can have (``integrators.simulator`` implements them):
#: ``compliant``, a spring-damper normal force with Coulomb/static/viscous (Stribeck) friction on
#: it, ``soft_constraint``, MuJoCo's soft constraint on the friction pyramid's edges (its default
#: cone), and ``soft_elliptic``, the same constraint on MuJoCo's elliptic friction cone. The law is
#: part of the model's structure: a parameter set carries it (:attr:`ModelParameters.contact_law`),
#: because its ground values mean something only under that law.
CONTACT_LAWS: tuple[str, ...] = ("compliant", "soft_constraint", "soft_elliptic")

#: How the compliant ground's friction enters the step, with the speed its sign is regularised at:
#: ``explicit``, at the step's start velocity with the sign at 1 cm/s (faithful to the Stribeck
#: curve above 2.65 cm/s), or ``implicit``, at the step's end slip with the sign at 1 mm/s
#: (faithful above 2.65 mm/s; ``integrators.kernels.implicit_friction_acceleration``). Like the
#: contact law it is part of the model a parameter set was fitted with
#: (:attr:`ModelParameters.friction_step`): below the faithful speed the two ground models creep
#: and stick differently. The soft-constraint laws have no regularised sign and ignore it.
FRICTION_STEPS: tuple[str, ...] = ("explicit", "implicit")

#: Parameters that may be expanded to one value per joint.
PER_JOINT_CAPABLE: tuple[str, ...] = ("armature", "joint_damping", "motor_km")


class ModelParameters:
    """An ordered, immutable set of :class:`Parameter` objects.

    Values are read by name as attributes (``p.mu_c``) or with :meth:`value`; vectors contain
    only the free (not frozen) parameters, in table order. :attr:`contact_law` is the ground-contact
    law (one of :data:`CONTACT_LAWS`) the values belong to and :attr:`friction_step` how the
    compliant ground's friction is stepped (one of :data:`FRICTION_STEPS`); every derived set
    keeps both.

    Raises:
        InputError: for duplicate names, ``mu_s < mu_c``, an unknown contact law or friction step.
    """

    __slots__ = ("_params", "_index", "contact_law", "friction_step")

    def __init__(self, params: Iterable[Parameter], contact_law: str = "compliant", friction_step: str = "explicit"):
        if contact_law not in CONTACT_LAWS:
            raise InputError(f"contact law must be one of {', '.join(CONTACT_LAWS)}, got {contact_law!r}")
        if friction_step not in FRICTION_STEPS:
            raise InputError(f"friction step must be one of {', '.join(FRICTION_STEPS)}, got {friction_step!r}")
        object.__setattr__(self, "contact_law", contact_law)
        object.__setattr__(self, "friction_step", friction_step)
        object.__setattr__(self, "_params", tuple(params))
        index = {p.name: i for i, p in enumerate(self._params)}
        if len(index) != len(self._params):
            raise InputError("duplicate parameter names in " + ", ".join(p.name for p in self._params))
        object.__setattr__(self, "_index", index)
        self._check_relations()

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def nominal(cls) -> "ModelParameters":
        """The nominal COBRA parameters (datasheet-derived actuator, estimated ground)."""
        return cls(NOMINAL)

    def _check_relations(self) -> None:
        if "mu_s" in self._index and "mu_c" in self._index and self.value("mu_s") < self.value("mu_c"):
            raise InputError(
                f"parameter 'mu_s' = {self.value('mu_s')} must be >= 'mu_c' = {self.value('mu_c')} "
                "(static friction is at least the Coulomb friction)"
            )

    # -- access -----------------------------------------------------------------------------
    def __getattr__(self, name: str) -> float:
        index = object.__getattribute__(self, "_index")
        if name in index:
            return object.__getattribute__(self, "_params")[index[name]].value
        raise AttributeError(name)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("ModelParameters is immutable; use with_values()")

    def __reduce__(self) -> tuple:
        """Pickle as the constructor call (for process and Ray executors)."""
        return (ModelParameters, (self._params, self.contact_law, self.friction_step))

    def __iter__(self) -> Iterator[Parameter]:
        return iter(self._params)

    def __len__(self) -> int:
        return len(self._params)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, ModelParameters) and self._params == other._params
                and self.contact_law == other.contact_law and self.friction_step == other.friction_step)

    def __hash__(self) -> int:
        return hash((self._params, self.contact_law, self.friction_step))

    def __repr__(self) -> str:
        inner = ", ".join(f"{p.name}={p.value:.6g}" for p in self._params)
        return f"ModelParameters({inner}, contact_law={self.contact_law!r}, friction_step={self.friction_step!r})"

    def __getitem__(self, name: str) -> Parameter:
        try:
            return self._params[self._index[name]]
        except KeyError:
            raise InputError(
                f"unknown parameter {name!r}; known: {', '.join(self.names)}"
            ) from None

    @property
    def names(self) -> tuple[str, ...]:
        """All parameter names in table order."""
        return tuple(p.name for p in self._params)

    @property
    def free_names(self) -> tuple[str, ...]:
        """Names of the parameters that are not frozen, in table order."""
        return tuple(p.name for p in self._params if not p.frozen)

    def value(self, name: str) -> float:
        """Value of parameter ``name`` in its unit."""
        return self[name].value

    def get(self, name: str, default: float | None = None) -> float:
        """Value of ``name`` if the set has it (e.g. an added effect's parameter), else ``default``,
        else the nominal value (a parameter file written before that parameter existed).

        The value at which an effect's parameter is inactive belongs to the physics that reads it
        (``integrators.simulator.effect_parameter``), which passes it as ``default``.

        Raises:
            InputError: for a name that is neither, without a default.
        """
        if name in self._index:
            return self._params[self._index[name]].value
        if default is not None:
            return default
        if name in _NOMINAL_BY_NAME:
            return _NOMINAL_BY_NAME[name].value
        return self.value(name)  # raises, naming the known parameters

    def per_joint(self, name: str, default: float | None = None) -> np.ndarray:
        """(11,) values of a per-joint capable parameter: ``name_k`` where present, else ``name``
        (see :meth:`get`, which ``default`` is passed to)."""
        shared = self.get(name, default)
        return np.array([self.get(f"{name}_{k}", shared) for k in range(1, design.NUM_JOINTS + 1)])

    # -- derived sets -------------------------------------------------------------------------
    def _derived(self, params: Iterable[Parameter]) -> "ModelParameters":
        """A set of ``params`` under this set's contact law and friction step."""
        return ModelParameters(params, self.contact_law, self.friction_step)

    def with_contact_law(self, law: str) -> "ModelParameters":
        """A copy under contact law ``law`` (one of :data:`CONTACT_LAWS`), values unchanged."""
        return ModelParameters(self._params, law, self.friction_step)

    def with_friction_step(self, step: str) -> "ModelParameters":
        """A copy with friction step ``step`` (one of :data:`FRICTION_STEPS`), values unchanged."""
        return ModelParameters(self._params, self.contact_law, step)

    def with_values(self, **values: float) -> "ModelParameters":
        """A copy with the given values (bounds are checked)."""
        for name in values:
            self[name]  # raises a clear error for unknown names
        return self._derived(
            replace(p, value=float(values[p.name])) if p.name in values else p for p in self._params
        )

    def with_frozen(self, frozen: Iterable[str] = (), free: Iterable[str] | None = None) -> "ModelParameters":
        """A copy where ``free`` (if given) are the only free parameters, then ``frozen`` are frozen."""
        frozen = set(frozen)
        free_set = None if free is None else set(free)
        for name in frozen | (free_set or set()):
            self[name]
        def is_frozen(p: Parameter) -> bool:
            if p.name in frozen:
                return True
            return p.frozen if free_set is None else p.name not in free_set
        return self._derived(replace(p, frozen=is_frozen(p)) for p in self._params)

    def with_parameters(self, extra: Iterable[Parameter]) -> "ModelParameters":
        """A copy with parameters added (or replaced by name), e.g. those of a model effect."""
        extra = list(extra)
        names = {p.name for p in extra}
        return self._derived([p for p in self._params if p.name not in names] + extra)

    def with_per_joint(self, name: str) -> "ModelParameters":
        """Replace shared actuator parameter ``name`` by ``name_1`` .. ``name_11`` (same value)."""
        if name not in PER_JOINT_CAPABLE:
            raise InputError(f"parameter {name!r} cannot be per joint; only {', '.join(PER_JOINT_CAPABLE)}")
        base = self[name]
        per = [replace(base, name=f"{name}_{k}", doc=f"{base.doc} (joint {k})")
               for k in range(1, design.NUM_JOINTS + 1)]
        return self.with_parameters(per).with_frozen(frozen=[name])

    # -- vectors ----------------------------------------------------------------------------
    def as_vector(self) -> np.ndarray:
        """Free parameter values in table order [their units]."""
        return np.array([p.value for p in self._params if not p.frozen], dtype=float)

    def update_from_vector(self, x: np.ndarray) -> "ModelParameters":
        """A copy with the free parameters set from ``x`` (same order as :meth:`as_vector`)."""
        free = self.free_names
        x = np.asarray(x, dtype=float).ravel()
        if x.shape != (len(free),):
            raise InputError(f"parameter vector has {x.size} entries, expected {len(free)} ({', '.join(free)})")
        return self.with_values(**dict(zip(free, x)))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) bounds of the free parameters."""
        free = [p for p in self._params if not p.frozen]
        return np.array([p.min for p in free]), np.array([p.max for p in free])

    def to_unit(self) -> np.ndarray:
        """Free parameters mapped to [0, 1] (log-scaled where flagged); ``from_unit`` inverts it."""
        return np.array([float(p.to_unit_interval(p.value)) for p in self._params if not p.frozen])

    def from_unit(self, x: np.ndarray) -> "ModelParameters":
        """Inverse of :meth:`to_unit`; ``x`` is clipped to [0, 1].

        A point on the relation's edge ``mu_s = mu_c`` (where a fit may end, and where a
        constrained step lands) can come back from the transforms with ``mu_s`` a few ulps below
        ``mu_c``; such a round-off gap (at most :data:`EDGE_RTOL` of ``mu_c``) is closed by
        setting ``mu_s = mu_c``. A larger gap is an invalid set and raises.
        """
        free = [p for p in self._params if not p.frozen]
        x = np.clip(np.asarray(x, dtype=float).ravel(), 0.0, 1.0)
        if x.shape != (len(free),):
            raise InputError(f"unit vector has {x.size} entries, expected {len(free)}")
        values = {p.name: float(p.from_unit_interval(xi)) for p, xi in zip(free, x)}
        if "mu_s" in values and "mu_c" in self._index:
            mu_c = values.get("mu_c", self.value("mu_c"))
            if mu_c - EDGE_RTOL * abs(mu_c) <= values["mu_s"] < mu_c:
                values["mu_s"] = mu_c
        return self.with_values(**values)

    # -- files ------------------------------------------------------------------------------
    def to_json_dict(self) -> dict[str, Any]:
        """The parameter-file object: ``{"format", "contact_law", "friction_step", "parameters":
        {name: {value, unit, min, max, frozen, ...}}}``."""
        return {
            "format": PARAMS_FORMAT,
            "contact_law": self.contact_law,
            "friction_step": self.friction_step,
            "parameters": {
                p.name: {
                    "value": p.value, "unit": p.unit, "min": p.min, "max": p.max,
                    "frozen": p.frozen, "log_scale": p.log_scale, "group": p.group, "doc": p.doc,
                }
                for p in self._params
            },
        }

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any], *, source: str = "<parameters>") -> "ModelParameters":
        """Parse a parameter-file object; names not in the nominal table must give unit and bounds.
        A file without ``contact_law`` (written before the law was recorded) is ``compliant``; one
        without ``friction_step`` (written before 2026-12-04) is ``explicit``.

        Raises:
            InputError: naming ``source`` and the parameter, for a missing ``parameters`` object,
                an unknown name without unit/bounds, a non-numeric or out-of-bound value, or an
                unknown ``contact_law`` or ``friction_step``.
        """
        if not isinstance(data, Mapping) or not isinstance(data.get("parameters"), Mapping):
            raise InputError(f"{source}: expected a JSON object with a \"parameters\" object")
        fmt = data.get("format", PARAMS_FORMAT)
        if fmt != PARAMS_FORMAT:
            raise InputError(f"{source}: format is {fmt!r}, expected {PARAMS_FORMAT!r}")
        law = data.get("contact_law", "compliant")
        if law not in CONTACT_LAWS:
            raise InputError(f"{source}: \"contact_law\" is {law!r}, expected one of {', '.join(CONTACT_LAWS)}")
        step = data.get("friction_step", "explicit")
        if step not in FRICTION_STEPS:
            raise InputError(f"{source}: \"friction_step\" is {step!r}, expected one of {', '.join(FRICTION_STEPS)}")
        known = {p.name: p for p in NOMINAL}
        params: list[Parameter] = []
        for name, entry in data["parameters"].items():
            where = f"{source}: parameter {name!r}"
            if not isinstance(entry, Mapping) or "value" not in entry:
                raise InputError(f"{where}: expected an object with at least \"value\"")
            base = known.get(name) or _per_joint_base(name, known)
            fields: dict[str, Any] = {}
            for key, kind in (("value", float), ("min", float), ("max", float), ("frozen", bool),
                              ("log_scale", bool), ("unit", str), ("group", str), ("doc", str)):
                if key in entry:
                    raw = entry[key]
                    ok = isinstance(raw, bool) if kind is bool else (
                        isinstance(raw, (int, float)) and not isinstance(raw, bool) if kind is float
                        else isinstance(raw, str))
                    if not ok:
                        raise InputError(f"{where}: {key!r} must be a {kind.__name__}, got {raw!r}")
                    fields[key] = kind(raw)
            if base is None:
                missing = [k for k in ("unit", "min", "max") if k not in fields]
                if missing:
                    raise InputError(
                        f"{where} is not a known parameter ({', '.join(known)}) and does not give "
                        f"{', '.join(missing)}"
                    )
                base = Parameter(name, fields["unit"], fields["value"], fields["min"], fields["max"])
            try:
                params.append(replace(base, name=name, **fields))
            except InputError as exc:
                raise InputError(f"{source}: {exc}") from None
        try:
            return cls(params, law, step)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def save(self, path: str | Path, *, force: bool = False) -> Path:
        """Write the parameter file; refuses to overwrite unless ``force``."""
        path = Path(path)
        if path.exists() and not force:
            raise FileExistsError(f"{path} exists; pass --force to overwrite it")
        path.write_text(json.dumps(self.to_json_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "ModelParameters":
        """Read a parameter file written by :meth:`save` (or by hand)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"parameter file {path} does not exist")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: not valid JSON ({exc})") from None
        return cls.from_json_dict(data, source=str(path))


def _per_joint_base(name: str, known: Mapping[str, Parameter]) -> Parameter | None:
    """The shared parameter behind a per-joint name such as ``armature_7``."""
    stem, _, k = name.rpartition("_")
    if stem in PER_JOINT_CAPABLE and k.isdigit() and 1 <= int(k) <= design.NUM_JOINTS:
        return known[stem]
    return None
