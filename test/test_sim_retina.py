"""Retinas: camera model, stereo geometry, Phong intensity, labels, noise, live world edits."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from roger_common.errors import WorldFileError
from roger_common.geometry import project_point
from roger_common.types import Action, Goal, ObjectSpec, WorldSpec
from roger_sim.config import SimConfig
from roger_sim.robot import BASELINE, NECK_HEIGHT
from roger_sim.simulator import Simulator

QUIET = SimConfig(pixel_noise=0.0)


def _centroid(labels: np.ndarray, index: int) -> tuple[float, float]:
    v, u = np.nonzero(labels == index)
    assert len(u) > 20, "object not in view"
    return float(u.mean() + 0.5), float(v.mean() + 0.5)


def test_frame_layout() -> None:
    world = WorldSpec(objects=(ObjectSpec("b", "box", (0.75, 0.0), 0.2, 99, 1.0),))
    cfg = SimConfig(image_size=96, fov_deg=50.0)
    with Simulator(world, cfg) as sim:
        frame = sim.render(goal_id=7)
        assert sim.camera.width == sim.camera.height == 96
        assert sim.camera.focal_px == pytest.approx(48 / math.tan(math.radians(25)))
        for img in (frame.left, frame.right):
            assert img.shape == (96, 96) and img.dtype == np.float32
            assert 0.0 <= img.min() and img.max() <= 1.0
        for lab in (frame.left_labels, frame.right_labels):
            assert lab.shape == (96, 96) and lab.dtype == np.int32
            assert set(np.unique(lab)) == {-1, 0}
        assert frame.label_names == ("b",) and frame.goal_id == 7
        assert frame.stamp == sim.sim_time and frame.haptic is None
        # Eye poses: baseline apart, rotations orthonormal (OpenCV axes: right, down, fwd).
        assert np.linalg.norm(frame.left_pose.position - frame.right_pose.position) == \
            pytest.approx(BASELINE, abs=1e-6)
        for pose in (frame.left_pose, frame.right_pose):
            assert pose.rotation.T @ pose.rotation == pytest.approx(np.eye(3), abs=1e-6)
            assert pose.rotation[2, 1] < 0  # image "down" points down in the world


def _vergence_angle(point: np.ndarray, left: np.ndarray, right: np.ndarray) -> float:
    a, b = left - point, right - point
    return math.acos(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


@pytest.mark.parametrize("k", [1.0, 0.8, 1.25, 1.6])
def test_vergence_gives_the_disparity_stereo_predicts(k: float) -> None:
    """Verge at k times the ball's distance along the line of sight: disparity follows."""
    ball = np.array([0.7, 0.1, 0.05])
    world = WorldSpec(objects=(ObjectSpec("ball", "sphere", (0.7, 0.1), 0.1, 120, 1.0),))
    with Simulator(world, QUIET) as sim:
        neck = np.array([0.0, 0.0, NECK_HEIGHT])
        fixation = tuple(neck + k * (ball - neck))
        assert sim.execute(Goal(1, Action.ATTENTION_SHIFT, fixation)).converged
        report, frame = sim.run_goal(Goal(2, Action.VISUAL_IMPROVEMENT, fixation))
        assert report.converged
        ul, vl = _centroid(frame.left_labels, 0)
        ur, vr = _centroid(frame.right_labels, 0)
        measured = ul - ur
        left, right = frame.left_pose.position, frame.right_pose.position
        # Disparity = f * (vergence angle of the ball - vergence angle of the fixation).
        predicted = frame.camera.focal_px * (_vergence_angle(ball, left, right)
                                             - _vergence_angle(np.array(fixation), left, right))
        assert abs(measured - predicted) < 0.05 * abs(predicted) + 0.3, (measured, predicted)
        # ... and what projecting with the reported eye poses says.
        pl = project_point(frame.camera, frame.left_pose, ball)
        pr = project_point(frame.camera, frame.right_pose, ball)
        assert measured == pytest.approx(pl[0] - pr[0], abs=0.3)
        assert abs(vl - vr) < 0.3  # no vertical disparity on the line of sight
        if k == 1.0:
            assert abs(ul - 64) < 0.3 and abs(ur - 64) < 0.3  # on both foveae
        else:
            assert (measured > 1.0) == (k > 1.0) and abs(measured) > 1.0  # crossed if nearer


def test_rendered_intensity_rises_with_object_intensity() -> None:
    means = []
    world = WorldSpec(objects=())
    with Simulator(world, QUIET) as sim:
        for grey in (59, 69, 79, 99, 160):
            sim.add_object(ObjectSpec("b", "box", (0.8, 0.0), 0.25, grey, 1.0))
            frame = sim.render()
            means.append(float(frame.left[frame.left_labels == 0].mean()))
            sim.remove_object("b")
    assert all(a < b for a, b in itertools.pairwise(means)), means
    # Phong with no specular saturation: brightness is proportional to the grey level.
    assert means[-1] / means[0] == pytest.approx(160 / 59, rel=0.05)
    ground = frame.left[frame.left_labels == -1].mean()
    assert ground < means[0] / 2  # dark ground, objects stand out


