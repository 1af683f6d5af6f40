"""Messages <-> roger_sim core types. Every message conversion of roger_sim lives here."""

from __future__ import annotations

import math

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Header

from roger_common.conversions import eye_pose_msg, point, point_tuple, seconds_to_time
from roger_common.types import (
    Action,
    CameraModel,
    ControllerReport,
    ControllerState,
    Goal,
    HapticReading,
    ObjectSpec,
    StereoFrame,
)
from roger_interfaces.msg import (
    ActionGoal,
    ControllerStatus,
    ConvergenceEvent,
    GroundTruth,
    GroundTruthLabels,
    StereoGeometry,
    WorldObject,
)
from roger_interfaces.msg import HapticReading as HapticReadingMsg

LEFT_FRAME = "roger_left_eye"
RIGHT_FRAME = "roger_right_eye"
ROBOT_FRAME = "roger_base"


def header(stamp: float, frame_id: str = ROBOT_FRAME) -> Header:
    """A std_msgs/Header at simulated time ``stamp``."""
    return Header(stamp=seconds_to_time(stamp), frame_id=frame_id)


def msg_to_goal(msg: ActionGoal) -> Goal:
    """An ActionGoal as a core Goal. Raises ValueError on an unknown action."""
    action = Action(msg.action)
    if action == Action.MAP_UPDATE:
        raise ValueError("a map update is not a physical goal")
    target = point_tuple(msg.target)
    if not all(math.isfinite(v) for v in target):
        raise ValueError(f"goal {msg.goal_id}: target {target} is not finite")
    return Goal(goal_id=int(msg.goal_id), action=action, target=target, arm=int(msg.arm))


def goal_to_msg(goal: Goal, stamp: float) -> ActionGoal:
    """A core Goal as an ActionGoal."""
    return ActionGoal(header=header(stamp), goal_id=goal.goal_id, action=int(goal.action),
                      target=point(goal.target), arm=goal.arm)


def image_msg(img: np.ndarray, stamp: float, frame_id: str) -> Image:
    """A float32 retina image in [0, 1] as a 32FC1 sensor_msgs/Image."""
    data = np.ascontiguousarray(img, dtype=np.float32)
    h, w = data.shape
    return Image(header=header(stamp, frame_id), height=h, width=w, encoding="32FC1",
                 is_bigendian=0, step=4 * w, data=data.tobytes())


def labels_msg(labels: np.ndarray, stamp: float, frame_id: str) -> Image:
    """A per-pixel int32 label image as a 32SC1 sensor_msgs/Image."""
    data = np.ascontiguousarray(labels, dtype=np.int32)
    h, w = data.shape
    return Image(header=header(stamp, frame_id), height=h, width=w, encoding="32SC1",
                 is_bigendian=0, step=4 * w, data=data.tobytes())


def camera_info_msg(camera: CameraModel, stamp: float, frame_id: str,
                    baseline: float, right: bool) -> CameraInfo:
    """CameraInfo of one retina; the right one carries -f*baseline in P like a stereo rig."""
    f = camera.focal_px
    cx, cy = camera.width / 2.0, camera.height / 2.0
    tx = -f * baseline if right else 0.0
    return CameraInfo(
        header=header(stamp, frame_id), height=camera.height, width=camera.width,
        distortion_model="plumb_bob", d=[0.0] * 5,
        k=[f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=[f, 0.0, cx, tx, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def stereo_geometry_msg(frame: StereoFrame, map_revision: int = 0) -> StereoGeometry:
    """The eye poses of a stereo pair; ``map_revision`` comes from the goal that made it."""
    return StereoGeometry(
        header=header(frame.stamp), goal_id=frame.goal_id,
        left_eye=eye_pose_msg(frame.left_pose), right_eye=eye_pose_msg(frame.right_pose),
        exposures=frame.exposures, map_revision=int(map_revision),
        haptic=frame.haptic is not None)


def haptic_msg(reading: HapticReading, goal_id: int, stamp: float) -> HapticReadingMsg:
    """A core HapticReading as a message."""
    return HapticReadingMsg(header=header(stamp), goal_id=goal_id, arm=reading.arm,
                            contact=reading.contact, position=point(reading.position),
                            weight=float(reading.weight))


def controller_status_msg(states: dict[str, ControllerState], stamp: float) -> ControllerStatus:
    """The five controllers' states."""
    return ControllerStatus(header=header(stamp), controllers=list(states),
                            status=[int(s) for s in states.values()])


def convergence_msg(report: ControllerReport, action: Action, stamp: float) -> ConvergenceEvent:
    """A finished goal as a ConvergenceEvent."""
    failed = any(s == ControllerState.FAILED for s in report.states.values())
    return ConvergenceEvent(
        header=header(stamp), goal_id=report.goal_id, action=int(action), converged=not failed,
        controllers=list(report.states), status=[int(s) for s in report.states.values()],
        duration=float(report.sim_time), physics_steps=int(report.physics_steps))


def joint_state_msg(names: list[str], pos: list[float], vel: list[float], eff: list[float],
                    stamp: float) -> JointState:
    """The robot's joints."""
    return JointState(header=header(stamp), name=list(names), position=[float(v) for v in pos],
                      velocity=[float(v) for v in vel], effort=[float(v) for v in eff])


def object_to_msg(spec: ObjectSpec) -> WorldObject:
    """A world object as a message."""
    return WorldObject(name=spec.name, shape=spec.shape, x=float(spec.position[0]),
                       y=float(spec.position[1]), yaw=float(spec.yaw), size=float(spec.size),
                       intensity=float(spec.intensity), weight=float(spec.weight),
                       texture=spec.texture)


def msg_to_object_dict(msg: WorldObject) -> dict[str, object]:
    """A WorldObject as a world-file dictionary (validated by roger_sim.world)."""
    return {"name": msg.name, "shape": msg.shape, "position": [msg.x, msg.y], "yaw": msg.yaw,
            "size": msg.size, "intensity": msg.intensity, "weight": msg.weight,
            "texture": msg.texture or "plain"}


def ground_truth_msg(world_name: str, objects: tuple[ObjectSpec, ...],
                     poses: dict[str, tuple[float, float, float, float]],
                     stamp: float) -> GroundTruth:
    """The world as it is now, for evaluation."""
    return GroundTruth(
        header=header(stamp), world_name=world_name,
        objects=[object_to_msg(o) for o in objects],
        positions=[point(poses[o.name][:3]) if o.name in poses else point((0.0, 0.0, 0.0))
                   for o in objects])


def ground_truth_labels_msg(frame: StereoFrame) -> GroundTruthLabels | None:
    """Which object each pixel of each retina shows; None when the frame has no labels."""
    if frame.left_labels is None or frame.right_labels is None:
        return None
    return GroundTruthLabels(
        header=header(frame.stamp), label_names=list(frame.label_names),
        left=labels_msg(frame.left_labels, frame.stamp, LEFT_FRAME),
        right=labels_msg(frame.right_labels, frame.stamp, RIGHT_FRAME))
