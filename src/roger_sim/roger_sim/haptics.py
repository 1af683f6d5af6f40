"""Haptic improvement: an arm reaches an object, touches it, probes its shape, lifts it and
weighs it.

The routine is a sequence of arm-servo references, each started when the previous one
converged (the probe moves: when it passed, see below):

    reach     hand at HOVER height over the target (planar inverse kinematics; a target
              beyond reach by at most ``reach_slack_m`` is pulled back to the edge of
              reach, ``edge_of_reach``; one farther fails at once)
    approach  hand quickly down to just above the expected top (2 * target z + 5 cm)
    touch     hand down at ``touch_speed`` until it touches an object (contact points)
    probe     (``probe_directions`` > 0) after the first touch, for each direction:
              up towards ``probe_rise_m`` above the first touch, across to the first touch
              + ``probe_radius_m`` * direction, down at ``touch_speed`` until the hand
              touches something or is ``probe_depth_m`` below the first touch (it fell off
              the object: nothing recorded); an unreachable probe is skipped, and so is
              one whose descent stalls before the hand touches anything (another link
              of the arm rests on an object: ``PROBE_STALL_S``). Then back
              over the first touch, down at ``touch_speed`` to touch it again, and grasp
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

The probe moves are via points, not stops, so that probing costs at most half of the
routine's time (docs/simulator.md has the measurements): the hand goes across as soon as
it is ``PROBE_GLIDE`` above the highest touch so far (while still rising), at that
height, and starts down once every arm joint is within tolerance of the probe's pose.
On a convex top, touched first at its highest point, nothing lies in the way.

Shape from touch: every touch (the first and each probe that touched) is one
:class:`TactileContact`, what a tactile sensor on the fingertip reports: the contact point
on the touched surface (plus Gaussian noise of std ``tactile_noise_m``) and that surface's
outward normal (turned by Gaussian noise of about ``tactile_normal_noise_rad`` per axis:
a tactile array's pressure pattern gives the direction only so well, and a sensor that
read a flat top as exactly vertical every time would hand the memory a feature with no
spread at all). They come from the hand's contact query, never from object poses.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from roger_common.types import ControllerState, HapticReading, TactileContact
from roger_sim.config import SimConfig
from roger_sim.controllers import JointServo
from roger_sim.robot import (
    ARM_REST,
    FINGER,
    HOVER,
    JOINT_LIMITS,
    PAD_HALF,
    REACH,
    RobotModel,
    arm_ik,
    shoulder_xy,
)

GRAVITY: float = 9.81
#: Smallest normal force that counts as a touch, newtons.
TOUCH_FORCE: float = 0.5
#: A probe's descent that has not come down ``PROBE_STALL_M`` in this many simulated
#: seconds, the hand touching nothing, is given up: another link of the arm rests on an
#: object on the way (a box beside the shoulder on random 8x3 / yaw 10021), and waiting
#: would run into the goal's timeout and lose the weight with it.
PROBE_STALL_S: float = 0.1
PROBE_STALL_M: float = 0.002
#: Between probe touches the hand glides to this far above the first touch's height (the
#: expected top) before it comes down at ``touch_speed``, metres.
PROBE_GLIDE: float = 0.003
#: A taxel's ray starts this far inside the pad, above a surface pressed into the skin.
TAXEL_START: float = 0.003


def weight_from_efforts(efforts: np.ndarray, gravity_model: np.ndarray) -> float:
    """Weight (kg) of a held object from lift-joint forces (equation 5's w).

    Args:
        efforts: Forces the lift motor applied while holding still, newtons.
        gravity_model: Forces the arm alone needs at the same poses, newtons.
    """
    return float(np.mean(np.asarray(efforts, float) - np.asarray(gravity_model, float))
                 / GRAVITY)


def probe_offsets(config: SimConfig) -> list[tuple[float, float]]:
    """Horizontal offsets (dx, dy) of the probe touches from the first touch, robot frame.

    ``probe_directions`` unit directions evenly spread from +x (0, 90, 180, 270 degrees for
    four), each ``probe_radius_m`` long; none when ``probe_directions`` is 0.
    """
    n, r = config.probe_directions, config.probe_radius_m
    return [(r * math.cos(2.0 * math.pi * k / n), r * math.sin(2.0 * math.pi * k / n))
            for k in range(n)]


def edge_of_reach(arm: str, xy: tuple[float, float], slack: float
                  ) -> tuple[float, float] | None:
    """The point at the edge of ``arm``'s reach on the line from its shoulder to ``xy``,
    when ``xy`` lies beyond the reach by at most ``slack`` metres; else None.

    An object at the edge of reach whose position the eyes put a centimetre or two too far
    (radial error 1-2 cm, docs/simulator.md) still reaches into it: the hand touches its
    near side there.
    """
    sx, sy = shoulder_xy(arm)
    dx, dy = xy[0] - sx, xy[1] - sy
    r = math.hypot(dx, dy)
    if slack <= 0.0 or not REACH < r <= REACH + slack:
        return None
    # A millimetre inside the edge, so that the inverse kinematics holds.
    k = (REACH - 0.001) / r
    return sx + k * dx, sy + k * dy


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
        rng: Generator of the weight sensor noise; the tactile noise comes from a child
            of it (``Generator.spawn``), which leaves its own draws as they were.
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
        # Spawning draws nothing from ``rng``: the weight noise of this and every later goal
        # is the same with or without probe touches (probe_directions = 0 is today's run).
        self._tactile_rng = rng.spawn(1)[0]
        # The tactile images' noise from a child of that (spawning draws nothing).
        self._image_rng = self._tactile_rng.spawn(1)[0]
        self._contacts: list[TactileContact] = []
        self._probes = probe_offsets(config)
        self._next_probe = 0
        # Probe touches so far whose pad was pressed all over: the later probes go out
        # ``probe_step_m`` farther for each.
        self._pressed_all = 0
        self._probe = (0.0, 0.0)
        self._probe_planar: tuple[float, float] = (0.0, 0.0)
        # The lift height and step count when the probe's descent last made progress.
        self._descent = (math.inf, 0)
        # The largest joint error and step count when the move across last made progress,
        # and whether this move was raised to the probe height after a stall.
        self._across = (math.inf, 0)
        self._raised = False
        self._step_count = 0
        # Lift height of the highest touch so far (the first touch's, on a convex top).
        self._top = 0.0
        self._efforts: list[float] = []
        self._gravity: list[float] = []
        lift = f"{arm.split('_')[0]}_arm_lift"
        self._floor = JOINT_LIMITS[lift][0] + 0.01
        self._ceiling = JOINT_LIMITS[lift][1]
        self._dof = robot.dof_index[lift]
        ik = arm_ik(arm, (self.target[0], self.target[1]))
        if ik is None:
            edge = edge_of_reach(arm, (self.target[0], self.target[1]), config.reach_slack_m)
            if edge is not None:
                self.target = (edge[0], edge[1], self.target[2])
                ik = arm_ik(arm, edge)
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

    def _contact(self) -> tuple[int, tuple[float, float, float],
                                tuple[float, float, float]] | None:
        """The hand's tactile sensor: touched body, contact point on it, its outward normal.

        bodyA is the robot, so positionOnB (6) lies on the object and contactNormalOnB (7),
        which points from B to A, is the object's outward surface normal there.
        """
        points = pb.getContactPoints(bodyA=self.robot.body,
                                     linkIndexA=self.robot.hand_link[self.arm],
                                     physicsClientId=self.client)
        for point in points:
            if point[2] in self.objects and point[9] > TOUCH_FORCE:
                return point[2], tuple(point[6]), tuple(point[7])
        return None

    def _record(self, point: tuple[float, float, float], normal: tuple[float, float, float],
                probe: tuple[float, float]) -> None:
        noisy = np.asarray(point, float) + self._tactile_rng.normal(
            0.0, self.config.tactile_noise_m, 3)
        unit = np.asarray(normal, float)
        unit = unit / max(float(np.linalg.norm(unit)), 1e-12)
        if self.config.tactile_normal_noise_rad > 0:
            unit = unit + self._tactile_rng.normal(0.0, self.config.tactile_normal_noise_rad, 3)
            unit = unit / max(float(np.linalg.norm(unit)), 1e-12)
        image, pitch = self._tactile_image()
        self._contacts.append(TactileContact(
            point=(float(noisy[0]), float(noisy[1]), float(noisy[2])),
            normal=(float(unit[0]), float(unit[1]), float(unit[2])),
            probe=(float(probe[0]), float(probe[1])), image=image, pitch=pitch))

    def _tactile_image(self) -> tuple[tuple[float, ...], float]:
        """The tactile array's image at this instant (``TactileContact.image``) and its
        taxel pitch; ((), 0.0) without an array.

        Each taxel casts a ray straight down the finger from just inside the pad to
        ``tactile_range_m`` below it: the depth of what it meets there (the robot's own
        links are passed through), or NaN. A skin that reports how far each taxel is
        pressed, as optical tactile sensors do, over a range of a few millimetres.
        """
        n = self.config.tactile_taxels
        if n == 0:
            return (), 0.0
        state = pb.getLinkState(self.robot.body, self.robot.hand_link[self.arm],
                                computeForwardKinematics=True, physicsClientId=self.client)
        origin = np.asarray(state[4], float)
        rotation = np.asarray(pb.getMatrixFromQuaternion(state[5]), float).reshape(3, 3)
        grid = np.linspace(-PAD_HALF, PAD_HALF, n)
        xs, ys = np.meshgrid(grid, grid)  # row by row: y outer, x inner
        local = np.stack([xs.ravel(), ys.ravel(), np.full(n * n, -FINGER)], axis=1)
        down = rotation @ np.array([0.0, 0.0, -1.0])
        pads = origin + local @ rotation.T
        starts = pads - TAXEL_START * down
        length = TAXEL_START + self.config.tactile_range_m
        ends = pads + self.config.tactile_range_m * down
        depth = np.full(n * n, math.inf)
        # Up to three hits per ray, the first that is not the robot's own.
        for k in range(3):
            hits = pb.rayTestBatch(starts.tolist(), ends.tolist(), reportHitNumber=k,
                                   physicsClientId=self.client)
            for i, hit in enumerate(hits):
                if hit[0] >= 0 and hit[0] != self.robot.body:
                    depth[i] = min(depth[i], hit[2] * length - TAXEL_START)
        if self.config.tactile_depth_noise_m > 0:
            depth = depth + self._image_rng.normal(0.0, self.config.tactile_depth_noise_m,
                                                   n * n)
        depth[~(depth <= self.config.tactile_range_m)] = math.nan
        return tuple(float(v) for v in depth), float(grid[1] - grid[0])

    @property
    def _probe_height(self) -> float:
        """Where the hand rises to after a probe touch: ``probe_rise_m`` above the top."""
        return min(self._ceiling, self._top + self.config.probe_rise_m)

    @property
    def _glide_height(self) -> float:
        """Where the hand moves across between probes: just above the highest touch."""
        return min(self._probe_height, self._top + PROBE_GLIDE)

    def _rise(self, q_arm: np.ndarray) -> None:
        """Up from a probe (touched or fallen off), at the probe's planar pose."""
        self._top = max(self._top, float(q_arm[0]))
        self.phase = "probe_up"
        self._go(self._probe_height, planar=self._probe_planar)

    def _next_probe_or_return(self) -> None:
        """Across to the next reachable probe at glide height, or back over the first touch."""
        cx, cy = self.target[0], self.target[1]
        while self._next_probe < len(self._probes):
            dx, dy = self._probes[self._next_probe]
            self._next_probe += 1
            out = 1.0 + self._pressed_all * self.config.probe_step_m / self.config.probe_radius_m
            dx, dy = dx * out, dy * out
            ik = arm_ik(self.arm, (cx + dx, cy + dy))
            # An unreachable probe is skipped.
            if ik is not None and self.servo.reachable(np.array([self._probe_height, *ik])):
                self._probe, self._probe_planar = (dx, dy), ik
                self.phase = "probe_move"
                self._raised = False
                self._go(self._glide_height, planar=ik)
                return
        self.phase = "return"
        self._raised = False
        self._go(self._glide_height)

    def _stalled(self, lift: float) -> bool:
        """True when the lift has not come down ``PROBE_STALL_M`` for ``PROBE_STALL_S``
        since the descent began (``probe_down`` entered) or last made progress."""
        height, since = self._descent
        if lift < height - PROBE_STALL_M:
            self._descent = (lift, self._step_count)
            return False
        return self._step_count - since >= math.ceil(PROBE_STALL_S / self.config.time_step)

    def _blocked(self, q_arm: np.ndarray) -> bool:
        """True when a move across (to a probe, or back over the first touch) has not come
        ``PROBE_STALL_M`` nearer its reference (largest joint error) for ``PROBE_STALL_S``:
        the hand is held against something, a prism's ridge above a touch on its slope."""
        ref = self.servo.reference
        if ref is None:
            return False
        error = float(np.max(np.abs(q_arm - ref)))
        best, since = self._across
        if error < best - PROBE_STALL_M:
            self._across = (error, self._step_count)
            return False
        return self._step_count - since >= math.ceil(PROBE_STALL_S / self.config.time_step)

    def _across_again(self, planar: tuple[float, float]) -> bool:
        """After a stalled move across: the first time, the same move at the probe height
        (True); the second time, nothing (False: the caller gives the move up)."""
        if self._raised:
            return False
        self._raised = True
        self._go(self._probe_height, planar=planar)
        return True

    def _passed(self, q_arm: np.ndarray) -> bool:
        """Every arm joint within tolerance of the reference, moving or not.

        The moves between probes end on this (a via point) rather than on convergence:
        waiting for a critically damped servo to come to rest cost over half their time.
        """
        ref = self.servo.reference
        return ref is not None and bool(np.all(np.abs(q_arm - ref) < self.servo.tolerance))

    def _lower(self, bottom: float, planar: tuple[float, float]) -> bool:
        """Move the lift reference down at ``touch_speed``; True once it is at ``bottom``."""
        ref = self.servo.reference
        if ref is not None and ref[0] > bottom:
            lowered = max(bottom, ref[0] - self.config.touch_speed * self.config.time_step)
            self.servo.move_reference(np.array([lowered, *planar]))
            return False
        return True

    def _go(self, lift: float, planar: tuple[float, float] | None = None,
            tolerance: float | None = None) -> None:
        planar = self._planar if planar is None else planar
        self._across = (math.inf, self._step_count)
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
                                         position=self._contact_point, weight=math.nan,
                                         contacts=tuple(self._contacts))
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
        self._step_count += 1
        state = self.servo.state
        if state == ControllerState.FAILED:
            self._finish()
            return
        converged = state == ControllerState.CONVERGED
        if self.phase == "probe_down":
            hit = self._contact()
            if hit is not None:
                # Recorded whatever body it is: a probe that lands on a neighbour of the
                # first touch's object feels the same to a tactile sensor.
                self._record(hit[1], hit[2], self._probe)
                if self._contacts[-1].taxels and all(
                        math.isfinite(v) for v in self._contacts[-1].image):
                    self._pressed_all += 1
                self._rise(q_arm)
                return
        if self.phase in ("approach", "touch", "retouch"):
            hit = self._contact()
            if hit is not None:
                body = hit[0]
                self._contact_z = float(q_arm[0])
                if self.phase != "retouch":
                    self._touched, self._contact_point = body, hit[1]
                    self._record(hit[1], hit[2], (0.0, 0.0))
                    if self._probes:
                        self._probe_planar = self._planar
                        self._rise(q_arm)
                        return
                else:
                    # The grasp holds what the hand touches now (the probes may have
                    # nudged the object); the reading keeps the first touch's position.
                    self._touched = body
                    # The hand came back from the probes as a via point and may still be
                    # settling sideways: held to where it is, so that it does not carry
                    # the object along while it lifts (2-4 mm on touching.yaml before,
                    # enough to turn two touching objects into one ROI for perception).
                    self._planar = (float(q_arm[1]), float(q_arm[2]))
                self._grasp(body)
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
        elif self.phase in ("touch", "retouch"):
            if self._lower(self._floor, self._planar) and converged:
                self.phase = "rise"  # reached the floor without touching anything
                self._go(HOVER)
        elif self.phase == "probe_up" and (converged or q_arm[0] >= self._glide_height):
            # Clear of the highest touch: across at once, while still rising.
            self._next_probe_or_return()
        elif self.phase == "probe_move" and (converged or self._passed(q_arm)):
            self.phase = "probe_down"
            self._descent = (float(q_arm[0]), self._step_count)
        elif self.phase == "probe_move" and self._blocked(q_arm):
            # Held against the object on the way across (gliding just above a first touch
            # on a prism's slope, into its ridge): once more higher, then on to the next.
            if not self._across_again(self._probe_planar):
                self._next_probe_or_return()
        elif self.phase == "probe_down":
            bottom = max(self._floor, self._contact_z - self.config.probe_depth_m)
            if self._lower(bottom, self._probe_planar) and converged:
                # Fell off the object: this probe touched nothing, it records nothing.
                self._rise(q_arm)
            elif self._stalled(float(q_arm[0])):
                # Held up before the hand touched: nothing recorded, on to the next probe
                # (its height is no touch, so the glide height stays).
                self.phase = "probe_up"
                self._go(self._probe_height, planar=self._probe_planar)
        elif self.phase == "return" and (converged or self._passed(q_arm)):
            self.phase = "retouch"
        elif self.phase == "return" and self._blocked(q_arm) and not self._across_again(
                self._planar):
            self.phase = "retouch"  # down towards the first touch from where the hand is
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
                                             position=self._contact_point, weight=weight,
                                             contacts=tuple(self._contacts))
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
