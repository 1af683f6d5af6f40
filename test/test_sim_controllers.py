"""Servo controllers: status rules, convergence, failure, gravity compensation, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roger_common.errors import ConfigError
from roger_common.geometry import project_point
from roger_common.types import Action, ControllerState, Goal, ObjectSpec, WorldSpec
from roger_sim.config import SimConfig
from roger_sim.controllers import JointServo
from roger_sim.robot import LINK1, LINK2, arm_fk, arm_ik, fixation_angles
from roger_sim.simulator import Simulator

S = ControllerState
DT = 1.0 / 240.0


def _servo(**kw: object) -> JointServo:
    args: dict[str, object] = {
        "name": "eye", "joints": ("pan",), "bandwidth": 30.0, "time_step": DT,
        "lower": np.array([-1.0]), "upper": np.array([1.0]), "timeout": 1.0,
        "tolerance": 0.005, "velocity_tolerance": 0.05, "settle_steps": 3}
    args.update(kw)
    return JointServo(**args)  # type: ignore[arg-type]


def _integrate(servo: JointServo, q: float, steps: int, stuck: bool = False) -> list[S]:
    """Unit-inertia joint under the servo's acceleration (semi-implicit Euler)."""
    qd = 0.0
    states = []
    for _ in range(steps):
        states.append(servo.update_status(np.array([q]), np.array([qd])))
        if not stuck:
            qd += float(servo.acceleration(np.array([q]), np.array([qd]))[0]) * DT
            q += qd * DT
    return states


def test_servo_status_sequence() -> None:
    servo = _servo()
    assert servo.state == S.NO_REFERENCE
    assert _integrate(servo, 0.0, 5) == [S.NO_REFERENCE] * 5
    servo.set_reference(np.array([0.5]))
    states = _integrate(servo, 0.0, 240)
    assert states[0] == S.TRANSIENT
    assert S.CONVERGED in states
    first = states.index(S.CONVERGED)
    assert first * DT < 0.5  # critically damped at 30 rad/s settles well within 0.5 s
    assert S.FAILED not in states


def test_servo_out_of_reach_fails_at_once() -> None:
    servo = _servo()
    servo.set_reference(np.array([2.0]))
    assert servo.state == S.FAILED
    assert servo.reference is None  # keeps holding, does not chase the bad target


def test_servo_timeout_fails() -> None:
    servo = _servo(timeout=0.25)
    servo.set_reference(np.array([0.5]))
    states = _integrate(servo, 0.0, 120, stuck=True)  # a blocked joint never gets there
    assert states[-1] == S.FAILED
    first = states.index(S.FAILED)
    assert abs((first + 1) * DT - 0.25) <= DT + 1e-9  # fails right at the timeout


@pytest.mark.parametrize("kw", [{"bandwidth": 200.0}, {"tolerance": 0.0},
                                {"time_step": -1.0}, {"lower": np.array([0.0, 1.0])}])
def test_servo_rejects_bad_settings(kw: dict) -> None:
    with pytest.raises(ValueError):
        _servo(**kw)


def test_arm_kinematics_round_trip() -> None:
    for arm, xy in (("left_arm", (0.7, 0.5)), ("right_arm", (0.8, -0.1)),
                    ("left_arm", (0.3, 0.0))):
        angles = arm_ik(arm, xy)
        assert angles is not None
        assert arm_fk(arm, *angles) == pytest.approx(xy, abs=1e-9)
    assert arm_ik("left_arm", (0.0, 0.2 + LINK1 + LINK2 + 0.01)) is None
    assert arm_ik("right_arm", (0.0, -0.2)) is None  # at the shoulder itself


def test_fixation_angles_verge_inwards() -> None:
    angles = fixation_angles((1.0, 0.0, 0.8))
    assert angles is not None
    assert angles["neck_pan"] == pytest.approx(0.0) and angles["neck_tilt"] == pytest.approx(0)
    assert angles["left_eye_pan"] < 0 < angles["right_eye_pan"]
    assert angles["left_eye_pan"] == pytest.approx(-angles["right_eye_pan"])


@pytest.fixture
def sim() -> Simulator:
    world = WorldSpec(objects=(ObjectSpec("ball", "sphere", (0.8, 0.1), 0.2, 99, 1.0),))
    s = Simulator(world, SimConfig(goal_timeout_s=2.0), seed=3)
    yield s
    s.close()


def test_reachable_shift_converges_and_fixates(sim: Simulator) -> None:
    target = (0.8, 0.1, 0.1)
    report = sim.execute(Goal(1, Action.ATTENTION_SHIFT, target))
    assert report.converged
    for name in ("neck", "left_eye", "right_eye"):
        assert report.states[name] == S.CONVERGED
    assert report.states["left_arm"] == S.NO_REFERENCE
    assert 0 < report.physics_steps * sim.config.time_step < 1.0
    assert report.sim_time == pytest.approx(sim.sim_time) and sim.physics_steps > 0
    frame = sim.render()
    for pose in (frame.left_pose, frame.right_pose):
        u, v, _ = project_point(frame.camera, pose, target)
        assert abs(u - 64) < 0.6 and abs(v - 64) < 0.6


