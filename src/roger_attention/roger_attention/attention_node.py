"""ROS node of attentional control: drives one control cycle after another.

Each cycle (one action): publish a goal and wait for the ROI array of the stereo pair
rendered after it, then send the focused ROI's features to the memory and wait for the
answer; a map update only talks to the memory (to store a new object) or to nobody. Every
wait is a callback, never a blocking call. Run alone: ``roger-attention`` (or ``python -m
roger_attention.attention_node``); it starts once the simulator, perception and memory
nodes are matched on its topics.

Resuming after a crash (docs/reliability.md): when the orchestrator sets ``ROGER_STATE_DIR``,
the node writes ``attention.json`` there atomically at the end of every cycle, before it
reports the cycle: counters, cycle number, next goal and request ids, the Q-table, the mapped
places and the last cycle's PolicyState. A restarted node loads it, rebuilds its spatial map
by a fresh initial scan, marks the places it had mapped as mapped again, re-sends the last
report (the orchestrator's recorder drops a cycle number it already has) and goes on with
the next cycle, so cycle numbers and Table 2's identities hold across the restart.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo

from roger_attention import conversions as conv
from roger_attention.config import (
    AttentionConfig,
    QLearningConfig,
    RewardConfig,
    SpatialMapConfig,
)
from roger_attention.controller import AttentionController, CyclePlan
from roger_attention.policies import make_policy
from roger_common.atomic import atomic_write_bytes, sync_file
from roger_common.conversions import (
    IMAGES,
    LATCHED,
    RELIABLE,
    declare_config,
    guard_parameters,
    msg_to_eye_pose,
    spin_node,
    time_to_seconds,
)
from roger_common.errors import MessageError, RogerError
from roger_common.geometry import in_view
from roger_common.types import Action, CameraModel, EyePose, Goal, MemoryRequest, RunCounters
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
from roger_memory.conversions import msg_to_result, request_to_msg
from roger_perception.conversions import msg_to_rois
from roger_sim.conversions import goal_to_msg

#: Goal ids of the looks of the initial scan (not control cycles) start here, far above the
#: controller's own ids (1, 2, ...). Each look has an id of its own: with one shared id, a
#: retried look's late frame answered the next look and started a second chain of cycles.
LOOK_ID_BASE = 1 << 62


def is_look(goal_id: int) -> bool:
    """True for the goal id of an initial-scan look."""
    return goal_id >= LOOK_ID_BASE
#: Environment variable naming the folder of the resume state (set by the orchestrator).
STATE_DIR_ENV = "ROGER_STATE_DIR"
#: Format tag of the resume state file.
STATE_FORMAT = "roger_attention_state/1"


def _check_node_params(params: list[Any]) -> SetParametersResult:
    """Refuse out-of-range values of the node's own (non-config) parameters at set time."""
    for prm in params:
        v = prm.value
        bad = None
        if prm.name == "retry_after_s" and not (isinstance(v, (int, float))
                                                and math.isfinite(v) and v > 0):
            bad = "must be a number of seconds > 0"
        elif prm.name in ("max_cycles", "wait_for_observers") and not (
                isinstance(v, int) and not isinstance(v, bool) and v >= 0):
            bad = "must be an integer >= 0"
        elif prm.name == "home_targets":
            try:
                _home_targets(v)
            except ValueError as exc:
                bad = str(exc)
        if bad is not None:
            return SetParametersResult(successful=False,
                                       reason=f"{prm.name}: {bad}, got {v!r}")
    return SetParametersResult(successful=True)


def _home_targets(flat: Any) -> list[tuple[float, float, float]]:
    """The initial scan's fixation points from a flat x, y, z list; ValueError if unusable."""
    vals = [float(v) for v in (flat or [])]
    if not vals or len(vals) % 3 or not all(math.isfinite(v) for v in vals):
        raise ValueError("home_targets must hold finite x, y, z triples")
    return [(vals[i], vals[i + 1], vals[i + 2]) for i in range(0, len(vals), 3)]


