"""Roger's TF tree and robot description on the graph (issue 36, items 1 and 2).

The simulator node publishes the URDF latched on /robot_description, the fixed frames on
/tf_static and the joints on /tf after each goal. Composed, the transforms put each eye's
optical frame (the frame its images and camera infos name) exactly at the eye pose that
goes out in StereoGeometry. tf2_msgs is built into the venv from ROS 2 Jazzy's definitions
(no wheel has it): its type hash must be Jazzy's, as recorded by rosbags' Jazzy type store
and as the middleware advertises it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import WORLDS
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import ros_graph, spin_until
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from roger_bringup.msgdefs import type_hash
from roger_common import frames
from roger_common.conversions import goal_to_msg, msg_to_eye_pose
from roger_common.geometry import rotation_from_quaternion
from roger_common.types import Action, Goal
from roger_interfaces.msg import ActionGoal, StereoGeometry
from roger_sim.sim_node import SimNode
from roger_sim.urdf import URDF_PATH

#: REP-2011 type hashes of ROS 2 Jazzy's tf2_msgs (share/tf2_msgs/msg/*.json of a Jazzy
#: install; rosbags' Jazzy store computes the same).
JAZZY_HASHES = {
    "tf2_msgs/msg/TFMessage":
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "tf2_msgs/msg/TF2Error":
        "RIHS01_db2485e7d6a0ec75bf087e058ee45df682acc3a621ca7780503d10aac141809a",
}


@pytest.mark.parametrize("name", sorted(JAZZY_HASHES))
def test_tf2_msgs_type_hash_is_jazzys(name: str) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    assert store.hash_rihs01(name) == JAZZY_HASHES[name]
    assert type_hash(name) == JAZZY_HASHES[name]


class Watcher(Node):
    """Keeps the latest message of each topic the test looks at (all /tf ones)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("tf_watcher", **kwargs)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.latest: dict[str, object] = {}
        self.tf: list[TFMessage] = []
        for topic, cls, qos in (("/robot_description", String, latched),
                                ("/tf_static", TFMessage, latched),
                                ("/roger/stereo_geometry", StereoGeometry, 10),
                                ("/roger/left/image_raw", Image, 10),
                                ("/roger/right/image_raw", Image, 10),
                                ("/roger/left/camera_info", CameraInfo, 10),
                                ("/roger/right/camera_info", CameraInfo, 10)):
            self.create_subscription(cls, topic, self._keep(topic), qos)
        self.create_subscription(TFMessage, "/tf", self.tf.append, 100)
        self.pub_goal = self.create_publisher(ActionGoal, "/roger/goal", 10)

    def _keep(self, topic):
        return lambda msg: self.latest.__setitem__(topic, msg)


def chain_pose(tree: dict, frame: str, root: str) -> tuple[np.ndarray, np.ndarray]:
    """Pose of ``frame`` in ``root`` composed from child -> (parent, rotation, translation)."""
    rot, pos = np.eye(3), np.zeros(3)
    while frame != root:
        parent, r, p = tree[frame]
        rot, pos = r @ rot, r @ pos + p
        frame = parent
    return rot, pos


def as_tree(*messages: TFMessage) -> dict:
    tree = {}
    for msg in messages:
        for t in msg.transforms:
            q, v = t.transform.rotation, t.transform.translation
            tree[t.child_frame_id] = (t.header.frame_id,
                                      rotation_from_quaternion((q.x, q.y, q.z, q.w)),
                                      np.array([v.x, v.y, v.z]))
    return tree


def test_sim_node_publishes_description_and_a_tree_that_holds_the_eyes(no_leaks, ros_domain):
    with ros_graph(ros_domain) as g:
        sim = g.add(SimNode, params={"world": str(WORLDS / "table1.yaml"), "seed": 1})
        w = g.add(Watcher)
        ex = g.executor
        # Latched: a late subscriber still gets the description and the fixed frames.
        assert spin_until(ex, lambda: {"/robot_description", "/tf_static"} <= set(w.latest)
                          and w.pub_goal.get_subscription_count() > 0, 10), w.latest.keys()
        assert w.latest["/robot_description"].data == URDF_PATH.read_text()
        goal = Goal(goal_id=1, action=Action.ATTENTION_SHIFT, target=(0.6, 0.25, 0.05))
        w.pub_goal.publish(goal_to_msg(goal, 0.0))
        assert spin_until(ex, lambda: "/roger/right/image_raw" in w.latest and any(
            m.transforms and m.transforms[0].header.stamp
            == w.latest["/roger/stereo_geometry"].header.stamp for m in w.tf)
            if "/roger/stereo_geometry" in w.latest else False, 30)
        geometry = w.latest["/roger/stereo_geometry"]
        tf = next(m for m in w.tf if m.transforms[0].header.stamp == geometry.header.stamp)
        # Every movable joint, once, stamped like the frame it belongs to.
        assert sorted(t.child_frame_id for t in tf.transforms) == sorted(
            j.child for j in sim.description.joints if j.movable)
        static = w.latest["/tf_static"]
        assert (static.transforms[0].header.frame_id,
                static.transforms[0].child_frame_id) == (frames.GROUND_FRAME,
                                                         frames.BASE_FRAME)
        tree = as_tree(static, tf)
        for side, pose_msg in (("left", geometry.left_eye), ("right", geometry.right_eye)):
            optical = frames.optical_frame(side)
            assert w.latest[f"/roger/{side}/image_raw"].header.frame_id == optical
            assert w.latest[f"/roger/{side}/camera_info"].header.frame_id == optical
            rot, pos = chain_pose(tree, optical, frames.GROUND_FRAME)
            eye = msg_to_eye_pose(pose_msg)
            assert np.linalg.norm(pos - eye.position) < 1e-5
            angle = math.acos(min(1.0, (np.trace(rot.T @ eye.rotation) - 1) / 2))
            assert angle < 1e-5
        # The tree follows the joints: the left optical axis (z) points at the target.
        rot, pos = chain_pose(tree, frames.optical_frame("left"), frames.GROUND_FRAME)
        to_target = np.subtract(goal.target, pos)
        assert rot[:, 2] @ to_target / np.linalg.norm(to_target) > math.cos(0.05)
        # What the middleware advertises for /tf is Jazzy's type.
        infos = w.get_publishers_info_by_topic("/tf")
        assert infos and all(str(i.topic_type_hash) == JAZZY_HASHES["tf2_msgs/msg/TFMessage"]
                             for i in infos)
