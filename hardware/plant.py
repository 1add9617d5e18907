"""What the emulated servos are attached to: the :class:`Plant` protocol and two plants.

* :class:`SimulatorPlant` is COBRA itself: the project's simulator (:mod:`integrators`) with the
  robot resting on the ground, so the emulated servos move with the physics and a run recorded
  on the emulator is comparable with a simulated run. This is the emulator's plant.
* :class:`KinematicPlant` is an ideal servo (each joint follows its goal with a first-order lag
  and a speed limit, no dynamics): fast and deterministic, for protocol and fault tests and
  for trying the tools without Pinocchio.

Joint quantities are in joint order and joint units (rad, rad/s, A), as in the URDF.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from cobra_model.design import NUM_JOINTS
from cobra_model.servo import SERVO_NO_LOAD_SPEED_RAD_S

if TYPE_CHECKING:
    from integrators import Simulator


class Plant(Protocol):
    """The mechanics behind the emulated servos."""

    #: A remark for the operator about what the plant could not do as asked, or "".
    note: str

    def advance(self, dt_total: float, goal_rad: np.ndarray, torque_on: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance by ``dt_total`` [s] (0 only reads) with goal joint angles (11,) [rad] and
        torque flags (11,) bool; return joint angles [rad], velocities [rad/s] and motor
        currents [A], each (11,)."""

    def set_gains(self, p: np.ndarray, i: np.ndarray, d: np.ndarray, pwm_limit: np.ndarray) -> None:
        """Position-loop registers (raw Position P/I/D Gain and PWM Limit) of each servo, (11,)."""


class KinematicPlant:
    """Ideal servos: each joint moves toward its goal as a first-order lag, speed-limited.

    ``dq = clip((goal - q) / tau, -v_max, v_max)`` with ``tau = time_constant_s * 800 / P``
    (a stiffer position loop tracks faster); a joint without torque stays where it is. The
    "current" is ``amp_per_rad * (goal - q)`` clipped to ``max_current_a``: a stand-in that
    grows with the tracking error, not a motor model.

    Args:
        q0: initial joint angles (11,) [rad] (default straight).
        time_constant_s: lag at the default P gain 800 [s].
        max_speed_rad_s: joint speed limit [rad/s] (default: XH540-W270 no-load speed).
        amp_per_rad: current per radian of tracking error [A/rad].
        max_current_a: current limit [A].
    """

    def __init__(self, q0: np.ndarray | None = None, *, time_constant_s: float = 0.03,
                 max_speed_rad_s: float = SERVO_NO_LOAD_SPEED_RAD_S, amp_per_rad: float = 5.0,
                 max_current_a: float = 4.0) -> None:
        self._q = np.zeros(NUM_JOINTS) if q0 is None else np.array(q0, dtype=float)
        self._dq = np.zeros(NUM_JOINTS)
        self._current = np.zeros(NUM_JOINTS)
        self._tau0 = time_constant_s
        self._tau = np.full(NUM_JOINTS, time_constant_s)
        self._v_max = max_speed_rad_s
        self._amp_per_rad = amp_per_rad
        self._max_current = max_current_a
        self.note = ""

    def advance(self, dt_total: float, goal_rad: np.ndarray, torque_on: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if dt_total > 0:
            on = np.asarray(torque_on, dtype=bool)
            error = np.asarray(goal_rad, dtype=float) - self._q
            speed = np.clip(error / self._tau, -self._v_max, self._v_max)
            # Never step past the goal (exact for dt_total << tau, stable for any dt_total).
            step = np.where(np.abs(speed * dt_total) > np.abs(error), error, speed * dt_total)
            self._dq = np.where(on, step / dt_total, 0.0)
            self._q = self._q + self._dq * dt_total
            self._current = np.where(
                on, np.clip(self._amp_per_rad * (goal_rad - self._q), -self._max_current, self._max_current), 0.0)
        return self._q.copy(), self._dq.copy(), self._current.copy()

    def set_gains(self, p: np.ndarray, i: np.ndarray, d: np.ndarray, pwm_limit: np.ndarray) -> None:
        self._tau = self._tau0 * 800.0 / np.maximum(np.asarray(p, dtype=float), 1.0)


class SimulatorPlant:
    """COBRA in the project's simulator, resting on the ground and driven by its servos.

    The simulator takes one set of position-loop gains for all joints; new register values are
    applied once every servo holds the same ones (a driver writes them servo by servo), and
    :attr:`note` says so when they disagree.

    Args:
        simulator: an :class:`integrators.Simulator` of COBRA.
        q0: initial joint pose (11,) [rad] (default straight), at rest on the ground.
    """

    def __init__(self, simulator: Simulator, q0: np.ndarray | None = None) -> None:
        self._sim = simulator
        self._state = simulator.rest_state(q_joints=np.zeros(NUM_JOINTS) if q0 is None else np.asarray(q0))
        self._dt = simulator.settings.dt
        self._carry_s = 0.0
        self.note = ""
        # The first step loads (or compiles) the simulator's numba kernels, which takes a while:
        # pay it here, not while a client waits for a reply.
        simulator.step(self._state, np.zeros(NUM_JOINTS), np.zeros(NUM_JOINTS, dtype=bool))

    @classmethod
    def nominal(cls, *, dt: float = 1e-3) -> SimulatorPlant:
        """COBRA with the nominal parameters, physics and servo loop every ``dt`` [s]."""
        from cobra_model import CobraModel, ModelParameters
        from integrators import ServoGains, SimSettings, Simulator

        sim = Simulator(CobraModel.load(), ModelParameters.nominal(),
                        SimSettings(dt=dt, control_dt=dt, gains=ServoGains()))
        return cls(sim)

    def advance(self, dt_total: float, goal_rad: np.ndarray, torque_on: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self._carry_s += dt_total
        steps = int(self._carry_s / self._dt + 1e-9)
        self._carry_s -= steps * self._dt
        goal = np.asarray(goal_rad, dtype=float)
        on = np.asarray(torque_on, dtype=bool)
        for _ in range(steps):
            self._state = self._sim.step(self._state, goal, on)
        model = self._sim.model
        return (model.joint_positions(self._state.q).copy(), self._state.v[model.n_base:].copy(),
                self._sim.motor_current(self._state))

    def set_gains(self, p: np.ndarray, i: np.ndarray, d: np.ndarray, pwm_limit: np.ndarray) -> None:
        from integrators import ServoGains

        columns = np.column_stack([p, i, d, pwm_limit]).astype(int)
        if (columns != columns[0]).any():
            self.note = ("servos hold different position gains; the simulator keeps one set "
                         f"for all joints: {self._sim.settings.gains}")
            return
        self.note = ""
        gains = ServoGains(p=int(columns[0, 0]), i=int(columns[0, 1]), d=int(columns[0, 2]),
                           pwm_limit=int(columns[0, 3]))
        if gains != self._sim.settings.gains:
            self._sim = self._sim.with_gains(gains)
