"""The perception node processes a stereo pair only once what it depends on has arrived.

DDS orders messages per topic, not across topics: the haptic reading of a haptic goal and
the spatial map the attention node published before the goal may reach the perception
node after the pair itself. The node must then wait (ROS callbacks called directly here,
in the worst delivery order, so the test does not depend on timing).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from ros_helpers import ros_graph

from roger_common import conversions as sc
from roger_common.geometry import eye_pose
from roger_common.types import CameraModel, HapticReading, StereoFrame
from roger_interfaces.msg import MapEntry, SpatialMap
from roger_perception import perception_node
from roger_perception.perception_node import PerceptionNode
from roger_sim.robot import BASELINE


def frame_parts(goal_id: int, stamp: float, map_revision: int = 0,
                haptic: HapticReading | None = None) -> dict[str, Any]:
    size = 32
    cam = CameraModel(width=size, height=size, focal_px=30.0)
    pose = eye_pose(np.zeros(3), (0.0, 0.0, 0.0, 1.0))
    img = np.full((size, size), 0.2, np.float32)
    frame = StereoFrame(stamp=stamp, goal_id=goal_id, left=img, right=img, camera=cam,
                        left_pose=pose, right_pose=pose, haptic=haptic)
    return {
        "left": sc.image_msg(img, stamp, "l"), "right": sc.image_msg(img, stamp, "r"),
        "info": sc.camera_info_msg(cam, stamp, "l", BASELINE, right=False),
        "geometry": sc.stereo_geometry_msg(frame, map_revision),
    }


def deliver(node: PerceptionNode, parts: dict[str, Any]) -> None:
    for kind in ("geometry", "left", "right", "info"):
        node._part(parts[kind].header.stamp, kind, parts[kind])


def spatial_map(revision: int, *positions: tuple[float, float, float]) -> SpatialMap:
    msg = SpatialMap(revision=revision)
    msg.entries = [MapEntry(id=i, mapped=True) for i in range(len(positions))]
    for e, p in zip(msg.entries, positions, strict=True):
        e.position.x, e.position.y, e.position.z = p
    return msg


@pytest.fixture
def node(ros_domain):
    with ros_graph(ros_domain) as graph:
        n = graph.add(PerceptionNode)
        n.seen = []

        def process(frame: StereoFrame, mapped: Any = ()) -> list:
            n.seen.append((frame.goal_id, frame.haptic, list(mapped)))
            return []

        n.perception.process = process
        yield n


def test_a_pair_waits_for_its_haptic_reading(node):
    reading = HapticReading(arm=0, contact=True, position=(0.6, 0.1, 0.05), weight=1.5)
    deliver(node, frame_parts(5, 1.0, haptic=reading))
    assert node.seen == []  # complete, but its haptic reading is still on the way
    node.on_haptic(sc.haptic_msg(reading, 5, 1.0))
    assert [(g, h is not None and h.weight) for g, h, _ in node.seen] == [(5, 1.5)]


def test_a_pair_waits_for_the_map_its_goal_was_sent_after(node):
    node.on_map(spatial_map(1))
    deliver(node, frame_parts(6, 1.0, map_revision=2))
    assert node.seen == []
    node.on_map(spatial_map(2, (0.5, 0.0, 0.05)))
    assert node.seen == [(6, None, [(0.5, 0.0, 0.05)])]


def test_pairs_are_processed_in_order(node):
    deliver(node, frame_parts(7, 1.0, map_revision=1))
    deliver(node, frame_parts(8, 2.0))  # needs nothing, but comes after goal 7's pair
    assert node.seen == []
    node.on_map(spatial_map(1))
    assert [g for g, _, _ in node.seen] == [7, 8]


def test_a_pair_whose_map_never_comes_is_processed_after_the_limit(node, monkeypatch):
    deliver(node, frame_parts(9, 1.0, map_revision=4))
    node._flush_stale()
    assert node.seen == []  # not yet: under the limit
    monkeypatch.setattr(perception_node, "WAIT_LIMIT_S", 0.0)
    node._flush_stale()
    assert [g for g, _, _ in node.seen] == [9]


def test_a_reading_without_contact_releases_the_pair(node):
    """The hand closed on nothing: NaN weight, still the pair's reading (no 2 s wait)."""
    empty = HapticReading(arm=1, contact=False, position=(0.6, 0.1, 0.05),
                          weight=float("nan"))
    deliver(node, frame_parts(10, 1.0, haptic=empty))
    node.on_haptic(sc.haptic_msg(empty, 10, 1.0))
    assert [(g, h.contact) for g, h, _ in node.seen] == [(10, False)]


def test_an_unusable_reading_releases_the_pair_without_one(node):
    bad = HapticReading(arm=0, contact=True, position=(0.6, 0.1, 0.05), weight=-2.0)
    deliver(node, frame_parts(11, 1.0, haptic=bad))
    node.on_haptic(sc.haptic_msg(bad, 11, 1.0))
    assert node.seen == [(11, None, [])]


def test_a_pair_with_a_fovea_waits_for_it_and_carries_it(node):
    size, fsize = 32, 48
    cam = CameraModel(width=size, height=size, focal_px=30.0)
    fcam = CameraModel(width=fsize, height=fsize, focal_px=90.0)
    pose = eye_pose(np.zeros(3), (0.0, 0.0, 0.0, 1.0))
    img = np.full((size, size), 0.2, np.float32)
    fimg = np.full((fsize, fsize), 0.3, np.float32)
    frame = StereoFrame(stamp=2.0, goal_id=7, left=img, right=img, camera=cam,
                        left_pose=pose, right_pose=pose, fovea=fimg, fovea_camera=fcam)
    parts = frame_parts(7, 2.0)
    parts["geometry"] = sc.stereo_geometry_msg(frame)
    assert parts["geometry"].fovea
    seen = []
    node.perception.process = lambda f, mapped=(): seen.append(f) or []
    deliver(node, parts)
    assert seen == []  # the pair is complete, its fovea is not
    node._part(parts["geometry"].header.stamp, "fovea", sc.image_msg(fimg, 2.0, "l"))
    assert seen == []
    node._part(parts["geometry"].header.stamp, "fovea_info",
               sc.camera_info_msg(fcam, 2.0, "l", 0.0, right=False))
    assert len(seen) == 1 and seen[0].goal_id == 7
    assert seen[0].fovea is not None and seen[0].fovea.shape == (fsize, fsize)
    assert seen[0].fovea_camera.focal_px == pytest.approx(90.0)
    # A pair without a fovea does not wait for one.
    deliver(node, frame_parts(8, 3.0))
    assert [f.goal_id for f in seen] == [7, 8] and seen[1].fovea is None