class AttentionNode(Node):
    """Runs the AttentionController over the graph: goals, ROI arrays, memory requests."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_attention", **kwargs)
        p = self.declare_parameter
        p("seed", 0, ParameterDescriptor(description="Seed of the policy's exploration"))
        p("qtable_file", "", ParameterDescriptor(
            description="Q-table file: loaded at start if it exists, saved atomically after "
                        "every cycle while learning. Empty: kept in RAM only."))
        p("learn", True, ParameterDescriptor(
            description="Q-learning: update the table (training) or only run it"))
        p("max_cycles", 0, ParameterDescriptor(
            description="Stop after this many control cycles; 0 runs until shut down"))
        p("home_targets", [0.45, 0.7, 0.0, 0.75, 0.4, 0.0, 0.9, 0.0, 0.0, 0.75, -0.4, 0.0,
           0.45, -0.7, 0.0],
          ParameterDescriptor(
              description="Points (x, y, z triples, robot frame, m) fixated in turn by the "
                          "initial scan that settles the map before the first cycle"))
        p("wait_for_observers", 0, ParameterDescriptor(
            description="Start only once this many subscriptions listen on "
                        "/roger/policy_state (the orchestrator's monitor sets 1), so that "
                        "no cycle goes unrecorded"))
        p("retry_after_s", 10.0, ParameterDescriptor(
            description="Wall seconds without an answer before a goal or request is re-sent"))
        nested = {
            "rewards": declare_config(self, RewardConfig, "rewards."),
            "qlearning": declare_config(self, QLearningConfig, "qlearning."),
            "spatial_map": declare_config(self, SpatialMapConfig, "spatial_map.")}
        self.config = declare_config(self, AttentionConfig, **nested)
        for cls, prefix in ((AttentionConfig, ""), (RewardConfig, "rewards."),
                            (QLearningConfig, "qlearning."), (SpatialMapConfig, "spatial_map.")):
            guard_parameters(self, cls, prefix, lambda c=cls, x=prefix: self._config_of(x))
        self.add_on_set_parameters_callback(_check_node_params)
        for name in ("retry_after_s", "max_cycles", "wait_for_observers", "home_targets"):
            check = _check_node_params([self.get_parameter(name)])
            if not check.successful:
                raise ValueError(check.reason)
        seed = int(self.get_parameter("seed").value)
        qtable = str(self.get_parameter("qtable_file").value)
        self.qtable_path = Path(qtable) if qtable else None
        self.learn = bool(self.get_parameter("learn").value)
        self.max_cycles = int(self.get_parameter("max_cycles").value)
        rng = np.random.default_rng(seed)
        self.policy = make_policy(self.config.policy, self.config, rng,
                                  qtable_path=self.qtable_path, learn=self.learn)
        self.ctl = AttentionController(self.config, self.policy, rng)
        state_dir = os.environ.get(STATE_DIR_ENV, "")
        self.state_path = Path(state_dir) / "attention.json" if state_dir else None
        # What a resume state restores (set first: _load_state overwrites them).
        self._memory_size = 0
        self._sim_now = 0.0
        self._map_revision = 0
        self._resume: dict[str, Any] | None = self._load_state()

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
        self._started = False
        self._done = False
        self._looks = 0
        # Wall-clock timers: the simulated clock only advances when a goal is executed, so a
        # sim-time timer would never fire while the graph waits for its first goal.
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(0.05, self.tick, clock=self._wall)

    def _config_of(self, prefix: str) -> Any:
        return self.config if not prefix else getattr(self.config, prefix.rstrip("."))

    # -- start-up ------------------------------------------------------------------------
    def peers_ready(self) -> bool:
        """True once simulator, perception and memory are matched on our topics."""
        return (self.pub_goal.get_subscription_count() > 0
                and self.pub_request.get_subscription_count() > 0
                and self.count_publishers("/roger/rois") > 0
                and self.count_publishers("/roger/memory/result") > 0
                and self.pub_state.get_subscription_count()
                >= int(self.get_parameter("wait_for_observers").value))

    def tick(self) -> None:
        """Start when the peers are up; re-send a goal or request left unanswered."""
        if not self._started:
            if self.peers_ready():
                self._started = True
                self.get_logger().info(f"peers up; policy {self.config.policy}; first look")
                self._relook = self.create_timer(0.0, self._look_again, clock=self._wall)
            return
        retry = float(self.get_parameter("retry_after_s").value)
        if self._last_sent is not None and time.monotonic() - self._last_sent[1] > retry:
            msg = self._last_sent[0]
            self.get_logger().warn(
                f"no answer after {retry:.0f} s: re-sending {type(msg).__name__}")
            self._publish(msg)

    # -- the cycle -----------------------------------------------------------------------
    def _publish(self, msg: Any) -> None:
        self._last_sent = (msg, time.monotonic())
        (self.pub_goal if isinstance(msg, ActionGoal) else self.pub_request).publish(msg)

    def _send_goal(self, goal: Goal) -> None:
        self._waiting_goal = goal.goal_id
        msg = goal_to_msg(goal, self._sim_now)
        msg.map_revision = self._map_revision  # perceive the pair with this map
        self._publish(msg)

    def _publish_map(self, stamp: float) -> None:
        self._map_revision += 1
        msg = conv.spatial_map_msg(self.ctl.spatial_map, stamp)
        msg.revision = self._map_revision
        self.pub_map.publish(msg)

    def _send_request(self, req: MemoryRequest) -> None:
        self._waiting_request = req.request_id
        self._publish(request_to_msg(req, self._sim_now))

    def next_cycle(self) -> None:
        """Begin the next control cycle, unless the run is over."""
        if self.max_cycles and self.ctl.counters.cycles >= self.max_cycles:
            self._finish()
            return
        plan = self.ctl.begin_cycle(self._sim_now)
        self._plan = plan
        if plan.idle:
            # Nothing in the map to attend to: look again in a moment (an empty world,
            # or everything vanished), without counting a cycle.
            self.ctl.end_cycle(None, self._sim_now)
            self._plan = None
            self._relook = self.create_timer(0.5, self._look_again, clock=self._wall)
            return
        if plan.goal is not None:
            self._send_goal(plan.goal)
        elif plan.memory_request is not None:
            self._send_request(plan.memory_request)
        else:
            self._end_cycle(None)

    def _look_again(self) -> None:
        self.destroy_timer(self._relook)
        self._scan = _home_targets(self.get_parameter("home_targets").value)
        self._send_look()

    def _send_look(self) -> None:
        self._looks += 1
        self._send_goal(Goal(LOOK_ID_BASE + self._looks, Action.ATTENTION_SHIFT,
                             self._scan.pop(0)))

    def on_rois(self, msg: RoiArray) -> None:
        """The stereo pair after our goal was perceived: observe, then match."""
        if self._waiting_goal is None or int(msg.goal_id) != self._waiting_goal:
            return
        self._waiting_goal, self._last_sent = None, None
        stamp = time_to_seconds(msg.header.stamp)
        self._sim_now = max(self._sim_now, stamp)
        self._frame_stamp = stamp
        try:
            rois = msg_to_rois(msg)
        except MessageError as exc:
            self.get_logger().error(f"ROI array of goal {msg.goal_id} unusable: {exc}")
            rois = []
        self.ctl.observe(rois, stamp, self._visible(msg.header.stamp))
        if is_look(int(msg.goal_id)):
            self._publish_map(stamp)  # the next look's goal carries its revision
            if self._scan:
                self._send_look()
            else:
                self._resumed()
                self.next_cycle()
            return
        # No map here: the cycle's end publishes one before the next goal, and the frame of
        # that goal is perceived with it (a publish with its subscribers costs ~0.4 ms here).
        req = self.ctl.match_request()
        if req is None:
            self._end_cycle(None)
        else:
            self._send_request(req)

    def on_result(self, msg: MemoryResult) -> None:
        """The memory answered this cycle's match or store."""
        if self._waiting_request is None or int(msg.request_id) != self._waiting_request:
            return
        try:
            result = msg_to_result(msg)
        except ValueError as exc:
            # Unusable answer: treated like no answer, so the cycle ends as "lost".
            self.get_logger().error(f"memory result {msg.request_id} unusable: {exc}")
            result = None
        self._waiting_request, self._last_sent = None, None
        self._memory_size = int(msg.memory_size)
        self._end_cycle(result)

    def _end_cycle(self, result: Any) -> None:
        plan = self._plan
        assert plan is not None
        record = self.ctl.end_cycle(result, self._sim_now)
        self._plan = None
        frame_stamp = self._frame_stamp if plan.goal is not None else 0.0
        state_msg = conv.record_to_msg(record, self.config.policy, self._sim_now, frame_stamp)
        # Persist before reporting: a kill between the two loses no cycle that was reported.
        self._save_state(state_msg)
        if self.learn and self.qtable_path is not None and self.policy.learns:
            self.policy.save(self.qtable_path, durable=False)
        self.pub_state.publish(state_msg)
        self._publish_map(self._sim_now)
        self._publish_metrics(done=False)
        self.next_cycle()

    def _finish(self) -> None:
        if not self._done:
            self._done = True
            self.get_logger().info(f"done after {self.ctl.counters.cycles} cycles")
        self._publish_metrics(done=True)

    def _publish_metrics(self, done: bool) -> None:
        self.pub_metrics.publish(conv.metrics_msg(
            self.ctl.counters, self.config.policy, len(self.ctl.spatial_map),
            self._memory_size, done, self._sim_now))

    # -- resuming after a restart ------------------------------------------------------
    def _save_state(self, last: PolicyState | None) -> None:
        """Write the resume state atomically (nothing without ROGER_STATE_DIR)."""
        if self.state_path is None:
            return
        table = getattr(self.policy, "table", None)
        state = {
            "format": STATE_FORMAT, "policy": self.config.policy,
            "counters": dataclasses.asdict(self.ctl.counters),
            "next_goal_id": self.ctl._next_goal_id,
            "next_request_id": self.ctl._next_request_id,
            "sim_now": self._sim_now, "memory_size": self._memory_size,
            "map_revision": self._map_revision,
            "q": table.q.tolist() if table is not None else None,
            "mapped": [{"position": list(e.position), "address": int(e.address)}
                       for e in self.ctl.spatial_map if e.mapped],
            "last_state": base64.b64encode(serialize_message(last)).decode()
            if last is not None else None,
        }
        # Not fsynced: this sits on every cycle's critical path (sync_file at exit).
        atomic_write_bytes(self.state_path, json.dumps(state).encode(), durable=False)

    def destroy_node(self) -> None:
        """Flush the per-cycle files (resume state, Q-table) to the disk, then go."""
        sync_file(self.state_path)
        sync_file(self.qtable_path)
        super().destroy_node()

    def _load_state(self) -> dict[str, Any] | None:
        """Restore counters, ids and Q-table from the resume state, if there is one."""
        path = self.state_path
        if path is None or not path.exists():
            return None
        try:
            state = json.loads(path.read_text())
            if state.get("format") != STATE_FORMAT or state["policy"] != self.config.policy:
                raise ValueError(f"format {state.get('format')!r}, policy "
                                 f"{state.get('policy')!r}")
            counters = RunCounters(**state["counters"])
            q = state["q"]
            table = getattr(self.policy, "table", None)
            if q is not None and table is not None:
                arr = np.asarray(q, dtype=float)
                if arr.shape != table.q.shape or not np.all(np.isfinite(arr)):
                    raise ValueError(f"Q-table of shape {arr.shape}")
                table.q[...] = arr
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RogerError(f"{path}: resume state unusable ({exc}); delete it to start "
                             "afresh") from None
        self.ctl.counters = counters
        # The cycle in flight when the node died may have used the saved ids: skip them,
        # and save at once so that a second crash before the next cycle skips further.
        self.ctl._next_goal_id = int(state["next_goal_id"]) + 1
        self.ctl._next_request_id = int(state["next_request_id"]) + 1
        self._sim_now = float(state["sim_now"])
        self._memory_size = int(state["memory_size"])
        # Revisions go on rising across a restart (perception waits for >=); the margin
        # covers maps published after the last save.
        self._map_revision = int(state.get("map_revision", 0)) + 1000
        state["next_goal_id"] = self.ctl._next_goal_id
        state["next_request_id"] = self.ctl._next_request_id
        atomic_write_bytes(path, json.dumps(state).encode())
        self.get_logger().warn(f"resuming after cycle {counters.cycles} from {path}")
        return state

    def _resumed(self) -> None:
        """After a restart's initial scan: map again what was mapped, re-send the last report."""
        state, self._resume = self._resume, None
        if state is None:
            return
        smap = self.ctl.spatial_map
        radius = self.config.spatial_map.association_radius
        for place in state["mapped"]:
            near = [(math.dist(e.position, place["position"]), e.entry_id) for e in smap
                    if not e.mapped]
            if near and min(near)[0] <= radius:
                smap.set_mapped(min(near)[1], int(place["address"]))
        if state["last_state"]:
            self.pub_state.publish(deserialize_message(
                base64.b64decode(state["last_state"]), PolicyState))
        self._publish_map(self._sim_now)
        self._publish_metrics(done=False)

    # -- what is in view -----------------------------------------------------------------
    def on_geometry(self, msg: StereoGeometry) -> None:
        """Keep the left eye's pose by stamp, to tell which map places are in view."""
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        pose = msg_to_eye_pose(msg.left_eye)
        if not (np.all(np.isfinite(pose.position)) and np.all(np.isfinite(pose.rotation))):
            self.get_logger().error("stereo geometry with NaN eye pose ignored")
            return
        self._geometry[key] = pose
        while len(self._geometry) > 16:
            self._geometry.pop(next(iter(self._geometry)))

    def on_info(self, msg: CameraInfo) -> None:
        """Keep the retina's intrinsics."""
        focal = float(msg.k[0])
        if msg.width <= 0 or msg.height <= 0 or not math.isfinite(focal) or focal <= 0:
            self.get_logger().error(f"camera info ignored: {msg.width}x{msg.height}, "
                                    f"focal {focal}")
            return
        self._camera = CameraModel(int(msg.width), int(msg.height), focal)

    def _visible(self, stamp: Any) -> Any:
        pose = self._geometry.get((stamp.sec, stamp.nanosec))
        camera = self._camera
        if pose is None or camera is None:
            return None
        margin = 0.1 * camera.width
        return lambda p: in_view(camera, pose, p, margin)


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-attention``."""
    spin_node(AttentionNode, "roger-attention", args)

if __name__ == "__main__":
    main()
