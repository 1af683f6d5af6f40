"""Servo controllers of Roger's five effectors (neck, two eyes, two arms).

Each controller owns a few joints and runs every physics step. It is a computed-torque
PD servo: it asks for the joint acceleration

    qdd* = wn^2 (q_ref - q) - 2 wn qd          (critically damped, natural frequency wn)

and the simulator turns the accelerations of all controllers into joint torques with one
call to pybullet's inverse dynamics, tau = M(q) qdd* + C(q, qd) + g(q), which is where the
gravity compensation comes from. Controllers take arrays, never the simulator.

Status rules (as Roger-the-Crab's controllers reported them):

* NO_REFERENCE: no goal has given this controller a reference yet (it holds its pose).
* TRANSIENT: it has a reference and is not (yet) within tolerance.
* CONVERGED: every joint error is below ``tolerance`` and every joint speed below
  ``velocity_tolerance`` for ``settle_steps`` consecutive steps.
* FAILED: the reference was out of reach (``fail``) or the controller stayed transient
  for longer than ``timeout`` simulated seconds. FAILED is latched until a new reference.
"""

from __future__ import annotations

import numpy as np

from roger_common.types import ControllerState


class JointServo:
    """Computed-torque PD servo with Roger's status reporting, over ``n`` joints.

    Args:
        name: Controller name ("neck", "left_eye", ...).
        joints: Names of its joints, in the order of the reference vector.
        bandwidth: Natural frequency wn of the closed loop, rad/s.
        time_step: Physics step, seconds (to count time towards the timeout).
        lower, upper: Joint limits; a reference outside them is out of reach.
        timeout: Simulated seconds a reference may stay transient before FAILED.
        tolerance: Joint error below which the servo is within tolerance.
        velocity_tolerance: Joint speed below which the servo is at rest.
        settle_steps: Consecutive steps within tolerance needed to converge.

    Raises:
        ValueError: On a non-positive rate, gain or tolerance, or mismatched limits.
    """

    def __init__(self, name: str, joints: tuple[str, ...], bandwidth: float, time_step: float,
                 lower: np.ndarray, upper: np.ndarray, timeout: float, tolerance: float,
                 velocity_tolerance: float, settle_steps: int = 3) -> None:
        for label, value in (("bandwidth", bandwidth), ("time_step", time_step),
                             ("timeout", timeout), ("tolerance", tolerance),
                             ("velocity_tolerance", velocity_tolerance),
                             ("settle_steps", settle_steps)):
            if not value > 0:
                raise ValueError(f"{name}: {label} must be > 0, got {value!r}")
        if bandwidth * time_step > 0.5:
            raise ValueError(f"{name}: bandwidth {bandwidth} rad/s is unstable at "
                             f"time step {time_step} s (need bandwidth * time_step <= 0.5)")
        self.name = name
        self.joints = tuple(joints)
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        if self.lower.shape != (len(self.joints),) or self.upper.shape != self.lower.shape:
            raise ValueError(f"{name}: limits must have one entry per joint "
                             f"({len(self.joints)}), got {self.lower.shape}/{self.upper.shape}")
        self.kp = bandwidth ** 2
        self.kd = 2.0 * bandwidth
        self.time_step = time_step
        self.timeout = timeout
        self.tolerance = tolerance
        self.velocity_tolerance = velocity_tolerance
        self.settle_steps = int(settle_steps)
        self.reference: np.ndarray | None = None
        self._hold: np.ndarray | None = None
        self.state = ControllerState.NO_REFERENCE
        self.elapsed = 0.0
        self._settled = 0

    def reachable(self, reference: np.ndarray) -> bool:
        """True when every component of ``reference`` lies within the joint limits."""
        ref = np.asarray(reference, float)
        return bool(np.all(ref >= self.lower - 1e-9) and np.all(ref <= self.upper + 1e-9))

    def set_reference(self, reference: np.ndarray, tolerance: float | None = None) -> None:
        """Start a new movement towards ``reference`` (restarts the timeout).

        A reference outside the joint limits fails at once; the servo keeps holding
        its previous reference so the joints do not drift.
        """
        ref = np.asarray(reference, float).copy()
        if tolerance is not None:
            if not tolerance > 0:
                raise ValueError(f"{self.name}: tolerance must be > 0, got {tolerance!r}")
            self.tolerance = tolerance
        self.elapsed = 0.0
        self._settled = 0
        if ref.shape != (len(self.joints),) or not np.all(np.isfinite(ref)) \
                or not self.reachable(ref):
            self.fail()
            return
        self.reference = ref
        self.state = ControllerState.TRANSIENT

    def move_reference(self, reference: np.ndarray) -> None:
        """Shift the reference along a path without restarting the timeout (a ramp)."""
        if self.state == ControllerState.FAILED:
            return
        self.reference = np.clip(np.asarray(reference, float), self.lower, self.upper)
        self._settled = 0
        self.state = ControllerState.TRANSIENT

    def fail(self) -> None:
        """Report FAILED (target out of reach or timeout) until the next reference."""
        self.state = ControllerState.FAILED
        self._settled = 0

    def target(self, q: np.ndarray) -> np.ndarray:
        """The joint positions the servo drives to: its reference, or the pose it holds.

        Without a reference (or after a failure) the servo holds the pose it had when
        it was first asked, so a failed or idle effector does not fall under gravity.
        """
        if self.reference is not None:
            return self.reference
        if self._hold is None:
            self._hold = np.array(q, float)
        return self._hold

    def acceleration(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Desired joint accelerations qdd* for the current joint state."""
        q = np.asarray(q, float)
        qd = np.asarray(qd, float)
        return self.kp * (self.target(q) - q) - self.kd * qd

    @property
    def tracking(self) -> bool:
        """True while the status depends on the joints (TRANSIENT or CONVERGED)."""
        return self.reference is not None and self.state not in (
            ControllerState.NO_REFERENCE, ControllerState.FAILED)

    def update_status(self, q: np.ndarray, qd: np.ndarray) -> ControllerState:
        """Advance the status by one physics step after the joints moved to ``q``, ``qd``."""
        if not self.tracking:
            return self.state
        assert self.reference is not None
        err = abs(self.reference - np.asarray(q, float))
        speed = abs(np.asarray(qd, float))
        return self.advance(bool((err < self.tolerance).all()
                                 and (speed < self.velocity_tolerance).all()))

    def advance(self, within: bool) -> ControllerState:
        """Advance the status by one physics step, given whether every joint is within
        ``tolerance`` and slower than ``velocity_tolerance`` (:meth:`update_status`; the
        simulator computes ``within`` for all servos at once)."""
        if not self.tracking:
            return self.state
        if within:
            self._settled += 1
        else:
            self._settled = 0
        if self._settled >= self.settle_steps:
            self.state = ControllerState.CONVERGED
            return self.state
        self.state = ControllerState.TRANSIENT
        self.elapsed += self.time_step
        if self.elapsed > self.timeout:
            self.fail()
        return self.state
