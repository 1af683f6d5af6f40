"""Pinhole camera geometry shared by perception (triangulation) and attention (what is in view)."""

from __future__ import annotations

import numpy as np

from roger_common.types import CameraModel, EyePose


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
