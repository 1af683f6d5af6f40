"""Parameters as ROS users see them (``ros2 param describe`` / ``set``), through rclpy.

Every parameter of every node has a description, a numeric one its range, and all but
the live ones are read-only; a live one set by a parameter client (what ``ros2 param set``
calls) changes what the core does next, and a read-only or out-of-range one is refused.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from conftest import WORLDS
from rcl_interfaces.msg import ParameterType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from roger_common.configdoc import field_range
from roger_common.types import MatchOutcome, feature_dim

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: The parameters that may change while a node runs, per node.
LIVE = {
    "roger_sim": {"realtime"},
    "roger_perception": set(),
    "roger_memory": {"identify_share", "veto", "flat_veto", "flat_crease", "flat_curvature",
                     "straight_outline", "straight_veto", "curved_veto",
                     "veto_any_look", "veto_rerun", "crease_found_veto",
                     "rim_found_veto"},
    "roger_attention": {"qlearning.epsilon", "spatial_map.interest_rate", "max_cycles",
                        "stop_when_complete", "wait_for_observers", "retry_after_s"},
}
NUMERIC = (ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_INTEGER)


def _nodes(ctx: Any) -> list[Node]:
    from roger_attention.attention_node import AttentionNode
    from roger_memory.memory_node import MemoryNode
    from roger_perception.perception_node import PerceptionNode
    from roger_sim.sim_node import SimNode
    sim = SimNode(context=ctx, parameter_overrides=[
        Parameter("world", value=str(WORLDS / "table1.yaml")),
        Parameter("image_size", value=64)])
    return [sim, PerceptionNode(context=ctx), MemoryNode(context=ctx),
            AttentionNode(context=ctx)]


@contextmanager
def _spinning(ctx: Any, *nodes: Node) -> Iterator[SingleThreadedExecutor]:
    executor = SingleThreadedExecutor(context=ctx)
    for n in nodes:
        executor.add_node(n)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        executor.shutdown(timeout_sec=5.0)
        thread.join(timeout=5.0)


def _wait(future: Any, timeout: float = 20.0) -> Any:
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(timeout), "no answer from the parameter services"
    return future.result()


def test_every_parameter_describes_itself(no_leaks, ros_context) -> None:
    nodes = _nodes(ros_context)
    try:
        for node in nodes:
            names = sorted(node._parameters)            # noqa: SLF001 (rclpy has no getter)
            names = [n for n in names if n != "use_sim_time"]
            assert names, node.get_name()
            described = node.describe_parameters(names)
            for d in described:
                where = f"{node.get_name()}.{d.name}"
                assert d.description and "Config." not in d.description, where
                assert d.read_only == (d.name not in LIVE[node.get_name()]), where
                if d.type in NUMERIC:
                    ranges = d.floating_point_range or d.integer_range
                    assert len(ranges) == 1, where
                    r = ranges[0]
                    value = node.get_parameter(d.name).value
                    assert r.from_value <= value <= r.to_value, where
            live_described = {d.name for d in described if not d.read_only}
            assert live_described == LIVE[node.get_name()], node.get_name()
    finally:
        for node in nodes:
            node.destroy_node()


def test_ranges_are_what_the_validation_accepts() -> None:
    from roger_attention.config import AttentionConfig
    from roger_sim.config import SimConfig
    assert field_range(SimConfig, ("image_size",)) == (16, 1024)
    assert field_range(SimConfig, ("pixel_noise",)) == (0.0, 0.5)
    assert field_range(SimConfig, ("far_clip",)) == (1.0, math.inf)    # > 1 m: open
    assert field_range(AttentionConfig, ("qlearning", "epsilon")) == (0.0, 1.0)
    assert field_range(AttentionConfig, ("qlearning", "initial_q")) == (-1e6, 1e6)
    assert field_range(SimConfig, ("realtime",)) is None                # a bool


def test_a_live_parameter_set_by_a_client_changes_the_next_decision(no_leaks,
                                                                    ros_context) -> None:
    from roger_interfaces.msg import MemoryRequest
    from roger_memory.memory_node import MemoryNode

    class Sink:
        def __init__(self) -> None:
            self.msgs: list[Any] = []

        def publish(self, msg: Any) -> None:
            self.msgs.append(msg)

    memory = MemoryNode(context=ros_context)
    client_node = Node("param_client", context=ros_context)
    try:
        memory.pub_result, memory.pub_learned = Sink(), Sink()
        mode = memory.memory.config.features
        x = np.linspace(0.2, 0.7, feature_dim(mode)).astype(np.float32)
        known = [True] * feature_dim(mode)
        memory.on_request(MemoryRequest(request_id=1, op=1, feature_mode=mode,
                                        features=x.tolist(), known=known))
        ask = MemoryRequest(request_id=2, op=0, feature_mode=mode, features=x.tolist(),
                            known=known, final_trial=False)
        memory.on_request(ask)
        first = memory.pub_result.msgs[-1]
        assert first.outcome == MatchOutcome.IDENTIFIED and first.confidence < 0.999
        with _spinning(ros_context, memory, client_node):
            client = AsyncParameterClient(client_node, "roger_memory")
            assert client.wait_for_services(timeout_sec=20.0)
            ok = _wait(client.set_parameters([Parameter("identify_share", value=0.999)]))
            assert ok.results[0].successful, ok.results[0].reason
            fixed = _wait(client.set_parameters([Parameter("learning_rate", value=0.5)]))
            assert not fixed.results[0].successful
            assert "read-only" in fixed.results[0].reason
            bad = _wait(client.set_parameters([Parameter("identify_share", value=1.5)]))
            assert not bad.results[0].successful
        assert memory.memory.config.identify_share == 0.999
        assert memory.memory.config.learning_rate == 0.02
        ask.request_id = 3
        memory.on_request(ask)
        # The same look, the same network: now short of the share it needs.
        assert memory.pub_result.msgs[-1].outcome == MatchOutcome.UNDETERMINED
    finally:
        client_node.destroy_node()
        memory.destroy_node()


def test_live_attention_and_sim_parameters_reach_their_cores(no_leaks, ros_context) -> None:
    from roger_attention.attention_node import AttentionNode
    from roger_sim.sim_node import SimNode
    attention = AttentionNode(context=ros_context, parameter_overrides=[
        Parameter("policy", value="qlearning")])
    sim = SimNode(context=ros_context, parameter_overrides=[
        Parameter("world", value=str(WORLDS / "table1.yaml")),
        Parameter("image_size", value=64)])
    try:
        for name, value in (("qlearning.epsilon", 0.7), ("spatial_map.interest_rate", 0.3)):
            assert attention.set_parameters([Parameter(name, value=value)])[0].successful
        assert attention.ctl.policy.epsilon == 0.7                     # type: ignore[attr-defined]
        assert attention.ctl.spatial_map.config.interest_rate == 0.3
        assert attention.ctl.config.qlearning.epsilon == 0.7
        assert sim.set_parameters([Parameter("realtime", value=True)])[0].successful
        assert sim.sim.config.realtime
    finally:
        sim.destroy_node()
        attention.destroy_node()
