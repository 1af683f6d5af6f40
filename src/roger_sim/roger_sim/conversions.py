"""Messages <-> what only the simulator reports: controller status, convergence events,
joint states and the ground truth of its world. The messages it shares with the other
packages (goals, retinas, eye geometry, haptic readings) convert in roger_common.conversions."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from roger_common.conversions import LEFT_FRAME, RIGHT_FRAME, header, point
from roger_common.types import (
    Action,
    ControllerReport,
    ControllerState,
    ObjectSpec,
    StereoFrame,
)
from roger_interfaces.msg import (
    ControllerStatus,
    ConvergenceEvent,
    GroundTruth,
    GroundTruthLabels,
    WorldObject,
)
from roger_sim.tf_tree import Transform as CoreTransform


def labels_msg(labels: np.ndarray, stamp: float, frame_id: str) -> Image:
    """A per-pixel int32 label image as a 32SC1 sensor_msgs/Image."""
    data = np.ascontiguousarray(labels, dtype=np.int32)
    h, w = data.shape
    return Image(header=header(stamp, frame_id), height=h, width=w, encoding="32SC1",
                 is_bigendian=0, step=4 * w, data=data.tobytes())


def controller_status_msg(states: dict[str, ControllerState], stamp: float) -> ControllerStatus:
    """The five controllers' states."""
    return ControllerStatus(header=header(stamp), controllers=list(states),
                            status=[int(s) for s in states.values()])


def convergence_msg(report: ControllerReport, action: Action, stamp: float) -> ConvergenceEvent:
    """A finished goal as a ConvergenceEvent (``converged``: none of the controllers the
    goal drove failed)."""
    return ConvergenceEvent(
        header=header(stamp), goal_id=report.goal_id, action=int(action),
        converged=report.converged,
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


# -- the robot model and its TF tree -------------------------------------------------------
def robot_description_msg(urdf: str) -> String:
    """The URDF as /robot_description carries it (std_msgs/String, as robot_state_publisher)."""
    return String(data=urdf)


def tf_msg(transforms: list[CoreTransform], stamp: float) -> TFMessage:
    """Transforms of roger_sim.tf_tree as a tf2_msgs/TFMessage stamped ``stamp``."""
    return TFMessage(transforms=[
        TransformStamped(
            header=header(stamp, t.parent), child_frame_id=t.child,
            transform=Transform(
                translation=Vector3(x=t.translation[0], y=t.translation[1],
                                    z=t.translation[2]),
                rotation=Quaternion(x=t.rotation[0], y=t.rotation[1], z=t.rotation[2],
                                    w=t.rotation[3])))
        for t in transforms])
