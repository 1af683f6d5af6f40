"""Roger-the-Crab's body: geometry, the pybullet multibody, and its closed-form kinematics.

Robot frame = world frame: origin on the ground under the body, x forward, y left, z up.
The body is a fixed base. A neck (pan, then tilt) carries a head with two eyes
``BASELINE`` apart, each on its own pan joint so the eyes verge. Two planar two-link arms
(``LINK1`` = ``LINK2`` = 0.5 m, as in the original simulator) work in a horizontal plane;
a vertical prismatic "lift" joint at each shoulder moves that plane up and down so a hand
can come down onto an object, press it and lift it. The lift joint's value is the height
of the fingertip above the ground.

Every joint about a vertical axis (neck pan, eye pans, shoulders, elbows) feels no
gravity; gravity compensation matters for the neck tilt and the lift joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from roger_common.geometry import eye_pose, quaternion_from_rotation
from roger_common.types import EyePose

#: Distance between the two eyes, metres.
BASELINE: float = 0.16
#: Height of the neck's tilt axis above the ground, metres.
NECK_HEIGHT: float = 0.8
#: Eyes sit this far in front of the tilt axis, in the head's horizontal plane, metres.
EYE_FORWARD: float = 0.05
#: Length of the upper arm and of the forearm, metres.
LINK1: float = 0.5
LINK2: float = 0.5
#: Lateral offset of each shoulder from the body's mid-plane, metres.
SHOULDER_Y: float = 0.2
#: Length of the finger hanging below the wrist, metres.
FINGER: float = 0.1
#: Half the side of the finger's square flat tip (the hand's tactile pad), metres.
PAD_HALF: float = 0.02
#: Horizontal reach of a hand from its shoulder, metres (a little short of full extension).
REACH: float = LINK1 + LINK2 - 0.02
#: Closest horizontal distance a hand can work at from its shoulder, metres.
MIN_REACH: float = 0.15

#: Controller names, in the order of reports.
CONTROLLERS: tuple[str, ...] = ("neck", "left_eye", "right_eye", "left_arm", "right_arm")
#: Movable joints of each controller, in the order of its reference vector.
CONTROLLER_JOINTS: dict[str, tuple[str, ...]] = {
    "neck": ("neck_pan", "neck_tilt"),
    "left_eye": ("left_eye_pan",),
    "right_eye": ("right_eye_pan",),
    "left_arm": ("left_arm_lift", "left_shoulder", "left_elbow"),
    "right_arm": ("right_arm_lift", "right_shoulder", "right_elbow"),
}
#: Joint limits (lower, upper): radians, or metres for the lift joints.
JOINT_LIMITS: dict[str, tuple[float, float]] = {
    "neck_pan": (-math.radians(100), math.radians(100)),
    "neck_tilt": (-math.radians(20), math.radians(80)),
    "left_eye_pan": (-math.radians(45), math.radians(45)),
    "right_eye_pan": (-math.radians(45), math.radians(45)),
    "left_arm_lift": (0.01, 0.9),
    "left_shoulder": (-math.pi, math.pi),
    "left_elbow": (-math.radians(170), math.radians(170)),
    "right_arm_lift": (0.01, 0.9),
    "right_shoulder": (-math.pi, math.pi),
    "right_elbow": (-math.radians(170), math.radians(170)),
}
#: Largest torque (N m) or force (N) each joint's motor gives.
JOINT_EFFORT: dict[str, float] = {
    "neck_pan": 40.0, "neck_tilt": 40.0, "left_eye_pan": 2.0, "right_eye_pan": 2.0,
    "left_arm_lift": 400.0, "left_shoulder": 150.0, "left_elbow": 100.0,
    "right_arm_lift": 400.0, "right_shoulder": 150.0, "right_elbow": 100.0,
}
#: Fingertip height of a resting or travelling hand: above the tallest allowed object.
HOVER: float = 0.6
#: Rest pose of each arm: upper arm out and back, forearm folded behind the body, so the
#: arms stay out of the retinas (lift at HOVER).
ARM_REST: dict[str, tuple[float, float]] = {
    "left_arm": (math.radians(120), math.radians(120)),
    "right_arm": (-math.radians(120), -math.radians(120)),
}


def shoulder_xy(arm: str) -> tuple[float, float]:
    """Horizontal position of a shoulder ("left_arm" or "right_arm") in the robot frame."""
    return (0.0, SHOULDER_Y if arm == "left_arm" else -SHOULDER_Y)


def arm_ik(arm: str, xy: tuple[float, float]) -> tuple[float, float] | None:
    """Shoulder and elbow angles that put the fingertip over ``xy``, elbow outwards.

    Returns:
        (shoulder, elbow) in radians, or None when ``xy`` is out of reach.
    """
    sx, sy = shoulder_xy(arm)
    px, py = xy[0] - sx, xy[1] - sy
    r2 = px * px + py * py
    r = math.sqrt(r2)
    if r > REACH or r < MIN_REACH:
        return None
    c2 = (r2 - LINK1 ** 2 - LINK2 ** 2) / (2.0 * LINK1 * LINK2)
    # Elbow outwards (away from the body): negative elbow angle on the left arm.
    sign = -1.0 if arm == "left_arm" else 1.0
    elbow = sign * math.acos(max(-1.0, min(1.0, c2)))
    shoulder = math.atan2(py, px) - math.atan2(LINK2 * math.sin(elbow),
                                               LINK1 + LINK2 * math.cos(elbow))
    shoulder = math.atan2(math.sin(shoulder), math.cos(shoulder))
    return shoulder, elbow


def arm_fk(arm: str, shoulder: float, elbow: float) -> tuple[float, float]:
    """Horizontal fingertip position for given shoulder and elbow angles."""
    sx, sy = shoulder_xy(arm)
    return (sx + LINK1 * math.cos(shoulder) + LINK2 * math.cos(shoulder + elbow),
            sy + LINK1 * math.sin(shoulder) + LINK2 * math.sin(shoulder + elbow))


def fixation_angles(target: tuple[float, float, float]) -> dict[str, float] | None:
    """Neck and eye angles that put ``target`` on both foveae (an attention shift).

    The neck pans to face the target and tilts so the target lies in the head's
    horizontal plane (which contains both eyes and the tilt axis); each eye then pans in
    that plane to look straight at it. Positive tilt looks down.

    Returns:
        Joint name -> angle for the neck and eye joints (the servos check the joint
        limits), or None for a target straight above or below the neck.
    """
    tx, ty, tz = (float(c) for c in target)
    d = math.hypot(tx, ty)
    h = tz - NECK_HEIGHT
    if d < 1e-6:
        return None
    pan = math.atan2(ty, tx)
    tilt = math.atan2(-h, d)
    r = math.hypot(d, h)
    angles = {"neck_pan": pan, "neck_tilt": tilt}
    angles.update(eye_vergence_angles((r, 0.0)))
    return angles


def eye_vergence_angles(target_head_xy: tuple[float, float]) -> dict[str, float]:
    """Eye pan angles that verge on a point given in the head's horizontal plane."""
    x, y = target_head_xy
    half = BASELINE / 2.0
    return {"left_eye_pan": math.atan2(y - half, x - EYE_FORWARD),
            "right_eye_pan": math.atan2(y + half, x - EYE_FORWARD)}


