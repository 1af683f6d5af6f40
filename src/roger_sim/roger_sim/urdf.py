"""Roger's URDF, read back from the pybullet multibody that ``robot.build_robot`` creates.

The simulator builds Roger with ``createMultiBody`` from the geometry constants of
``robot.py``; this module builds the very same body in a private pybullet client and reads
its kinematic tree back (joint frames, axes, link boxes, masses, inertias), adding what
pybullet does not keep (``JOINT_LIMITS``, ``JOINT_EFFORT``) from ``robot.py``. The URDF
and the simulator therefore cannot drift: change ``build_robot`` and the URDF follows
(test/test_urdf.py compares a URDF parser's forward kinematics with pybullet's link poses,
and the shipped file with a freshly generated one).

Frame names are those of ``roger_common.frames``. Besides pybullet's links the description
has frames that carry no mass: each eye's optical frame (REP 103: z forward, x right,
y down) and each fingertip.

Regenerate the shipped file with ``python -m roger_sim.urdf > src/roger_sim/urdf/roger.urdf``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import pybullet as pb

from roger_common import frames
from roger_sim.robot import (
    CONTROLLER_JOINTS,
    FINGER,
    JOINT_EFFORT,
    JOINT_LIMITS,
    RobotModel,
    build_robot,
)

#: The shipped URDF, next to the package (installed as share/roger_sim/urdf/roger.urdf).
URDF_PATH = Path(__file__).resolve().parent.parent / "urdf" / "roger.urdf"
#: Name of the robot in the URDF.
ROBOT_NAME = "roger"
#: URDF asks every revolute and prismatic joint for a velocity limit; the simulator's servos
#: have none (their bandwidth sets how fast they move). A nominal bound, not enforced.
NOMINAL_VELOCITY = 10.0
#: Grey of the boxes drawn by viewers (the simulator's robot is near black).
VISUAL_RGBA = (0.35, 0.35, 0.38, 1.0)
#: Camera frame (x forward, y left, z up) -> optical frame (z forward, x right, y down).
OPTICAL_RPY = (-math.pi / 2.0, 0.0, -math.pi / 2.0)

_TYPES = {pb.JOINT_REVOLUTE: "revolute", pb.JOINT_PRISMATIC: "prismatic",
          pb.JOINT_FIXED: "fixed"}

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Box:
    """A box of a link: full ``size`` (metres), centred at ``xyz`` in the link frame."""

    size: Vec3
    xyz: Vec3


@dataclass(frozen=True)
class Link:
    """One link (one TF frame).

    Attributes:
        name: Frame name (``roger_common.frames``).
        mass: kg; 0 for a massless frame (optical frame, fingertip, the fixed base).
        com: Centre of mass in the link frame.
        inertia: Principal moments (ixx, iyy, izz) about the centre of mass, kg m^2.
        box: Collision and visual box; None for a frame without geometry.
    """

    name: str
    mass: float = 0.0
    com: Vec3 = (0.0, 0.0, 0.0)
    inertia: Vec3 = (0.0, 0.0, 0.0)
    box: Box | None = None


@dataclass(frozen=True)
class Joint:
    """One joint: the child frame sits at ``xyz``/``rpy`` in the parent frame, then moves
    about (revolute) or along (prismatic) ``axis`` by the joint's value.

    Attributes:
        name: Joint name (the simulator's, as on /roger/joint_states, for movable joints).
        type: "revolute", "prismatic" or "fixed".
        parent: Parent frame.
        child: Child frame.
        xyz: Origin of the child frame in the parent frame at a zero joint value, metres.
        rpy: Its orientation, fixed-axis roll, pitch, yaw (URDF's convention), radians.
        axis: Unit axis in the child frame.
        limits: (lower, upper), radians or metres; None for a fixed joint.
        effort: Largest torque (N m) or force (N); 0 for a fixed joint.
    """

    name: str
    type: str
    parent: str
    child: str
    xyz: Vec3
    rpy: Vec3 = (0.0, 0.0, 0.0)
    axis: Vec3 = (0.0, 0.0, 1.0)
    limits: tuple[float, float] | None = None
    effort: float = 0.0

    @property
    def movable(self) -> bool:
        """True for a revolute or prismatic joint."""
        return self.type != "fixed"


@dataclass(frozen=True)
class RobotDescription:
    """Roger's kinematic tree: links, and joints parents before children."""

    name: str
    links: tuple[Link, ...]
    joints: tuple[Joint, ...]

    @property
    def root(self) -> str:
        """The root link (the base)."""
        return self.links[0].name


def link_frames() -> dict[str, str]:
    """Frame name of the link that each of the simulator's joints moves (and of each hand,
    keyed by its arm: "left_arm" -> "roger_left_hand")."""
    names = {"neck_pan": frames.NECK_FRAME, "neck_tilt": frames.HEAD_FRAME,
             "left_eye_pan": frames.eye_frame("left"),
             "right_eye_pan": frames.eye_frame("right")}
    for arm in ("left_arm", "right_arm"):
        for joint, part in zip(CONTROLLER_JOINTS[arm], ("shoulder", "upper_arm", "forearm"),
                               strict=True):
            names[joint] = frames.arm_link_frame(arm, part)
        names[arm] = frames.hand_frame(arm)
    return names


def _vec(v: Iterable[float]) -> Vec3:
    x, y, z = (float(c) for c in v)
    return (x, y, z)


def _clean(v: Vec3) -> Vec3:
    """Rounded to 7 significant digits, -0.0 as 0.0: pybullet keeps shapes and frames in
    float32, and 0.15 comes back as 0.15000000596."""
    x, y, z = (float(f"{c:.7g}") + 0.0 for c in v)
    return (x, y, z)


def describe_robot() -> RobotDescription:
    """Build Roger in a private DIRECT pybullet client and read its kinematic tree back."""
    client = pb.connect(pb.DIRECT)
    try:
        return describe_model(build_robot(client, 0.0))
    finally:
        pb.disconnect(physicsClientId=client)


def describe_model(model: RobotModel) -> RobotDescription:
    """The kinematic tree of the multibody ``model`` (as ``build_robot`` made it)."""
    client, body = model.client, model.body
    frame_of = link_frames()
    link_name = {-1: frames.BASE_FRAME}
    joint_name: dict[int, str] = {}
    for name, i in model.joint_index.items():
        link_name[i], joint_name[i] = frame_of[name], name
    for arm, i in model.hand_link.items():
        link_name[i], joint_name[i] = frame_of[arm], f"{arm.removesuffix('_arm')}_wrist"
    links = [_link(client, body, -1, frames.BASE_FRAME)]
    joints: list[Joint] = []
    # pybullet numbers links parents first, so the joints come out parents first.
    for i in range(pb.getNumJoints(body, physicsClientId=client)):
        info = pb.getJointInfo(body, i, physicsClientId=client)
        parent = int(info[16])
        # pybullet keeps a joint frame relative to its parent's centre of mass (inertial
        # frame); URDF relative to the parent's link frame.
        dyn = pb.getDynamicsInfo(body, parent, physicsClientId=client)
        pos, orn = pb.multiplyTransforms(dyn[3], dyn[4], info[14], info[15])
        name = joint_name[i]
        jtype = _TYPES[int(info[2])]
        joints.append(Joint(
            name=name, type=jtype, parent=link_name[parent], child=link_name[i],
            xyz=_clean(_vec(pos)), rpy=_clean(_vec(pb.getEulerFromQuaternion(orn))),
            axis=_clean(_vec(info[13])),
            limits=JOINT_LIMITS[name] if jtype != "fixed" else None,
            effort=JOINT_EFFORT[name] if jtype != "fixed" else 0.0))
        links.append(_link(client, body, i, link_name[i]))
    for side in ("left", "right"):
        joints.append(Joint(f"{side}_eye_optical", "fixed", frames.eye_frame(side),
                            frames.optical_frame(side), (0.0, 0.0, 0.0), OPTICAL_RPY))
        links.append(Link(frames.optical_frame(side)))
    for arm in ("left_arm", "right_arm"):
        tip = frames.arm_link_frame(arm, "fingertip")
        joints.append(Joint(f"{arm.removesuffix('_arm')}_fingertip", "fixed",
                            frames.hand_frame(arm), tip, (0.0, 0.0, -FINGER)))
        links.append(Link(tip))
    return RobotDescription(ROBOT_NAME, tuple(links), tuple(joints))


def _link(client: int, body: int, index: int, name: str) -> Link:
    """A pybullet link (``index`` -1: the base) with its mass, inertia and box."""
    dyn = pb.getDynamicsInfo(body, index, physicsClientId=client)
    box = None
    for shape in pb.getCollisionShapeData(body, index, physicsClientId=client):
        if shape[2] == pb.GEOM_BOX:
            # The collision frame, too, is kept relative to the centre of mass.
            centre, _ = pb.multiplyTransforms(dyn[3], dyn[4], shape[5], shape[6])
            box = Box(size=_clean(_vec(shape[3])), xyz=_clean(_vec(centre)))
    mass = float(dyn[0])
    return Link(name=name, mass=mass, com=_clean(_vec(dyn[3])),
                inertia=_clean(_vec(dyn[2])) if mass > 0 else (0.0, 0.0, 0.0), box=box)


# -- URDF text ---------------------------------------------------------------------------
def _num(v: float) -> str:
    return repr(float(v))


def _triple(v: tuple[float, ...]) -> str:
    return " ".join(_num(c) for c in v)


def to_urdf(desc: RobotDescription) -> str:
    """The description as URDF XML text."""
    r, g, b, a = VISUAL_RGBA
    out = ['<?xml version="1.0"?>',
           "<!-- Generated by roger_sim.urdf from the pybullet body of roger_sim.robot: do not"
           " edit. -->",
           f"<robot name={quoteattr(desc.name)}>",
           f'  <material name="roger_grey"><color rgba="{_triple((r, g, b, a))}"/></material>']
    for link in desc.links:
        out.append(f"  <link name={quoteattr(link.name)}>")
        if link.mass > 0:
            ixx, iyy, izz = link.inertia
            out += ["    <inertial>",
                    f'      <origin xyz="{_triple(link.com)}" rpy="0.0 0.0 0.0"/>',
                    f'      <mass value="{_num(link.mass)}"/>',
                    f'      <inertia ixx="{_num(ixx)}" ixy="0.0" ixz="0.0" iyy="{_num(iyy)}"'
                    f' iyz="0.0" izz="{_num(izz)}"/>',
                    "    </inertial>"]
        if link.box is not None:
            for tag in ("visual", "collision"):
                out += [f"    <{tag}>",
                        f'      <origin xyz="{_triple(link.box.xyz)}" rpy="0.0 0.0 0.0"/>',
                        f'      <geometry><box size="{_triple(link.box.size)}"/></geometry>']
                if tag == "visual":
                    out.append('      <material name="roger_grey"/>')
                out.append(f"    </{tag}>")
        out.append("  </link>")
    for j in desc.joints:
        out += [f"  <joint name={quoteattr(j.name)} type={quoteattr(j.type)}>",
                f"    <parent link={quoteattr(j.parent)}/>",
                f"    <child link={quoteattr(j.child)}/>",
                f'    <origin xyz="{_triple(j.xyz)}" rpy="{_triple(j.rpy)}"/>']
        if j.movable:
            assert j.limits is not None
            out += [f'    <axis xyz="{_triple(j.axis)}"/>',
                    f'    <limit lower="{_num(j.limits[0])}" upper="{_num(j.limits[1])}"'
                    f' effort="{_num(j.effort)}" velocity="{_num(NOMINAL_VELOCITY)}"/>']
        out.append("  </joint>")
    out.append("</robot>")
    return "\n".join(out) + "\n"


def robot_urdf() -> str:
    """Roger's URDF, generated now from ``build_robot`` (what /robot_description carries)."""
    return to_urdf(describe_robot())


def main() -> None:
    """Print the URDF (``python -m roger_sim.urdf > src/roger_sim/urdf/roger.urdf``)."""
    sys.stdout.write(robot_urdf())


if __name__ == "__main__":
    main()
