"""ROI outlines on both retinas (roger_perception.overlay), scored on the simulator's frames.

The left outline is the ROI's bounding box. The right one is that box moved by the stereo
projection of the ROI's position; on real frames of roger_sim it must lie on the object in
the right retina's label image (ground truth, used here only) better than the unmoved box.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import WORLDS
from perception_synth import camera_model, eye_poses
from test_perception_sim import GAZES, _scored

from roger_common.geometry import look_rotation
from roger_common.types import FEATURE_DIM, Action, EyePose, Goal, Roi, StereoFrame
from roger_perception.overlay import (
    MAPPED_RGBA,
    UNMAPPED_RGBA,
    RetinaOverlay,
    right_shift,
    roi_overlays,
)
from roger_sim.simulator import Simulator
from roger_sim.world import load_world

#: Worlds whose objects stand at several depths, so that many ROIs have a clear disparity.
WORLDS_SCORED = ("two_rows", "touching")
#: An ROI whose outline moves this far (pixels) must lie better on its object in the right
#: retina; below it a silhouette's own left/right difference can outweigh the shift.
CLEAR_SHIFT_PX = 3.5
#: Any ROI's right outline may lie worse than the unmoved box by at most this IoU.
IOU_SLACK = 0.02


@pytest.fixture(scope="module")
def frames() -> list[StereoFrame]:
    out = []
    for world in WORLDS_SCORED:
        with Simulator(load_world(WORLDS / f"{world}.yaml"), seed=0) as sim:
            out += [sim.run_goal(Goal(i + 1, Action.ATTENTION_SHIFT, g))[1]
                    for i, g in enumerate(GAZES)]
    return out


def boxes(overlay: RetinaOverlay) -> dict[int, tuple[float, float, float, float]]:
    """ROI id -> (u0, v0, u1, v1) of its four segments, which must close a rectangle."""
    out = {}
    for n, roi_id in enumerate(overlay.roi_ids):
        pts = overlay.points[8 * n:8 * n + 8]
        assert pts[1::2] == pts[2::2] + pts[:1], pts  # each side starts where one ended
        us, vs = [p[0] for p in pts], [p[1] for p in pts]
        out[roi_id] = (min(us), min(vs), max(us), max(vs))
    return out


def iou(box: tuple[float, float, float, float], mask: np.ndarray) -> float:
    """Intersection over union of a pixel box (pixel centres inside) and a mask."""
    u0, v0, u1, v1 = box
    v, u = np.mgrid[:mask.shape[0], :mask.shape[1]] + 0.5
    inside = (u >= u0) & (u < u1) & (v >= v0) & (v < v1)
    return float((inside & mask).sum() / (inside | mask).sum())


def test_the_right_outline_lies_on_the_object_in_the_right_retina(frames) -> None:
    clear, scored = 0, 0
    for frame in frames:
        scoring = _scored(frame)
        left, right = roi_overlays([roi for roi, *_ in scoring], frame.camera,
                                   frame.left_pose, frame.right_pose)
        left_boxes, right_boxes = boxes(left), boxes(right)
        assert len(left.colors) == len(left.points) // 2 == 4 * len(scoring)
        for roi, name, share, cut in scoring:
            assert left_boxes[roi.roi_id] == tuple(float(c) for c in roi.bbox)
            if cut or share < 0.7:  # part of the object lies outside the left box
                continue
            obj = frame.right_labels == frame.label_names.index(name)
            moved, still = iou(right_boxes[roi.roi_id], obj), iou(left_boxes[roi.roi_id], obj)
            shift = right_shift(roi, frame.camera, frame.left_pose, frame.right_pose)
            assert shift is not None
            scored += 1
            assert moved >= still - IOU_SLACK, (name, roi.bbox, shift, moved, still)
            if abs(shift[0]) >= CLEAR_SHIFT_PX:
                clear += 1
                assert moved > still + 0.05, (name, roi.bbox, shift, moved, still)
    assert scored >= 10 and clear >= 4, (scored, clear)


def _roi(roi_id: int, position: tuple[float, float, float], mapped: bool = False) -> Roi:
    return Roi(roi_id=roi_id, bbox=(10, 20, 30, 50), position=position,
               features=np.zeros(FEATURE_DIM), known=np.ones(FEATURE_DIM, bool), mapped=mapped)


def test_colours_by_mapping_status_and_no_right_outline_behind_the_right_eye() -> None:
    camera = camera_model(128)
    left_pose, right_pose = eye_poses((0.9, 0.0, 0.0))
    # The right eye turned round: the ROI is in front of the left eye only.
    back = EyePose(position=right_pose.position, rotation=look_rotation(
        right_pose.position, right_pose.position - np.array([1.0, 0.0, 0.0])))
    rois = [_roi(0, (0.9, 0.0, 0.0)), dataclasses.replace(_roi(1, (0.8, 0.1, 0.0)),
                                                          mapped=True)]
    left, right = roi_overlays(rois, camera, left_pose, right_pose)
    assert left.colors == [UNMAPPED_RGBA] * 4 + [MAPPED_RGBA] * 4
    assert right.colors == left.colors and right.roi_ids == [0, 1]
    # Fixated: the gaze point projects to the centre of both eyes, no shift.
    assert boxes(right)[0] == pytest.approx(boxes(left)[0], abs=1e-6)
    left, right = roi_overlays(rois, camera, left_pose, back)
    assert left.roi_ids == [0, 1] and right.roi_ids == [] and right.points == []
    assert roi_overlays([], camera, left_pose, right_pose) == (RetinaOverlay(),
                                                                RetinaOverlay())
