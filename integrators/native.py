"""The articulated-body algorithm (and, for the soft-constraint contact, the inverse mass matrix
from Pinocchio's pass) for the compiled loops: the C interface of ``integrators/_aba.cpp``.

The simulator's kernels are numba code; a rollout that called ``pin.aba`` from Python between
two kernel calls paid a trip through the interpreter twice per physics step, several times
what the kernels cost. ``_aba.cpp`` (built with the package against the same
``libpinocchio_default`` that ``pin`` uses) exposes ABA as C functions; numba calls :data:`ABA`
like any C function, so a whole rollout runs in one compiled loop
(``integrators.kernels.rollout_loop``). Which ABA (:attr:`NativeModel.generated`):

- on COBRA's kinematic structure, ``integrators/_aba_cobra.c``: straight-line C that CasADi
  generated from Pinocchio's ABA run on its symbolic scalar (``tools/generate_aba.py``), the
  bodies' inertias, the armature and the gravity its inputs. About half the cost of Pinocchio's
  generic pass; the same accelerations as ``pin.aba`` in the WORLD convention to roundoff;
- on any other structure, Pinocchio's own ABA: the same explicit instantiation as ``pin.aba``,
  whose accelerations in the WORLD convention (the faster pass; the same joint accelerations as
  the LOCAL one to roundoff) it reproduces bit for bit.

:data:`ABA_MINVERSE` is always Pinocchio's pass, then ``pin.computeMinverse`` (the soft-constraint
law's inverse mass matrix), bit for bit.

:class:`NativeModel` rebuilds a :class:`~cobra_model.model.RobotModel`'s Pinocchio model on the
C++ side from its fields (:mod:`cobra_model.pinocchio_fields`); :class:`NativeData` is one
workspace. Both free their C++ object when collected.
"""
from __future__ import annotations

import ctypes
import importlib.util
import weakref
from pathlib import Path

import llvmlite.binding as llvm
import numpy as np
import pinocchio  # noqa: F401  (loads libpinocchio_default, which the library links against, before it)
from numba import types

from cobra_model.model import RobotModel
from cobra_model.pinocchio_fields import model_fields


def _library_path() -> Path:
    """The built ``integrators._aba`` extension (built by ``pip install``; see ``setup.py``)."""
    spec = importlib.util.find_spec("integrators._aba")
    if spec is None or spec.origin is None:
        raise ImportError("integrators._aba is not built: install the package (make install, or pip install -e .) "
                          "so that setup.py compiles integrators/_aba.cpp against Pinocchio")
    return Path(spec.origin)


LIBRARY = _library_path()
llvm.load_library_permanently(str(LIBRARY))  # numba's compiled code resolves cobra_aba by name
_lib = ctypes.CDLL(str(LIBRARY))
_I32P = ctypes.POINTER(ctypes.c_int32)
_F64P = ctypes.POINTER(ctypes.c_double)
_lib.cobra_model_new.restype = ctypes.c_ssize_t
_lib.cobra_model_new.argtypes = [ctypes.c_int32, _I32P, _I32P, _F64P, _F64P, _F64P, _F64P, _F64P]
_lib.cobra_model_free.argtypes = [ctypes.c_ssize_t]
_lib.cobra_model_generated.restype = ctypes.c_int32
_lib.cobra_model_generated.argtypes = [ctypes.c_ssize_t]
_lib.cobra_data_new.restype = ctypes.c_ssize_t
_lib.cobra_data_new.argtypes = [ctypes.c_ssize_t]
_lib.cobra_data_free.argtypes = [ctypes.c_ssize_t]
_lib.cobra_aba.restype = ctypes.c_int32
_lib.cobra_aba.argtypes = [ctypes.c_ssize_t, ctypes.c_ssize_t, _F64P, _F64P, _F64P, _F64P, _F64P]
_lib.cobra_aba_minverse.restype = ctypes.c_int32
_lib.cobra_aba_minverse.argtypes = [ctypes.c_ssize_t, ctypes.c_ssize_t, _F64P, _F64P, _F64P, _F64P, _F64P, _F64P]
_F64 = types.CPointer(types.float64)

#: ``cobra_aba(model, data, q, v, tau, armature, a)`` for numba code: the acceleration (nv,) into
#: ``a`` from ``q`` (nq,), ``v`` (nv,), ``tau`` (nv,) of the model with the transmission inertia
#: ``armature`` (nv,) [kg m^2] (pass ``array.ctypes``), as ``pin.aba`` in the WORLD convention
#: (the generated ABA on COBRA's structure, to roundoff); ``model`` and ``data`` are
#: :attr:`NativeModel.handle` and :attr:`NativeData.handle`. Returns 0. Stateless for the
#: generated ABA, ``data`` Pinocchio's workspace otherwise: one per thread. The armature is an
#: argument, not the model's alone, because a servo whose gear play is open carries none
#: (``integrators.kernels.gear_step``).
ABA = types.ExternalFunction("cobra_aba", types.int32(types.intp, types.intp, _F64, _F64, _F64, _F64, _F64))
#: ``cobra_aba_minverse(model, data, q, v, tau, armature, a, minv)``: the acceleration without
#: contact (nv,) into ``a`` and ``D(q)^-1`` into ``minv`` (nv, nv) C-ordered, its upper triangle,
#: from one articulated-body pass of the model with ``armature``: ``pin.aba(model, data, q, v,
#: tau, pin.Convention.WORLD)`` then ``pin.computeMinverse(model, data)``. Returns 0.
ABA_MINVERSE = types.ExternalFunction("cobra_aba_minverse",
                                      types.int32(types.intp, types.intp, _F64, _F64, _F64, _F64, _F64, _F64))


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


