"""What crosses the wire arrives bit for bit: eye poses (quaternion kept, not rebuilt from a
matrix) and the float fields of a ROI. The graph can then compute exactly what the core
loop computes (test_graph_matches_core)."""

from __future__ import annotations

import numpy as np
import pytest

from roger_common.conversions import eye_pose_msg, msg_to_eye_pose, msg_to_rois, rois_to_msg
from roger_common.geometry import eye_pose, quaternion_from_rotation, rotation_from_quaternion
from roger_common.types import FEATURE_DIM, Roi


def random_quaternion(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


@pytest.mark.parametrize("seed", range(5))
def test_eye_pose_round_trip_is_exact(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(50):
        # As the simulator makes them: from a matrix, through its quaternion.
        r = rotation_from_quaternion(random_quaternion(rng))
        pose = eye_pose(rng.normal(size=3), quaternion_from_rotation(r))
        back = msg_to_eye_pose(eye_pose_msg(pose))
        assert np.array_equal(back.rotation, pose.rotation)
        assert np.array_equal(back.position, pose.position)
        assert np.allclose(pose.rotation, r, atol=1e-12)


def test_roi_float_fields_round_trip_exactly() -> None:
    rng = np.random.default_rng(1)
    rois = [Roi(roi_id=i, bbox=(1, 2, 3, 4), position=tuple(rng.normal(size=3)),
                features=rng.random(FEATURE_DIM).astype(np.float32),
                known=np.ones(FEATURE_DIM, bool), activation=float(rng.random()),
                retinal_size=float(rng.random()), mean_intensity=float(rng.random()),
                motion=float(rng.random()), tactile=1.0 / 3.0, mapped=i % 2 == 0,
                cut=i % 3 == 0, size_m=float(rng.random())) for i in range(4)]
    for a, b in zip(rois, msg_to_rois(rois_to_msg(rois, 1.0, 3)), strict=True):
        for name in ("position", "activation", "retinal_size", "mean_intensity", "motion",
                     "tactile", "mapped", "cut", "size_m"):
            assert getattr(a, name) == getattr(b, name), name
        assert np.array_equal(a.features, b.features)