@dataclass
class RobotModel:
    """Handles to Roger's multibody in one pybullet client.

    Attributes:
        client: pybullet physics client id.
        body: Unique id of the multibody.
        joint_index: Movable joint name -> pybullet joint index.
        dof_index: Movable joint name -> index in inverse-dynamics vectors.
        hand_link: Arm controller name -> link index of its hand (finger).
        eye_link: "left"/"right" -> link index of the eye.
    """

    client: int
    body: int
    joint_index: dict[str, int]
    dof_index: dict[str, int]
    hand_link: dict[str, int]
    eye_link: dict[str, int]

    @property
    def joint_names(self) -> list[str]:
        """Movable joints in pybullet order."""
        return sorted(self.joint_index, key=self.joint_index.__getitem__)

    def eye_pose(self, side: str) -> EyePose:
        """Camera pose of the ``side`` ("left"/"right") eye, OpenCV axes, robot frame."""
        state = pb.getLinkState(self.body, self.eye_link[side], computeForwardKinematics=True,
                                physicsClientId=self.client)
        pos = np.array(state[4], float)
        rot = np.array(pb.getMatrixFromQuaternion(state[5]), float).reshape(3, 3)
        # Eye link axes: x along the optical axis, y left, z up. OpenCV: right, down, fwd.
        cv_axes = np.column_stack([-rot[:, 1], -rot[:, 2], rot[:, 0]])
        # Rebuilt from its quaternion, which travels in StereoGeometry: every receiver
        # computes the very same matrix.
        return eye_pose(pos, quaternion_from_rotation(cv_axes))


def _box(client: int, half: tuple[float, float, float], offset: tuple[float, float, float],
         grey: float, visual: bool = True) -> tuple[int, int]:
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, collisionFramePosition=offset,
                                  physicsClientId=client)
    if visual:
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, visualFramePosition=offset,
                                   rgbaColor=[grey, grey, grey, 1.0], physicsClientId=client)
    else:
        # A link without a visual shape has its collision shape drawn (in white) by the
        # TinyRenderer; a speck of 0.1 mm is what "not seen" takes.
        vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=1e-4, visualFramePosition=offset,
                                   rgbaColor=[grey, grey, grey, 1.0], physicsClientId=client)
    return col, vis


