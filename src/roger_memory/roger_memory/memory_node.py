"""ROS node of the associative memory: match and store requests in, results out.

Run alone: ``roger-memory --ros-args -p memory_file:=runs/ltm.pt`` (or ``python -m
roger_memory.memory_node``). With ``memory_file`` set, the long-term memory is loaded at
start and written atomically after every change (a store, or an identification that added
looks to its address), before the reply goes out.

Re-sent requests (the attention node re-sends one left unanswered, e.g. while this node was
restarting) are answered once: the last replies are kept by request id, and a STORE whose
features an exemplar already holds exactly (it was stored, then the node died before it
could reply) is answered with that address instead of storing the object twice.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Any

import torch
from rclpy.node import Node

from roger_common import conversions as conv
from roger_common import topics
from roger_common.atomic import sync_file
from roger_common.configdoc import take_live_fields
from roger_common.errors import MessageError
from roger_common.ros_node import LATCHED, RELIABLE, BadInput, declare_config, spin_node
from roger_common.types import MatchOutcome, MatchResult, MemoryOp, mode_of_dim
from roger_interfaces.msg import MemoryRequest, MemoryResult
from roger_memory.config import MemoryConfig, MemoryNodeConfig
from roger_memory.memory import AssociativeMemory

#: Replies kept for re-sent requests.
REPLIES_KEPT = 32
REQUEST_TOPIC = topics.MEMORY_REQUEST


class MemoryNode(Node):
    """Answers MemoryRequest messages with MemoryResult messages of the same request_id."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_memory", **kwargs)
        self.node_config = declare_config(self, MemoryNodeConfig)
        self.config = declare_config(
            self, MemoryConfig,
            apply=lambda new: self.memory.reconfigure(take_live_fields(self.memory.config, new)))
        path = self.node_config.memory_file
        self.path = Path(path) if path else None
        seed = self.node_config.seed
        if self.path is not None and self.path.exists():
            # A corrupt file stops the node with one line (MemoryFileError, in main); the
            # orchestrator checks the file before it starts anything.
            self.memory = AssociativeMemory.load(self.path, self.config)
            self.get_logger().info(f"loaded {self.memory.size} objects from {self.path}")
        else:
            self.memory = AssociativeMemory(self.config, seed=seed)
        self._replies: OrderedDict[int, MemoryResult] = OrderedDict()
        self.bad_input = BadInput(self)
        self.pub_result = self.create_publisher(MemoryResult, topics.MEMORY_RESULT, RELIABLE)
        self.pub_learned = self.create_publisher(MemoryResult, topics.MEMORY_LEARNED, LATCHED)
        self.create_subscription(MemoryRequest, REQUEST_TOPIC, self.on_request, RELIABLE)

    def on_request(self, msg: MemoryRequest) -> None:
        """Match or store, then reply; a malformed request is logged and answered as such."""
        stamp = conv.time_to_seconds(msg.header.stamp)
        try:
            req = conv.msg_to_request(msg)
        except MessageError as exc:
            self.bad_input.drop(REQUEST_TOPIC, exc)
            return
        mode = mode_of_dim(len(req.features))
        if mode.value != self.memory.config.features:
            self.bad_input.drop(
                REQUEST_TOPIC,
                f"memory request {req.request_id} refused: it carries {mode.value}-mode "
                f"features, this memory compares {self.memory.config.features}-mode ones "
                "(give perception and memory one feature mode)")
            return
        cached = self._replies.get(req.request_id)
        if cached is not None and cached.op == int(req.op):
            self.get_logger().warn(f"request {req.request_id} received again: same answer")
            self.pub_result.publish(cached)
            return
        stored = self.memory.find_exact(req.features, req.known) \
            if req.op == MemoryOp.STORE else None
        if stored is not None:
            self.get_logger().warn(f"store {req.request_id}: already stored at address "
                                   f"{stored} (a re-sent request)")
        revision = self.memory.revision
        try:
            result = (self.memory.handle(req) if stored is None
                      else MatchResult(MatchOutcome.NEW, stored, 1.0))
        except MessageError as exc:
            self.bad_input.drop(REQUEST_TOPIC, f"memory request {req.request_id}: {exc}")
            return
        reply = conv.result_to_msg(req.request_id, req.op, result, self.memory.size, stamp)
        if self.memory.revision != revision and self.path is not None:
            # A store, or an identification that refined its address.
            try:
                # Not fsynced: it delays the reply (sync_file at exit).
                self.memory.save(self.path, durable=False)
            except OSError as exc:
                self.get_logger().error(f"could not write {self.path}: {exc}; the memory "
                                        "is kept in RAM only")
        if req.op == MemoryOp.STORE and stored is None:
            self.pub_learned.publish(reply)
            self.get_logger().info(f"stored object at address {result.address} "
                                   f"({self.memory.size} in memory)")
        self._replies[req.request_id] = reply
        while len(self._replies) > REPLIES_KEPT:
            self._replies.popitem(last=False)
        self.pub_result.publish(reply)

    def destroy_node(self) -> None:
        """Flush the memory file (written after each store without fsync) to the disk."""
        sync_file(self.path)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-memory``."""
    # One torch thread: the node is single-threaded and shares two cores with the others.
    spin_node(MemoryNode, "roger-memory", args, setup=lambda: torch.set_num_threads(1))

if __name__ == "__main__":
    main()
