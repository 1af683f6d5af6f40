"""A memory node whose request callback raises once, when a test asks (test_faults.py).

The test runs the orchestrator with this module in place of ``roger_memory.memory_node``
(``python -m fault_nodes``, the test folder on PYTHONPATH) and creates
``<ROGER_STATE_DIR>/raise_in_callback``: the next request raises instead of being answered.
The file is removed first, so the restarted node answers as usual.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from roger_bringup.orchestrator import STATE_DIR_ENV
from roger_common.ros_node import spin_node
from roger_memory.memory_node import MemoryNode

TRIGGER = "raise_in_callback"


class RaisingMemoryNode(MemoryNode):
    """The memory node, with a fault injected into its request callback on demand."""

    def on_request(self, msg: Any) -> None:
        trigger = Path(os.environ[STATE_DIR_ENV]) / TRIGGER
        if trigger.exists():
            trigger.unlink()
            raise RuntimeError(f"injected fault in the callback of request {msg.request_id}")
        super().on_request(msg)


if __name__ == "__main__":
    spin_node(RaisingMemoryNode, "roger-memory", setup=lambda: torch.set_num_threads(1))
