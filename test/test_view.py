"""The view of what Roger attends to (issue 10, item 1): the picture, its files, its node."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import WORLDS
from PIL import Image as PILImage
from rclpy.node import Node
from ros_helpers import ros_graph, spin_until
from sensor_msgs.msg import Image

from roger_attention.attention_node import AttentionNode
from roger_bringup.view_node import ViewNode
from roger_common.errors import ConfigError
from roger_common.types import FEATURE_DIM, Roi
from roger_experiments.view import (
    FOCUS_COLOR,
    MARGIN,
    ROI_COLOR,
    ViewWriter,
    compose_view,
    focus_roi_id,
    interests_by_roi,
)
from roger_interfaces.msg import Metrics
from roger_memory.memory_node import MemoryNode
from roger_perception.perception_node import PerceptionNode
from roger_sim.sim_node import SimNode

H, W = 48, 64


def roi(roi_id, bbox, activation=0.5, position=(0.5, 0.0, 0.05)):
    return Roi(roi_id=roi_id, bbox=bbox, position=position,
               features=np.zeros(FEATURE_DIM, np.float32), known=np.ones(FEATURE_DIM, bool),
               activation=activation)


def retinas(seed=0):
    rng = np.random.default_rng(seed)
    # Dark retinas, so that no retina pixel can be mistaken for a drawn colour.
    return (rng.random((H, W)) * 0.3).astype(np.float32), \
        (rng.random((H, W)) * 0.3).astype(np.float32)


def has_color(img, color):
    return bool(np.any(np.all(img == np.array(color, np.uint8), axis=-1)))


def test_view_has_the_retinas_size_and_keeps_their_pixels():
    left, right = retinas()
    view = compose_view(left, right, [], None, "000", "attention_shift", {"cycles": 3})
    assert view.dtype == np.uint8 and view.shape[2] == 3
    assert view.shape[1] == 2 * W + MARGIN and view.shape[0] > H
    expected_left = (left * 255 + 0.5).astype(np.uint8)
    expected_right = (right * 255 + 0.5).astype(np.uint8)
    assert np.array_equal(view[:H, :W, 0], expected_left)
    assert np.array_equal(view[:H, W + MARGIN:, 1], expected_right)
    assert not has_color(view[:H], FOCUS_COLOR)


@pytest.mark.parametrize("scale", [1, 2])
def test_view_marks_the_focused_roi_only(scale):
    left, right = retinas(1)
    rois = [roi(1, (5, 6, 20, 18), 0.9), roi(2, (30, 20, 50, 40), 0.2)]
    view = compose_view(left, right, rois, (30, 20, 50, 40), "010", "visual_improvement",
                        {"cycles": 4, "attention_shifts": 2}, {1: 0.5, 2: 1.25}, scale=scale)
    assert view.shape[1] == 2 * W * scale + MARGIN
    s = scale
    # The attention window's top edge is in FOCUS_COLOR, the other ROI's in ROI_COLOR.
    assert np.all(view[20 * s, 30 * s:50 * s - 1] == FOCUS_COLOR)
    assert np.all(view[6 * s, 5 * s:20 * s - 1] == ROI_COLOR)
    # Nothing of the focus colour outside the window on the left retina.
    mask = np.all(view[:H * s, :W * s] == FOCUS_COLOR, axis=-1)
    ys, xs = np.nonzero(mask)
    assert ys.min() >= 20 * s - 1 and xs.min() >= 30 * s - 1
    assert ys.max() <= 40 * s and xs.max() <= 50 * s
    assert not has_color(view[:H * s, W * s + MARGIN:], FOCUS_COLOR)
    assert focus_roi_id(rois, (30, 20, 50, 40)) == 2


def test_view_refuses_mismatched_retinas_and_bad_scale():
    left, _ = retinas()
    with pytest.raises(ValueError, match="differ"):
        compose_view(left, left[:, :10], [], None, "000", "", {})
    with pytest.raises(ValueError, match="scale"):
        compose_view(left, left, [], None, "000", "", {}, scale=0)


def test_interest_goes_to_the_nearest_entry_within_the_radius():
    rois = [roi(1, (0, 0, 2, 2), position=(0.5, 0.0, 0.0)),
            roi(2, (0, 0, 2, 2), position=(1.5, 0.0, 0.0))]
    entries = [((0.52, 0.0, 0.0), 0.7), ((0.4, 0.0, 0.0), 0.1)]
    assert interests_by_roi(rois, entries, 0.15) == {1: 0.7}
    assert interests_by_roi(rois, [], 0.15) == {}


def test_view_writer_writes_frames_and_a_gif(tmp_path):
    writer = ViewWriter(tmp_path / "v", fps=5)
    left, right = retinas()
    for i in range(3):
        writer.write(compose_view(left * (i + 1) / 3, right, [], None, "000", "", {"cycles": i}))
    gif = writer.close()
    assert [p.name for p in sorted((tmp_path / "v").glob("frame_*.png"))] == \
        ["frame_00001.png", "frame_00002.png", "frame_00003.png"]
    with PILImage.open(gif) as im:
        assert im.n_frames == 3
        assert im.size == (2 * W + MARGIN, writer_height(tmp_path / "v" / "frame_00001.png"))
    assert writer.close() is None
    with pytest.raises(RuntimeError):
        writer.write(np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ConfigError):
        ViewWriter(tmp_path / "w", fps=0)


def writer_height(png):
    with PILImage.open(png) as im:
        return im.size[1]


class ViewListener(Node):
    def __init__(self, **kwargs):
        super().__init__("test_view_listener", **kwargs)
        self.views: list[Image] = []
        self.done = False
        self.create_subscription(Image, "/roger/view", self.views.append, 10)
        self.create_subscription(Metrics, "/roger/metrics", self.on_metrics, 10)

    def on_metrics(self, msg):
        self.done = self.done or msg.done


def test_view_node_publishes_one_view_per_cycle_and_writes_a_gif(no_leaks, ros_domain,
                                                                   tmp_path):
    cycles, size, scale = 4, 64, 2
    with ros_graph(ros_domain) as g:
        listener = g.add(ViewListener)
        view = g.add(ViewNode, tmp_path / "view", params=dict(scale=scale))
        g.add(SimNode, params=dict(world=str(WORLDS / "table1.yaml"), image_size=size))
        g.add(PerceptionNode)
        g.add(MemoryNode)
        g.add(AttentionNode, params=dict(max_cycles=cycles))
        assert spin_until(g.executor, lambda: listener.done, 120)
        assert spin_until(g.executor, lambda: len(listener.views) >= cycles, 10), \
            f"{len(listener.views)} views"
        first = listener.views[0]
        assert first.encoding == "rgb8"
        assert first.width == 2 * size * scale + MARGIN and first.height > size * scale
        assert len(first.data) == first.step * first.height == first.width * 3 * first.height
        gif = view.close()
    assert view.published == cycles == len(listener.views)
    with PILImage.open(gif) as im:
        assert im.n_frames == cycles
