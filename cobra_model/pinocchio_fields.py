"""A robot's Pinocchio model as flat arrays: what the C++ side builds it from.

``integrators/_aba.cpp`` (the compiled loops' ABA, :mod:`integrators.native`) and
``tools/generate_aba.cpp`` (the generated ABA of COBRA's structure) rebuild a Pinocchio model
from these fields (``integrators/_aba_model.hpp``). Kept apart from :mod:`integrators.native`,
which loads the built extension, so that the generator runs before the extension is rebuilt.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cobra_model.model import RobotModel

#: Joint type codes of ``_aba_model.hpp`` by Pinocchio's joint model name.
JOINT_CODES = {"JointModelFreeFlyer": 0, "JointModelRX": 1, "JointModelRY": 2, "JointModelRZ": 3,
               "JointModelRevoluteUnaligned": 4}


class ModelFields(NamedTuple):
    """A robot's Pinocchio model as ``_aba.cpp`` builds it (``integrators/_aba_model.hpp``): per
    joint after the universe, its code (:data:`JOINT_CODES`), its parent's index, its placement
    in the parent's frame (row-major rotation, then translation), its body's inertia (mass,
    lever [m], then the inertia about the centre of mass in ``Symmetric3`` order) and its axis
    (revolute joints about an unaligned axis; zeros otherwise); the armature (nv,) and gravity (3,)."""

    code: np.ndarray
    parent: np.ndarray
    placement: np.ndarray
    inertia: np.ndarray
    axis: np.ndarray
    armature: np.ndarray
    gravity: np.ndarray


def model_fields(model: RobotModel) -> ModelFields:
    """The fields of ``model``'s Pinocchio model that ``_aba.cpp`` builds it from.

    Raises:
        ValueError: a joint type ``_aba.cpp`` does not build.
    """
    pm = model.pin_model
    joints = range(1, pm.njoints)
    names = [pm.joints[i].shortname() for i in joints]
    unknown = sorted(set(names) - set(JOINT_CODES))
    if unknown:
        raise ValueError(f"the native ABA builds {', '.join(JOINT_CODES)} joints, not {', '.join(unknown)}")
    return ModelFields(
        code=np.array([JOINT_CODES[n] for n in names], dtype=np.int32),
        parent=np.array([pm.parents[i] for i in joints], dtype=np.int32),
        placement=_f64([np.r_[pm.jointPlacements[i].rotation.ravel(), pm.jointPlacements[i].translation]
                        for i in joints]),
        inertia=_f64([np.r_[pm.inertias[i].mass, pm.inertias[i].lever, _symmetric3(pm.inertias[i].inertia)]
                      for i in joints]),
        axis=_f64([pm.joints[i].extract().axis if n == "JointModelRevoluteUnaligned" else np.zeros(3)
                   for i, n in zip(joints, names)]),
        armature=_f64(pm.armature), gravity=_f64(pm.gravity.linear))


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _symmetric3(inertia: np.ndarray) -> np.ndarray:
    """A symmetric 3x3 inertia in Pinocchio's ``Symmetric3`` order (xx, xy, yy, xz, yz, zz)."""
    return inertia[[0, 1, 1, 2, 2, 2], [0, 0, 1, 0, 1, 2]]
