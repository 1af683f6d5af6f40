"""``ViewNode``: publishes what Roger attends to as /roger/view (sensor_msgs/Image, rgb8).

One picture per control cycle (view.compose_view): both retinas of the cycle's stereo pair,
the ROI boundaries with activation and interest, the attention window, the FSM state
before and after, the action and the Table 2 counters. The attention node publishes each
cycle's PolicyState, then the spatial map, then the Metrics, so a cycle's picture is drawn
once its Metrics arrived (or when the next cycle's state comes first): counters and
interests are then those after the cycle. With ``out_dir`` it also writes PNG frames and,
when the node is destroyed, an animated GIF (view.ViewWriter).

Run alone: ``python -m roger_bringup.view_node --ros-args -p out_dir:=runs/view``.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image

from roger_bringup.conversions import map_interests, view_to_msg
from roger_bringup.monitor_logic import COUNTER_FIELDS
from roger_common import topics
from roger_common.conversions import image_to_array, msg_to_rois
from roger_common.errors import ConfigError, MessageError
from roger_common.ros_node import IMAGES, LATCHED, RELIABLE, REPORTS, declare_config, spin_node
from roger_common.types import Action, Roi
from roger_experiments.evaluation import ACTION_NAMES
from roger_experiments.view import ViewWriter, compose_view, interests_by_roi
from roger_interfaces.msg import Metrics, PolicyState, RoiArray, SpatialMap

#: Stereo pairs kept by stamp until a policy state refers to them.
FRAMES_KEPT = 16


@dataclass(frozen=True)
class ViewNodeConfig:
    """Parameters of the view node.

    Attributes:
        out_dir: Folder for PNG frames and view.gif; empty: publish /roger/view only.
        scale: Integer magnification of the retinas in the view.
        fps: Frames per second of view.gif.
        association_radius: A ROI takes the interest of the spatial-map entry within this
            distance (m); as spatial_map.association_radius of the attention node.
    """

    out_dir: str = ""
    scale: int = 2
    fps: float = 4.0
    association_radius: float = 0.15

    def __post_init__(self) -> None:
        if isinstance(self.scale, bool) or not isinstance(self.scale, int) or self.scale < 1:
            raise ConfigError(f"ViewNodeConfig.scale must be an integer >= 1, got {self.scale!r}")
        for name in ("fps", "association_radius"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"ViewNodeConfig.{name} must be a number > 0, got {value!r}")


class ViewNode(Node):
    """Draws one view per control cycle; optionally keeps them as PNG frames and a GIF.

    Attributes:
        writer: The PNG/GIF writer, None without an output folder.
        published: Views published so far.
    """

    def __init__(self, out_dir: Path | None = None, **node_kwargs: Any) -> None:
        """Declare the parameters, subscribe, and open the writer.

        Args:
            out_dir: Folder for the PNG frames and view.gif; None reads the ``out_dir``
                parameter ("" = publish only).
            **node_kwargs: Passed to ``Node`` (``context=``, ``parameter_overrides=``...).
        """
        super().__init__("roger_view", **node_kwargs)
        cfg = declare_config(self, ViewNodeConfig)
        self.scale, self.radius = cfg.scale, cfg.association_radius
        folder = out_dir if out_dir is not None else cfg.out_dir
        self.writer = ViewWriter(Path(folder), cfg.fps) if folder else None
        self.published = 0
        self._frames: OrderedDict[tuple[int, int], dict[str, Any]] = OrderedDict()
        self._latest: tuple[int, int] | None = None
        self._entries: list[tuple[tuple[float, float, float], float]] = []
        self._counters: dict[str, int] = {}
        self._pending: PolicyState | None = None
        self.pub_view = self.create_publisher(Image, topics.VIEW, IMAGES)
        self.create_subscription(Image, topics.LEFT_IMAGE,
                                 lambda m: self._part(m, "left"), IMAGES)
        self.create_subscription(Image, topics.RIGHT_IMAGE,
                                 lambda m: self._part(m, "right"), IMAGES)
        self.create_subscription(RoiArray, topics.ROIS, self.on_rois, RELIABLE)
        self.create_subscription(PolicyState, topics.POLICY_STATE, self.on_state, REPORTS)
        self.create_subscription(Metrics, topics.METRICS, self.on_metrics, REPORTS)
        self.create_subscription(SpatialMap, topics.SPATIAL_MAP, self.on_map, LATCHED)

    def _slot(self, stamp: Any) -> dict[str, Any]:
        key = (int(stamp.sec), int(stamp.nanosec))
        slot = self._frames.setdefault(key, {})
        while len(self._frames) > FRAMES_KEPT:
            self._frames.popitem(last=False)
        return slot

    def _part(self, msg: Image, side: str) -> None:
        try:
            self._slot(msg.header.stamp)[side] = image_to_array(msg)
        except MessageError as exc:
            self.get_logger().error(f"{side} retina unusable: {exc}")
            return
        self._latest = (int(msg.header.stamp.sec), int(msg.header.stamp.nanosec))

    def on_rois(self, msg: RoiArray) -> None:
        """The ROIs of a stereo pair."""
        try:
            self._slot(msg.header.stamp)["rois"] = msg_to_rois(msg)
        except MessageError as exc:
            self.get_logger().error(f"ROI array unusable: {exc}")

    def on_map(self, msg: SpatialMap) -> None:
        """Positions and interests of the spatial map."""
        self._entries = map_interests(msg)

    def on_state(self, msg: PolicyState) -> None:
        """A cycle finished: drawn once its Metrics arrive (or now, if one was waiting)."""
        if self._pending is not None:
            self.render(self._pending)
        self._pending = msg

    def on_metrics(self, msg: Metrics) -> None:
        """Counters after a cycle; draws the cycle waiting for them."""
        self._counters = {k: int(getattr(msg, k, 0)) for k in COUNTER_FIELDS}
        if self._pending is not None and int(msg.cycles) >= int(self._pending.cycle):
            self.render(self._pending)
            self._pending = None

    def _frame_of(self, msg: PolicyState) -> dict[str, Any] | None:
        key: tuple[int, int] | None = (int(msg.frame_stamp.sec), int(msg.frame_stamp.nanosec))
        if msg.action == Action.MAP_UPDATE or key not in self._frames:
            key = self._latest  # a map update looks at nothing new: the last pair
        frame = self._frames.get(key) if key is not None else None
        if frame is None or "left" not in frame or "right" not in frame:
            return None
        return frame

    def render(self, msg: PolicyState) -> np.ndarray | None:
        """Draw and publish the view of one cycle (and write it); None without its retinas."""
        frame = self._frame_of(msg)
        if frame is None:
            self.get_logger().warn(f"cycle {msg.cycle}: no stereo pair to draw")
            return None
        rois: list[Roi] = frame.get("rois", [])
        focus = (msg.x0, msg.y0, msg.x1, msg.y1) if msg.x1 > msg.x0 else None
        view = compose_view(
            frame["left"], frame["right"], rois, focus,
            f"{msg.state_before}->{msg.state_after}",
            ACTION_NAMES.get(int(msg.action), str(msg.action)), self._counters,
            interests_by_roi(rois, self._entries, self.radius), scale=self.scale)
        self.pub_view.publish(view_to_msg(view, msg.header))
        self.published += 1
        if self.writer is not None:
            self.writer.write(view)
        return view

    def close(self) -> Path | None:
        """Draw a cycle still waiting, then write the GIF; returns its path (or None)."""
        if self._pending is not None:
            self.render(self._pending)
            self._pending = None
        return self.writer.close() if self.writer is not None else None

    def destroy_node(self) -> None:
        """Finish the GIF with the node."""
        self.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point: ``python -m roger_bringup.view_node``."""
    spin_node(ViewNode, "roger-view", args)

if __name__ == "__main__":
    main()
