"""Pre-attentive activation of a ROI (section 2): the input of the winner-take-all.

The paper makes the activation a normalised function in [0, 1] of the retinal size, the
average intensity, the visual motion, the tactile response and the mapping status. Here
it is the weighted mean of five terms, each in [0, 1]:

- size: retinal share / ``size_norm``, clipped (large ROIs attract attention);
- intensity: mean retinal intensity / ``contrast_max``, clipped (bright ROIs attract);
- motion: change of the ROI's pixels since the previous frame once Roger's own eye and
  neck motion is compensated (see ``visual_motion``);
- tactile: 1 while a hand touches the ROI's object;
- unmapped: 1 - mapping status (objects not yet in the spatial map attract).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from roger_common.types import CameraModel, EyePose
from roger_perception.config import PerceptionConfig

#: Erosion element of ``visual_motion``: one pixel off the ROI's rim.
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
#: Fewer interior pixels than this and the whole ROI is compared.
_MIN_INNER = 4


def pre_attentive_activation(retinal_size: float, mean_intensity: float, motion: float,
                             tactile: float, mapped: bool, cfg: PerceptionConfig) -> float:
    """Activation in [0, 1]: weighted mean of the size, intensity, motion, tactile and
    unmapped terms, with the weights of ``cfg``."""
    terms = np.array([
        min(1.0, max(0.0, retinal_size / cfg.size_norm)),
        min(1.0, max(0.0, mean_intensity / cfg.contrast_max)),
        min(1.0, max(0.0, motion)),
        min(1.0, max(0.0, tactile)),
        0.0 if mapped else 1.0,
    ])
    weights = np.asarray(cfg.activation_weights())
    return float(np.clip(weights @ terms / weights.sum(), 0.0, 1.0))


@dataclass(frozen=True)
class MotionView:
    """What visual motion compares a new frame against: the previous left retina, smoothed
    (``motion_image``), with the camera and left-eye pose it was seen with."""

    image: np.ndarray
    camera: CameraModel
    pose: EyePose


def motion_image(left: np.ndarray, cfg: PerceptionConfig) -> np.ndarray:
    """The left retina smoothed by ``motion_blur_px``: pixel noise and the sub-pixel
    misregistration of a re-projection then no longer pass for change."""
    image = np.asarray(left, np.float32)
    if cfg.motion_blur_px <= 0:
        return image
    return cv2.GaussianBlur(image, (0, 0), cfg.motion_blur_px)


def _into_previous(u: np.ndarray, v: np.ndarray, depth: float | np.ndarray,
                   camera: CameraModel, pose: EyePose,
                   previous: MotionView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel centres (u, v) of this left retina, put back in space at ``depth`` (one value
    or one per pixel) and projected into the previous frame's left eye.

    Returns:
        The previous retina's array coordinates (up, vp) and whether each point lies ahead
        of that eye and inside its retina.
    """
    ray = np.stack([(u - camera.width / 2.0) / camera.focal_px,
                    (v - camera.height / 2.0) / camera.focal_px, np.ones(u.shape)])
    points = pose.rotation @ (ray * depth) + np.asarray(pose.position, float)[:, None]
    local = previous.pose.rotation.T @ (points - np.asarray(previous.pose.position,
                                                            float)[:, None])
    ahead = local[2] > 1e-6
    z = np.where(ahead, local[2], 1.0)
    pcam = previous.camera
    up = pcam.focal_px * local[0] / z + pcam.width / 2.0 - 0.5   # array coordinates
    vp = pcam.focal_px * local[1] / z + pcam.height / 2.0 - 0.5
    seen = ahead & (up >= 0) & (up <= pcam.width - 1) & (vp >= 0) & (vp <= pcam.height - 1)
    return up, vp, seen