def build_robot(client: int, grey: float, visible: bool = False) -> RobotModel:
    """Create Roger's multibody in ``client`` and return its handles.

    Args:
        client: pybullet physics client id.
        grey: Grey level of every robot link (near black so perception ignores it).
        visible: Give the links visual shapes (for pybullet's GUI window). Off by default:
            the retinas must not see the robot's own body, head or arms (seen: with the neck
            turned far, the shoulder below an eye filled half its retina and hid objects).
    """
    # The body stands behind the eyes; with the neck turned far an eye still swings over it.
    base_col, base_vis = _box(client, (0.12, 0.15, 0.35), (-0.15, 0.0, 0.35), grey,
                              visual=visible)
    links: list[tuple[str, int, str, float, tuple, tuple, tuple]] = []
    # (name, parent link index +1, joint type, mass, joint position in parent, half, offset)
    links.append(("neck_pan", 0, "rz", 0.5, (0.0, 0.0, NECK_HEIGHT - 0.1),
                  (0.03, 0.03, 0.05), (0.0, 0.0, 0.05)))
    links.append(("neck_tilt", 1, "ry", 1.0, (0.0, 0.0, 0.1),
                  (0.05, 0.1, 0.04), (-0.06, 0.0, 0.0)))
    links.append(("left_eye_pan", 2, "rz", 0.05, (EYE_FORWARD, BASELINE / 2.0, 0.0),
                  (0.012, 0.012, 0.012), (0.0, 0.0, 0.0)))
    links.append(("right_eye_pan", 2, "rz", 0.05, (EYE_FORWARD, -BASELINE / 2.0, 0.0),
                  (0.012, 0.012, 0.012), (0.0, 0.0, 0.0)))
    for side, y in (("left", SHOULDER_Y), ("right", -SHOULDER_Y)):
        first = len(links) + 1
        links.append((f"{side}_arm_lift", 0, "pz", 0.5, (0.0, y, FINGER),
                      (0.04, 0.04, 0.04), (0.0, 0.0, 0.0)))
        links.append((f"{side}_shoulder", first, "rz", 1.0, (0.0, 0.0, 0.0),
                      (LINK1 / 2.0, 0.025, 0.025), (LINK1 / 2.0, 0.0, 0.0)))
        links.append((f"{side}_elbow", first + 1, "rz", 0.8, (LINK1, 0.0, 0.0),
                      (LINK2 / 2.0, 0.02, 0.02), (LINK2 / 2.0, 0.0, 0.0)))
        links.append((f"{side}_hand", first + 2, "fixed", 0.2, (LINK2, 0.0, 0.0),
                      (PAD_HALF, PAD_HALF, FINGER / 2.0), (0.0, 0.0, -FINGER / 2.0)))
    axes = {"rz": (0, 0, 1), "ry": (0, 1, 0), "pz": (0, 0, 1), "fixed": (0, 0, 1)}
    types = {"rz": pb.JOINT_REVOLUTE, "ry": pb.JOINT_REVOLUTE, "pz": pb.JOINT_PRISMATIC,
             "fixed": pb.JOINT_FIXED}
    cols, viss = [], []
    for name, _, _, _, _, half, offset in links:
        # The eyes never get a visual shape: a camera must not see its own eyeball.
        col, vis = _box(client, half, offset, grey, visual=visible and "eye" not in name)
        cols.append(col)
        viss.append(vis)
    body = pb.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=base_col, baseVisualShapeIndex=base_vis,
        basePosition=[0, 0, 0],
        linkMasses=[link[3] for link in links],
        linkCollisionShapeIndices=cols, linkVisualShapeIndices=viss,
        linkPositions=[link[4] for link in links],
        linkOrientations=[[0, 0, 0, 1]] * len(links),
        linkInertialFramePositions=[link[6] for link in links],
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * len(links),
        linkParentIndices=[link[1] for link in links],
        linkJointTypes=[types[link[2]] for link in links],
        linkJointAxis=[axes[link[2]] for link in links],
        physicsClientId=client)
    joint_index: dict[str, int] = {}
    hand_link: dict[str, int] = {}
    for i, link in enumerate(links):
        pb.changeDynamics(body, i, linearDamping=0.0, angularDamping=0.0, lateralFriction=1.0,
                          physicsClientId=client)
        if link[2] == "fixed":
            hand_link[link[0].replace("_hand", "_arm")] = i
        else:
            joint_index[link[0]] = i
    # Default velocity motors would fight the torque servos: switch them off.
    idx = sorted(joint_index.values())
    pb.setJointMotorControlArray(body, idx, pb.VELOCITY_CONTROL, forces=[0.0] * len(idx),
                                 physicsClientId=client)
    order = sorted(joint_index, key=joint_index.__getitem__)
    dof_index = {name: k for k, name in enumerate(order)}
    return RobotModel(client=client, body=body, joint_index=joint_index, dof_index=dof_index,
                      hand_link=hand_link,
                      eye_link={"left": joint_index["left_eye_pan"],
                                "right": joint_index["right_eye_pan"]})
