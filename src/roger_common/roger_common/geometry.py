"""Pinhole camera geometry shared by perception (triangulation) and attention (what is in view)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from roger_common.types import CameraModel, EyePose


def as_point(p: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """Three numbers as an (x, y, z) tuple of floats; ValueError unless exactly three."""
    x, y, z = (float(v) for v in p)
    return (x, y, z)


def camera_ray(camera: CameraModel, pose: EyePose, u: float, v: float) -> np.ndarray:
    """Unit direction, robot frame, of the ray through pixel (u, v) (pixel centres at +0.5)."""
    cx, cy = camera.width / 2.0, camera.height / 2.0
    d_cam = np.array([(u - cx) / camera.focal_px, (v - cy) / camera.focal_px, 1.0])
    d = pose.rotation @ d_cam
    return d / np.linalg.norm(d)


def project_point(
    camera: CameraModel, pose: EyePose, point: np.ndarray | tuple[float, float, float]
) -> tuple[float, float, float]:
    """Project a robot-frame point into the image.

    Returns:
        (u, v, depth): pixel coordinates and the depth along the optical axis; depth <= 0
        means the point is behind the camera.
    """
    p_cam = pose.rotation.T @ (np.asarray(point, float) - pose.position)
    depth = float(p_cam[2])
    if depth <= 1e-9:
        return float("nan"), float("nan"), depth
    u = camera.focal_px * p_cam[0] / depth + camera.width / 2.0
    v = camera.focal_px * p_cam[1] / depth + camera.height / 2.0
    return float(u), float(v), depth


def in_view(
    camera: CameraModel, pose: EyePose, point: np.ndarray | tuple[float, float, float],
    margin: float = 0.0,
) -> bool:
    """True when the point projects inside the image, at least ``margin`` pixels from its edge."""
    u, v, depth = project_point(camera, pose, point)
    if depth <= 0:
        return False
    return margin <= u < camera.width - margin and margin <= v < camera.height - margin


def triangulate(
    origin_a: np.ndarray, dir_a: np.ndarray, origin_b: np.ndarray, dir_b: np.ndarray
) -> tuple[np.ndarray, float]:
    """Midpoint of the shortest segment between two rays.

    Returns:
        (point, gap): the midpoint, and the length of the segment (how far the rays
        miss each other; large means a bad stereo match). For parallel rays the point
        is NaN and the gap infinite.
    """
    w0 = origin_a - origin_b
    a, b, c = dir_a @ dir_a, dir_a @ dir_b, dir_b @ dir_b
    d, e = dir_a @ w0, dir_b @ w0
    den = a * c - b * b
    if abs(den) < 1e-12:
        return np.full(3, np.nan), float("inf")
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    pa = origin_a + s * dir_a
    pb = origin_b + t * dir_b
    return (pa + pb) / 2.0, float(np.linalg.norm(pa - pb))


def look_rotation(position: np.ndarray, target: np.ndarray,
                  up: np.ndarray | None = None) -> np.ndarray:
    """Rotation (columns: image right, image down, forward) of a camera at ``position``
    looking at ``target`` with the world ``up`` (default +z) pointing up in the image."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    fwd = np.asarray(target, float) - np.asarray(position, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(fwd, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    return np.column_stack([right, down, fwd])


def quaternion_from_rotation(r: np.ndarray) -> tuple[float, float, float, float]:
    """A 3x3 rotation matrix as a unit quaternion (x, y, z, w) (Shepperd's method)."""
    m = np.asarray(r, float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, \
            (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, \
            (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, \
            (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, \
            (m[1, 2] + m[2, 1]) / s, 0.25 * s
    return float(x), float(y), float(z), float(w)


def rotation_from_quaternion(q: Sequence[float]) -> np.ndarray:
    """A unit quaternion (x, y, z, w) as a 3x3 rotation matrix."""
    x, y, z, w = (float(c) for c in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def eye_pose(position: Sequence[float] | np.ndarray, quaternion: Sequence[float]) -> EyePose:
    """An EyePose whose rotation is computed from ``quaternion`` (x, y, z, w), which it
    keeps: the same quaternion gives the same matrix wherever it is rebuilt."""
    q = tuple(float(c) for c in quaternion)
    return EyePose(position=np.asarray(position, float), rotation=rotation_from_quaternion(q),
                   quaternion=(q[0], q[1], q[2], q[3]))
