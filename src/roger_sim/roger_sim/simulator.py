"""The Roger-the-Crab simulator: pybullet world, five servo controllers, retinas, haptics.

One :class:`Simulator` owns one pybullet client (DIRECT unless ``config.gui``) and passes
its id to every call, so several simulators can live in one process. Time is simulated:
``sim_time = physics_steps * time_step``; nothing depends on the wall clock unless
``config.realtime`` asks to slow down for watching. Same seed and world and the same goals
give the same images and readings, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Self

import numpy as np
import pybullet as pb

from roger_common.configdoc import check_live_change
from roger_common.errors import WorldFileError
from roger_common.types import (
    Action,
    CameraModel,
    ControllerReport,
    ControllerState,
    Goal,
    HapticReading,
    ObjectSpec,
    Rngs,
    StereoFrame,
    WorldSpec,
)
from roger_sim.config import SimConfig
from roger_sim.controllers import JointServo
from roger_sim.haptics import HapticRoutine
from roger_sim.objects import ObjectFactory, yaw_of
from roger_sim.retina import Retina
from roger_sim.robot import (
    ARM_REST,
    CONTROLLER_JOINTS,
    CONTROLLERS,
    HOVER,
    JOINT_EFFORT,
    JOINT_LIMITS,
    build_robot,
    eye_vergence_angles,
    fixation_angles,
)
from roger_sim.world import check_overlap, object_from_dict, world_to_dict

#: Where the eyes look before the first goal (the middle of the usual table).
INITIAL_FIXATION: tuple[float, float, float] = (0.75, 0.0, 0.1)


class Simulator:
    """Roger-the-Crab in pybullet.

    Args:
        world: Objects and light; an empty world is allowed here (objects can be added).
        config: Simulator parameters.
        seed: Seed of the pixel and weight noise.
        start_steps: Physics steps already taken (the simulated clock starts at
            ``start_steps * time_step``): a restarted simulator goes on from the
            simulated time it had, so that stamps never run backwards.
    """

    def __init__(self, world: WorldSpec, config: SimConfig | None = None,
                 seed: int = 0, start_steps: int = 0) -> None:
        if isinstance(start_steps, bool) or not isinstance(start_steps, int) or start_steps < 0:
            raise ValueError(f"Simulator.start_steps must be an integer >= 0, "
                             f"got {start_steps!r}")
        self.config = config or SimConfig()
        cfg = self.config
        self.client = pb.connect(pb.GUI if cfg.gui else pb.DIRECT)
        c = self.client
        pb.resetSimulation(physicsClientId=c)
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        pb.setTimeStep(cfg.time_step, physicsClientId=c)
        self._rngs = Rngs(seed)
        self._pixel_rng = self._rngs.child("pixels")
        self._weight_rng = self._rngs.child("weight")
        g = cfg.ground_grey
        ground_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[50.0, 50.0, 0.05],
                                             physicsClientId=c)
        ground_vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[50.0, 50.0, 0.05],
                                          rgbaColor=[g, g, g, 1.0], physicsClientId=c)
        self._ground = pb.createMultiBody(0.0, ground_col, ground_vis, [0.0, 0.0, -0.05],
                                          physicsClientId=c)
        pb.changeDynamics(self._ground, -1, lateralFriction=0.8, physicsClientId=c)
        self.robot = build_robot(c, cfg.robot_grey, visible=cfg.gui)
        self._names = self.robot.joint_names
        self._indices = [self.robot.joint_index[n] for n in self._names]
        self._servos: dict[str, JointServo] = {}
        for name in CONTROLLERS:
            joints = CONTROLLER_JOINTS[name]
            bandwidth = cfg.arm_bandwidth if name.endswith("arm") else cfg.head_bandwidth
            tol = cfg.arm_tolerance if name.endswith("arm") else cfg.shift_tolerance_rad
            self._servos[name] = JointServo(
                name, joints, bandwidth, cfg.time_step,
                np.array([JOINT_LIMITS[j][0] for j in joints]),
                np.array([JOINT_LIMITS[j][1] for j in joints]),
                cfg.goal_timeout_s, tol, cfg.velocity_tolerance, cfg.settle_steps)
        self._effort_limit = np.array([JOINT_EFFORT[n] for n in self._names])
        self._effort_low = -self._effort_limit
        self._servo_dofs = [(servo, np.array(self._dofs(name), np.intp))
                            for name, servo in self._servos.items()]
        self._servo_list = [servo for servo, _ in self._servo_dofs]
        order = np.concatenate([d for _, d in self._servo_dofs])
        self._bank_sizes = np.array([len(d) for _, d in self._servo_dofs])
        self._bank_starts: np.ndarray | None = None
        if np.array_equal(order, np.arange(len(self._names))):
            self._bank_starts = np.concatenate([[0], np.cumsum(self._bank_sizes)[:-1]])
        self._bank_kp = np.repeat([s.kp for s in self._servo_list], self._bank_sizes)
        self._bank_kd = np.repeat([s.kd for s in self._servo_list], self._bank_sizes)
        self._tol_key: tuple[tuple[float, float], ...] = ()
        self._tol_arrays = (np.zeros(0), np.zeros(0))
        self._physics_seconds = 0.0
        self._reset_pose()
        self._factory = ObjectFactory(c)
        self._label_lut: np.ndarray | None = None
        self._specs: dict[str, ObjectSpec] = {}
        self._bodies: dict[str, int] = {}
        self._world_meta = world
        for spec in world.objects:
            self._spawn(spec)
        self._retina = Retina(c, cfg, world.light_direction)
        # The fovea: the left eye's central field at a higher resolution, rendered after a
        # visual improvement. Its pixel noise has its own stream, so that the retinas'
        # noise (and every run without a fovea look) stays what it was.
        self._fovea = (Retina(c, dataclasses.replace(cfg, fov_deg=cfg.fovea_fov_deg,
                                                     fovea_fov_deg=0.0,
                                                     image_size=cfg.fovea_size),
                              world.light_direction) if cfg.fovea_fov_deg > 0 else None)
        self._fovea_rng = self._rngs.child("fovea")
        # The right fovea's noise has a stream of its own: the left fovea's stays as it was.
        self._fovea_right_rng = self._rngs.child("fovea_right")
        self._applied = np.zeros(len(self._names))
        self._steps = start_steps
        self._last_haptic: HapticReading | None = None
        self._last_goal_haptic = False

    # ----------------------------------------------------------------------------- state

    def _reset_pose(self) -> None:
        pose = dict(fixation_angles(INITIAL_FIXATION) or {})
        for arm in ("left_arm", "right_arm"):
            lift, shoulder, elbow = CONTROLLER_JOINTS[arm]
            pose[lift] = HOVER
            pose[shoulder], pose[elbow] = ARM_REST[arm]
        for name, value in pose.items():
            pb.resetJointState(self.robot.body, self.robot.joint_index[name], value,
                               physicsClientId=self.client)

    @property
    def camera(self) -> CameraModel:
        """Intrinsics shared by both retinas."""
        return self._retina.camera

    def reconfigure(self, config: SimConfig) -> None:
        """Take a new configuration that differs only in fields marked live (``realtime``
        pacing); the next goal uses it.

        Raises:
            ValueError: Another field differs (it shaped the world or the retinas).
        """
        check_live_change(self.config, config)
        self.config = config

    @property
    def sim_time(self) -> float:
        """Simulated seconds since the start."""
        return self._steps * self.config.time_step

    @property
    def physics_steps(self) -> int:
        """Physics steps taken since the start."""
        return self._steps

    @property
    def floor_seconds(self) -> dict[str, float]:
        """Wall seconds spent so far in pybullet's integrator and renderer alone.

        ``physics``: inside ``stepSimulation``; ``render``: inside ``getCameraImage``. Their
        sum over a control cycle is its physical floor (``roger bench``).
        """
        return {"physics": self._physics_seconds,
                "render": self._retina.seconds + (self._fovea.seconds if self._fovea else 0.0)}

    @property
    def fovea_retina(self) -> Retina | None:
        """The fovea's renderer (the left eye's by default; any eye pose may be passed to
        its ``render``), None without a fovea. For diagnosis (bench/fovea_stereo.py)."""
        return self._fovea

    def object_bodies(self) -> dict[str, int]:
        """Object name -> pybullet body id, as the renderers' id images hold them."""
        return dict(self._bodies)

    @property
    def last_haptic(self) -> HapticReading | None:
        """Reading of the last goal if it was a haptic improvement, else None."""
        return self._last_haptic if self._last_goal_haptic else None

    @property
    def world(self) -> WorldSpec:
        """The current world: objects as they stand now (positions from the physics)."""
        poses = self.object_poses()
        objects = []
        for name, spec in self._specs.items():
            x, y, _, yaw = poses[name]
            objects.append(ObjectSpec(name=spec.name, shape=spec.shape, position=(x, y),
                                      size=spec.size, intensity=spec.intensity,
                                      weight=spec.weight, yaw=yaw, texture=spec.texture))
        meta = self._world_meta
        return WorldSpec(objects=tuple(objects), name=meta.name,
                         light_direction=meta.light_direction, source=meta.source)

    def object_poses(self) -> dict[str, tuple[float, float, float, float]]:
        """Ground truth: object name -> (x, y, z, yaw) of its centre, robot frame."""
        out = {}
        for name, body in self._bodies.items():
            pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
            out[name] = (float(pos[0]), float(pos[1]), float(pos[2]), yaw_of(orn))
        return out

    def joint_state(self) -> tuple[list[str], list[float], list[float], list[float]]:
        """(names, positions, velocities, efforts) of the movable joints.

        Efforts are the torques (N m) or forces (N) applied in the last physics step.
        """
        q, qd = self._read()
        return list(self._names), q.tolist(), qd.tolist(), self._applied.tolist()

    def controller_states(self) -> dict[str, ControllerState]:
        """Status of the five controllers, keyed by controller name."""
        return {name: servo.state for name, servo in self._servos.items()}

    def _read(self) -> tuple[np.ndarray, np.ndarray]:
        states = pb.getJointStates(self.robot.body, self._indices, physicsClientId=self.client)
        both = np.array([s[:2] for s in states], float)
        return both[:, 0].copy(), both[:, 1].copy()

    def _dofs(self, controller: str) -> list[int]:
        return [self.robot.dof_index[j] for j in CONTROLLER_JOINTS[controller]]

    # ------------------------------------------------------------------------- physics

    def _step(self, routine: HapticRoutine | None) -> None:
        """One physics step: statuses, haptic routine, computed torques, integration."""
        q, qd = self._read()
        servos = self._servo_list
        if self._bank_starts is None:
            for servo, dofs in self._servo_dofs:
                servo.update_status(q[dofs], qd[dofs])
        else:
            # Every servo's status test at once (the dofs are contiguous, servo by servo):
            # the same comparisons as JointServo.update_status, one numpy call each.
            refs = np.concatenate([s.reference if s.reference is not None else q[d]
                                   for s, d in self._servo_dofs])
            tol, vtol = self._bank_tolerances(servos)
            ok = (abs(refs - q) < tol) & (abs(qd) < vtol)
            within = np.logical_and.reduceat(ok, self._bank_starts).tolist()
            for servo, w in zip(servos, within, strict=True):
                servo.advance(w)
        q_list = q.tolist()
        if routine is not None and not routine.done:
            zeros = [0.0] * len(q_list)
            gravity = np.array(pb.calculateInverseDynamics(
                self.robot.body, q_list, zeros, zeros, physicsClientId=self.client))
            routine.on_step(q[self._dofs(routine.arm)], self._applied, gravity)
        if self._bank_starts is None:
            qdd = np.zeros(len(q_list))
            for servo, dofs in self._servo_dofs:
                qdd[dofs] = servo.acceleration(q[dofs], qd[dofs])
        else:
            # qdd* = wn^2 (q_ref - q) - 2 wn qd for every joint at once (controllers.py).
            target = np.concatenate([s.target(q[d]) for s, d in self._servo_dofs])
            qdd = self._bank_kp * (target - q) - self._bank_kd * qd
        # Computed torque: tau = M(q) qdd* + C(q, qd) + g(q); g(q) is the gravity compensation.
        tau = np.array(pb.calculateInverseDynamics(self.robot.body, q_list, qd.tolist(),
                                                   qdd.tolist(), physicsClientId=self.client))
        # np.clip's Python wrapper cost more than the clipping (ufuncs called directly).
        np.maximum(tau, self._effort_low, out=tau)
        np.minimum(tau, self._effort_limit, out=tau)
        pb.setJointMotorControlArray(self.robot.body, self._indices, pb.TORQUE_CONTROL,
                                     forces=tau.tolist(), physicsClientId=self.client)
        t0 = time.perf_counter()
        pb.stepSimulation(physicsClientId=self.client)
        self._physics_seconds += time.perf_counter() - t0
        self._applied = tau
        self._steps += 1

    def _bank_tolerances(self, servos: list[JointServo]) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint position and speed tolerances (a goal may change a servo's), cached."""
        key = tuple((s.tolerance, s.velocity_tolerance) for s in servos)
        if key != self._tol_key:
            self._tol_key = key
            self._tol_arrays = (np.repeat([k[0] for k in key], self._bank_sizes),
                                np.repeat([k[1] for k in key], self._bank_sizes))
        return self._tol_arrays

    def _busy(self, routine: HapticRoutine | None) -> bool:
        if routine is not None and not routine.done:
            return True
        return any(s.state == ControllerState.TRANSIENT for s in self._servos.values())

    def hold(self, steps: int) -> None:
        """Let ``steps`` physics steps pass with no goal: every servo holds its reference
        (the simulated clock advances)."""
        for _ in range(steps):
            self._step(None)

    def execute(self, goal: Goal) -> ControllerReport:
        """Run one physical action until every controller converged or failed.

        Attention shift: neck and both eyes fixate ``goal.target``. Visual improvement:
        the eyes alone verge on ``goal.target`` with the tighter tolerance. Haptic
        improvement: an arm touches, lifts and weighs what is at ``goal.target``.

        Returns:
            The five statuses, the controllers this goal drove, the simulated time at the
            end and the physics steps it took. Controllers still transient at
            ``goal_timeout_s`` are FAILED. A haptic improvement on a target beyond the
            arm's reach by more than ``reach_slack_m`` fails at once (the arm does not
            move); one within it touches from the edge of reach.

        Raises:
            ValueError: For MAP_UPDATE (no controller moves) or an unknown action.
        """
        action = Action(goal.action)
        if action not in (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT,
                          Action.HAPTIC_IMPROVEMENT):
            raise ValueError(f"goal {goal.goal_id}: {action.name} is not a physical action")
        target = tuple(float(c) for c in goal.target)
        if len(target) != 3 or not all(math.isfinite(c) for c in target):
            raise ValueError(f"goal {goal.goal_id}: target must be 3 finite numbers, "
                             f"got {goal.target!r}")
        cfg = self.config
        routine: HapticRoutine | None = None
        self._last_goal_haptic = action == Action.HAPTIC_IMPROVEMENT
        if action == Action.ATTENTION_SHIFT:
            driven: tuple[str, ...] = ("neck", "left_eye", "right_eye")
            self._attention_shift(target)
        elif action == Action.VISUAL_IMPROVEMENT:
            driven = ("left_eye", "right_eye")
            self._visual_improvement(target)
        else:
            arm = {0: "left_arm", 1: "right_arm"}.get(goal.arm)
            if arm is None:
                arm = "left_arm" if target[1] >= 0.0 else "right_arm"
            driven = (arm,)
            objects = {body: name for name, body in self._bodies.items()}
            routine = HapticRoutine(self.client, self.robot, arm, self._servos[arm], target,
                                    objects, cfg, self._weight_rng)
        start = self._steps
        limit = math.ceil(cfg.goal_timeout_s / cfg.time_step)
        wall0 = time.perf_counter()
        while True:
            self._step(routine)
            if not self._busy(routine) or self._steps - start >= limit:
                break
            if cfg.realtime:
                lag = (self._steps - start) * cfg.time_step - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)
        if routine is not None:
            routine.abort()
            self._last_haptic = routine.reading
        for servo in self._servos.values():
            if servo.state == ControllerState.TRANSIENT:
                servo.fail()
        return ControllerReport(goal_id=goal.goal_id, states=self.controller_states(),
                                sim_time=self.sim_time, physics_steps=self._steps - start,
                                driven=driven)

    def _attention_shift(self, target: tuple[float, float, float]) -> None:
        angles = fixation_angles(target)
        tol = self.config.shift_tolerance_rad
        for name in ("neck", "left_eye", "right_eye"):
            servo = self._servos[name]
            if angles is None:
                servo.fail()
                continue
            servo.set_reference(np.array([angles[j] for j in CONTROLLER_JOINTS[name]]),
                                tolerance=tol)

    def _visual_improvement(self, target: tuple[float, float, float]) -> None:
        head = pb.getLinkState(self.robot.body, self.robot.joint_index["neck_tilt"],
                               computeForwardKinematics=True, physicsClientId=self.client)
        rot = np.array(pb.getMatrixFromQuaternion(head[5])).reshape(3, 3)
        local = rot.T @ (np.asarray(target) - np.asarray(head[4]))
        # Fine vergence: only the eyes move, in the head's plane (the neck stays put).
        angles = eye_vergence_angles((float(local[0]), float(local[1])))
        tol = self.config.fine_tolerance_rad
        for name in ("left_eye", "right_eye"):
            self._servos[name].set_reference(np.array([angles[f"{name}_pan"]]), tolerance=tol)

    # ---------------------------------------------------------------------------- vision

    def render(self, goal_id: int = 0, exposures: int = 1, fovea: bool = False) -> StereoFrame:
        """Render both retinas now.

        Args:
            goal_id: Goal the frame belongs to (0: none).
            exposures: Renders integrated; the scene is static while rendering, so this
                is one render with pixel noise of std ``pixel_noise / sqrt(exposures)``.
            fovea: Also render the left eye's fovea (``SimConfig.fovea_fov_deg``; nothing
                when that is 0), with the same exposures, and the right eye's with it
                (``SimConfig.fovea_stereo``).
        """
        if not isinstance(exposures, int) or exposures < 1:
            raise ValueError(f"exposures must be an integer >= 1, got {exposures!r}")
        poses = {side: self.robot.eye_pose(side) for side in ("left", "right")}
        label_names = tuple(self._bodies)
        lut = self._labels_lut()
        images, labels = {}, {}
        sigma = self.config.pixel_noise / math.sqrt(exposures)
        for side in ("left", "right"):
            intensity, ids = self._retina.render(poses[side])
            if sigma > 0:
                noise = self._pixel_rng.normal(0.0, sigma, intensity.shape).astype(np.float32)
                intensity = np.clip(intensity + noise, 0.0, 1.0, dtype=np.float32)
            images[side] = intensity
            # One table lookup per pixel (body id + 1 -> label; -1, the sky, -> -1) instead
            # of one pass over the image per object.
            labels[side] = lut[np.where((ids >= -1) & (ids < len(lut) - 1), ids + 1, 0)]
        fovea_image, fovea_camera, fovea_right = None, None, None
        if fovea and self._fovea is not None:
            fovea_camera = self._fovea.camera
            fovea_image, _ = self._fovea.render(poses["left"])
            if sigma > 0:
                noise = self._fovea_rng.normal(0.0, sigma, fovea_image.shape).astype(np.float32)
                fovea_image = np.clip(fovea_image + noise, 0.0, 1.0, dtype=np.float32)
            if self.config.fovea_stereo:
                fovea_right, _ = self._fovea.render(poses["right"])
                if sigma > 0:
                    shape = fovea_right.shape
                    noise = self._fovea_right_rng.normal(0.0, sigma, shape).astype(np.float32)
                    fovea_right = np.clip(fovea_right + noise, 0.0, 1.0, dtype=np.float32)
        return StereoFrame(stamp=self.sim_time, goal_id=goal_id, left=images["left"],
                           right=images["right"], camera=self.camera,
                           left_pose=poses["left"], right_pose=poses["right"],
                           exposures=exposures, haptic=self.last_haptic,
                           left_labels=labels["left"], right_labels=labels["right"],
                           label_names=label_names, fovea=fovea_image,
                           fovea_camera=fovea_camera, fovea_right=fovea_right)

    def _labels_lut(self) -> np.ndarray:
        """Table from pybullet body id + 1 to label index (-1 for the sky and the robot)."""
        if self._label_lut is None:
            top = max([self.robot.body, self._ground, *self._bodies.values()]) + 2
            lut = np.full(top, -1, np.int32)
            for index, body in enumerate(self._bodies.values()):
                lut[body + 1] = index
            self._label_lut = lut
        return self._label_lut

    def run_goal(self, goal: Goal) -> tuple[ControllerReport, StereoFrame]:
        """Execute ``goal`` then render (integrating exposures, and the fovea, after a
        visual improvement)."""
        report = self.execute(goal)
        improve = Action(goal.action) == Action.VISUAL_IMPROVEMENT
        exposures = self.config.improve_exposures if improve else 1
        return report, self.render(goal.goal_id, exposures, fovea=improve)

    # ---------------------------------------------------------------- world at run time

    def _spawn(self, spec: ObjectSpec) -> None:
        body = self._factory.create(spec)
        # An object at rest goes to sleep (Bullet's deactivation: below its sleeping speeds
        # for 2 s) and costs no contact solving until something touches it. Without this
        # every resting object was solved every step: 0.018 ms per object per step, the
        # physics 7x slower with 64 objects than with 4 (docs/performance.md).
        pb.changeDynamics(body, -1, activationState=pb.ACTIVATION_STATE_ENABLE_SLEEPING,
                          physicsClientId=self.client)
        self._bodies[spec.name] = body
        self._specs[spec.name] = spec
        self._label_lut = None

    def _validated(self, spec: ObjectSpec, source: str) -> ObjectSpec:
        entry = world_to_dict(WorldSpec(objects=(spec,)))["objects"][0]
        # object_from_dict names the object after ``where``: "object (obj01).size".
        checked = object_from_dict(entry, source, "object")
        others = [o for o in self.world.objects if o.name != spec.name]
        check_overlap(others, checked, source, f"object ({spec.name})")
        return checked

    def add_object(self, spec: ObjectSpec) -> None:
        """Add an object; it shows up in the next rendered frame.

        Raises:
            WorldFileError: Duplicate name, invalid field, overlap, or out of view.
        """
        if spec.name in self._bodies:
            raise WorldFileError("add_object", f"object ({spec.name}).name",
                                 f"duplicate name {spec.name!r}: remove it first")
        self._spawn(self._validated(spec, "add_object"))

    def remove_object(self, name: str) -> None:
        """Remove an object by name.

        Raises:
            KeyError: No object has that name.
        """
        if name not in self._bodies:
            raise KeyError(f"remove_object: no object named {name!r}; "
                           f"known: {', '.join(self._bodies) or 'none'}")
        self._factory.remove(self._bodies.pop(name))
        del self._specs[name]
        self._label_lut = None

    def move_object(self, name: str, position_xy: tuple[float, float],
                    yaw: float | None = None) -> None:
        """Put an object somewhere else on the ground (and turn it, if ``yaw`` is given).

        Raises:
            KeyError: No object has that name.
            WorldFileError: The new place overlaps another object or is out of view.
        """
        if name not in self._bodies:
            raise KeyError(f"move_object: no object named {name!r}; "
                           f"known: {', '.join(self._bodies) or 'none'}")
        old = self._specs[name]
        current_yaw = self.object_poses()[name][3]
        spec = ObjectSpec(name=name, shape=old.shape,
                          position=(float(position_xy[0]), float(position_xy[1])),
                          size=old.size, intensity=old.intensity, weight=old.weight,
                          yaw=current_yaw if yaw is None else float(yaw), texture=old.texture)
        spec = self._validated(spec, "move_object")
        self._factory.move(self._bodies[name], spec)
        pb.changeDynamics(self._bodies[name], -1,
                          activationState=pb.ACTIVATION_STATE_WAKE_UP, physicsClientId=self.client)
        self._specs[name] = spec

    def close(self) -> None:
        """Disconnect this simulator's own pybullet client (idempotent)."""
        if self.client >= 0:
            try:
                pb.disconnect(physicsClientId=self.client)
            except pb.error:
                pass
            self.client = -1

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
