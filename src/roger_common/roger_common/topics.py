"""The topics of the Roger graph: their names, and one table of them for the README, the
tests and the tools.

Every node takes a topic's name from here (``topics.ROIS``, not ``"/roger/rois"``), so a
name lives in one place; ``test_topics.py`` fails on a topic name written as a string
anywhere else in src/.

Each row: topic, message type, QoS profile name, publisher node, subscriber nodes, what
it carries. ``per_cycle`` marks topics that carry messages in every run of a few cycles.
The QoS name is that of the profile the topic's publisher is created with
(``roger_common.ros_node``: RELIABLE, IMAGES, LABELS, REPORTS, LATCHED); bags record it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

# -- names ------------------------------------------------------------------------------
CLOCK = "/clock"
LEFT_IMAGE = "/roger/left/image_raw"
RIGHT_IMAGE = "/roger/right/image_raw"
LEFT_INFO = "/roger/left/camera_info"
RIGHT_INFO = "/roger/right/camera_info"
FOVEA_IMAGE = "/roger/fovea/image_raw"
FOVEA_INFO = "/roger/fovea/camera_info"
FOVEA_RIGHT_IMAGE = "/roger/fovea_right/image_raw"
STEREO_GEOMETRY = "/roger/stereo_geometry"
JOINT_STATES = "/roger/joint_states"
TF = "/tf"
TF_STATIC = "/tf_static"
ROBOT_DESCRIPTION = "/robot_description"
CONTROLLER_STATUS = "/roger/controller_status"
CONVERGENCE = "/roger/convergence"
HAPTIC = "/roger/haptic"
GROUND_TRUTH = "/roger/ground_truth"
GROUND_TRUTH_LABELS = "/roger/ground_truth/labels"
ROIS = "/roger/rois"
LEFT_ROI_MARKERS = "/roger/left/roi_markers"
RIGHT_ROI_MARKERS = "/roger/right/roi_markers"
GOAL = "/roger/goal"
MEMORY_REQUEST = "/roger/memory/request"
MEMORY_RESULT = "/roger/memory/result"
MEMORY_LEARNED = "/roger/memory/learned"
POLICY_STATE = "/roger/policy_state"
METRICS = "/roger/metrics"
SPATIAL_MAP = "/roger/spatial_map"
MAP_MARKERS = "/roger/spatial_map/markers"
VIEW = "/roger/view"
WORLD_EDIT = "/roger/world_edit"
DIAGNOSTICS = "/diagnostics"
#: Service of the simulator: add / remove / move an object (as WORLD_EDIT, with a reply).
EDIT_WORLD_SERVICE = "/roger/edit_world"


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
    Topic(CLOCK, "rosgraph_msgs/Clock", "reliable", "sim", "all (use_sim_time)",
          "simulated time, advanced by each executed goal"),
    Topic(LEFT_IMAGE, "sensor_msgs/Image", "images", "sim", "perception",
          "left retina, 32FC1 intensity in [0, 1], Phong-lit"),
    Topic(RIGHT_IMAGE, "sensor_msgs/Image", "images", "sim", "perception",
          "right retina"),
    Topic(LEFT_INFO, "sensor_msgs/CameraInfo", "images", "sim",
          "perception, attention", "left intrinsics"),
    Topic(RIGHT_INFO, "sensor_msgs/CameraInfo", "images", "sim", "-",
          "right intrinsics, P carries -f*baseline"),
    Topic(FOVEA_IMAGE, "sensor_msgs/Image", "images", "sim", "perception",
          "after a visual improvement: the left eye's fovea (30 degrees at 192 px)",
          per_cycle=False),
    Topic(FOVEA_INFO, "sensor_msgs/CameraInfo", "images", "sim",
          "perception", "the fovea's intrinsics", per_cycle=False),
    Topic(FOVEA_RIGHT_IMAGE, "sensor_msgs/Image", "images", "sim", "perception",
          "with the fovea: the right eye's (the same intrinsics), for depth layers",
          per_cycle=False),
    Topic(STEREO_GEOMETRY, "roger_interfaces/StereoGeometry", "images", "sim",
          "perception, attention", "eye poses of each stereo pair (verging eyes)"),
    Topic(JOINT_STATES, "sensor_msgs/JointState", "reliable", "sim", "-",
          "neck, eye and arm joints after each goal"),
    Topic(TF, "tf2_msgs/TFMessage", "reliable", "sim", "-",
          "TF of the neck, eye and arm joints after each goal (as robot_state_publisher)"),
    Topic(TF_STATIC, "tf2_msgs/TFMessage", "latched", "sim", "-",
          "fixed frames: world -> roger_base, wrists, fingertips, eyes' optical frames"),
    Topic(ROBOT_DESCRIPTION, "std_msgs/String", "latched", "sim", "-",
          "Roger's URDF, generated from the simulator's pybullet body (roger_sim.urdf)"),
    Topic(CONTROLLER_STATUS, "roger_interfaces/ControllerStatus", "reliable", "sim",
          "-", "status of the five servo controllers"),
    Topic(CONVERGENCE, "roger_interfaces/ConvergenceEvent", "reports", "sim",
          "monitor (evaluation only)",
          "a goal finished: converged or failed, sim time and physics steps"),
    Topic(HAPTIC, "roger_interfaces/HapticReading", "reliable", "sim", "perception",
          "what an arm felt (weight) in a haptic improvement", per_cycle=False),
    Topic(GROUND_TRUTH, "roger_interfaces/GroundTruth", "latched", "sim",
          "monitor (evaluation only)", "the world's objects and poses"),
    Topic(GROUND_TRUTH_LABELS, "roger_interfaces/GroundTruthLabels", "labels", "sim",
          "monitor (evaluation only)", "which object each retina pixel shows"),
    Topic(ROIS, "roger_interfaces/RoiArray", "reliable", "perception", "attention",
          "ROIs of each stereo pair: features (eqs. 1-5), position, activation"),
    Topic(LEFT_ROI_MARKERS, "visualization_msgs/ImageMarker", "images", "perception", "-",
          "the ROIs' outlines over the left retina (its image's stamp), green once mapped"),
    Topic(RIGHT_ROI_MARKERS, "visualization_msgs/ImageMarker", "images", "perception", "-",
          "the same outlines over the right retina, moved by each ROI's stereo disparity"),
    Topic(GOAL, "roger_interfaces/ActionGoal", "reliable", "attention", "sim",
          "physical action of a control cycle"),
    Topic(MEMORY_REQUEST, "roger_interfaces/MemoryRequest", "reliable", "attention",
          "memory", "match or store a feature vector"),
    Topic(MEMORY_RESULT, "roger_interfaces/MemoryResult", "reliable", "memory",
          "attention", "identified / new / undetermined, address, confidence"),
    Topic(MEMORY_LEARNED, "roger_interfaces/MemoryResult", "latched", "memory", "-",
          "the last object stored in long-term memory", per_cycle=False),
    Topic(POLICY_STATE, "roger_interfaces/PolicyState", "reports", "attention",
          "monitor", "each cycle: state bits, action, reward, TD error, focus"),
    Topic(METRICS, "roger_interfaces/Metrics", "reports", "attention", "monitor",
          "Table 2 counters as the run goes"),
    Topic(SPATIAL_MAP, "roger_interfaces/SpatialMap", "latched", "attention",
          "perception", "the pre-attentional map: positions, mapping status, interest"),
    Topic(MAP_MARKERS, "visualization_msgs/MarkerArray", "latched",
          "attention", "-", "the map drawn in the world frame: entries by mapping status, "
          "interest bars, the focus, the last identified or stored address"),
    Topic(VIEW, "sensor_msgs/Image", "images", "view (roger run --view)", "-",
          "retinas side by side, ROIs, attention window, state, counters", per_cycle=False),
    Topic(WORLD_EDIT, "roger_interfaces/WorldEdit", "reliable", "user", "sim",
          "add / remove / move an object while running (also service /roger/edit_world)",
          per_cycle=False),
    Topic(DIAGNOSTICS, "diagnostic_msgs/DiagnosticArray", "reliable", "every node",
          "orchestrator", "heartbeat of a node started by its main (roger_common.liveness): "
          "pid, host, longest gap; a node silent for 8 s is restarted", per_cycle=False),
)
