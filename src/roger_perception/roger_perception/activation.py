"""Pre-attentive activation of a ROI (section 2): the input of the winner-take-all.

The paper makes the activation a normalised function in [0, 1] of the retinal size, the
average intensity, the visual motion, the tactile response and the mapping status. Here
it is the weighted mean of five terms, each in [0, 1]:

- size: retinal share / ``size_norm``, clipped (large ROIs attract attention);
- intensity: mean retinal intensity / ``contrast_max``, clipped (bright ROIs attract);
- motion: displacement of the ROI since the previous frame (see ``motion_term``);
- tactile: 1 while a hand touches the ROI's object;
- unmapped: 1 - mapping status (objects not yet in the spatial map attract).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from roger_common.geometry import as_point, in_view
from roger_common.types import CameraModel, EyePose
from roger_perception.config import PerceptionConfig


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


def motion_term(position: Sequence[float], previous: Sequence[Sequence[float]],
                previous_view: tuple[CameraModel, EyePose] | None,
                cfg: PerceptionConfig) -> float:
    """Visual motion of a ROI in [0, 1] from its displacement since the previous frame.

    The displacement is the distance (robot frame) to the nearest ROI position of the
    previous frame, so eye and neck movements do not count as motion. Less than
    ``motion_deadband_m`` is triangulation jitter (0); ``motion_norm_m`` more gives 1. A
    ROI that the previous left eye could not see has no evidence of motion (0); one it
    could see but that had no ROI near it has appeared (1).

    Args:
        position: The ROI's position now.
        previous: ROI positions of the previous frame.
        previous_view: Camera and left-eye pose of the previous frame; None on the first.
        cfg: Gives the dead band and the normaliser.
    """
    if previous_view is None:
        return 0.0
    camera, pose = previous_view
    if not in_view(camera, pose, as_point(position)):
        return 0.0
    if len(previous) == 0:
        return 1.0
    d = float(np.min(np.linalg.norm(np.asarray(previous, float)
                                    - np.asarray(position, float), axis=1)))
    return float(min(1.0, max(0.0, (d - cfg.motion_deadband_m) / cfg.motion_norm_m)))


def is_mapped(position: Sequence[float], mapped_positions: Sequence[Sequence[float]],
              radius: float) -> bool:
    """Mapping status: True when a mapped position lies within ``radius`` metres."""
    if len(mapped_positions) == 0:
        return False
    d = np.linalg.norm(np.asarray(mapped_positions, float).reshape(-1, 3)
                       - np.asarray(position, float), axis=1)
    return bool(np.min(d) <= radius)