def _edge_share(img: np.ndarray, labels: np.ndarray, index: int) -> float:
    """Share of neighbouring pixel pairs inside one object that differ by > 0.04."""
    inside = (labels[:, 1:] == index) & (labels[:, :-1] == index)
    return float((np.abs(np.diff(img, axis=1))[inside] > 0.04).mean())


@pytest.mark.parametrize("shape", ["box", "cylinder", "sphere", "prism"])
@pytest.mark.parametrize("texture", ["stripes", "checker"])
def test_textures_show_up(shape: str, texture: str) -> None:
    world = WorldSpec(objects=(
        ObjectSpec("plain", shape, (0.8, 0.25), 0.2, 150, 1.0),
        ObjectSpec("textured", shape, (0.8, -0.25), 0.2, 150, 1.0, texture=texture)))
    with Simulator(world, QUIET) as sim:
        frame = sim.render()
        img, lab = frame.left, frame.left_labels
        plain, textured = _edge_share(img, lab, 0), _edge_share(img, lab, 1)
        assert textured > 2 * plain + 0.03, (plain, textured)
        # Half the texture is half as bright: about 3/4 of the plain object's brightness.
        ratio = img[lab == 1].mean() / img[lab == 0].mean()
        assert ratio == pytest.approx(0.75, abs=0.08)


def test_pixel_noise_is_seeded_and_averages_down() -> None:
    world = WorldSpec(objects=(ObjectSpec("b", "box", (0.8, 0.0), 0.2, 99, 1.0),))
    with Simulator(world, QUIET) as clean_sim:
        clean = clean_sim.render().left
    with Simulator(world, SimConfig(pixel_noise=0.02), seed=1) as sim:
        mask = (clean > 0.06) & (clean < 0.94)  # away from the clipping at 0 and 1
        one = (sim.render(exposures=1).left - clean)[mask].std()
        sixteen = (sim.render(exposures=16).left - clean)[mask].std()
        with pytest.raises(ValueError):
            sim.render(exposures=0)
    assert one == pytest.approx(0.02, rel=0.15)
    assert sixteen == pytest.approx(0.005, rel=0.15)


def test_world_changes_show_in_the_next_frame() -> None:
    world = WorldSpec(objects=(ObjectSpec("a", "box", (0.8, 0.2), 0.2, 99, 1.0),))
    with Simulator(world, QUIET) as sim:
        before = sim.render()
        assert before.label_names == ("a",)
        sim.add_object(ObjectSpec("b", "cylinder", (0.8, -0.2), 0.2, 70, 0.5))
        frame = sim.render()
        assert frame.label_names == ("a", "b") and (frame.left_labels == 1).sum() > 50
        assert [o.name for o in sim.world.objects] == ["a", "b"]
        u_before, _ = _centroid(frame.left_labels, 0)
        sim.move_object("a", (0.7, 0.45), yaw=0.5)
        moved = sim.render()
        u_after, _ = _centroid(moved.left_labels, 0)
        assert u_after < u_before - 5  # moved left in the image
        x, y, z, yaw = sim.object_poses()["a"]
        assert (x, y, yaw) == pytest.approx((0.7, 0.45, 0.5), abs=1e-6)
        assert z == pytest.approx(0.1, abs=1e-6)
        sim.remove_object("a")
        last = sim.render()
        assert last.label_names == ("b",)
        assert set(np.unique(last.left_labels)) == {-1, 0}
        assert sim.world.objects[0].name == "b"


def test_world_change_errors() -> None:
    world = WorldSpec(objects=(ObjectSpec("a", "box", (0.8, 0.2), 0.2, 99, 1.0),))
    with Simulator(world) as sim:
        with pytest.raises(WorldFileError, match="duplicate"):
            sim.add_object(ObjectSpec("a", "box", (0.8, -0.3), 0.2, 99, 1.0))
        with pytest.raises(WorldFileError, match="overlaps 'a'"):
            sim.add_object(ObjectSpec("b", "box", (0.85, 0.25), 0.2, 99, 1.0))
        with pytest.raises(WorldFileError, match="size"):
            sim.add_object(ObjectSpec("c", "box", (0.8, -0.3), -0.2, 99, 1.0))
        with pytest.raises(WorldFileError, match="view"):
            sim.move_object("a", (0.1, 0.0))
        with pytest.raises(KeyError, match="zz"):
            sim.remove_object("zz")
        with pytest.raises(KeyError, match="zz"):
            sim.move_object("zz", (0.8, 0.0))
        assert [o.name for o in sim.world.objects] == ["a"]
        assert sim.object_poses()["a"][:2] == pytest.approx((0.8, 0.2))
