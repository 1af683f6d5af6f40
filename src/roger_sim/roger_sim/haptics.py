"""Haptic improvement: an arm reaches an object, touches it, lifts it and weighs it.

The routine is a sequence of arm-servo references, each started when the previous one
converged:

    reach     hand at HOVER height over the target (planar inverse kinematics)
    approach  hand quickly down to just above the expected top (2 * target z + 5 cm)
    touch     hand down at ``touch_speed`` until it touches an object (contact points)
    lift      a fixed constraint holds the object (a simulated grasp); lift it
    weigh     hold still: let it settle ``weigh_steps``, then average the lift joint's
              force over ``weigh_steps`` more
    lower     put the object back, release it
    rise      hand back to HOVER height
    rest      arm back to its rest pose

The weight comes from the joint torque: with the object held still, the lift motor
applies tau = g_model(q) + m g, where g_model is the gravity torque of the arm alone
(pybullet inverse dynamics with zero speed and acceleration). So
m = mean(tau - g_model) / g  (equation 5 then normalises it: W = w / W_max), plus
Gaussian sensor noise of std ``weight_noise_kg``.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from roger_common.types import ControllerState, HapticReading
from roger_sim.config import SimConfig
from roger_sim.controllers import JointServo
from roger_sim.robot import ARM_REST, HOVER, JOINT_LIMITS, RobotModel, arm_ik

GRAVITY: float = 9.81
#: Smallest normal force that counts as a touch, newtons.
TOUCH_FORCE: float = 0.5


def weight_from_efforts(efforts: np.ndarray, gravity_model: np.ndarray) -> float:
    """Weight (kg) of a held object from lift-joint forces (equation 5's w).

    Args:
        efforts: Forces the lift motor applied while holding still, newtons.
        gravity_model: Forces the arm alone needs at the same poses, newtons.
    """
    return float(np.mean(np.asarray(efforts, float) - np.asarray(gravity_model, float))
                 / GRAVITY)


class HapticRoutine:
    """One haptic improvement by one arm (see the module docstring for the phases).

    Args:
        client: pybullet client id.
        robot: Roger's handles.
        arm: "left_arm" or "right_arm".
        servo: That arm's servo.
        target: Point to touch, robot frame, metres.
        objects: Body unique id -> object name of everything that can be touched.
        config: Simulator configuration.
        rng: Generator of the weight sensor noise.
    """

    def __init__(self, client: int, robot: RobotModel, arm: str, servo: JointServo,
                 target: tuple[float, float, float], objects: dict[int, str],
                 config: SimConfig, rng: np.random.Generator) -> None:
        self.client = client
        self.robot = robot
        self.arm = arm
        self.servo = servo
        self.target = tuple(float(c) for c in target)
        self.objects = objects
        self.config = config
        self.rng = rng
        self.phase = "reach"
        self.reading: HapticReading | None = None
        self._constraint: int | None = None
        self._contact_z = 0.0
        self._contact_point = (math.nan, math.nan, math.nan)
        self._touched: int | None = None
        self._efforts: list[float] = []
        self._gravity: list[float] = []
        self._floor = JOINT_LIMITS[f"{arm.split('_')[0]}_arm_lift"][0] + 0.01
        self._dof = robot.dof_index[f"{arm.split('_')[0]}_arm_lift"]
        ik = arm_ik(arm, (self.target[0], self.target[1]))
        if ik is None:
            self.servo.fail()
            self._finish()
            return
        self._planar = ik
        self.servo.set_reference(np.array([HOVER, *ik]), tolerance=config.arm_tolerance)

    @property
    def done(self) -> bool:
        """True when the routine has finished (successfully or not)."""
        return self.phase == "done"

    @property
    def side(self) -> int:
        """0 for the left arm, 1 for the right arm (as in Goal.arm)."""
        return 0 if self.arm == "left_arm" else 1

    def _contact(self) -> tuple[int, tuple[float, float, float]] | None:
        points = pb.getContactPoints(bodyA=self.robot.body,
                                     linkIndexA=self.robot.hand_link[self.arm],
                                     physicsClientId=self.client)
        for point in points:
            if point[2] in self.objects and point[9] > TOUCH_FORCE:
                return point[2], tuple(point[6])
        return None

    def _go(self, lift: float, planar: tuple[float, float] | None = None,
            tolerance: float | None = None) -> None:
        planar = self._planar if planar is None else planar
        self.servo.set_reference(np.array([lift, *planar]),
                                 tolerance=tolerance or self.config.arm_tolerance)

    def _release(self) -> None:
        if self._constraint is not None:
            pb.removeConstraint(self._constraint, physicsClientId=self.client)
            self._constraint = None

    def _grasp(self, body: int) -> None:
        hand = pb.getLinkState(self.robot.body, self.robot.hand_link[self.arm],
                               computeForwardKinematics=True, physicsClientId=self.client)
        obj_pos, obj_orn = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        # Objects at rest sleep (Simulator._spawn); one held by the hand must move with it.
        pb.changeDynamics(body, -1, activationState=pb.ACTIVATION_STATE_WAKE_UP,
                          physicsClientId=self.client)
        # Constraint frames of a multibody link are relative to its centre of mass.
        inv_pos, inv_orn = pb.invertTransform(hand[0], hand[1])
        rel_pos, rel_orn = pb.multiplyTransforms(inv_pos, inv_orn, obj_pos, obj_orn)
        self._constraint = pb.createConstraint(
            self.robot.body, self.robot.hand_link[self.arm], body, -1, pb.JOINT_FIXED,
            [0, 0, 0], rel_pos, [0, 0, 0], parentFrameOrientation=rel_orn,
            physicsClientId=self.client)
        pb.changeConstraint(self._constraint, maxForce=2000.0, physicsClientId=self.client)

    def _finish(self) -> None:
        self._release()
        if self.reading is None:
            contact = self._touched is not None
            self.reading = HapticReading(arm=self.side, contact=contact,
                                         position=self._contact_point, weight=math.nan)
        self.phase = "done"

    def abort(self) -> None:
        """Stop at once (goal timeout): release any held object and keep the reading."""
        if not self.done:
            self._finish()

    def on_step(self, q_arm: np.ndarray, applied: np.ndarray, gravity_model: np.ndarray) -> None:
        """Advance by one physics step.

        Args:
            q_arm: The arm's joint positions (lift, shoulder, elbow).
            applied: Torques/forces applied to every joint in the last step (dof order).
            gravity_model: Inverse-dynamics gravity torques of the robot alone (dof order).
        """
        if self.done:
            return
        state = self.servo.state
        if state == ControllerState.FAILED:
            self._finish()
            return
        converged = state == ControllerState.CONVERGED
        if self.phase in ("approach", "touch"):
            hit = self._contact()
            if hit is not None:
                self._touched, self._contact_point = hit
                self._contact_z = float(q_arm[0])
                self._grasp(self._touched)
                self.phase = "lift"
                # Under load the lift joint sags (the model does not know the object):
                # accept a looser error while holding it.
                self._go(self._contact_z + self.config.lift_height_m,
                         tolerance=max(self.config.arm_tolerance, 0.03))
                return
        if self.phase == "reach" and converged:
            self.phase = "approach"
            pre = min(HOVER, max(self._floor, 2.0 * self.target[2] + 0.05))
            self._go(pre)
        elif self.phase == "approach" and converged:
            self.phase = "touch"
        elif self.phase == "touch":
            ref = self.servo.reference
            if ref is not None and ref[0] > self._floor:
                lowered = max(self._floor,
                              ref[0] - self.config.touch_speed * self.config.time_step)
                self.servo.move_reference(np.array([lowered, *self._planar]))
            elif converged:
                self.phase = "rise"  # reached the floor without touching anything
                self._go(HOVER)
        elif self.phase == "lift" and converged:
            self.phase = "weigh"
        elif self.phase == "weigh":
            self._efforts.append(float(applied[self._dof]))
            self._gravity.append(float(gravity_model[self._dof]))
            # The first half lets the swing of the lift die out; the second is measured.
            if len(self._efforts) >= 2 * self.config.weigh_steps:
                self._efforts = self._efforts[self.config.weigh_steps:]
                self._gravity = self._gravity[self.config.weigh_steps:]
                weight = weight_from_efforts(np.array(self._efforts), np.array(self._gravity))
                weight += float(self.rng.normal(0.0, self.config.weight_noise_kg))
                self.reading = HapticReading(arm=self.side, contact=True,
                                             position=self._contact_point, weight=weight)
                self.phase = "lower"
                self._go(self._contact_z + 0.005, tolerance=max(self.config.arm_tolerance,
                                                                 0.03))
        elif self.phase == "lower" and converged:
            self._release()
            self.phase = "rise"
            self._go(HOVER)
        elif self.phase == "rise" and converged:
            self.phase = "rest"
            self._go(HOVER, planar=ARM_REST[self.arm])
        elif self.phase == "rest" and converged:
            self._finish()
