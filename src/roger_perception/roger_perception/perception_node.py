"""ROS node of the pre-attentive stage: stereo pair in, ROI array out (and the ROIs'
outlines over each retina, for Foxglove's Image panel).

Run alone: ``roger-perception`` (or ``python -m roger_perception.perception_node``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from visualization_msgs.msg import ImageMarker

from roger_common import conversions as common
from roger_common import topics
from roger_common.errors import MessageError
from roger_common.ros_node import (
    IMAGES,
    LATCHED,
    RELIABLE,
    BadInput,
    declare_config,
    spin_node,
)
from roger_common.types import HapticReading, StereoFrame
from roger_interfaces.msg import HapticReading as HapticReadingMsg
from roger_interfaces.msg import RoiArray, SpatialMap, StereoGeometry
from roger_perception import conversions as conv
from roger_perception.config import PerceptionConfig
from roger_perception.overlay import roi_overlays
from roger_perception.perception import Perception

#: Partial stereo pairs kept while their other parts arrive.
MAX_PENDING = 8
#: A complete pair still waiting for its haptic reading or spatial map after this many
#: seconds (wall) is processed without them, with a warning.
WAIT_LIMIT_S = 2.0


class PerceptionNode(Node):
    """Joins left/right image, camera info and eye geometry by stamp; runs Perception.

    A pair is processed once it is complete, in the order of completion, and once what it
    depends on has arrived on the other topics: the haptic reading of its goal (when the
    geometry says there is one) and a spatial map of at least the goal's ``map_revision``.
    DDS does not order messages across topics, so without this wait the weight feature
    and the "mapped" term of the activation depended on delivery order: two runs of the
    same seed parted ways (docs/performance.md).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_perception", **kwargs)
        self.config = declare_config(self, PerceptionConfig)
        self.perception = Perception(self.config)
        self._pending: dict[tuple[int, int], dict[str, Any]] = {}
        self._haptic: dict[int, HapticReading | None] = {}
        self._mapped: list[tuple[float, float, float]] = []
        self._map_revision = 0
        #: Complete pairs waiting for their haptic reading or map: (parts, since).
        self._ready: list[tuple[dict[str, Any], float]] = []
        self.bad_input = BadInput(self)
        self.pub_rois = self.create_publisher(RoiArray, topics.ROIS, RELIABLE)
        # The ROIs drawn over each retina (roger_perception.overlay), stamped like its image.
        self.pub_left_markers = self.create_publisher(ImageMarker, topics.LEFT_ROI_MARKERS,
                                                      IMAGES)
        self.pub_right_markers = self.create_publisher(ImageMarker, topics.RIGHT_ROI_MARKERS,
                                                       IMAGES)
        for kind, cls, topic in (("left", Image, topics.LEFT_IMAGE),
                                 ("right", Image, topics.RIGHT_IMAGE),
                                 ("geometry", StereoGeometry, topics.STEREO_GEOMETRY),
                                 ("info", CameraInfo, topics.LEFT_INFO),
                                 ("fovea", Image, topics.FOVEA_IMAGE),
                                 ("fovea_info", CameraInfo, topics.FOVEA_INFO),
                                 ("fovea_right", Image, topics.FOVEA_RIGHT_IMAGE)):
            self.create_subscription(cls, topic, self._part_of(kind, topic), IMAGES)
        self.create_subscription(HapticReadingMsg, topics.HAPTIC, self.on_haptic, RELIABLE)
        self.create_subscription(SpatialMap, topics.SPATIAL_MAP, self.on_map, LATCHED)
        self.create_timer(0.5, self._flush_stale,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def on_haptic(self, msg: HapticReadingMsg) -> None:
        """Keep the haptic reading for the frame of the same goal."""
        try:
            reading: HapticReading | None = common.msg_to_haptic(msg)
        except MessageError as exc:
            self.bad_input.drop(topics.HAPTIC, exc)
            reading = None  # the pair of this goal need not wait for it any longer
        self._haptic[int(msg.goal_id)] = reading
        while len(self._haptic) > MAX_PENDING:
            self._haptic.pop(next(iter(self._haptic)))
        self._drain()

    def on_map(self, msg: SpatialMap) -> None:
        """Mapping status feeds the pre-attentive activation."""
        self._mapped = conv.mapped_positions(msg)
        self._map_revision = max(self._map_revision, int(msg.revision))
        self._drain()

    def _part_of(self, kind: str, topic: str) -> Callable[[Any], None]:
        check = _CHECKS[kind]

        def on_part(msg: Any) -> None:
            # Each part is checked on its own as it comes: an unusable one never takes the
            # place of a usable part of the same stamp, nor of a partial pair (MAX_PENDING).
            try:
                check(msg)
            except MessageError as exc:
                self.bad_input.drop(topic, exc)
                return
            self._part(msg.header.stamp, kind, msg)
        return on_part

    def _part(self, stamp: Any, kind: str, msg: Any) -> None:
        key = (stamp.sec, stamp.nanosec)
        parts = self._pending.setdefault(key, {})
        parts[kind] = msg
        if _complete(parts):
            del self._pending[key]
            self._ready.append((parts, time.monotonic()))
            self._drain()
        while len(self._pending) > MAX_PENDING:
            self._pending.pop(next(iter(self._pending)))

    def _waits_for(self, geometry: StereoGeometry) -> str | None:
        """What a complete pair still lacks, or None."""
        if geometry.haptic and int(geometry.goal_id) not in self._haptic:
            return "its haptic reading"
        if self._map_revision < int(geometry.map_revision):
            return f"spatial map {geometry.map_revision} (have {self._map_revision})"
        return None

    def _drain(self, force: bool = False) -> None:
        """Process the waiting pairs in order, up to the first that still lacks something."""
        while self._ready:
            parts, since = self._ready[0]
            lacks = self._waits_for(parts["geometry"])
            if lacks is not None:
                if not force or time.monotonic() - since < WAIT_LIMIT_S:
                    return
                self.get_logger().warn(f"stereo pair of goal {parts['geometry'].goal_id} "
                                       f"processed without {lacks} after {WAIT_LIMIT_S} s")
            self._ready.pop(0)
            self._process(parts)

    def _flush_stale(self) -> None:
        self._drain(force=True)

    def _process(self, parts: dict[str, Any]) -> None:
        geometry: StereoGeometry = parts["geometry"]
        try:
            camera = common.camera_from_info(parts["info"])
            left_pose, right_pose = common.poses_from_geometry(geometry)
            left = common.image_to_array(parts["left"])
            right = common.image_to_array(parts["right"])
            if left.shape != right.shape or left.shape != (camera.height, camera.width):
                raise MessageError(f"stereo pair sizes {left.shape} / {right.shape} do not "
                                   f"match the camera ({camera.height}, {camera.width})")
        except MessageError as exc:
            self.bad_input.drop(topics.LEFT_IMAGE, f"stereo pair of goal "
                                f"{geometry.goal_id}: {exc}; the attention node will ask for "
                                "it again")
            return
        stamp = common.time_to_seconds(geometry.header.stamp)
        fovea, fovea_camera, fovea_right = None, None, None
        if geometry.fovea:
            try:
                fovea_camera = common.camera_from_info(parts["fovea_info"])
                fovea = common.image_to_array(parts["fovea"])
                if fovea.shape != (fovea_camera.height, fovea_camera.width):
                    raise MessageError(f"foveal image size {fovea.shape} does not match its "
                                       f"camera ({fovea_camera.height}, {fovea_camera.width})")
                if geometry.fovea_right:
                    fovea_right = common.image_to_array(parts["fovea_right"])
                    if fovea_right.shape != fovea.shape:
                        raise MessageError(f"right foveal image size {fovea_right.shape} "
                                           f"does not match the left one's {fovea.shape}")
            except MessageError as exc:
                self.get_logger().warn(f"fovea of goal {geometry.goal_id} dropped: {exc}")
                fovea, fovea_camera, fovea_right = None, None, None
        frame = StereoFrame(stamp=stamp, goal_id=int(geometry.goal_id), left=left, right=right,
                            camera=camera, left_pose=left_pose, right_pose=right_pose,
                            exposures=int(geometry.exposures),
                            haptic=self._haptic.pop(int(geometry.goal_id), None),
                            fovea=fovea, fovea_camera=fovea_camera, fovea_right=fovea_right)
        rois = self.perception.process(frame, self._mapped)
        self.pub_rois.publish(common.rois_to_msg(rois, stamp, frame.goal_id,
                                                 self.perception.config.features))
        # Every pair gets its markers, none drawn when there are no ROIs: a viewer then
        # drops the outlines of the previous pair.
        left_overlay, right_overlay = roi_overlays(rois, camera, left_pose, right_pose)
        self.pub_left_markers.publish(conv.overlay_to_msg(left_overlay, parts["left"].header))
        self.pub_right_markers.publish(conv.overlay_to_msg(right_overlay, parts["right"].header))


def _complete(parts: dict[str, Any]) -> bool:
    """A stereo pair has its two images, camera info and geometry, and, when the geometry
    says a fovea belongs to it, the foveal image and its camera info (and the right eye's
    foveal image when it says that one does too)."""
    if not {"left", "right", "geometry", "info"} <= parts.keys():
        return False
    geometry = parts["geometry"]
    if not geometry.fovea:
        return True
    want = {"fovea", "fovea_info"} | ({"fovea_right"} if geometry.fovea_right else set())
    return want <= parts.keys()


#: What each part of a stereo pair must pass on its own (roger_common.conversions).
_CHECKS: dict[str, Callable[[Any], object]] = {
    "left": common.image_to_array, "right": common.image_to_array,
    "info": common.camera_from_info, "geometry": common.poses_from_geometry,
    "fovea": common.image_to_array, "fovea_info": common.camera_from_info,
    "fovea_right": common.image_to_array}


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-perception``."""
    spin_node(PerceptionNode, "roger-perception", args)

if __name__ == "__main__":
    main()
