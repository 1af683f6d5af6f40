"""The ROIs drawn on both retinas: their outlines in each eye's pixels, for an image viewer.

An ROI's bounding box is measured in the left retina. In the right retina the same object
lies elsewhere by its disparity, which the ROI's stereo position gives: the right outline is
the left box moved by where the position projects in the right eye minus where it projects
in the left eye. An ROI whose position is not in front of the right eye has no right
outline.

Plain data only (``RetinaOverlay``); the perception node turns each into a
visualization_msgs/ImageMarker (LINE_LIST) stamped like its retina's image, which
Foxglove's Image panel draws over that image. Pixel coordinates have their origin at the
top-left corner of the top-left pixel (as ImageMarker's viewers read them), so the box
(u0, v0, u1, v1), u1 and v1 exclusive, is drawn around its pixels exactly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from roger_common.geometry import project_point
from roger_common.types import CameraModel, EyePose, Roi

Pixel = tuple[float, float]
Rgba = tuple[float, float, float, float]

# The colours of roger_attention.markers (the spatial map in 3D), copied rather than
# imported: perception and attention are peers that never import each other (.importlinter).
# An ROI is drawn in the colour its map entry has in the 3D view.
#: Outline of an ROI at a mapped position.
MAPPED_RGBA: Rgba = (0.2, 0.8, 0.2, 1.0)
#: Outline of an ROI at a position not mapped yet.
UNMAPPED_RGBA: Rgba = (1.0, 0.55, 0.0, 1.0)


@dataclass
class RetinaOverlay:
    """The ROI outlines of one retina, as a list of line segments.

    Attributes:
        points: Segment ends in pixels, two a segment: segment i runs from
            ``points[2 * i]`` to ``points[2 * i + 1]``.
        colors: One RGBA in [0, 1] a segment.
        roi_ids: The ids of the ROIs drawn, in order; each has four segments.
    """

    points: list[Pixel] = field(default_factory=list)
    colors: list[Rgba] = field(default_factory=list)
    roi_ids: list[int] = field(default_factory=list)

    def add_box(self, roi_id: int, box: tuple[float, float, float, float], rgba: Rgba) -> None:
        """Append the four sides of the box (u0, v0, u1, v1)."""
        u0, v0, u1, v1 = box
        corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
        for i, corner in enumerate(corners):
            self.points += [corner, corners[(i + 1) % 4]]
        self.colors += [rgba] * 4
        self.roi_ids.append(roi_id)


def roi_color(roi: Roi) -> Rgba:
    """Green for an ROI at a mapped position, orange before."""
    return MAPPED_RGBA if roi.mapped else UNMAPPED_RGBA


def right_shift(roi: Roi, camera: CameraModel, left_pose: EyePose,
                right_pose: EyePose) -> Pixel | None:
    """Where the ROI's position projects in the right eye minus where it projects in the
    left eye, pixels; None when it is not in front of both eyes."""
    ul, vl, depth_l = project_point(camera, left_pose, roi.position)
    ur, vr, depth_r = project_point(camera, right_pose, roi.position)
    shift = (ur - ul, vr - vl)
    if depth_l <= 0 or depth_r <= 0 or not all(math.isfinite(s) for s in shift):
        return None
    return shift


def roi_overlays(rois: Iterable[Roi], camera: CameraModel, left_pose: EyePose,
                 right_pose: EyePose) -> tuple[RetinaOverlay, RetinaOverlay]:
    """The outlines of every ROI in the left and the right retina.

    Args:
        rois: The ROIs of one stereo pair (bbox in the left retina, position in the robot
            frame).
        camera: The pinhole model of both retinas.
        left_pose, right_pose: The eye poses the pair was rendered from.

    Returns:
        (left, right): the left outlines are the bounding boxes; the right ones the same
        boxes shifted by ``right_shift`` (ROIs without one are left out of the right).
    """
    left, right = RetinaOverlay(), RetinaOverlay()
    for roi in rois:
        u0, v0, u1, v1 = (float(c) for c in roi.bbox)
        left.add_box(roi.roi_id, (u0, v0, u1, v1), roi_color(roi))
        shift = right_shift(roi, camera, left_pose, right_pose)
        if shift is not None:
            du, dv = shift
            right.add_box(roi.roi_id, (u0 + du, v0 + dv, u1 + du, v1 + dv), roi_color(roi))
    return left, right
