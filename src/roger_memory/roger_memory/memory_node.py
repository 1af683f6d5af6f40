"""ROS node of the associative memory: match and store requests in, results out.

Run alone: ``roger-memory --ros-args -p memory_file:=runs/ltm.pt`` (or ``python -m
roger_memory.memory_node``). With ``memory_file`` set, the long-term memory is loaded at
start and written atomically after every store.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import rclpy
import torch
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rcl_interfaces.msg import ParameterDescriptor
from roger_common.conversions import LATCHED, RELIABLE, declare_config, guard_parameters, \
    time_to_seconds
from roger_common.errors import MessageError, RogerError
from roger_common.types import MemoryOp

from roger_interfaces.msg import MemoryRequest, MemoryResult
from roger_memory import conversions as conv
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory


class MemoryNode(Node):
    """Answers MemoryRequest messages with MemoryResult messages of the same request_id."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_memory", **kwargs)
        self.declare_parameter("memory_file", "", ParameterDescriptor(
            description="Long-term memory file; loaded at start if it exists, written "
                        "atomically after each store. Empty: memory lives in RAM only."))
        self.declare_parameter("seed", 0, ParameterDescriptor(
            description="Seed of the network's initial weights and training order"))
        self.config = declare_config(self, MemoryConfig)
        guard_parameters(self, MemoryConfig, "", lambda: self.config)
        path = str(self.get_parameter("memory_file").value)
        self.path = Path(path) if path else None
        seed = int(self.get_parameter("seed").value)
        if self.path is not None and self.path.exists():
            self.memory = AssociativeMemory.load(self.path, self.config)
            self.get_logger().info(f"loaded {self.memory.size} objects from {self.path}")
        else:
            self.memory = AssociativeMemory(self.config, seed=seed)
        self.pub_result = self.create_publisher(MemoryResult, "/roger/memory/result", RELIABLE)
        self.pub_learned = self.create_publisher(MemoryResult, "/roger/memory/learned", LATCHED)
        self.create_subscription(MemoryRequest, "/roger/memory/request", self.on_request,
                                 RELIABLE)

    def on_request(self, msg: MemoryRequest) -> None:
        """Match or store, then reply; a malformed request is logged and answered as such."""
        stamp = time_to_seconds(msg.header.stamp)
        try:
            req = conv.msg_to_request(msg)
        except MessageError as exc:
            self.get_logger().error(f"memory request refused: {exc}")
            return
        try:
            result = self.memory.handle(req)
        except MessageError as exc:
            self.get_logger().error(f"memory request {req.request_id} refused: {exc}")
            return
        reply = conv.result_to_msg(req.request_id, req.op, result, self.memory.size, stamp)
        if req.op == MemoryOp.STORE:
            if self.path is not None:
                self.memory.save(self.path)
            self.pub_learned.publish(reply)
            self.get_logger().info(f"stored object at address {result.address} "
                                   f"({self.memory.size} in memory)")
        self.pub_result.publish(reply)


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-memory``."""
    # One torch thread: the node is single-threaded and shares two cores with the others.
    torch.set_num_threads(1)
    rclpy.init(args=args)
    node = None
    try:
        node = MemoryNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (RogerError, ValueError) as exc:
        print(f"roger-memory: {exc}", file=sys.stderr)
        sys.exit(2)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
