"""ROS helpers shared by every package's node and conversions (QoS, time, poses, parameters).

The only module of roger_common that imports rclpy; the core modules never do.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, fields, is_dataclass, replace
from typing import Any, TypeVar

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from roger_common.geometry import eye_pose, quaternion_from_rotation, rotation_from_quaternion
from roger_common.types import EyePose

#: Commands and state: reliable, depth 10 (house style).
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)
#: Retinal images. Reliable rather than the sensor-data profile on purpose: every control
#: cycle waits for the stereo pair rendered after its goal, so a dropped pair would stall it.
IMAGES = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                    history=HistoryPolicy.KEEP_LAST)
#: One-shot data (world description, spatial map, ground truth): latched.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)

C = TypeVar("C")


def seconds_to_time(t: float) -> Time:
    """Simulated seconds as a builtin_interfaces/Time."""
    sec = int(math.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def time_to_seconds(t: Time) -> float:
    """A builtin_interfaces/Time as seconds."""
    return t.sec + t.nanosec * 1e-9


def point(p: tuple[float, float, float] | np.ndarray) -> Point:
    """A geometry_msgs/Point from three numbers."""
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def point_tuple(p: Point) -> tuple[float, float, float]:
    """A geometry_msgs/Point as a tuple."""
    return (p.x, p.y, p.z)


def rotation_to_quaternion(r: np.ndarray) -> Quaternion:
    """A 3x3 rotation matrix as a unit quaternion (Shepperd's method)."""
    x, y, z, w = quaternion_from_rotation(r)
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_to_rotation(q: Quaternion) -> np.ndarray:
    """A unit quaternion as a 3x3 rotation matrix."""
    return rotation_from_quaternion((q.x, q.y, q.z, q.w))


def pose_msg(position: np.ndarray, rotation: np.ndarray) -> Pose:
    """A geometry_msgs/Pose from a position and a rotation matrix."""
    return Pose(position=point(position), orientation=rotation_to_quaternion(rotation))


def eye_pose_msg(pose: EyePose) -> Pose:
    """An eye pose as a Pose; its own quaternion when it has one (exact round trip)."""
    if pose.quaternion is None:
        return pose_msg(pose.position, pose.rotation)
    x, y, z, w = pose.quaternion
    return Pose(position=point(pose.position), orientation=Quaternion(x=x, y=y, z=z, w=w))


def msg_to_eye_pose(p: Pose) -> EyePose:
    """A Pose as an EyePose (rotation rebuilt from the quaternion, which it keeps)."""
    o = p.orientation
    return eye_pose(point_tuple(p.position), (o.x, o.y, o.z, o.w))


def declare_config(node: Node, config_cls: type[C], prefix: str = "",
                   overrides: dict[str, Any] | None = None, **nested: Any) -> C:
    """Declare one ROS parameter per field of a frozen config dataclass and build it.

    Values flow one way: ROS parameters -> config -> core. Tuple fields become arrays.
    The dataclass's own validation (``__post_init__``) rejects bad values; the caller
    lets that error reach ``main``.

    Args:
        node: The node that owns the parameters.
        config_cls: A dataclass whose fields all have defaults.
        prefix: Prepended to each parameter name, e.g. ``"memory."``.
        overrides: Defaults to use instead of the dataclass's (still overridable by the user).
        **nested: Values of fields that hold a nested config dataclass (declared by the
            caller with their own prefix); such fields are not declared here.
    """
    values: dict[str, Any] = dict(nested)
    for f in fields(config_cls):  # type: ignore[arg-type]
        if f.name in nested:
            continue
        if f.default is not MISSING:
            default = f.default
        elif f.default_factory is not MISSING:  # type: ignore[misc]
            default = f.default_factory()  # type: ignore[misc]
        else:
            continue
        if overrides and f.name in overrides:
            default = overrides[f.name]
        if isinstance(default, tuple):
            default = list(default)
        if default is None or is_dataclass(default):
            continue
        doc = (f.metadata or {}).get("doc", f"{config_cls.__name__}.{f.name}")
        node.declare_parameter(prefix + f.name, default,
                               ParameterDescriptor(description=doc))
        value = node.get_parameter(prefix + f.name).value
        if isinstance(default, list):
            value = tuple(value)
        values[f.name] = value
    return config_cls(**values)  # type: ignore[call-arg]


def guard_parameters(node: Node, config_cls: type[C], prefix: str, get_config: Any,
                     apply: Any = None) -> None:
    """Validate parameter changes at set time against the config dataclass.

    A value the dataclass rejects is refused with its reason. A valid value is applied
    through ``apply(new_config)`` when the node supports live changes, and refused as
    "read at start only" otherwise.

    Args:
        node: The node that owns the parameters.
        config_cls: The dataclass the parameters were declared from.
        prefix: The parameter name prefix used in ``declare_config``.
        get_config: Callable returning the config in force.
        apply: Callable taking the new config, or None.
    """
    names = {prefix + f.name: f.name for f in fields(config_cls)}  # type: ignore[arg-type]

    def _check(params: list[Any]) -> SetParametersResult:
        changes = {names[p.name]: (tuple(p.value) if isinstance(p.value, list) else p.value)
                   for p in params if p.name in names}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            new = replace(get_config(), **changes)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if apply is None:
            return SetParametersResult(
                successful=False,
                reason=f"{', '.join(prefix + n for n in changes)}: read at start only; "
                       "restart the node to change it")
        apply(new)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_check)


def spin_node(factory: Any, prog: str, args: list[str] | None = None,
              setup: Any = None) -> None:
    """The ``main`` of every Roger node: init, build, spin, and shut down cleanly.

    Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException) end the spin
    quietly. A setup failure (a bad world file, parameter or memory file: RogerError,
    ValueError, OSError) prints one line ``prog: message`` and exits with status 2, which
    the orchestrator reads as "do not restart". An exception raised later, in a callback,
    is logged with its traceback and exits with status 70, which the orchestrator restarts.
    While it spins, the node publishes a heartbeat on ``/diagnostics`` (roger_common.liveness
    has the details).

    Args:
        factory: Callable returning the node (called after ``rclpy.init``).
        prog: Program name for the error line, e.g. ``"roger-sim"``.
        args: Command-line arguments for ``rclpy.init`` (None: sys.argv).
        setup: Optional callable run once before ``rclpy.init``.
    """
    from roger_common import liveness

    liveness.spin_node(factory, prog, args, setup)
