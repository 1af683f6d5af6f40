"""ROS node of attentional control: carries the AttentionController's cycles over the graph.

The controller (controller.py) owns the control cycle: the initial scan, the policy's
action, goal and request ids, what is in view, and what a restart resumes. This node only
converts and delegates: it publishes each goal and waits for the ROI array of the stereo
pair rendered after it, sends the memory request and waits for the answer, and reports
each cycle. Every wait is a callback, never a blocking call; an unanswered goal or request
is re-sent after ``retry_after_s``. Run alone: ``roger-attention`` (or ``python -m
roger_attention.attention_node``); it starts once the simulator, perception and memory
nodes are matched on its topics.

Resuming after a crash (docs/reliability.md): when the orchestrator sets ``ROGER_STATE_DIR``,
the node writes ``attention.json`` there atomically at the end of every cycle, before it
reports the cycle: the controller's ``export_state`` and the last report. A restarted node
restores both, scans again (the controller maps again what was mapped), re-sends the last
report (the orchestrator's recorder drops a cycle number it already has) and goes on.
"""

from __future__ import annotations

import base64
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo

from roger_attention import conversions as conv
from roger_attention.config import (
    AttentionConfig,
    AttentionNodeConfig,
    QLearningConfig,
    RewardConfig,
    SpatialMapConfig,
)
from roger_attention.controller import AttentionController, CyclePlan, is_look
from roger_attention.policies import make_policy
from roger_common import conversions as common
from roger_common.atomic import atomic_write_bytes, sync_file
from roger_common.errors import MessageError, RogerError
from roger_common.ros_node import (
    IMAGES,
    LATCHED,
    RELIABLE,
    declare_config,
    guard_parameters,
    spin_node,
)
from roger_common.types import CameraModel, EyePose, Goal, MatchResult, MemoryRequest
from roger_interfaces.msg import (
    ActionGoal,
    MemoryResult,
    Metrics,
    PolicyState,
    RoiArray,
    SpatialMap,
    StereoGeometry,
)
from roger_interfaces.msg import MemoryRequest as MemoryRequestMsg

#: Environment variable naming the folder of the resume state (set by the orchestrator).
STATE_DIR_ENV = "ROGER_STATE_DIR"
#: Format tag of the resume state file.
STATE_FORMAT = "roger_attention_state/2"
#: Configs of the node: (parameter prefix, dataclass).
NESTED = (("rewards.", RewardConfig), ("qlearning.", QLearningConfig),
          ("spatial_map.", SpatialMapConfig))


