"""ROS node of attentional control: carries the attention session's messages.

Everything the node decides is decided in the core: the AttentionController owns the
control cycle (initial scan, the policy's action, ids, what is in view, what a restart
resumes) and the AttentionSession its asynchronous protocol (what is awaited, what goes
out next, re-sending, the resume file; session.py). This node converts each message to a
session event and each outgoing item to a message. Run alone: ``roger-attention`` (or
``python -m roger_attention.attention_node``); it starts once the simulator, perception
and memory nodes are matched on its topics.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo
from visualization_msgs.msg import MarkerArray

from roger_attention import conversions as conv
from roger_attention import session as ses
from roger_attention.config import AttentionConfig, AttentionNodeConfig
from roger_attention.controller import AttentionController
from roger_attention.markers import MapView
from roger_attention.policies import make_policy
from roger_common import conversions as common
from roger_common import topics
from roger_common.atomic import sync_file
from roger_common.configdoc import take_live_fields
from roger_common.errors import MessageError
from roger_common.ros_node import (
    IMAGES,
    LATCHED,
    RELIABLE,
    REPORTS,
    BadInput,
    declare_config,
    spin_node,
)
from roger_common.types import CameraModel, EyePose, MatchResult, Roi
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


class AttentionNode(Node):
    """Runs an AttentionSession over the graph: goals, ROI arrays, memory requests."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_attention", **kwargs)
        self.config = declare_config(
            self, AttentionConfig,
            apply=lambda new: self.ctl.reconfigure(take_live_fields(self.ctl.config, new)))
        nc = declare_config(self, AttentionNodeConfig,
                            apply=lambda new: setattr(self.session, "config", new))
        qtable = Path(nc.qtable_file) if nc.qtable_file else None
        rng = np.random.default_rng(nc.seed)
        policy = make_policy(self.config.policy, self.config, rng, qtable_path=qtable,
                             learn=nc.learn)
        state_dir = os.environ.get(STATE_DIR_ENV, "")
        self.session = ses.AttentionSession(
            AttentionController(self.config, policy, rng), nc,
            Path(state_dir) / "attention.json" if state_dir else None, qtable)
        if self.session.resumed:
            self.get_logger().warn(f"resuming after cycle {self.ctl.counters.cycles} from "
                                   f"{self.session.state_path}")
        self.pub_goal = self.create_publisher(ActionGoal, topics.GOAL, RELIABLE)
        self.pub_request = self.create_publisher(MemoryRequestMsg, topics.MEMORY_REQUEST,
                                                 RELIABLE)
        self.pub_state = self.create_publisher(PolicyState, topics.POLICY_STATE, REPORTS)
        self.pub_metrics = self.create_publisher(Metrics, topics.METRICS, REPORTS)
        self.pub_map = self.create_publisher(SpatialMap, topics.SPATIAL_MAP, LATCHED)
        # The map as RViz and Foxglove draw it (roger_attention.markers).
        self.map_view = MapView()
        self.pub_markers = self.create_publisher(MarkerArray, topics.MAP_MARKERS,
                                                 LATCHED)
        # Geometry and camera first: when a frame's geometry and its ROI array are taken in
        # the same executor pass, callbacks run in subscription order.
        self.create_subscription(StereoGeometry, topics.STEREO_GEOMETRY, self.on_geometry,
                                 IMAGES)
        self.create_subscription(CameraInfo, topics.LEFT_INFO, self.on_info, IMAGES)
        self.create_subscription(RoiArray, topics.ROIS, self.on_rois, RELIABLE)
        self.create_subscription(MemoryResult, topics.MEMORY_RESULT, self.on_result, RELIABLE)
        self._geometry: dict[tuple[int, int], EyePose] = {}
        self._camera: CameraModel | None = None
        self._started = self._done_logged = False
        self.bad_input = BadInput(self)
        # Wall clock: the simulated clock only advances when a goal is executed, so a
        # sim-time timer would never fire while the graph waits for its first goal.
        self.create_timer(0.05, self.tick, clock=Clock(clock_type=ClockType.STEADY_TIME))

    @property
    def ctl(self) -> AttentionController:
        """The controller the session drives."""
        return self.session.ctl

    def peers_ready(self) -> bool:
        """True once simulator, perception and memory are matched on our topics."""
        return (self.pub_goal.get_subscription_count() > 0
                and self.pub_request.get_subscription_count() > 0
                and self.count_publishers(topics.ROIS) > 0
                and self.count_publishers(topics.MEMORY_RESULT) > 0
                and self.pub_state.get_subscription_count()
                >= self.session.config.wait_for_observers)

    def tick(self) -> None:
        """Start when the peers are up; then let the session re-send or look again."""
        if self._started:
            resends = self.session.resends
            out = self.session.tick()
            if self.session.resends > resends:
                self.get_logger().warn(f"no answer after {self.session.config.retry_after_s}"
                                       f" s: re-sending {type(out[0]).__name__}")
            self._emit(out)
        elif self.peers_ready():
            self._started = True
            self.get_logger().info(f"peers up; policy {self.config.policy}; first look")
            self._emit(self.session.start())

    def on_rois(self, msg: RoiArray) -> None:
        """A stereo pair was perceived: hand its ROIs and eye pose to the session.

        An unusable array is dropped, not taken for an empty one: it may come from outside
        the graph, and the session's retry brings the pair's own array again."""
        try:
            rois: Sequence[Roi] = common.msg_to_rois(msg)
        except MessageError as exc:
            self.bad_input.drop(topics.ROIS, exc)
            return
        stamp = msg.header.stamp
        self._emit(self.session.on_rois(int(msg.goal_id), rois, common.time_to_seconds(stamp),
                                        self._camera,
                                        self._geometry.get((stamp.sec, stamp.nanosec))))

    def on_result(self, msg: MemoryResult) -> None:
        """The memory answered a match or store (an unusable answer is dropped: the
        session's retry asks again)."""
        try:
            result: MatchResult = common.msg_to_result(msg)
        except MessageError as exc:
            self.bad_input.drop(topics.MEMORY_RESULT, exc)
            return
        self._emit(self.session.on_result(int(msg.request_id), result, int(msg.memory_size)))

    def _emit(self, out: list[ses.Outgoing]) -> None:
        policy = self.config.policy
        for item in out:
            if isinstance(item, ses.SendGoal):
                self.pub_goal.publish(common.goal_to_msg(item.goal, item.stamp,
                                                         item.map_revision))
            elif isinstance(item, ses.SendRequest):
                self.pub_request.publish(common.request_to_msg(item.request, item.stamp))
            elif isinstance(item, ses.Report):
                self.pub_state.publish(conv.report_to_msg(item, policy))
                self.map_view.note(item.record)
            elif isinstance(item, ses.PublishMap):
                self.pub_map.publish(conv.publish_map_to_msg(item))
                self.pub_markers.publish(conv.markers_msg(self.map_view.markers(item.entries),
                                                          item.stamp))
            elif isinstance(item, ses.PublishMetrics):
                if item.done and not self._done_logged:
                    self._done_logged = True
                    how = ": complete (the robot's own rule)" if item.complete else ""
                    self.get_logger().info(f"done after {item.counters.cycles} cycles{how}")
                self.pub_metrics.publish(conv.publish_metrics_to_msg(item, policy))

    def on_geometry(self, msg: StereoGeometry) -> None:
        """Keep the left eye's pose by stamp, to tell which map places are in view."""
        try:
            pose = common.poses_from_geometry(msg)[0]
        except MessageError as exc:
            self.bad_input.drop(topics.STEREO_GEOMETRY, exc)
            return
        self._geometry[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = pose
        while len(self._geometry) > 16:
            self._geometry.pop(next(iter(self._geometry)))

    def on_info(self, msg: CameraInfo) -> None:
        """Keep the retina's intrinsics."""
        try:
            self._camera = common.camera_from_info(msg)
        except MessageError as exc:
            self.bad_input.drop(topics.LEFT_INFO, exc)

    def destroy_node(self) -> None:
        """Flush the per-cycle files (resume state, Q-table) to the disk, then go."""
        sync_file(self.session.state_path)
        sync_file(self.session.qtable_path)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-attention``."""
    spin_node(AttentionNode, "roger-attention", args)

if __name__ == "__main__":
    main()
