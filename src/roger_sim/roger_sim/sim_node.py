"""ROS node around the pybullet simulator: goals in, retinas, controller status and clock out.

Run alone: ``roger-sim --ros-args -p world:=worlds/table1.yaml`` (or ``python -m
roger_sim.sim_node``; from a colcon install space ``ros2 run roger_sim roger-sim``). Topics
are listed in the README's node-graph table.

A relative ``world`` not found from the working directory is looked up where roger_sim keeps
the shipped worlds (``resolve_world``), so the default ``worlds/table1.yaml`` loads from any
directory.

Resuming after a crash (docs/reliability.md): when the orchestrator sets ``ROGER_STATE_DIR``,
the node writes ``sim.json`` there atomically after every goal and world edit: the world as
it stands (objects moved at run time included) and the physics step count. A restarted node
renders that world and goes on from that simulated time, so stamps never run backwards.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from roger_common import conversions as common
from roger_common import topics
from roger_common.atomic import atomic_write_bytes, sync_file
from roger_common.configdoc import take_live_fields
from roger_common.errors import MessageError, RogerError
from roger_common.ros_node import (
    IMAGES,
    LABELS,
    LATCHED,
    RELIABLE,
    REPORTS,
    BadInput,
    declare_config,
    spin_node,
)
from roger_common.types import Action, StereoFrame
from roger_interfaces.msg import (
    ActionGoal,
    ControllerStatus,
    ConvergenceEvent,
    GroundTruth,
    GroundTruthLabels,
    HapticReading,
    StereoGeometry,
    WorldEdit,
)
from roger_interfaces.srv import EditWorld
from roger_sim import conversions as conv
from roger_sim.config import SimConfig, SimNodeConfig
from roger_sim.simulator import Simulator
from roger_sim.tf_tree import joint_transforms, static_transforms
from roger_sim.urdf import describe_model, to_urdf
from roger_sim.world import load_world, object_from_dict, parse_world, resolve_world, world_to_dict

#: Eye separation (metres), for the right CameraInfo's projection matrix.
BASELINE = 0.16
#: Environment variable naming the folder of the resume state (set by the orchestrator).
STATE_DIR_ENV = "ROGER_STATE_DIR"
class SimNode(Node):
    """Owns one Simulator; executes each ActionGoal and publishes what Roger then senses."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("roger_sim", **kwargs)
        self.node_config = declare_config(self, SimNodeConfig)
        self.config = declare_config(self, SimConfig, apply=self._reconfigure)
        world_path = resolve_world(self.node_config.world)
        self.world = load_world(world_path)
        state_dir = os.environ.get(STATE_DIR_ENV, "")
        self.state_path = Path(state_dir) / "sim.json" if state_dir else None
        saved = self._load_state()
        world = saved[0] if saved is not None else self.world
        self.sim = Simulator(world, self.config, seed=self.node_config.seed,
                             start_steps=saved[1] if saved is not None else 0)
        self._last_goal_id = -1
        self._last_frame: StereoFrame | None = None
        self._map_revision = 0
        self._last_haptic_msg: HapticReading | None = None
        self._wall_start = time.monotonic()
        self.bad_input = BadInput(self)

        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, RELIABLE)
        self.pub_left = self.create_publisher(Image, topics.LEFT_IMAGE, IMAGES)
        self.pub_right = self.create_publisher(Image, topics.RIGHT_IMAGE, IMAGES)
        self.pub_left_info = self.create_publisher(CameraInfo, topics.LEFT_INFO, IMAGES)
        self.pub_right_info = self.create_publisher(CameraInfo, topics.RIGHT_INFO,
                                                    IMAGES)
        self.pub_fovea = self.create_publisher(Image, topics.FOVEA_IMAGE, IMAGES)
        self.pub_fovea_right = self.create_publisher(Image, topics.FOVEA_RIGHT_IMAGE, IMAGES)
        self.pub_fovea_info = self.create_publisher(CameraInfo, topics.FOVEA_INFO,
                                                    IMAGES)
        self.pub_geometry = self.create_publisher(StereoGeometry, topics.STEREO_GEOMETRY,
                                                  IMAGES)
        self.pub_joints = self.create_publisher(JointState, topics.JOINT_STATES, RELIABLE)
        self.pub_status = self.create_publisher(ControllerStatus, topics.CONTROLLER_STATUS,
                                                RELIABLE)
        self.pub_convergence = self.create_publisher(ConvergenceEvent, topics.CONVERGENCE,
                                                     REPORTS)
        self.pub_haptic = self.create_publisher(HapticReading, topics.HAPTIC, RELIABLE)
        self.pub_truth = self.create_publisher(GroundTruth, topics.GROUND_TRUTH, LATCHED)
        self.pub_labels = self.create_publisher(GroundTruthLabels, topics.GROUND_TRUTH_LABELS,
                                                LABELS)
        # The robot model and its TF tree (roger_sim.urdf, roger_sim.tf_tree).
        self.description = describe_model(self.sim.robot)
        self.pub_robot = self.create_publisher(String, topics.ROBOT_DESCRIPTION, LATCHED)
        self.pub_tf_static = self.create_publisher(TFMessage, topics.TF_STATIC, LATCHED)
        self.pub_tf = self.create_publisher(TFMessage, topics.TF, RELIABLE)
        self.create_subscription(ActionGoal, topics.GOAL, self.on_goal, RELIABLE)
        self.create_subscription(WorldEdit, topics.WORLD_EDIT, self.on_world_edit, RELIABLE)
        self.create_service(EditWorld, topics.EDIT_WORLD_SERVICE, self.on_edit_world)
        self._publish_clock()
        self._publish_ground_truth()
        self.pub_robot.publish(conv.robot_description_msg(to_urdf(self.description)))
        self.pub_tf_static.publish(conv.tf_msg(static_transforms(self.description),
                                               self.sim.sim_time))
        self._publish_tf(*self.sim.joint_state()[:2], self.sim.sim_time)
        self.get_logger().info(
            f"world {world_path}: {len(self.world.objects)} objects; waiting for goals")

    # -- goals ---------------------------------------------------------------------------
    def on_goal(self, msg: ActionGoal) -> None:
        """Execute a goal (or re-send the frame of a goal already executed)."""
        try:
            goal = common.msg_to_goal(msg)
        except MessageError as exc:
            self.bad_input.drop(topics.GOAL, exc)
            return
        # A goal id seen again is a retry after a lost reply: re-send, do not re-execute.
        # Goal 0 is the initial look, which may be asked for repeatedly.
        if goal.goal_id > 0 and goal.goal_id == self._last_goal_id \
                and self._last_frame is not None:
            self.get_logger().warn(f"goal {goal.goal_id} received again: re-sending its frame")
            if self._last_haptic_msg is not None:
                self.pub_haptic.publish(self._last_haptic_msg)
            self._publish_frame(self._last_frame)
            return
        try:
            report, frame = self.sim.run_goal(goal)
        except (RogerError, ValueError) as exc:
            self.get_logger().error(f"goal {goal.goal_id} refused: {exc}")
            return
        self._save_state()
        stamp = self.sim.sim_time
        self._pace(stamp)
        self._last_goal_id, self._last_frame = goal.goal_id, frame
        self._map_revision = int(msg.map_revision)
        self._last_haptic_msg = None
        # What perception waits for goes first (the haptic reading, then the frame): the
        # rest is for observers and would only delay the control cycle.
        if goal.action == Action.HAPTIC_IMPROVEMENT and frame.haptic is not None:
            self._last_haptic_msg = common.haptic_msg(frame.haptic, goal.goal_id, stamp)
            self.pub_haptic.publish(self._last_haptic_msg)
        self._publish_frame(frame)
        self._publish_clock()
        self.pub_status.publish(conv.controller_status_msg(report.states, stamp))
        self.pub_convergence.publish(conv.convergence_msg(report, goal.action, stamp))
        names, pos, vel, eff = self.sim.joint_state()
        self.pub_joints.publish(conv.joint_state_msg(names, pos, vel, eff, stamp))
        self._publish_tf(names, pos, stamp)
        if self._last_haptic_msg is not None:
            self._publish_ground_truth()

    def _reconfigure(self, new: SimConfig) -> None:
        """A live parameter change (``realtime``): pacing starts from now when it turns on."""
        config = take_live_fields(self.sim.config, new)
        if config.realtime and not self.sim.config.realtime:
            self._wall_start = time.monotonic() - self.sim.sim_time
        self.sim.reconfigure(config)
        self.config = config

    def _pace(self, sim_time: float) -> None:
        """In real-time mode, hold the results until the wall clock has caught up."""
        if self.config.realtime:
            lag = sim_time - (time.monotonic() - self._wall_start)
            if lag > 0:
                time.sleep(min(lag, 5.0))

    def _publish_frame(self, frame: StereoFrame) -> None:
        stamp = frame.stamp
        self.pub_left_info.publish(common.camera_info_msg(frame.camera, stamp, common.LEFT_FRAME,
                                                        BASELINE, right=False))
        self.pub_right_info.publish(common.camera_info_msg(frame.camera, stamp, common.RIGHT_FRAME,
                                                         BASELINE, right=True))
        if frame.fovea is not None and frame.fovea_camera is not None:
            self.pub_fovea_info.publish(common.camera_info_msg(
                frame.fovea_camera, stamp, common.FOVEA_FRAME, 0.0, right=False))
            self.pub_fovea.publish(common.image_msg(frame.fovea, stamp, common.FOVEA_FRAME))
            if frame.fovea_right is not None:
                self.pub_fovea_right.publish(common.image_msg(frame.fovea_right, stamp,
                                                              common.FOVEA_RIGHT_FRAME))
        self.pub_geometry.publish(common.stereo_geometry_msg(frame, self._map_revision))
        self.pub_left.publish(common.image_msg(frame.left, stamp, common.LEFT_FRAME))
        self.pub_right.publish(common.image_msg(frame.right, stamp, common.RIGHT_FRAME))
        # After the frame: the monitor keeps labels by stamp and holds a frame's
        # PolicyState until they arrive (monitor_logic.RunMonitor.flush).
        labels = conv.ground_truth_labels_msg(frame)
        if labels is not None:
            self.pub_labels.publish(labels)

    def _publish_tf(self, names: list[str], positions: list[float], stamp: float) -> None:
        """/tf of the movable joints, from the joint state just read."""
        self.pub_tf.publish(conv.tf_msg(joint_transforms(self.description, names, positions),
                                        stamp))

    def _publish_clock(self) -> None:
        msg = Clock()
        msg.clock = common.seconds_to_time(self.sim.sim_time)
        self.pub_clock.publish(msg)

    def _publish_ground_truth(self) -> None:
        self.pub_truth.publish(conv.ground_truth_msg(
            self.world.name, self.sim.world.objects, self.sim.object_poses(), self.sim.sim_time))

    # -- world edits ---------------------------------------------------------------------
    def apply_edit(self, edit: WorldEdit) -> str:
        """Apply one edit; returns what was done. Raises RogerError/KeyError/ValueError."""
        obj = edit.object
        if edit.op == WorldEdit.ADD:
            spec = object_from_dict(conv.msg_to_object_dict(obj), "world_edit", "object")
            self.sim.add_object(spec)
            done = f"added {obj.name}"
        elif edit.op == WorldEdit.REMOVE:
            self.sim.remove_object(obj.name)
            done = f"removed {obj.name}"
        elif edit.op == WorldEdit.MOVE:
            self.sim.move_object(obj.name, (obj.x, obj.y), obj.yaw)
            done = f"moved {obj.name} to ({obj.x:.2f}, {obj.y:.2f})"
        else:
            raise ValueError(f"unknown world edit op {edit.op} (0 add, 1 remove, 2 move)")
        self._publish_ground_truth()
        self._save_state()
        return done

    # -- resuming after a restart ------------------------------------------------------
    def _save_state(self) -> None:
        """Write the current world and step count atomically (only with ROGER_STATE_DIR)."""
        if self.state_path is not None:
            state = {"world": world_to_dict(self.sim.world), "steps": self.sim.physics_steps}
            # Not fsynced: this sits on every cycle's critical path (sync_file at exit).
            atomic_write_bytes(self.state_path, json.dumps(state).encode(), durable=False)

    def _load_state(self) -> tuple[Any, int] | None:
        """The saved world and step count, or None (no state, or an unusable one)."""
        if self.state_path is None or not self.state_path.exists():
            return None
        try:
            state = json.loads(self.state_path.read_text())
            world = parse_world(state["world"], str(self.state_path))
            steps = int(state["steps"])
        except (OSError, ValueError, KeyError, TypeError, RogerError) as exc:
            self.get_logger().error(f"resume state ignored, starting from the world file: "
                                    f"{exc}")
            return None
        self.get_logger().warn(f"resuming at step {steps} with the world of {self.state_path}")
        return world, steps

    def on_world_edit(self, msg: WorldEdit) -> None:
        """Topic form of a world edit: errors are logged, the node goes on."""
        try:
            self.get_logger().info(self.apply_edit(msg))
        except (RogerError, KeyError, ValueError) as exc:
            self.bad_input.drop(topics.WORLD_EDIT, _reason(exc))

    def on_edit_world(self, request: EditWorld.Request,
                      response: EditWorld.Response) -> EditWorld.Response:
        """Service form of a world edit: the reply says whether it was applied and why not."""
        try:
            response.message = self.apply_edit(request.edit)
            response.ok = True
        except (RogerError, KeyError, ValueError) as exc:
            response.ok, response.message = False, _reason(exc)
        return response

    def destroy_node(self) -> None:
        """Disconnect the simulator with the node; flush the resume state to the disk."""
        sync_file(self.state_path)
        self.sim.close()
        super().destroy_node()


def _reason(exc: Exception) -> str:
    """Why an edit was refused, one line (a KeyError's str() would be its message's repr)."""
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return " ".join(text.splitlines())


def main(args: list[str] | None = None) -> None:
    """Entry point of ``roger-sim``."""
    spin_node(SimNode, "roger-sim", args)

if __name__ == "__main__":
    main()
