"""Bad input: one clear line, no traceback, and the node that got it keeps running.

World files (every malformed case), messages a node cannot use (encoding, size, NaN,
out-of-range features, repeated ROI ids, goals for vanished objects, unknown results) and
parameter values out of range, refused at set time.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import WORLDS
from rclpy.parameter import Parameter

from roger_common.errors import MessageError, WorldFileError
from roger_common.types import FEATURE_DIM, feature_dim
from roger_sim.world import load_world

OK = ("  - name: a\n    shape: box\n    position: [0.8, 0.0]\n    size: 0.2\n"
      "    intensity: 90\n    weight: 1.0\n")

#: (file content, text the one line must hold besides the file name)
BAD_WORLDS = {
    "syntax": ("objects: [\n", "line 2"),
    "missing field": ("objects:\n" + OK.replace("    size: 0.2\n", ""), "(a).size: missing"),
    "unknown field": ("objects:\n" + OK + "    colour: red\n", "(a).colour: unknown field"),
    "unknown top-level": ("objects:\n" + OK + "gravity: 9.8\n", "gravity: unknown field"),
    "wrong type": ("objects:\n" + OK.replace("size: 0.2", "size: big"), "(a).size: must be"),
    "bool as number": ("objects:\n" + OK.replace("weight: 1.0", "weight: true"),
                       "(a).weight: must be a number"),
    "NaN": ("objects:\n" + OK.replace("intensity: 90", "intensity: .nan"),
            "(a).intensity: must be finite"),
    "out of range": ("objects:\n" + OK.replace("intensity: 90", "intensity: 300"),
                     "(a).intensity: must be in [0, 255]"),
    "unknown shape": ("objects:\n" + OK.replace("box", "cube"), "(a).shape: unknown shape"),
    "duplicate name": ("objects:\n" + OK + OK.replace("[0.8, 0.0]", "[0.8, 0.5]"),
                       "duplicate name 'a'"),
    "overlap": ("objects:\n" + OK + OK.replace("name: a", "name: b")
                .replace("[0.8, 0.0]", "[0.85, 0.05]"), "(b).position: overlaps 'a'"),
    "out of view": ("objects:\n" + OK.replace("[0.8, 0.0]", "[0.1, 0.0]"), "out of view"),
    "empty world": ("objects: []\n", "the world is empty"),
    "no objects": ("name: nothing\n", "objects: missing required field"),
    "not a mapping": ("- just\n- a list\n", "must be a YAML mapping"),
}


@pytest.mark.parametrize("case", sorted(BAD_WORLDS))
def test_every_bad_world_file_gives_one_line(tmp_path, case):
    content, expected = BAD_WORLDS[case]
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    line = str(info.value)
    assert "\n" not in line and str(path) in line and expected in line, line


def test_missing_world_file_gives_one_line(tmp_path):
    with pytest.raises(WorldFileError, match="cannot read the file"):
        load_world(tmp_path / "nowhere.yaml")


@pytest.mark.parametrize("case", ["overlap", "out of view"])
def test_sim_node_refuses_a_bad_world_with_one_line(no_leaks, tmp_path, ros_domain, case):
    path = tmp_path / "bad.yaml"
    path.write_text(BAD_WORLDS[case][0])
    proc = subprocess.run(
        [sys.executable, "-m", "roger_sim.sim_node", "--ros-args", "-p", f"world:={path}"],
        capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "ROS_DOMAIN_ID": str(ros_domain)})
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert len(lines) == 1 and lines[0].startswith("roger-sim: ") and "bad.yaml" in lines[0]
    assert "Traceback" not in proc.stderr


# -- messages a node cannot use ----------------------------------------------------------
@pytest.fixture
def ctx(ros_context):
    return ros_context


class Sink:
    """Stands in for a publisher and keeps what was published."""

    def __init__(self) -> None:
        self.msgs: list = []

    def publish(self, msg) -> None:
        self.msgs.append(msg)


def image(encoding="32FC1", h=8, w=8, value=0.5):
    from sensor_msgs.msg import Image
    data = np.full((h, w), value, np.float32)
    return Image(height=h, width=w, encoding=encoding, step=4 * w, data=data.tobytes())


def test_perception_drops_unusable_stereo_pairs_and_keeps_running(no_leaks, ctx):
    from sensor_msgs.msg import CameraInfo

    from roger_interfaces.msg import HapticReading, StereoGeometry
    from roger_perception.perception_node import PerceptionNode
    node = PerceptionNode(context=ctx)
    try:
        node.pub_rois = Sink()
        info = CameraInfo(width=8, height=8, k=[10.0, 0, 4, 0, 10.0, 4, 0, 0, 1])
        geometry = StereoGeometry()
        geometry.left_eye.orientation.w = geometry.right_eye.orientation.w = 1.0
        bad_pairs = [
            (image("rgb8"), image(), info, geometry),                      # encoding
            (image(h=6), image(), info, geometry),                         # size
            (image(value=float("nan")), image(), info, geometry),          # NaN pixels
            (image(), image(), CameraInfo(width=0, height=8), geometry),   # camera
        ]
        nan_pose = StereoGeometry()
        nan_pose.left_eye.position.x = float("nan")
        bad_pairs.append((image(), image(), info, nan_pose))               # eye pose
        for left, right, cam, geo in bad_pairs:
            node._process({"left": left, "right": right, "info": cam, "geometry": geo})
        # A contact with a NaN weight is unusable: kept as None, so goal 3's pair stops
        # waiting for it; a reading without contact carries NaN weight and is kept as is.
        node.on_haptic(HapticReading(goal_id=3, contact=True, weight=float("nan")))
        node.on_haptic(HapticReading(goal_id=4, contact=False, weight=float("nan")))
        assert node.pub_rois.msgs == [] and node._haptic[3] is None
        assert node._haptic[4] is not None and not node._haptic[4].contact
        # Still working: a usable pair is perceived.
        node._process({"left": image(), "right": image(), "info": info, "geometry": geometry})
        assert len(node.pub_rois.msgs) == 1
    finally:
        node.destroy_node()


def test_repeated_or_nan_rois_are_refused():
    from roger_common.conversions import msg_to_rois
    from roger_interfaces.msg import Roi, RoiArray
    good = Roi(id=1, features=[0.5] * FEATURE_DIM, known=[True] * FEATURE_DIM)
    with pytest.raises(MessageError, match="repeat"):
        msg_to_rois(RoiArray(rois=[good, good]))
    nan = Roi(id=2, features=[float("nan")] * FEATURE_DIM, known=[True] * FEATURE_DIM)
    with pytest.raises(MessageError, match="NaN"):
        msg_to_rois(RoiArray(rois=[nan]))
    assert len(msg_to_rois(RoiArray(rois=[good]))) == 1


def test_memory_refuses_bad_requests_and_answers_a_resent_store_once(no_leaks, ctx):
    from roger_interfaces.msg import MemoryRequest
    from roger_memory.memory_node import MemoryNode
    node = MemoryNode(context=ctx)
    try:
        node.pub_result, node.pub_learned = Sink(), Sink()
        mode = node.memory.config.features
        n = feature_dim(mode)
        feats = [0.05 * i for i in range(n)]
        known = [True] * n
        for bad in (MemoryRequest(request_id=1, op=7, feature_mode=mode, features=feats,
                                  known=known),
                    MemoryRequest(request_id=2, op=0, feature_mode=mode, features=feats[:3],
                                  known=known[:3]),
                    MemoryRequest(request_id=3, op=0, feature_mode=mode,
                                  features=[float("nan")] * n, known=known),
                    MemoryRequest(request_id=4, op=1, feature_mode=mode,
                                  features=[2.0] * n, known=known),
                    # A look of the other mode (paper: the eleven), said so.
                    MemoryRequest(request_id=6, op=1, feature_mode="paper",
                                  features=feats[:FEATURE_DIM], known=known[:FEATURE_DIM]),
                    MemoryRequest(request_id=7, op=1, feature_mode="nonsense",
                                  features=feats, known=known)):
            node.on_request(bad)
        assert node.pub_result.msgs == [] and node.memory.size == 0
        store = MemoryRequest(request_id=5, op=1, feature_mode=mode, features=feats,
                              known=known)
        node.on_request(store)
        node.on_request(store)                     # re-sent: same answer, stored once
        again = MemoryRequest(request_id=9, op=1, feature_mode=mode, features=feats,
                              known=known)
        node.on_request(again)                     # re-sent by a restarted attention node
        assert node.memory.size == 1
        assert [m.address for m in node.pub_result.msgs] == [0, 0, 0]
        assert len(node.pub_learned.msgs) == 1
    finally:
        node.destroy_node()


def test_attention_ignores_unusable_messages_and_refuses_bad_parameters(no_leaks, ctx):
    from sensor_msgs.msg import CameraInfo

    from roger_attention.attention_node import AttentionNode
    from roger_interfaces.msg import MemoryResult, StereoGeometry
    node = AttentionNode(context=ctx)
    try:
        node.on_info(CameraInfo(width=0, height=0))
        assert node._camera is None
        geo = StereoGeometry()
        geo.left_eye.position.x = math.inf
        node.on_geometry(geo)
        assert node._geometry == {}
        node.on_result(MemoryResult(request_id=42, outcome=9))   # nobody asked: ignored
        for name, value in (("retry_after_s", -1.0), ("max_cycles", -5),
                            ("home_targets", [0.5, 0.1]), ("qlearning.alpha", 1.5),
                            ("visual_trials", -1)):
            result = node.set_parameters([Parameter(name, value=value)])[0]
            assert not result.successful and name.split(".")[-1] in result.reason, result
        assert node.set_parameters([Parameter("retry_after_s", value=2.0)])[0].successful
    finally:
        node.destroy_node()


def test_sim_refuses_bad_goals_and_serves_goals_for_vanished_objects(no_leaks, ctx):
    from roger_interfaces.msg import ActionGoal
    from roger_sim.sim_node import SimNode
    node = SimNode(context=ctx, parameter_overrides=[
        Parameter("world", value=str(WORLDS / "table1.yaml")),
        Parameter("image_size", value=64)])
    try:
        node.pub_left = Sink()
        nan_goal = ActionGoal(goal_id=1, action=0)
        nan_goal.target.x = float("nan")
        for goal in (nan_goal, ActionGoal(goal_id=2, action=9), ActionGoal(goal_id=3, action=3)):
            node.on_goal(goal)
        assert node.pub_left.msgs == []
        gone = node.world.objects[0]
        node.sim.remove_object(gone.name)
        goal = ActionGoal(goal_id=4, action=2)      # touch where the object was
        goal.target.x, goal.target.y = gone.position
        node.on_goal(goal)
        assert len(node.pub_left.msgs) == 1
        result = node.set_parameters([Parameter("image_size", value=-3)])[0]
        assert not result.successful and "image_size" in result.reason
    finally:
        node.destroy_node()