class AttentionNode(Node):
    """Runs the AttentionController over the graph: goals, ROI arrays, memory requests."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_attention", **kwargs)
        nested = {prefix[:-1]: declare_config(self, cls, prefix) for prefix, cls in NESTED}
        self.config = declare_config(self, AttentionConfig, **nested)
        self.node_config = declare_config(self, AttentionNodeConfig)
        for prefix, cls in (("", AttentionConfig), *NESTED):
            guard_parameters(self, cls, prefix,
                             lambda x=prefix: getattr(self.config, x[:-1]) if x else self.config)
        guard_parameters(self, AttentionNodeConfig, "", lambda: self.node_config,
                         apply=lambda new: setattr(self, "node_config", new))
        nc = self.node_config
        self.qtable_path = Path(nc.qtable_file) if nc.qtable_file else None
        rng = np.random.default_rng(nc.seed)
        self.policy = make_policy(self.config.policy, self.config, rng,
                                  qtable_path=self.qtable_path, learn=nc.learn)
        self.ctl = AttentionController(self.config, self.policy, rng)
        state_dir = os.environ.get(STATE_DIR_ENV, "")
        self.state_path = Path(state_dir) / "attention.json" if state_dir else None
        self._sim_now = 0.0
        self._memory_size = 0
        self._map_revision = 0
        self._last_report: PolicyState | None = None
        self._resumed = self._load_state()

        self.pub_goal = self.create_publisher(ActionGoal, "/roger/goal", RELIABLE)
        self.pub_request = self.create_publisher(MemoryRequestMsg, "/roger/memory/request",
                                                 RELIABLE)
        self.pub_state = self.create_publisher(PolicyState, "/roger/policy_state", RELIABLE)
        self.pub_metrics = self.create_publisher(Metrics, "/roger/metrics", RELIABLE)
        self.pub_map = self.create_publisher(SpatialMap, "/roger/spatial_map", LATCHED)
        # Geometry and camera first: when a frame's geometry and its ROI array are taken in
        # the same executor pass, callbacks run in subscription order.
        self.create_subscription(StereoGeometry, "/roger/stereo_geometry", self.on_geometry,
                                 IMAGES)
        self.create_subscription(CameraInfo, "/roger/left/camera_info", self.on_info, IMAGES)
        self.create_subscription(RoiArray, "/roger/rois", self.on_rois, RELIABLE)
        self.create_subscription(MemoryResult, "/roger/memory/result", self.on_result, RELIABLE)
        self._geometry: dict[tuple[int, int], EyePose] = {}
        self._camera: CameraModel | None = None
        self._plan: CyclePlan | None = None
        self._waiting_goal: int | None = None
        self._waiting_request: int | None = None
        self._last_sent: tuple[Any, float] | None = None
        self._frame_stamp = 0.0
        self._started = self._done = False
        # Wall-clock timers: the simulated clock only advances when a goal is executed, so a
        # sim-time timer would never fire while the graph waits for its first goal.
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(0.05, self.tick, clock=self._wall)

    def peers_ready(self) -> bool:
        """True once simulator, perception and memory are matched on our topics."""
        return (self.pub_goal.get_subscription_count() > 0
                and self.pub_request.get_subscription_count() > 0
                and self.count_publishers("/roger/rois") > 0
                and self.count_publishers("/roger/memory/result") > 0
                and self.pub_state.get_subscription_count()
                >= self.node_config.wait_for_observers)

    def tick(self) -> None:
        """Start when the peers are up; re-send a goal or request left unanswered."""
        if not self._started:
            if self.peers_ready():
                self._started = True
                self.get_logger().info(f"peers up; policy {self.config.policy}; first look")
                self._look_later(0.0)
            return
        retry = self.node_config.retry_after_s
        if self._last_sent is not None and time.monotonic() - self._last_sent[1] > retry:
            self.get_logger().warn(f"no answer after {retry:.0f} s: re-sending "
                                   f"{type(self._last_sent[0]).__name__}")
            self._publish(self._last_sent[0])

    def _publish(self, msg: Any) -> None:
        self._last_sent = (msg, time.monotonic())
        (self.pub_goal if isinstance(msg, ActionGoal) else self.pub_request).publish(msg)

    def _send_goal(self, goal: Goal) -> None:
        self._waiting_goal = goal.goal_id
        self._publish(common.goal_to_msg(goal, self._sim_now, self._map_revision))

    def _send_request(self, req: MemoryRequest) -> None:
        self._waiting_request = req.request_id
        self._publish(common.request_to_msg(req, self._sim_now))

    def _look_later(self, delay_s: float) -> None:
        def look() -> None:
            self.destroy_timer(timer)
            self._send_goal(self.ctl.next_look())  # type: ignore[arg-type]
        timer = self.create_timer(delay_s, look, clock=self._wall)

    def next_cycle(self) -> None:
        """Begin the next control cycle, unless the run is over."""
        if self.node_config.max_cycles and self.ctl.counters.cycles >= \
                self.node_config.max_cycles:
            if not self._done:
                self._done = True
                self.get_logger().info(f"done after {self.ctl.counters.cycles} cycles")
            self._publish_metrics(done=True)
            return
        self._plan = plan = self.ctl.begin_cycle(self._sim_now)
        if plan.idle:
            # Nothing in the map to attend to: the controller queued a new scan; look again
            # in a moment (an empty world, or everything vanished) without counting a cycle.
            self.ctl.end_cycle(None, self._sim_now)
            self._plan = None
            self._look_later(0.5)
        elif plan.goal is not None:
            self._send_goal(plan.goal)
        elif plan.memory_request is not None:
            self._send_request(plan.memory_request)
        else:
            self._end_cycle(None)

    def on_rois(self, msg: RoiArray) -> None:
        """The stereo pair after our goal was perceived: observe, then look on or match."""
        if self._waiting_goal is None or int(msg.goal_id) != self._waiting_goal:
            return
        self._waiting_goal, self._last_sent = None, None
        self._frame_stamp = stamp = common.time_to_seconds(msg.header.stamp)
        self._sim_now = max(self._sim_now, stamp)
        try:
            rois = common.msg_to_rois(msg)
        except MessageError as exc:
            self.get_logger().error(f"ROI array of goal {msg.goal_id} unusable: {exc}")
            rois = []
        pose = self._geometry.get((msg.header.stamp.sec, msg.header.stamp.nanosec))
        self.ctl.observe(rois, stamp, self.ctl.visibility(self._camera, pose))
        if not is_look(int(msg.goal_id)):
            # The map goes out at the cycle's end, before the next goal.
            req = self.ctl.match_request()
            if req is not None:
                self._send_request(req)
            else:
                self._end_cycle(None)
            return
        self._publish_map(stamp)  # the next look's goal carries its revision
        look = self.ctl.next_look()
        if look is not None:
            self._send_goal(look)
            return
        if self._resumed:  # the scan after a restart: report where the run stands
            self._resumed = False
            if self._last_report is not None:
                self.pub_state.publish(self._last_report)
            self._publish_map(self._sim_now)
            self._publish_metrics(done=False)
        self.next_cycle()

    def on_result(self, msg: MemoryResult) -> None:
        """The memory answered this cycle's match or store."""
        if self._waiting_request is None or int(msg.request_id) != self._waiting_request:
            return
        result: MatchResult | None
        try:
            result = common.msg_to_result(msg)
        except ValueError as exc:
            # Unusable answer: treated like no answer, so the cycle ends as "lost".
            self.get_logger().error(f"memory result {msg.request_id} unusable: {exc}")
            result = None
        self._waiting_request, self._last_sent = None, None
        self._memory_size = int(msg.memory_size)
        self._end_cycle(result)

    def _end_cycle(self, result: MatchResult | None) -> None:
        plan, self._plan = self._plan, None
        assert plan is not None
        record = self.ctl.end_cycle(result, self._sim_now)
        frame_stamp = self._frame_stamp if plan.goal is not None else 0.0
        self._last_report = conv.record_to_msg(record, self.config.policy, self._sim_now,
                                               frame_stamp)
        # Persist before reporting: a kill between the two loses no cycle that was reported.
        self._save_state()
        if self.node_config.learn and self.qtable_path is not None and self.policy.learns:
            self.policy.save(self.qtable_path, durable=False)
        self.pub_state.publish(self._last_report)
        self._publish_map(self._sim_now)
        self._publish_metrics(done=False)
        self.next_cycle()

    def _publish_map(self, stamp: float) -> None:
        self._map_revision += 1
        self.pub_map.publish(conv.spatial_map_msg(self.ctl.spatial_map, stamp,
                                                  self._map_revision))

    def _publish_metrics(self, done: bool) -> None:
        self.pub_metrics.publish(conv.metrics_msg(
            self.ctl.counters, self.config.policy, len(self.ctl.spatial_map),
            self._memory_size, done, self._sim_now))

    def _save_state(self) -> None:
        """Write the resume state atomically (nothing without ROGER_STATE_DIR)."""
        if self.state_path is None:
            return
        report = self._last_report
        state = {"format": STATE_FORMAT, "controller": self.ctl.export_state(),
                 "sim_now": self._sim_now, "memory_size": self._memory_size,
                 "map_revision": self._map_revision,
                 "last_state": base64.b64encode(serialize_message(report)).decode()
                 if report is not None else None}
        # Not fsynced: this sits on every cycle's critical path (sync_file at exit).
        atomic_write_bytes(self.state_path, json.dumps(state).encode(), durable=False)

    def _load_state(self) -> bool:
        """Restore the controller and the last report from the resume state, if any."""
        path = self.state_path
        if path is None or not path.exists():
            return False
        try:
            state = json.loads(path.read_text())
            if state.get("format") != STATE_FORMAT:
                raise ValueError(f"format {state.get('format')!r}")
            self.ctl.restore_state(state["controller"])
            self._sim_now, self._memory_size = float(state["sim_now"]), int(state["memory_size"])
            # Revisions go on rising across a restart (perception waits for >=); the
            # margin covers maps published after the last save.
            self._map_revision = int(state["map_revision"]) + 1000
            if state["last_state"]:
                self._last_report = deserialize_message(base64.b64decode(state["last_state"]),
                                                        PolicyState)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RogerError(f"{path}: resume state unusable ({exc}); delete it to start "
                             "afresh") from None
        # Save at once: a second crash before the next cycle then skips the ids further.
        self._save_state()
        self.get_logger().warn(f"resuming after cycle {self.ctl.counters.cycles} from {path}")
        return True

    def destroy_node(self) -> None:
        """Flush the per-cycle files (resume state, Q-table) to the disk, then go."""
        sync_file(self.state_path)
        sync_file(self.qtable_path)
        super().destroy_node()

    def on_geometry(self, msg: StereoGeometry) -> None:
        """Keep the left eye's pose by stamp, to tell which map places are in view."""
        try:
            pose = common.poses_from_geometry(msg)[0]
        except MessageError as exc:
            self.get_logger().error(f"stereo geometry ignored: {exc}")
            return
        self._geometry[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = pose
        while len(self._geometry) > 16:
            self._geometry.pop(next(iter(self._geometry)))

    def on_info(self, msg: CameraInfo) -> None:
        """Keep the retina's intrinsics."""
        try:
            self._camera = common.camera_from_info(msg)
        except MessageError as exc:
            self.get_logger().error(f"camera info ignored: {exc}")


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-attention``."""
    spin_node(AttentionNode, "roger-attention", args)

if __name__ == "__main__":
    main()
