"""ROS node plumbing shared by every Roger node: QoS profiles, parameters from the config
dataclasses, and the ``main`` every node runs (``spin_node``).

Message conversions are in ``conversions``; neither module is imported by core code.
"""

from __future__ import annotations

from dataclasses import MISSING, fields, is_dataclass, replace
from typing import Any, TypeVar

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from roger_common.configdoc import field_description, live_fields

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


def declare_config(node: Node, config_cls: type[C], prefix: str = "",
                   overrides: dict[str, Any] | None = None, **nested: Any) -> C:
    """Declare one ROS parameter per field of a frozen config dataclass and build it.

    Values flow one way: ROS parameters -> config -> core. Tuple fields become arrays.
    Each parameter's description is its field's (``configdoc.field_description``). The
    dataclass's own validation (``__post_init__``) rejects bad values; the caller lets
    that error reach ``main``.

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
        node.declare_parameter(prefix + f.name, default, ParameterDescriptor(
            description=field_description(config_cls, f.name)))
        value = node.get_parameter(prefix + f.name).value
        if isinstance(default, list):
            value = tuple(value)
        values[f.name] = value
    return config_cls(**values)  # type: ignore[call-arg]


def guard_parameters(node: Node, config_cls: type[C], prefix: str, get_config: Any,
                     apply: Any = None) -> None:
    """Validate parameter changes at set time against the config dataclass.

    A value the dataclass rejects is refused with its reason. A valid value of a field
    that may change while running (``configdoc.live_fields``) is applied through
    ``apply(new_config)``; any other change is refused as "read at start only".

    Args:
        node: The node that owns the parameters.
        config_cls: The dataclass the parameters were declared from.
        prefix: The parameter name prefix used in ``declare_config``.
        get_config: Callable returning the config in force.
        apply: Callable taking the new config, or None.
    """
    names = {prefix + f.name: f.name for f in fields(config_cls)}  # type: ignore[arg-type]
    live = live_fields(config_cls) if apply is not None else frozenset()

    def _check(params: list[Any]) -> SetParametersResult:
        changes = {names[p.name]: (tuple(p.value) if isinstance(p.value, list) else p.value)
                   for p in params if p.name in names}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            new = replace(get_config(), **changes)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        fixed = [n for n in changes if n not in live]
        if fixed:
            return SetParametersResult(
                successful=False,
                reason=f"{', '.join(prefix + n for n in fixed)}: read at start only; "
                       "restart the node to change it")
        assert apply is not None
        apply(new)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_check)


def spin_node(factory: Any, prog: str, args: list[str] | None = None,
              setup: Any = None) -> None:
    """The ``main`` of every Roger node: init, build, spin, and shut down cleanly.

    Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException) end the spin
    quietly. A setup failure (a bad world file, parameter or memory file: RogerError,
    ValueError, OSError) prints one line ``prog: message`` and exits with status 2, which
    the orchestrator reads as "do not restart".

    Args:
        factory: Callable returning the node (called after ``rclpy.init``).
        prog: Program name for the error line, e.g. ``"roger-sim"``.
        args: Command-line arguments for ``rclpy.init`` (None: sys.argv).
        setup: Optional callable run once before ``rclpy.init``.
    """
    import os
    import sys

    import rclpy
    from rclpy.executors import ExternalShutdownException

    from roger_common.dds import apply_dds_defaults
    from roger_common.errors import RogerError

    if setup is not None:
        setup()
    apply_dds_defaults(os.environ)
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (RogerError, ValueError, OSError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        sys.exit(2)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
