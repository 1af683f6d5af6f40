"""Fuzzed messages from outside the graph: dropped with one warning naming the topic.

Property-based (Hypothesis, settings in ``fuzz_settings``):

* every msg -> core conversion of ``roger_common.conversions`` takes any message (images of
  any size, encoding and content, ROI arrays with NaN or huge counts, goals out of range,
  malformed memory requests and results, broken eye poses and camera infos) and either
  returns a valid core value or raises ``MessageError``, nothing else;
* each node's callback takes any such message without raising, and drops a bad one with a
  warning that names the topic (``BadInput``), in process, no ROS graph needed;
* one graph test runs the four nodes with an outside publisher that sends bad messages on
  every topic they listen to: the nodes keep running, warn naming each topic, and the run's
  cycles are those of the same run without it.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from conftest import WORLDS
from fuzz_settings import fuzz
from hypothesis import given
from hypothesis import strategies as st
from ros_helpers import TopicListener, ros_graph, spin_until

from roger_common import conversions as conv
from roger_common.errors import MessageError
from roger_common.types import FEATURE_DIM, Action, feature_dim

# -- strategies for messages -------------------------------------------------------------
any_float = st.floats(allow_nan=True, allow_infinity=True)
f32 = st.floats(allow_nan=True, allow_infinity=True, width=32)
u8 = st.integers(0, 255)
u32 = st.integers(0, 2**32 - 1)
u64 = st.integers(0, 2**64 - 1)


def point(draw: st.DrawFn, coord: st.SearchStrategy = any_float):
    from geometry_msgs.msg import Point
    return Point(x=draw(coord), y=draw(coord), z=draw(coord))


@st.composite
def images(draw: st.DrawFn):
    from sensor_msgs.msg import Image
    encoding = draw(st.sampled_from(["32FC1", "mono8", "rgb8", "", "16UC1", "32FC1 "]))
    if draw(st.integers(0, 3)):  # mostly a consistent size, so the checks on values run
        h, w = draw(st.integers(0, 24)), draw(st.integers(0, 24))
        bpp = 4 if encoding.startswith("32") else 1
        step = w * bpp + draw(st.sampled_from([0, 0, 0, 1, -1]))
        n = max(step, 0) * h
        if encoding.startswith("32"):
            values = draw(st.lists(st.floats(0, 1, width=32) | f32, min_size=n // 4,
                                   max_size=n // 4))
            data = struct.pack(f"<{len(values)}f", *values) + b"\0" * (n % 4)
        else:
            data = draw(st.binary(min_size=n, max_size=n))
    else:  # anything at all
        h, w = draw(u32 | st.integers(0, 2000)), draw(u32 | st.integers(0, 2000))
        step, data = draw(u32), draw(st.binary(max_size=64))
    return Image(height=h, width=w, encoding=encoding, step=max(step, 0), data=data,
                 is_bigendian=draw(st.sampled_from([0, 0, 1])))


@st.composite
def camera_infos(draw: st.DrawFn):
    from sensor_msgs.msg import CameraInfo
    return CameraInfo(width=draw(st.integers(0, 2000) | u32),
                      height=draw(st.integers(0, 2000) | u32),
                      k=[draw(any_float | st.floats(1.0, 500.0)), *[0.0] * 8])


@st.composite
def geometries(draw: st.DrawFn):
    from geometry_msgs.msg import Pose, Quaternion

    from roger_interfaces.msg import StereoGeometry

    def pose():
        unit = draw(st.booleans())
        q = (Quaternion(x=0.0, y=0.0, z=0.0, w=1.0) if unit else
             Quaternion(x=draw(any_float), y=draw(any_float), z=draw(any_float),
                        w=draw(any_float)))
        return Pose(position=point(draw, any_float | st.floats(-2, 2)), orientation=q)
    return StereoGeometry(goal_id=draw(u64), left_eye=pose(), right_eye=pose(),
                          exposures=draw(u32), map_revision=draw(u32),
                          haptic=draw(st.booleans()))


@st.composite
def goals(draw: st.DrawFn):
    from roger_interfaces.msg import ActionGoal
    coord = any_float | st.floats(-2000, 2000) | st.floats(-1, 1)
    return ActionGoal(goal_id=draw(u64), action=draw(st.sampled_from([0, 1, 2, 3]) | u8),
                      target=point(draw, coord), arm=draw(st.integers(-128, 127)),
                      map_revision=draw(u32))


@st.composite
def rois(draw: st.DrawFn, n: int):
    from roger_interfaces.msg import Roi
    good = draw(st.booleans())
    length = n if good else draw(st.sampled_from([0, n - 1, n + 1, 3 * n]))
    features = draw(st.lists(st.floats(0, 1, width=32) if good else f32, min_size=length,
                             max_size=length))
    return Roi(id=draw(st.integers(0, 5)), x0=draw(st.integers(0, 2**16 - 1)),
               position=point(draw, any_float | st.floats(-2, 2)), features=features,
               known=draw(st.lists(st.booleans(), min_size=length, max_size=length)),
               activation=draw(any_float), retinal_size=draw(any_float),
               motion=draw(any_float), size_m=draw(any_float))


@st.composite
def roi_arrays(draw: st.DrawFn):
    from roger_interfaces.msg import RoiArray
    mode = draw(st.sampled_from(["", "paper", "extended", "nonsense"]))
    n = feature_dim(mode) if mode in ("paper", "extended") else FEATURE_DIM
    count = draw(st.integers(0, 4))
    array = RoiArray(goal_id=draw(u64), feature_mode=mode,
                     rois=[draw(rois(n)) for _ in range(count)])
    if draw(st.integers(0, 9)) == 0:  # a huge count: the same ROI, many times over
        array.rois = array.rois[:1] * draw(st.sampled_from([1025, 5000])) if array.rois \
            else []
    return array


@st.composite
def memory_requests(draw: st.DrawFn):
    from roger_interfaces.msg import MemoryRequest
    mode = draw(st.sampled_from(["paper", "extended", "", "nonsense"]))
    n = feature_dim(mode) if mode in ("paper", "extended") else FEATURE_DIM
    length = draw(st.sampled_from([n, n, 0, n - 1, n + 1, 1000]))
    return MemoryRequest(
        request_id=draw(u64), op=draw(st.sampled_from([0, 1]) | u8), feature_mode=mode,
        features=draw(st.lists(st.floats(0, 1, width=32) | f32, min_size=length,
                               max_size=length)),
        known=draw(st.lists(st.booleans(), min_size=length, max_size=length)),
        final_trial=draw(st.booleans()), focus_id=draw(st.integers(-(2**63), 2**63 - 1)))


@st.composite
def memory_results(draw: st.DrawFn):
    from roger_interfaces.msg import MemoryResult
    return MemoryResult(request_id=draw(u64), op=draw(u8), outcome=draw(u8),
                        address=draw(st.integers(-(2**31), 2**31 - 1)),
                        confidence=draw(f32), memory_size=draw(u32))


@st.composite
def haptic_readings(draw: st.DrawFn):
    from geometry_msgs.msg import Vector3

    from roger_interfaces.msg import HapticReading
    k = draw(st.integers(0, 3))
    return HapticReading(
        goal_id=draw(u64), arm=draw(st.integers(-128, 127)), contact=draw(st.booleans()),
        position=point(draw), weight=draw(f32),
        contact_points=[point(draw) for _ in range(k)],
        contact_normals=[Vector3(x=draw(any_float), y=0.0, z=1.0)
                         for _ in range(draw(st.sampled_from([k, k, k + 1])))],
        probe_offsets=draw(st.lists(any_float, min_size=2 * k, max_size=2 * k + 1)))


# -- the conversions: a valid core value or MessageError, nothing else ---------------------
def converts_or_refuses(convert, msg):
    """``convert(msg)``, or None when it raised MessageError with a one-line message."""
    try:
        return convert(msg)
    except MessageError as exc:
        assert len(str(exc).splitlines()) == 1 and len(str(exc)) < 500, str(exc)[:300]
        return None


@fuzz(examples=150)
@given(images())
def test_any_image_converts_or_is_refused(msg) -> None:
    img = converts_or_refuses(conv.image_to_array, msg)
    if img is not None:
        assert img.dtype == np.float32 and img.shape == (msg.height, msg.width)
        assert np.all(np.isfinite(img)) and img.min() >= 0.0 and img.max() <= 1.0


@fuzz(examples=100)
@given(camera_infos(), geometries())
def test_any_camera_info_or_eye_geometry_converts_or_is_refused(info, geometry) -> None:
    camera = converts_or_refuses(conv.camera_from_info, info)
    if camera is not None:
        assert camera.width >= 1 and camera.height >= 1 and math.isfinite(camera.focal_px)
    poses = converts_or_refuses(conv.poses_from_geometry, geometry)
    for pose in poses or ():
        assert np.all(np.isfinite(pose.position)) and np.all(np.isfinite(pose.rotation))
        assert np.allclose(pose.rotation @ pose.rotation.T, np.eye(3), atol=1e-2)


@fuzz(examples=150)
@given(goals())
def test_any_goal_converts_or_is_refused(msg) -> None:
    goal = converts_or_refuses(conv.msg_to_goal, msg)
    if goal is not None:
        assert goal.action != Action.MAP_UPDATE and goal.arm in (-1, 0, 1)
        assert all(math.isfinite(v) and abs(v) <= conv.TARGET_LIMIT_M for v in goal.target)


@fuzz(examples=150)
@given(roi_arrays())
def test_any_roi_array_converts_or_is_refused(msg) -> None:
    out = converts_or_refuses(conv.msg_to_rois, msg)
    for roi in out or ():
        assert len(out) <= conv.MAX_ROIS
        assert np.all(np.isfinite(roi.features)) and np.all(np.isfinite(roi.position))
        assert all(math.isfinite(v) for v in (roi.activation, roi.retinal_size, roi.motion))


@fuzz(examples=150)
@given(memory_requests(), memory_results())
def test_any_memory_request_or_result_converts_or_is_refused(request, result) -> None:
    req = converts_or_refuses(conv.msg_to_request, request)
    if req is not None:
        assert req.features.shape == req.known.shape
        assert np.all(np.isfinite(req.features))
        assert req.features.min(initial=0.0) >= 0.0 and req.features.max(initial=0.0) <= 1.0
    res = converts_or_refuses(conv.msg_to_result, result)
    if res is not None:
        assert math.isfinite(res.confidence)


@fuzz(examples=100)
@given(haptic_readings())
def test_any_haptic_reading_converts_or_is_refused(msg) -> None:
    reading = converts_or_refuses(conv.msg_to_haptic, msg)
    if reading is not None and reading.contact:
        assert math.isfinite(reading.weight) and reading.weight >= 0.0


# -- the nodes' callbacks, in process ------------------------------------------------------
class Sink:
    """Stands in for a publisher and keeps what was published."""

    def __init__(self) -> None:
        self.msgs: list = []

    def publish(self, msg) -> None:
        self.msgs.append(msg)


def test_memory_and_attention_callbacks_take_any_message(no_leaks, ros_context) -> None:
    from roger_attention.attention_node import AttentionNode
    from roger_memory.memory_node import MemoryNode
    memory = MemoryNode(context=ros_context)
    attention = AttentionNode(context=ros_context)
    try:
        memory.pub_result, memory.pub_learned = Sink(), Sink()

        @fuzz(examples=120)
        @given(memory_requests(), roi_arrays(), memory_results(), geometries(),
               camera_infos())
        def feed(request, array, result, geometry, info) -> None:
            valid = converts_or_refuses(conv.msg_to_request, request) is not None
            size, dropped = memory.memory.size, sum(memory.bad_input.dropped.values())
            memory.on_request(request)
            if not valid:  # dropped, counted, nothing stored
                assert memory.memory.size == size
                assert sum(memory.bad_input.dropped.values()) == dropped + 1
            attention.on_rois(array)
            attention.on_result(result)
            attention.on_geometry(geometry)
            attention.on_info(info)

        feed()
        for node, topics in ((memory, ["/roger/memory/request"]),
                             (attention, ["/roger/rois", "/roger/memory/result",
                                          "/roger/stereo_geometry", "/roger/left/camera_info"])):
            for topic in topics:
                assert node.bad_input.dropped.get(topic), (topic, node.bad_input.dropped)
                assert any(line.startswith(f"{topic}: ") for line in node.bad_input.lines)
            # Rate-limited: far fewer warnings than messages dropped.
            assert len(node.bad_input.lines) <= len(topics) < sum(node.bad_input.dropped.values())
    finally:
        attention.destroy_node()
        memory.destroy_node()


# -- the graph, with an outside publisher of bad messages ------------------------------------
def bad_messages() -> dict[str, list]:
    """A few bad messages for every topic the four nodes listen to."""
    from geometry_msgs.msg import Point
    from sensor_msgs.msg import CameraInfo, Image

    from roger_interfaces.msg import (
        ActionGoal,
        HapticReading,
        MemoryRequest,
        MemoryResult,
        Roi,
        RoiArray,
        StereoGeometry,
        WorldEdit,
        WorldObject,
    )
    nan = float("nan")
    nan_geometry = StereoGeometry(goal_id=1)
    nan_geometry.left_eye.position.x = nan
    huge = [Roi(id=i, features=[0.5] * FEATURE_DIM, known=[True] * FEATURE_DIM)
            for i in range(2000)]
    return {
        "/roger/left/image_raw": [Image(height=8, width=8, encoding="rgb8", step=24,
                                        data=bytes(192)),
                                  Image(height=4, width=4, encoding="32FC1", step=16,
                                        data=struct.pack("<16f", *[nan] * 16))],
        "/roger/right/image_raw": [Image(height=3000, width=3000, encoding="mono8")],
        "/roger/left/camera_info": [CameraInfo(width=0, height=0)],
        "/roger/stereo_geometry": [nan_geometry],
        "/roger/haptic": [HapticReading(goal_id=1, contact=True, weight=nan)],
        "/roger/rois": [RoiArray(goal_id=1, rois=huge),
                        RoiArray(goal_id=1, rois=[Roi(id=1, features=[nan] * FEATURE_DIM,
                                                      known=[True] * FEATURE_DIM)])],
        "/roger/goal": [ActionGoal(goal_id=10**6, action=0, target=Point(x=1e9)),
                        ActionGoal(goal_id=10**6 + 1, action=9)],
        "/roger/memory/request": [MemoryRequest(request_id=10**6, op=1, features=[2.0] * 3,
                                                known=[True] * 3)],
        "/roger/memory/result": [MemoryResult(request_id=10**6, outcome=7)],
        "/roger/world_edit": [WorldEdit(op=0, object=WorldObject(name="a\nb", shape="cube"))],
    }


class Listener(TopicListener):
    def __init__(self, **kwargs) -> None:
        super().__init__("fuzz_listener", **kwargs)
        self.states: list = []
        self.done = False

    def on_message(self, topic, msg) -> None:
        if topic == "/roger/policy_state":
            self.states.append((msg.cycle, msg.action, msg.outcome, msg.entry_id,
                                msg.address, msg.state_before, msg.state_after,
                                round(msg.reward, 9)))
        elif topic == "/roger/metrics" and msg.done:
            self.done = True


def run_cycles(domain: int, tmp, cycles: int, bad: bool):
    """The four nodes in one executor for ``cycles`` cycles, with an outside publisher of
    bad messages or without; returns the cycles seen and the nodes' BadInput logs."""
    from rclpy.node import Node

    from roger_attention.attention_node import AttentionNode
    from roger_common.ros_node import RELIABLE
    from roger_memory.memory_node import MemoryNode
    from roger_perception.perception_node import PerceptionNode
    from roger_sim.sim_node import SimNode
    tmp.mkdir(parents=True, exist_ok=True)
    with ros_graph(domain) as g:
        listener = g.add(Listener)
        nodes = [g.add(SimNode, params={"world": str(WORLDS / "table1.yaml"), "seed": 1,
                                        "image_size": 64}),
                 g.add(PerceptionNode),
                 g.add(MemoryNode, params={"memory_file": str(tmp / "ltm.pt")}),
                 g.add(AttentionNode, params={"policy": "straightforward",
                                              "max_cycles": cycles})]
        if bad:
            outsider = g.add(Node, "outsider")
            pubs = {topic: (outsider.create_publisher(type(msgs[0]), topic, RELIABLE), msgs)
                    for topic, msgs in bad_messages().items()}

            def send() -> None:
                for pub, msgs in pubs.values():
                    for msg in msgs:
                        pub.publish(msg)
            # A few bad messages a second, not a flood: a publisher that outpaces a topic's
            # history depth evicts good messages in DDS itself (docs/reliability.md).
            outsider.create_timer(0.25, send)
        assert spin_until(g.executor, lambda: listener.done, 120), \
            f"the run did not finish; cycles seen: {len(listener.states)}"
        spin_until(g.executor, lambda: len(listener.states) >= cycles, 5)
        logs = {node.get_name(): node.bad_input for node in nodes}
        return listener.states, logs


@pytest.mark.parametrize("cycles", [8])
def test_bad_publisher_on_every_topic_changes_nothing(no_leaks, ros_domain, tmp_path, cycles):
    clean, _ = run_cycles(ros_domain, tmp_path / "clean", cycles, bad=False)
    attacked, logs = run_cycles(ros_domain, tmp_path / "bad", cycles, bad=True)
    assert [s[0] for s in clean] == list(range(1, cycles + 1))
    assert attacked == clean  # the run's results do not change
    listened = {"roger_sim": ["/roger/goal", "/roger/world_edit"],
                "roger_perception": ["/roger/left/image_raw", "/roger/right/image_raw",
                                     "/roger/left/camera_info", "/roger/stereo_geometry",
                                     "/roger/haptic"],
                "roger_memory": ["/roger/memory/request"],
                "roger_attention": ["/roger/rois", "/roger/memory/result",
                                    "/roger/stereo_geometry", "/roger/left/camera_info"]}
    for name, topics in listened.items():
        for topic in topics:
            assert logs[name].dropped.get(topic), f"{name} dropped nothing on {topic}"
            assert any(line.startswith(f"{topic}: ") for line in logs[name].lines), \
                f"{name} gave no warning naming {topic}: {list(logs[name].lines)}"
