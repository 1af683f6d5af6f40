"""The documented topics of the Roger graph: one table for the README, the tests and tools.

Each row: topic, message type, QoS profile name, publisher node, subscriber nodes, what
it carries. ``per_cycle`` marks topics that carry messages in every run of a few cycles.
The QoS name is that of the profile the topic's publisher is created with
(``roger_common.ros_node``: RELIABLE, IMAGES, LABELS, REPORTS, LATCHED); bags record it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

#: QoS names of the table -> names of the profiles in roger_common.ros_node.
QOS_PROFILES: dict[str, str] = {"reliable": "RELIABLE", "images": "IMAGES", "labels": "LABELS",
                                "reports": "REPORTS", "latched": "LATCHED"}


@dataclass(frozen=True)
class Topic:
    """One row of the node-graph table."""

    name: str
    type: str
    qos: str
    publisher: str
    subscribers: str
    meaning: str
    per_cycle: bool = True

    def msg_class(self) -> Any:
        """The message class (imports the message package)."""
        pkg, _, cls = self.type.partition("/msg/") if "/msg/" in self.type else \
            self.type.partition("/")
        return getattr(importlib.import_module(f"{pkg}.msg"), cls)

    def qos_profile(self) -> Any:
        """The rclpy QoSProfile the topic's publisher uses (imports rclpy)."""
        return getattr(importlib.import_module("roger_common.ros_node"), QOS_PROFILES[self.qos])


TOPICS: tuple[Topic, ...] = (
    Topic("/clock", "rosgraph_msgs/Clock", "reliable", "sim", "all (use_sim_time)",
          "simulated time, advanced by each executed goal"),
    Topic("/roger/left/image_raw", "sensor_msgs/Image", "images", "sim", "perception",
          "left retina, 32FC1 intensity in [0, 1], Phong-lit"),
    Topic("/roger/right/image_raw", "sensor_msgs/Image", "images", "sim", "perception",
          "right retina"),
    Topic("/roger/left/camera_info", "sensor_msgs/CameraInfo", "images", "sim",
          "perception, attention", "left intrinsics"),
    Topic("/roger/right/camera_info", "sensor_msgs/CameraInfo", "images", "sim", "-",
          "right intrinsics, P carries -f*baseline"),
    Topic("/roger/fovea/image_raw", "sensor_msgs/Image", "images", "sim", "perception",
          "after a visual improvement: the left eye's fovea (30 degrees at 192 px)",
          per_cycle=False),
    Topic("/roger/fovea/camera_info", "sensor_msgs/CameraInfo", "images", "sim",
          "perception", "the fovea's intrinsics", per_cycle=False),
    Topic("/roger/stereo_geometry", "roger_interfaces/StereoGeometry", "images", "sim",
          "perception, attention", "eye poses of each stereo pair (verging eyes)"),
    Topic("/roger/joint_states", "sensor_msgs/JointState", "reliable", "sim", "-",
          "neck, eye and arm joints after each goal"),
    Topic("/tf", "tf2_msgs/TFMessage", "reliable", "sim", "-",
          "TF of the neck, eye and arm joints after each goal (as robot_state_publisher)"),
    Topic("/tf_static", "tf2_msgs/TFMessage", "latched", "sim", "-",
          "fixed frames: world -> roger_base, wrists, fingertips, eyes' optical frames"),
    Topic("/robot_description", "std_msgs/String", "latched", "sim", "-",
          "Roger's URDF, generated from the simulator's pybullet body (roger_sim.urdf)"),
    Topic("/roger/controller_status", "roger_interfaces/ControllerStatus", "reliable", "sim",
          "-", "status of the five servo controllers"),
    Topic("/roger/convergence", "roger_interfaces/ConvergenceEvent", "reports", "sim",
          "monitor (evaluation only)",
          "a goal finished: converged or failed, sim time and physics steps"),
    Topic("/roger/haptic", "roger_interfaces/HapticReading", "reliable", "sim", "perception",
          "what an arm felt (weight) in a haptic improvement", per_cycle=False),
    Topic("/roger/ground_truth", "roger_interfaces/GroundTruth", "latched", "sim",
          "monitor (evaluation only)", "the world's objects and poses"),
    Topic("/roger/ground_truth/labels", "roger_interfaces/GroundTruthLabels", "labels", "sim",
          "monitor (evaluation only)", "which object each retina pixel shows"),
    Topic("/roger/rois", "roger_interfaces/RoiArray", "reliable", "perception", "attention",
          "ROIs of each stereo pair: features (eqs. 1-5), position, activation"),
    Topic("/roger/goal", "roger_interfaces/ActionGoal", "reliable", "attention", "sim",
          "physical action of a control cycle"),
    Topic("/roger/memory/request", "roger_interfaces/MemoryRequest", "reliable", "attention",
          "memory", "match or store a feature vector"),
    Topic("/roger/memory/result", "roger_interfaces/MemoryResult", "reliable", "memory",
          "attention", "identified / new / undetermined, address, confidence"),
    Topic("/roger/memory/learned", "roger_interfaces/MemoryResult", "latched", "memory", "-",
          "the last object stored in long-term memory", per_cycle=False),
    Topic("/roger/policy_state", "roger_interfaces/PolicyState", "reports", "attention",
          "monitor", "each cycle: state bits, action, reward, TD error, focus"),
    Topic("/roger/metrics", "roger_interfaces/Metrics", "reports", "attention", "monitor",
          "Table 2 counters as the run goes"),
    Topic("/roger/spatial_map", "roger_interfaces/SpatialMap", "latched", "attention",
          "perception", "the pre-attentional map: positions, mapping status, interest"),
    Topic("/roger/spatial_map/markers", "visualization_msgs/MarkerArray", "latched",
          "attention", "-", "the map drawn in the world frame: entries by mapping status, "
          "interest bars, the focus, the last identified or stored address"),
    Topic("/roger/view", "sensor_msgs/Image", "images", "view (roger run --view)", "-",
          "retinas side by side, ROIs, attention window, state, counters", per_cycle=False),
    Topic("/roger/world_edit", "roger_interfaces/WorldEdit", "reliable", "user", "sim",
          "add / remove / move an object while running (also service /roger/edit_world)",
          per_cycle=False),
    Topic("/diagnostics", "diagnostic_msgs/DiagnosticArray", "reliable", "every node",
          "orchestrator", "heartbeat of a node started by its main (roger_common.liveness): "
          "pid, host, longest gap; a node silent for 8 s is restarted", per_cycle=False),
)
