"""Roger's TF tree from its joint states: what robot_state_publisher computes from a URDF.

Static transforms (/tf_static): the ground frame to the base (Roger never moves, so the
identity) and every fixed joint of the description (wrists, fingertips, optical frames).
Dynamic transforms (/tf): every movable joint at its current value. Frames follow REP 103
(x forward, y left, z up; optical frames z forward, x right, y down) and REP 105 (a
world-fixed frame above the base). ``forward_kinematics`` composes them into each frame's
pose in the base frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from roger_common import frames
from roger_common.geometry import quaternion_from_rotation
from roger_sim.urdf import Joint, RobotDescription

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


@dataclass(frozen=True)
class Transform:
    """Pose of ``child`` in ``parent``: ``translation`` (metres), ``rotation`` (x, y, z, w)."""

    parent: str
    child: str
    translation: Vec3
    rotation: Quat


def rpy_matrix(rpy: Vec3) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw as a rotation matrix: Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def axis_angle_matrix(axis: Vec3, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


def joint_matrix(joint: Joint, value: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation) of ``joint``'s child frame in its parent at ``value``."""
    rot = rpy_matrix(joint.rpy)
    pos = np.asarray(joint.xyz, float)
    if joint.type == "revolute":
        rot = rot @ axis_angle_matrix(joint.axis, value)
    elif joint.type == "prismatic":
        pos = pos + rot @ (np.asarray(joint.axis, float) * value)
    return rot, pos


def _transform(joint: Joint, value: float = 0.0) -> Transform:
    rot, pos = joint_matrix(joint, value)
    return Transform(joint.parent, joint.child, (float(pos[0]), float(pos[1]), float(pos[2])),
                     quaternion_from_rotation(rot))


def static_transforms(desc: RobotDescription) -> list[Transform]:
    """The ground frame on the base (identity), then every fixed joint: /tf_static."""
    out = [Transform(frames.GROUND_FRAME, desc.root, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]
    return out + [_transform(j) for j in desc.joints if not j.movable]


def joint_transforms(desc: RobotDescription, names: Iterable[str],
                     positions: Iterable[float]) -> list[Transform]:
    """Transforms of the movable joints named in a joint state: /tf.

    Raises:
        ValueError: A name that is no movable joint of ``desc``, a non-finite position, or
            names and positions of different lengths.
    """
    movable = {j.name: j for j in desc.joints if j.movable}
    out = []
    for name, value in zip(list(names), list(positions), strict=True):
        if name not in movable:
            raise ValueError(f"joint state names {name!r}, which is no movable joint of "
                             f"{desc.name}")
        if not math.isfinite(value):
            raise ValueError(f"joint {name}: position {value} is not finite")
        out.append(_transform(movable[name], float(value)))
    return out


def forward_kinematics(desc: RobotDescription,
                       positions: Mapping[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pose (rotation, position) of every frame in the base frame; a movable joint missing
    from ``positions`` is at zero."""
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {desc.root: (np.eye(3), np.zeros(3))}
    for j in desc.joints:  # parents first
        prot, ppos = poses[j.parent]
        rot, pos = joint_matrix(j, positions.get(j.name, 0.0))
        poses[j.child] = (prot @ rot, ppos + prot @ pos)
    return poses