class NativeModel:
    """The C++ copy of a robot's Pinocchio model, value for value.

    Args:
        model: the robot; its joints must be a free-flyer root and revolute joints (as
            :class:`RobotModel` already requires).

    Attributes:
        armature: the model's transmission inertia (nv,) [kg m^2], what :func:`aba` uses unless told.
        generated: whether its ABA is the generated one (``integrators/_aba_cobra.c``: the model
            has the kinematic structure it was generated for, COBRA's), or else Pinocchio's.

    Raises:
        ValueError: a joint type ``_aba.cpp`` does not build.
    """

    def __init__(self, model: RobotModel):
        f = model_fields(model)
        self.nq, self.nv = model.pin_model.nq, model.pin_model.nv
        self.armature = f.armature.copy()
        self.handle = int(_lib.cobra_model_new(
            len(f.code), f.code.ctypes.data_as(_I32P), f.parent.ctypes.data_as(_I32P),
            f.placement.ctypes.data_as(_F64P), f.inertia.ctypes.data_as(_F64P), f.axis.ctypes.data_as(_F64P),
            f.armature.ctypes.data_as(_F64P), f.gravity.ctypes.data_as(_F64P)))
        if not self.handle:
            raise ValueError(f"_aba.cpp did not build the model (joint codes {f.code.tolist()})")
        weakref.finalize(self, _lib.cobra_model_free, self.handle)
        self.generated = bool(_lib.cobra_model_generated(self.handle))

    def __reduce__(self):
        raise TypeError("a NativeModel points into this process's memory and does not pickle; "
                        "pickle the RobotModel and call native_model() where it is used")


class NativeData:
    """One workspace of a :class:`NativeModel` (Pinocchio's ``Data`` and a copy of the model that
    takes each call's armature): every rollout running at the same time needs its own. Keeps its
    model alive."""

    def __init__(self, model: NativeModel):
        self.model = model
        self.handle = int(_lib.cobra_data_new(model.handle))
        weakref.finalize(self, _lib.cobra_data_free, self.handle)

    def __reduce__(self):
        raise TypeError("a NativeData points into this process's memory and does not pickle; make a new one "
                        "where it is used")


_MODELS: "weakref.WeakKeyDictionary[RobotModel, NativeModel]" = weakref.WeakKeyDictionary()


def native_model(model: RobotModel) -> NativeModel:
    """The :class:`NativeModel` of ``model``, built once per model object (models are immutable
    and shared: :meth:`RobotModel.with_armature` returns the same object for the same values)."""
    if model not in _MODELS:
        _MODELS[model] = NativeModel(model)
    return _MODELS[model]


def _state(data: NativeData, q: np.ndarray, v: np.ndarray, tau: np.ndarray | None = None) -> tuple:
    """``q``, ``v`` (and ``tau``) as contiguous float64 of ``data``'s model's sizes, or ValueError."""
    nq, nv = data.model.nq, data.model.nv
    arrays = tuple(_f64(x) for x in (q, v) + (() if tau is None else (tau,)))
    if [x.shape for x in arrays] != [(nq,), (nv,), (nv,)][:len(arrays)]:
        raise ValueError(f"q, v, tau must be ({nq},), ({nv},), ({nv},); got {', '.join(str(x.shape) for x in arrays)}")
    return arrays


def _armature(data: NativeData, armature: np.ndarray | None) -> np.ndarray:
    """``armature`` (nv,) as contiguous float64, the model's own when None, or ValueError."""
    arm = data.model.armature if armature is None else _f64(armature)
    if arm.shape != (data.model.nv,):
        raise ValueError(f"armature must be ({data.model.nv},), got {arm.shape}")
    return arm


def aba(data: NativeData, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
        armature: np.ndarray | None = None) -> np.ndarray:
    """The acceleration (nv,) from Python (tests and one-off calls; the loops call :data:`ABA`),
    with the transmission inertia ``armature`` (nv,) [kg m^2] (default: the model's)."""
    q, v, tau = _state(data, q, v, tau)
    arm = _armature(data, armature)
    a = np.empty(data.model.nv)
    _lib.cobra_aba(data.model.handle, data.handle, q.ctypes.data_as(_F64P), v.ctypes.data_as(_F64P),
                   tau.ctypes.data_as(_F64P), arm.ctypes.data_as(_F64P), a.ctypes.data_as(_F64P))
    return a


def aba_minverse(data: NativeData, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
                 armature: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The acceleration (nv,) and ``D(q)^-1`` (nv, nv), upper triangle, from Python (the loops
    call :data:`ABA_MINVERSE`), with ``armature`` as :func:`aba` takes it."""
    q, v, tau = _state(data, q, v, tau)
    arm = _armature(data, armature)
    a = np.empty(data.model.nv)
    minv = np.zeros((data.model.nv, data.model.nv))
    _lib.cobra_aba_minverse(data.model.handle, data.handle, q.ctypes.data_as(_F64P), v.ctypes.data_as(_F64P),
                            tau.ctypes.data_as(_F64P), arm.ctypes.data_as(_F64P), a.ctypes.data_as(_F64P),
                            minv.ctypes.data_as(_F64P))
    return a, minv


__all__ = ["ABA", "ABA_MINVERSE", "LIBRARY", "NativeData", "NativeModel", "aba", "aba_minverse", "native_model"]
