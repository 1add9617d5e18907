"""Robot models in Pinocchio and COBRA's partitioned dynamics (paper Eq. 1).

``[D_H D_Ha; D_aH D_a] [qdd_H; qdd_a] + [H_H; H_a] = [0; B_a] u + [J_H^T; J_a^T] F_GRF``

``H`` is the floating head (6 velocity coordinates: linear then angular velocity of the head
frame, both in the head frame, as Pinocchio's free-flyer), ``a`` the 11 actuated joints.

A :class:`RobotModel` is an immutable description (the Pinocchio model, its collision geometry
and the ground-contact features derived from it); algorithms take ``q`` and ``v`` and use a
fresh ``pin.Data`` so no state is shared. Contact features come from the URDF's collision
primitives: a cylinder contributes its two end circles (the lowest point of each touches the
ground), a sphere its lowest point, a box its eight corners; meshes contribute nothing, and
robots with mesh collisions (e.g. Solo) name their contact frames explicitly.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np
import pinocchio as pin

from cobra_model import design
from cobra_model.errors import InputError

DEFAULT_URDF = design.DEFAULT_URDF_PATH
GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class ContactFeatures:
    """Ground-contact features, one row each (arrays consumed by the compiled kernel).

    Attributes:
        body: (nf,) kernel body index (Pinocchio joint id - 1) carrying the feature.
        kind: (nf,) 0 = point/sphere, 1 = circle (cylinder end).
        centre: (nf, 3) feature centre in the body frame [m].
        axis: (nf, 3) circle normal in the body frame (unused for points).
        radius: (nf,) sphere/circle radius [m].
        names: feature names, e.g. ``link_4:front``.
    """

    body: np.ndarray
    kind: np.ndarray
    centre: np.ndarray
    axis: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.body.shape[0])


@dataclass(frozen=True)
class ChainArrays:
    """The kinematic tree as arrays for the compiled kernels (body i = Pinocchio joint i + 1)."""

    floating: bool
    parents: np.ndarray   # (nb,) int64, -1 for the universe
    jR: np.ndarray        # (nb, 3, 3) joint placement rotation in the parent body frame
    jp: np.ndarray        # (nb, 3) joint placement translation [m]
    axes: np.ndarray      # (nb, 3) revolute axis
    qidx: np.ndarray      # (nb,) int64
    vidx: np.ndarray      # (nb,) int64


def _features_from_collision(model: pin.Model, geom: pin.GeometryModel) -> list[tuple]:
    import coal

    rows: list[tuple] = []
    for obj in geom.geometryObjects:
        body = obj.parentJoint - 1
        if body < 0:
            continue
        M = obj.placement
        g = obj.geometry
        base = obj.name.rsplit("_", 1)[0]
        if isinstance(g, coal.Cylinder):
            axis = M.rotation[:, 2]
            for side, sign in (("front", 1.0), ("rear", -1.0)):
                # the URDF cylinder's z axis; "front" is its +z end
                centre = M.translation + sign * g.halfLength * axis
                rows.append((body, 1, centre, axis, g.radius, f"{base}:{side}"))
        elif isinstance(g, coal.Sphere):
            rows.append((body, 0, M.translation.copy(), np.zeros(3), g.radius, f"{base}:sphere"))
        elif isinstance(g, coal.Box):
            h = g.halfSide
            for ix in (-1, 1):
                for iy in (-1, 1):
                    for iz in (-1, 1):
                        corner = M.act(np.array([ix * h[0], iy * h[1], iz * h[2]]))
                        rows.append((body, 0, corner, np.zeros(3), 0.0, f"{base}:corner"))
    return rows


class RobotModel:
    """A URDF in Pinocchio, optionally with a free-flyer root, plus its ground-contact features.

    Do not mutate :attr:`pin_model`; derive a new model instead (:meth:`with_armature`,
    :meth:`with_link_mass`). Models are shared: :meth:`CobraModel.load` returns the same model
    for the same URDF, and a derived model is made once per model and value.
    """

    def __init__(self, pin_model: pin.Model, features: ContactFeatures, urdf_path: Path | None):
        self.pin_model = pin_model
        self.features = features
        self.urdf_path = urdf_path
        self.chain = self._chain_arrays(pin_model)
        self._derived: dict[tuple, RobotModel] = {}

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path: str | Path, *, floating: bool = True,
                  contact_frames: Sequence[tuple[str, float]] = (),
                  package_dirs: Sequence[str] = ()) -> "RobotModel":
        """Load a URDF.

        Args:
            path: URDF file.
            floating: add a free-flyer root joint.
            contact_frames: extra point contacts as (frame name, sphere radius [m]).
            package_dirs: where ``package://`` mesh paths resolve (only for reading collisions).

        Raises:
            FileNotFoundError: the URDF does not exist. InputError: a joint type the kernels do not
                support (only revolute joints and one free-flyer root), or an unknown contact frame.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"URDF {path} does not exist")
        root = pin.JointModelFreeFlyer() if floating else None
        model = pin.buildModelFromUrdf(str(path), root) if floating else pin.buildModelFromUrdf(str(path))
        rows: list[tuple] = []
        try:
            geom = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.COLLISION, None,
                                         list(package_dirs) or [str(path.parent)])
            rows = _features_from_collision(model, geom)
        except ValueError:
            rows = []   # meshes that cannot be resolved: rely on contact_frames
        for frame_name, radius in contact_frames:
            if not model.existFrame(frame_name):
                raise InputError(f"{path}: no frame named {frame_name!r} for a contact point")
            frame = model.frames[model.getFrameId(frame_name)]
            rows.append((frame.parentJoint - 1, 0, frame.placement.translation.copy(), np.zeros(3),
                         float(radius), frame_name))
        features = ContactFeatures(
            body=np.array([r[0] for r in rows], dtype=np.int64),
            kind=np.array([r[1] for r in rows], dtype=np.int64),
            centre=np.array([r[2] for r in rows], dtype=float).reshape(-1, 3),
            axis=np.array([r[3] for r in rows], dtype=float).reshape(-1, 3),
            radius=np.array([r[4] for r in rows], dtype=float),
            names=tuple(r[5] for r in rows),
        )
        return cls(model, features, path)

    @staticmethod
    def _chain_arrays(model: pin.Model) -> ChainArrays:
        nb = model.njoints - 1
        floating = nb > 0 and model.joints[1].shortname() == "JointModelFreeFlyer"
        parents = np.array([model.parents[i] - 1 for i in range(1, model.njoints)], dtype=np.int64)
        jR = np.array([model.jointPlacements[i].rotation for i in range(1, model.njoints)]).reshape(nb, 3, 3)
        jp = np.array([model.jointPlacements[i].translation for i in range(1, model.njoints)]).reshape(nb, 3)
        axes = np.zeros((nb, 3))
        for i in range(1, model.njoints):
            jm = model.joints[i]
            name = jm.shortname()
            if floating and i == 1:
                if not model.jointPlacements[1].isIdentity():
                    raise InputError("the free-flyer root must have an identity placement")
                continue
            if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
                axes[i - 1, "XYZ".index(name[-1])] = 1.0
            elif name == "JointModelRevoluteUnaligned":
                axes[i - 1] = jm.extract().axis
            else:
                raise InputError(
                    f"joint {model.names[i]!r} is a {name}; the simulator supports revolute joints "
                    "and one free-flyer root"
                )
        qidx = np.array([model.joints[i].idx_q for i in range(1, model.njoints)], dtype=np.int64)
        vidx = np.array([model.joints[i].idx_v for i in range(1, model.njoints)], dtype=np.int64)
        return ChainArrays(floating, parents, jR, jp, axes, qidx, vidx)

    def with_armature(self, armature: np.ndarray) -> "RobotModel":
        """A copy whose actuated joints carry transmission inertia ``armature`` [kg m^2] (n_joints,)."""
        arm = np.zeros(self.nv)
        arm[self.n_base:] = np.broadcast_to(np.asarray(armature, dtype=float), (self.n_joints,))
        key = ("armature", tuple(arm))
        if key not in self._derived:
            model = self.pin_model.copy()
            model.armature = arm
            self._derived[key] = type(self)(model, self.features, self.urdf_path)
        return self._derived[key]

    def with_gravity(self, gravity: np.ndarray) -> "RobotModel":
        """A copy with gravity vector ``gravity`` [m/s^2] (e.g. zeros for invariance tests)."""
        model = self.pin_model.copy()
        model.gravity.linear = np.asarray(gravity, dtype=float)
        return type(self)(model, self.features, self.urdf_path)

    def without_contacts(self) -> "RobotModel":
        """A copy with no ground-contact features (a robot in free space)."""
        empty = ContactFeatures(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                                np.zeros((0, 3)), np.zeros(0), ())
        return type(self)(self.pin_model, empty, self.urdf_path)

    def with_link_mass(self, body: str, delta_kg: float) -> "RobotModel":
        """A copy with ``delta_kg`` added to link ``body`` at its centre of mass (inertia scaled)."""
        key = ("link_mass", body, float(delta_kg))
        if key in self._derived:
            return self._derived[key]
        model = self.pin_model.copy()
        jid = self.body_joint_id(body)
        inert = model.inertias[jid]
        m = inert.mass + delta_kg
        if m <= 0:
            raise InputError(f"link {body!r}: mass {inert.mass} + {delta_kg} kg is not positive")
        model.inertias[jid] = pin.Inertia(m, inert.lever, inert.inertia * (m / inert.mass))
        self._derived[key] = type(self)(model, self.features, self.urdf_path)
        return self._derived[key]

    # -- sizes and names --------------------------------------------------------------------
    @property
    def nq(self) -> int:
        return self.pin_model.nq

    @property
    def nv(self) -> int:
        return self.pin_model.nv

    @property
    def n_base(self) -> int:
        """Velocity coordinates of the root: 6 with a free-flyer, else 0."""
        return 6 if self.chain.floating else 0

    @property
    def n_joints(self) -> int:
        """Number of actuated (revolute) joints."""
        return self.nv - self.n_base

    @property
    def joint_names(self) -> tuple[str, ...]:
        start = 2 if self.chain.floating else 1
        return tuple(self.pin_model.names[i] for i in range(start, self.pin_model.njoints))

    @cached_property
    def body_names(self) -> tuple[str, ...]:
        """Link names carried by each Pinocchio joint (the root link first for a floating model)."""
        names = []
        for i in range(1, self.pin_model.njoints):
            frames = [f for f in self.pin_model.frames
                      if f.parentJoint == i and f.type == pin.FrameType.BODY]
            names.append(frames[0].name if frames else self.pin_model.names[i])
        return tuple(names)

    def body_joint_id(self, body: str) -> int:
        """Pinocchio joint id carrying link ``body``."""
        try:
            return 1 + self.body_names.index(body)
        except ValueError:
            raise InputError(f"no link named {body!r}; links: {', '.join(self.body_names)}") from None

    @property
    def total_mass(self) -> float:
        """Total mass [kg]."""
        return float(pin.computeTotalMass(self.pin_model))

    # -- configurations ---------------------------------------------------------------------
    def configuration(self, q_joints: np.ndarray | None = None, base_pos: np.ndarray | None = None,
                      base_quat_wxyz: np.ndarray | None = None) -> np.ndarray:
        """Assemble q (nq,) from joint angles [rad], root position [m] and orientation (w, x, y, z)."""
        q = pin.neutral(self.pin_model)
        if q_joints is not None:
            q[self.nq - self.n_joints:] = q_joints
        if self.chain.floating:
            if base_pos is not None:
                q[0:3] = base_pos
            if base_quat_wxyz is not None:
                w, x, y, z = np.asarray(base_quat_wxyz, dtype=float) / np.linalg.norm(base_quat_wxyz)
                q[3:7] = (x, y, z, w)
        return q

    def on_ground(self, q: np.ndarray, rounding: float = 0.0) -> np.ndarray:
        """``q`` with a floating root raised or lowered so that the lowest contact point is at
        z = 0 (``rounding`` as in :meth:`contact_points`); ``q`` itself if the root is fixed or
        there are no contact features."""
        q = np.array(q, dtype=float)
        if self.chain.floating and len(self.features):
            q[2] -= self.contact_points(q, rounding)[:, 2].min()
        return q

    def joint_positions(self, q: np.ndarray) -> np.ndarray:
        """Actuated joint angles [rad] from q."""
        return np.asarray(q)[self.nq - self.n_joints:]

    # -- dynamics (paper Eq. 1) -------------------------------------------------------------
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia matrix D(q) (nv, nv), armature included, symmetric."""
        data = self.pin_model.createData()
        M = pin.crba(self.pin_model, data, q)
        return np.triu(M) + np.triu(M, 1).T

    @cached_property
    def reference_weights(self) -> np.ndarray:
        """Each body's translational inverse inertia at the reference pose [1/kg] (one per
        Pinocchio joint after the universe, the root body first): ``trace(J_c D^-1 J_c^T) / 3``
        with ``J_c`` the linear Jacobian of the body's centre of mass and ``D`` the mass matrix,
        transmission inertia included, in the neutral configuration (joints at zero).

        The soft-constraint contact laws scale each contact's compliance by its body's weight
        (:func:`integrators.kernels.soft_contact_acceleration`): MuJoCo's ``body_invweight0``,
        which it computes the same way in its reference configuration.
        """
        m = self.pin_model
        data = m.createData()
        q = pin.neutral(m)
        pin.computeJointJacobians(m, data, q)
        D = pin.computeMinverse(m, data, q)
        D = np.triu(D) + np.triu(D, 1).T
        weights = np.empty(m.njoints - 1)
        for j in range(1, m.njoints):
            J = pin.getJointJacobian(m, data, j, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            lever = data.oMi[j].rotation @ m.inertias[j].lever
            Jc = J[:3] - pin.skew(lever) @ J[3:]
            weights[j - 1] = np.trace(Jc @ D @ Jc.T) / 3.0
        return weights

    def bias(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Coriolis, centrifugal and gravity terms H(q, v) (nv,) [N, N m]."""
        data = self.pin_model.createData()
        return pin.nonLinearEffects(self.pin_model, data, q, v).copy()

    def D_H(self, q: np.ndarray) -> np.ndarray:
        """(6, 6) head block of D [kg, kg m, kg m^2]."""
        return self.mass_matrix(q)[:6, :6]

    def D_Ha(self, q: np.ndarray) -> np.ndarray:
        """(6, 11) head-joint coupling block of D."""
        return self.mass_matrix(q)[:6, 6:]

    def D_a(self, q: np.ndarray) -> np.ndarray:
        """(11, 11) joint block of D [kg m^2], transmission inertia included."""
        return self.mass_matrix(q)[6:, 6:]

    def H_H(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(6,) head rows of H: force [N] and moment [N m] in the head frame."""
        return self.bias(q, v)[:6]

    def H_a(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(11,) joint rows of H [N m]."""
        return self.bias(q, v)[6:]

    @property
    def B_a(self) -> np.ndarray:
        """(n_joints, n_joints) actuation map of the joint rows: identity (one motor per joint)."""
        return np.eye(self.n_joints)

    @property
    def B(self) -> np.ndarray:
        """(nv, n_joints) full actuation matrix ``[0; B_a]``."""
        return np.vstack([np.zeros((self.n_base, self.n_joints)), self.B_a])

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Accelerations (nv,) from generalized forces tau (nv,) by Pinocchio's ABA."""
        data = self.pin_model.createData()
        return pin.aba(self.pin_model, data, q, v, tau).copy()

    # -- contact points ---------------------------------------------------------------------
    def _placements(self, q: np.ndarray, v: np.ndarray | None = None) -> pin.Data:
        data = self.pin_model.createData()
        if v is None:
            pin.forwardKinematics(self.pin_model, data, q)
        else:
            pin.forwardKinematics(self.pin_model, data, q, v)
        return data

    def contact_points(self, q: np.ndarray, rounding: float = 0.0) -> np.ndarray:
        """(nf, 3) world position [m] of each contact feature's lowest point.

        ``rounding`` [m] is the edge radius of the cylinders' ends (parameter
        ``contact_rounding``; see :func:`integrators.kernels.ground_forces`).
        """
        data = self._placements(q)
        out = np.empty((len(self.features), 3))
        z = np.array([0, 0, 1.0])
        for k in range(len(self.features)):
            M = data.oMi[int(self.features.body[k]) + 1]
            c = M.act(self.features.centre[k])
            if self.features.kind[k] == 0:
                out[k] = c - self.features.radius[k] * z
            else:
                rho = min(rounding, self.features.radius[k])
                a = M.rotation @ self.features.axis[k]
                down = -(z - a[2] * a)
                n = np.linalg.norm(down)
                out[k] = c + ((self.features.radius[k] - rho) * down / n if n > 1e-9 else 0.0) - rho * z
        return out

    def contact_jacobian(self, q: np.ndarray, rounding: float = 0.0) -> np.ndarray:
        """(3 nf, nv) stacked world-frame Jacobians of the material points at the contact points
        (``rounding`` as in :meth:`contact_points`).

        Rows 3k..3k+2 give feature k's point velocity [m/s] from v; ``J[:, :6]`` is ``J_H``
        and ``J[:, 6:]`` is ``J_a`` of paper Eq. 1.
        """
        data = self.pin_model.createData()
        pin.computeJointJacobians(self.pin_model, data, q)
        X = self.contact_points(q, rounding)
        J = np.zeros((3 * len(self.features), self.nv))
        for k in range(len(self.features)):
            jid = int(self.features.body[k]) + 1
            Jj = pin.getJointJacobian(self.pin_model, data, jid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            r = X[k] - data.oMi[jid].translation
            J[3 * k:3 * k + 3] = Jj[:3] - pin.skew(r) @ Jj[3:]
        return J

    def J_H(self, q: np.ndarray) -> np.ndarray:
        """(3 nf, 6) contact Jacobian columns of the head."""
        return self.contact_jacobian(q)[:, :self.n_base]

    def J_a(self, q: np.ndarray) -> np.ndarray:
        """(3 nf, n_joints) contact Jacobian columns of the joints."""
        return self.contact_jacobian(q)[:, self.n_base:]

    def contact_velocities(self, q: np.ndarray, v: np.ndarray, rounding: float = 0.0) -> np.ndarray:
        """(nf, 3) world velocity [m/s] of the material points at the contact points."""
        return (self.contact_jacobian(q, rounding) @ v).reshape(-1, 3)

    # -- energy and momentum ----------------------------------------------------------------
    def kinetic_energy(self, q: np.ndarray, v: np.ndarray) -> float:
        """``0.5 v^T D v`` [J], transmission inertia included."""
        return float(0.5 * v @ self.mass_matrix(q) @ v)

    def potential_energy(self, q: np.ndarray) -> float:
        """Gravitational potential energy [J] (zero at z = 0, g = 9.81 m/s^2 along -z)."""
        data = self.pin_model.createData()
        return float(pin.computePotentialEnergy(self.pin_model, data, q))

    def momentum(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear momentum [kg m/s] and angular momentum about the world origin [kg m^2/s], world frame.

        Rigid links only (the rotors' spin is internal to the transmission model).
        """
        data = self.pin_model.createData()
        h = pin.computeCentroidalMomentum(self.pin_model, data, q, v)
        c = data.com[0]
        return h.linear.copy(), h.angular + np.cross(c, h.linear)

    def centre_of_mass(self, q: np.ndarray) -> np.ndarray:
        """Centre of mass [m], world frame."""
        data = self.pin_model.createData()
        return pin.centerOfMass(self.pin_model, data, q).copy()

    def body_centres(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """World position [m] of each link's centre of mass (the tracked point of a module)."""
        data = self._placements(q)
        return {name: data.oMi[i + 1].act(self.pin_model.inertias[i + 1].lever)
                for i, name in enumerate(self.body_names)}

    def body_tracks(self, Q: np.ndarray, names: Sequence[str]) -> dict[str, np.ndarray]:
        """World positions [m], ``(N, 3)`` each, of the centres of the links ``names`` at every
        configuration of ``Q`` (N, nq): :meth:`body_centres` of many configurations at once (one
        kinematics pass each, only the links asked for).

        Raises:
            InputError: naming a link the model does not have.
        """
        index = {name: i + 1 for i, name in enumerate(self.body_names)}
        unknown = [n for n in names if n not in index]
        if unknown:
            raise InputError(f"unknown link(s) {unknown}; the model has {', '.join(index)}")
        data = self.pin_model.createData()
        levers = {n: self.pin_model.inertias[index[n]].lever for n in names}
        out = {n: np.empty((len(Q), 3)) for n in names}
        for k, q in enumerate(np.asarray(Q, dtype=float)):
            pin.forwardKinematics(self.pin_model, data, q)
            for n in names:
                out[n][k] = data.oMi[index[n]].act(levers[n])
        return out


class CobraModel(RobotModel):
    """COBRA: 12 modules, free-flyer head, 11 joints (odd pitch, even yaw); see ``urdf/cobra.urdf``."""

    @classmethod
    def load(cls, urdf: str | Path = DEFAULT_URDF) -> "CobraModel":
        """Load ``urdf/cobra.urdf`` (or another COBRA URDF) with a free-flyer head; the same
        model object for the same unchanged file (models are not mutated)."""
        path = Path(urdf).resolve()
        return _load_cobra(cls, path, path.stat().st_mtime_ns if path.exists() else 0)

    def rest_configuration(self, q_joints: np.ndarray | None = None, head_xy: tuple[float, float] = (0.0, 0.0),
                           heading_rad: float = 0.0) -> np.ndarray:
        """q with the head at (x, y) on the ground (z = module radius), yawed by ``heading_rad``."""
        half = 0.5 * heading_rad
        return self.configuration(
            q_joints, np.array([head_xy[0], head_xy[1], design.MODULE_RADIUS_M]),
            np.array([np.cos(half), 0.0, 0.0, np.sin(half)]),
        )


@lru_cache(maxsize=8)
def _load_cobra(cls: type[CobraModel], path: Path, _mtime_ns: int) -> CobraModel:
    """:meth:`CobraModel.load` of one version of a file (the modification time is part of the key)."""
    model = cls.from_urdf(path, floating=True)
    if model.n_joints != design.NUM_JOINTS:
        raise InputError(f"{path}: COBRA has {design.NUM_JOINTS} joints, this URDF has {model.n_joints}")
    return model
