"""Roger's URDF agrees with the simulator's pybullet body (issue 36, item 1).

An independent parser (yourdfpy, with its own forward kinematics) reads the shipped URDF;
for random joint values within the limits, every link frame it computes must lie within
1 mm and 0.01 rad of pybullet's link frame. The TF tree's own forward kinematics
(roger_sim.tf_tree) is held to the same standard, and the optical frames to the eye poses
the simulator reports with every stereo pair.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest
import yourdfpy

from roger_common import frames
from roger_sim.robot import FINGER, JOINT_LIMITS, arm_fk, build_robot
from roger_sim.tf_tree import forward_kinematics, static_transforms
from roger_sim.urdf import URDF_PATH, describe_model, link_frames, robot_urdf, to_urdf

POSITION_TOL = 1e-3  # metres
ANGLE_TOL = 0.01  # radians
CONFIGS = 25


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation that takes ``a`` to ``b``."""
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, c)))


@pytest.fixture(scope="module")
def sim():
    """Roger's body in a private pybullet client, as the simulator builds it."""
    client = pb.connect(pb.DIRECT)
    try:
        yield build_robot(client, 0.05)
    finally:
        pb.disconnect(physicsClientId=client)


@pytest.fixture(scope="module")
def parsed():
    return yourdfpy.URDF.load(str(URDF_PATH), build_collision_scene_graph=False,
                              load_meshes=False, load_collision_meshes=False)


def pybullet_frames(model, q: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every pybullet link frame (rotation, position) at joint values ``q``."""
    for name, value in q.items():
        pb.resetJointState(model.body, model.joint_index[name], value,
                           physicsClientId=model.client)
    names = link_frames()
    index = {**{names[j]: i for j, i in model.joint_index.items()},
             **{names[a]: i for a, i in model.hand_link.items()}}
    out = {}
    for frame, i in index.items():
        s = pb.getLinkState(model.body, i, computeForwardKinematics=True,
                            physicsClientId=model.client)
        rot = np.array(pb.getMatrixFromQuaternion(s[5]), float).reshape(3, 3)
        out[frame] = (rot, np.array(s[4], float))
    return out


def random_config(rng: np.random.Generator) -> dict[str, float]:
    return {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in JOINT_LIMITS.items()}


def test_shipped_urdf_is_the_generated_one() -> None:
    assert URDF_PATH.read_text() == robot_urdf(), (
        "src/roger_sim/urdf/roger.urdf is stale: regenerate it with "
        "`python -m roger_sim.urdf > src/roger_sim/urdf/roger.urdf`")


def test_urdf_names_every_frame_and_joint(parsed) -> None:
    joints = set(parsed.joint_map)
    assert set(JOINT_LIMITS) <= joints
    assert set(parsed.actuated_joint_names) == set(JOINT_LIMITS)
    for name, (lo, hi) in JOINT_LIMITS.items():
        limit = parsed.joint_map[name].limit
        assert (limit.lower, limit.upper) == pytest.approx((lo, hi))
    links = set(parsed.link_map)
    expected = {frames.BASE_FRAME, frames.NECK_FRAME, frames.HEAD_FRAME,
                *(f(s) for s in ("left", "right") for f in (frames.eye_frame,
                                                            frames.optical_frame)),
                *(frames.arm_link_frame(a, p) for a in ("left_arm", "right_arm")
                  for p in ("shoulder", "upper_arm", "forearm", "hand", "fingertip"))}
    assert links == expected
    assert parsed.base_link == frames.BASE_FRAME


def test_urdf_forward_kinematics_matches_pybullet(sim, parsed) -> None:
    rng = np.random.default_rng(36)
    desc = describe_model(sim)
    worst_pos = worst_ang = 0.0
    for _ in range(CONFIGS):
        q = random_config(rng)
        truth = pybullet_frames(sim, q)
        parsed.update_cfg(q)
        ours = forward_kinematics(desc, q)
        for frame, (rot, pos) in truth.items():
            t = parsed.get_transform(frame_to=frame, frame_from=frames.BASE_FRAME)
            for r, p in ((t[:3, :3], t[:3, 3]), ours[frame]):
                worst_pos = max(worst_pos, float(np.linalg.norm(p - pos)))
                worst_ang = max(worst_ang, rotation_angle(r, rot))
    assert worst_pos < POSITION_TOL, f"a link frame is {worst_pos * 1e3:.3f} mm off"
    assert worst_ang < ANGLE_TOL, f"a link frame is {worst_ang:.4f} rad off"


def test_fingertips_and_optical_frames(sim, parsed) -> None:
    """The fingertip is where robot.arm_fk and the lift joint say; the optical frame is the
    eye pose that goes out in StereoGeometry (OpenCV axes)."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = random_config(rng)
        pybullet_frames(sim, q)  # sets the joints
        parsed.update_cfg(q)
        for arm in ("left_arm", "right_arm"):
            side = arm.removesuffix("_arm")
            tip = parsed.get_transform(frames.arm_link_frame(arm, "fingertip"),
                                       frames.BASE_FRAME)[:3, 3]
            x, y = arm_fk(arm, q[f"{side}_shoulder"], q[f"{side}_elbow"])
            assert np.allclose(tip, (x, y, q[f"{side}_arm_lift"]), atol=POSITION_TOL)
            hand = parsed.get_transform(frames.hand_frame(arm), frames.BASE_FRAME)[:3, 3]
            assert hand[2] - tip[2] == pytest.approx(FINGER)
        for side in ("left", "right"):
            pose = sim.eye_pose(side)
            t = parsed.get_transform(frames.optical_frame(side), frames.BASE_FRAME)
            assert np.linalg.norm(t[:3, 3] - pose.position) < POSITION_TOL
            assert rotation_angle(t[:3, :3], pose.rotation) < ANGLE_TOL


def test_the_comparison_can_fail(sim, tmp_path) -> None:
    """A URDF with the elbow 1 cm further out disagrees with pybullet beyond the tolerance."""
    text = to_urdf(describe_model(sim))
    wrong = text.replace('<origin xyz="0.5 0.0 0.0"', '<origin xyz="0.51 0.0 0.0"', 1)
    assert wrong != text
    (tmp_path / "wrong.urdf").write_text(wrong)
    bad = yourdfpy.URDF.load(str(tmp_path / "wrong.urdf"), load_meshes=False)
    q = random_config(np.random.default_rng(1))
    truth = pybullet_frames(sim, q)
    bad.update_cfg(q)
    rot, pos = truth[frames.arm_link_frame("left_arm", "forearm")]
    t = bad.get_transform(frames.arm_link_frame("left_arm", "forearm"), frames.BASE_FRAME)
    assert np.linalg.norm(t[:3, 3] - pos) > POSITION_TOL


def test_static_transforms_put_the_base_on_the_ground(sim) -> None:
    desc = describe_model(sim)
    static = static_transforms(desc)
    assert static[0].parent == frames.GROUND_FRAME and static[0].child == frames.BASE_FRAME
    assert static[0].translation == (0.0, 0.0, 0.0)
    fixed = {(t.parent, t.child) for t in static[1:]}
    assert (frames.eye_frame("left"), frames.optical_frame("left")) in fixed
    assert (frames.arm_link_frame("right_arm", "forearm"), frames.hand_frame("right_arm")) \
        in fixed