def test_unreachable_shift_fails_within_bounded_time(sim: Simulator) -> None:
    report = sim.execute(Goal(1, Action.ATTENTION_SHIFT, (-1.0, 0.0, 0.2)))  # behind
    assert report.states["neck"] == S.FAILED
    assert not report.converged
    assert report.physics_steps * sim.config.time_step <= sim.config.goal_timeout_s


def test_unreachable_arm_fails_and_timeout_fails() -> None:
    world = WorldSpec(objects=(ObjectSpec("ball", "sphere", (0.8, 0.1), 0.2, 99, 1.0),))
    with Simulator(world, SimConfig(goal_timeout_s=0.3)) as s:
        far = s.execute(Goal(1, Action.HAPTIC_IMPROVEMENT, (2.0, 0.3, 0.1)))
        assert far.states["left_arm"] == S.FAILED and not far.converged
        assert far.physics_steps <= 2
        # The arm's FAILED stays latched, but it is not this shift's controller.
        look = s.execute(Goal(3, Action.ATTENTION_SHIFT, (0.8, 0.1, 0.1)))
        assert look.states["left_arm"] == S.FAILED and look.converged
        # Reachable but the whole routine cannot fit in 0.3 s: the arm times out.
        slow = s.execute(Goal(2, Action.HAPTIC_IMPROVEMENT, (0.8, 0.1, 0.1)))
        assert slow.states["left_arm"] == S.FAILED
        assert slow.physics_steps == math.ceil(0.3 / s.config.time_step)


def test_visual_improvement_tightens_vergence(sim: Simulator) -> None:
    target = (0.8, 0.1, 0.1)
    sim.execute(Goal(1, Action.ATTENTION_SHIFT, target))
    report, frame = sim.run_goal(Goal(2, Action.VISUAL_IMPROVEMENT, target))
    assert report.states["left_eye"] == S.CONVERGED == report.states["right_eye"]
    assert frame.exposures == sim.config.improve_exposures and frame.goal_id == 2
    for pose in (frame.left_pose, frame.right_pose):
        u, _, _ = project_point(frame.camera, pose, target)
        # fine tolerance 1 mrad ~ 0.11 px at 128 px / 60 deg
        assert abs(u - 64) < 0.2


def test_map_update_is_rejected(sim: Simulator) -> None:
    with pytest.raises(ValueError, match="MAP_UPDATE"):
        sim.execute(Goal(1, Action.MAP_UPDATE, (0.8, 0.0, 0.1)))


def test_gravity_compensation_holds_the_arms(sim: Simulator) -> None:
    names, q0, _, _ = sim.joint_state()
    sim.execute(Goal(1, Action.ATTENTION_SHIFT, (0.8, 0.1, 0.1)))
    sim.hold(240)  # one more simulated second of holding still
    names, q1, _, effort = sim.joint_state()
    lift = names.index("left_arm_lift")
    assert abs(q1[lift] - q0[lift]) < 1e-3
    assert effort[lift] > 20.0  # the lift motor carries the arm's weight
    assert abs(q1[names.index("neck_pan")] - 0.0) < 0.2


def test_same_seed_same_run() -> None:
    world = WorldSpec(objects=(ObjectSpec("box", "box", (0.8, -0.2), 0.2, 80, 1.0),))
    goals = [Goal(1, Action.ATTENTION_SHIFT, (0.8, -0.2, 0.1)),
             Goal(2, Action.VISUAL_IMPROVEMENT, (0.8, -0.2, 0.1))]
    runs = []
    for seed in (5, 5, 6):
        with Simulator(world, seed=seed) as s:
            runs.append([s.run_goal(g) for g in goals])
    for (ra, fa), (rb, fb) in zip(runs[0], runs[1]):
        assert ra == rb
        assert np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
        assert np.array_equal(fa.left_labels, fb.left_labels)
    assert not np.array_equal(runs[0][0][1].left, runs[2][0][1].left)  # other seed, other noise


@pytest.mark.parametrize(("field", "value"), [
    ("image_size", 8), ("image_size", 128.0), ("fov_deg", 0.0), ("pixel_noise", -0.1),
    ("realtime", 1), ("head_bandwidth", 500.0), ("fine_tolerance_rad", 0.01),
    ("goal_timeout_s", float("nan")), ("improve_exposures", 0)])
def test_config_rejects_bad_values(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"SimConfig.{field} = "):
        SimConfig(**{field: value})
    assert SimConfig().focal_px == pytest.approx(64 / math.tan(math.radians(30)))