def visual_motion(image: np.ndarray, mask: np.ndarray, bbox: tuple[int, int, int, int],
                  depth: float, camera: CameraModel, pose: EyePose,
                  previous: MotionView | None, cfg: PerceptionConfig) -> float:
    """Visual motion of a ROI in [0, 1], with Roger's own eye and neck motion compensated.

    Each pixel of the ROI (its mask eroded by one pixel, so that its rim, where a
    re-projection error shows most, does not count) is put back in space at the ROI's
    depth and projected into the previous frame's left eye: where the eyes moved but the
    world did not, the previous retina shows the same surface there. Eye and neck
    movements are mostly rotations about points near the eyes, so the re-projection
    hardly depends on the depth being exact. The motion is the share of those pixels
    whose (smoothed) intensity changed by more than ``motion_threshold``: near 0 for a
    still object whatever the eyes did, the share of the ROI the object moved off itself
    for a moved one, and 1 for an object where the previous frame saw bare ground.

    Args:
        image: ``motion_image`` of this frame's left retina.
        mask: The ROI's pixels inside ``bbox`` (shape ``(v1 - v0, u1 - u0)``).
        bbox: (u0, v0, u1, v1) in the left retina.
        depth: The ROI's depth along the left optical axis, metres.
        camera: Camera model of this frame.
        pose: Left-eye pose of this frame.
        previous: The previous frame's view; None on the first frame (motion 0).
        cfg: Gives ``motion_threshold`` and ``motion_min_evidence``.

    Returns:
        0 when there is no previous frame, or when less than ``motion_min_evidence`` of
        the ROI was in the previous left eye's view (no evidence either way).
    """
    if previous is None or not math.isfinite(depth) or depth <= 0:
        return 0.0
    inner = cv2.erode(mask.astype(np.uint8), _CROSS).astype(bool)
    if inner.sum() < _MIN_INNER:
        inner = mask.astype(bool)  # too thin to erode: keep the rim
    rows, cols = np.nonzero(inner)
    if rows.size == 0:
        return 0.0
    u0, v0 = bbox[0], bbox[1]
    up, vp, seen = _into_previous(cols + u0 + 0.5, rows + v0 + 0.5, depth, camera, pose,
                                  previous)
    if seen.mean() < cfg.motion_min_evidence:
        return 0.0
    before = cv2.remap(previous.image, up[seen].astype(np.float32)[None, :],
                       vp[seen].astype(np.float32)[None, :], cv2.INTER_LINEAR).ravel()
    now = image[rows[seen] + v0, cols[seen] + u0]
    return float(np.mean(np.abs(now - before) > cfg.motion_threshold))


def visual_motion_batch(image: np.ndarray,
                        rois: Sequence[tuple[np.ndarray, tuple[int, int, int, int], float]],
                        camera: CameraModel, pose: EyePose, previous: MotionView | None,
                        cfg: PerceptionConfig) -> list[float]:
    """``visual_motion`` of every ROI of a frame, with one re-projection and one remap for
    all their pixels (per call, ``cv2.remap`` and the small array operations cost more
    than the pixels of a ROI do).

    Each pixel goes through the same arithmetic as in ``visual_motion`` (the ROI's depth
    per pixel instead of per call), so the result is the same ROI by ROI.

    Args:
        image: ``motion_image`` of this frame's left retina.
        rois: (mask, bbox, depth) of each ROI, as ``visual_motion`` takes them.
        camera: Camera model of this frame.
        pose: Left-eye pose of this frame.
        previous: The previous frame's view; None on the first frame (all 0).
        cfg: Gives ``motion_threshold`` and ``motion_min_evidence``.

    Returns:
        The motion of each ROI, in the order of ``rois``.
    """
    out = [0.0] * len(rois)
    if previous is None:
        return out
    all_rows, all_cols, all_depths, owners = [], [], [], []
    for k, (mask, bbox, depth) in enumerate(rois):
        if not math.isfinite(depth) or depth <= 0:
            continue
        inner = cv2.erode(mask.astype(np.uint8), _CROSS).astype(bool)
        if inner.sum() < _MIN_INNER:
            inner = mask.astype(bool)  # too thin to erode: keep the rim
        rows, cols = np.nonzero(inner)
        if rows.size == 0:
            continue
        all_rows.append(rows + bbox[1])
        all_cols.append(cols + bbox[0])
        all_depths.append(np.full(rows.size, float(depth)))
        owners.append(np.full(rows.size, k))
    if not owners:
        return out
    rows, cols = np.concatenate(all_rows), np.concatenate(all_cols)
    owner = np.concatenate(owners)
    up, vp, seen = _into_previous(cols + 0.5, rows + 0.5, np.concatenate(all_depths),
                                  camera, pose, previous)
    total = np.bincount(owner, minlength=len(rois))
    evidence = np.bincount(owner, weights=seen, minlength=len(rois)) / np.maximum(total, 1)
    use = seen & (evidence >= cfg.motion_min_evidence)[owner]
    if not use.any():
        return out
    mu, mv = up[use].astype(np.float32), vp[use].astype(np.float32)
    before = np.empty(mu.size, np.float32)
    step = 32000  # cv2.remap needs maps narrower than 32767
    for s in range(0, mu.size, step):
        sl = slice(s, s + step)
        before[sl] = cv2.remap(previous.image, mu[None, sl], mv[None, sl],
                               cv2.INTER_LINEAR).ravel()
    changed = np.abs(image[rows[use], cols[use]] - before) > cfg.motion_threshold
    counts = np.bincount(owner[use], minlength=len(rois))
    moved = np.bincount(owner[use], weights=changed, minlength=len(rois))
    for j in np.flatnonzero(counts).tolist():
        out[j] = float(moved[j] / counts[j])
    return out


def is_mapped(position: Sequence[float],
              mapped_positions: Sequence[Sequence[float]] | np.ndarray,
              radius: float) -> bool:
    """Mapping status: True when a mapped position lies within ``radius`` metres.

    ``mapped_positions`` may be an (N, 3) array already (one conversion per frame)."""
    if len(mapped_positions) == 0:
        return False
    d = np.linalg.norm(np.asarray(mapped_positions, float).reshape(-1, 3)
                       - np.asarray(position, float), axis=1)
    return bool(np.min(d) <= radius)
