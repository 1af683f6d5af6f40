"""Helpers shared by the ROS tests: bounded spinning and a listener on every documented topic."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from roger_bringup.topics import TOPICS


def spin_until(executor: Any, flag: Callable[[], bool], timeout: float) -> bool:
    """spin_once until ``flag()`` is true or ``timeout`` seconds pass; returns the flag."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if flag():
            return True
    return False


class TopicListener(Node):
    """Subscribes to every documented topic (latched ones transient-local), counts the
    messages per topic and hands each to ``on_message``."""

    def __init__(self, name: str, depth: int = 10, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.counts = {t.name: 0 for t in TOPICS}
        for t in TOPICS:
            qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL
                             if t.qos == "latched" else DurabilityPolicy.VOLATILE)
            self.create_subscription(t.msg_class(), t.name, self._counter(t.name), qos)

    def _counter(self, name: str) -> Callable[[Any], None]:
        def cb(msg: Any) -> None:
            self.counts[name] += 1
            self.on_message(name, msg)
        return cb

    def on_message(self, topic: str, msg: Any) -> None:
        """Override to look at the messages."""


class RosGraph:
    """Nodes sharing one Context and one SingleThreadedExecutor (see ``ros_graph``)."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.context = context
        self.executor = executor
        self.nodes: list[Node] = []

    def add(self, cls: Any, *args: Any, params: dict[str, Any] | None = None,
            **kwargs: Any) -> Any:
        """Construct ``cls(*args, **kwargs)`` in this context with ``params`` as parameter
        overrides, and add it to the executor."""
        from rclpy.parameter import Parameter

        overrides = [Parameter(k, value=v) for k, v in (params or {}).items()]
        node = cls(*args, context=self.context, parameter_overrides=overrides, **kwargs)
        self.executor.add_node(node)
        self.nodes.append(node)
        return node


@contextmanager
def ros_context(domain_id: int) -> Iterator[Any]:
    """An rclpy Context of its own on ``domain_id``, shut down on the way out (the one way
    the tests make a ROS context: the ``ros_context`` fixture and ``ros_graph`` use it)."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@contextmanager
def ros_graph(domain_id: int) -> Iterator[RosGraph]:
    """A per-test Context and executor; every node added is destroyed on the way out."""
    from rclpy.executors import SingleThreadedExecutor

    with ros_context(domain_id) as context:
        graph = RosGraph(context, SingleThreadedExecutor(context=context))
        try:
            yield graph
        finally:
            for node in graph.nodes:
                graph.executor.remove_node(node)
                node.destroy_node()
            graph.executor.shutdown()
